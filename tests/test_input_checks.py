"""Every input a user passes is checked at make or reset, with an error naming the field, the value and what
is accepted; a failed or dropped env holds no PyBullet client; a closed env says so."""
import contextlib
import gc
import os
import re
import warnings

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

import ftcgym  # noqa: F401  (registers the envs)
from ftcgym.envs.flight_env import FaultAfterEndWarning, check_display

Q, P, AUTOPILOT = "ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0", "ftcgym/QuadPlaneAutopilot-v0"


def connected_clients() -> int:
    return sum(p.isConnected(client) for client in range(4096))


@pytest.mark.parametrize("env_id, overrides, message", [
    (Q, {"mass": 0}, "vehicle_overrides['mass']: must be > 0, got 0"),
    (Q, {"mass": -1}, "vehicle_overrides['mass']: must be > 0"),
    (Q, {"thrust_coefficient": -1e-6}, "vehicle_overrides['thrust_coefficient']: must be > 0"),
    (Q, {"motor_time_constant": 0}, "vehicle_overrides['motor_time_constant']: must be > 0"),
    (Q, {"unloaded_time_constant": 0}, "vehicle_overrides['unloaded_time_constant']: must be > 0"),
    (Q, {"inertia": [-1e-3, 1e-3, 1e-3]}, "vehicle_overrides['inertia']: must be > 0"),
    (Q, {"omega_min": 1300.0}, "omega_min must be below omega_max"),
    (Q, {"body_size": [0, 0.2, 0.1]}, "vehicle_overrides['body_size']: must be > 0"),
    (Q, {"body_drag": [-1, 0, 0]}, "vehicle_overrides['body_drag']: must be >= 0"),
    (Q, {"max_rotor_acceleration": -1}, "vehicle_overrides['max_rotor_acceleration']: must be > 0"),
    (Q, {"unloaded_speed_ratio": 0.5}, "vehicle_overrides['unloaded_speed_ratio']: must be >= 1"),
    (Q, {"mass": "1.0"}, "vehicle_overrides['mass']: expected a number > 0, got '1.0'"),
    (Q, {"mass": True}, "vehicle_overrides['mass']: expected a number > 0, got True"),
    (Q, {"inertia": [1e-3, 1e-3]}, "vehicle_overrides['inertia']: expected 3 numbers, got shape (2,)"),
    (Q, {"mass": float("nan")}, "vehicle_overrides['mass']: must be finite"),
    (P, {"hover_time_constant": 0}, "vehicle_overrides['hover_time_constant']: must be > 0"),
    (P, {"pusher_resistance": 0}, "vehicle_overrides['pusher_resistance']: must be > 0"),
    (P, {"air_density": -1}, "vehicle_overrides['air_density']: must be > 0"),
    (P, {"wing_area": -1}, "vehicle_overrides['wing_area']: must be > 0"),
    (P, {"battery_voltage": 0}, "vehicle_overrides['battery_voltage']: must be > 0"),
    (P, {"hover_yaw_signs": [1, -1, 0.5, -1]}, "hover_yaw_signs and pusher_spin_direction must each be -1 or +1"),
    (P, {"transition_start_speed": 20.0}, "transition_start_speed must be below transition_end_speed"),
    (Q, {"mass": 5e-324}, "vehicle_overrides['mass']: 5e-324 is more than 1000 times off the parameter set's "
                          "magnitude; accepted magnitudes 0.000374 to 374"),
    (Q, {"mass": 1e308}, "vehicle_overrides['mass']: 1e+308 is more than 1000 times off"),
    (Q, {"thrust_coefficient": 1e308}, "vehicle_overrides['thrust_coefficient']: 1e+308 is more than 1000 times off"),
    (Q, {"body_drag": [1e308, 0, 0]}, "vehicle_overrides['body_drag']: [1e+308, 0.0, 0.0] is more than 1000 times off"),
    (Q, {"rotational_drag": [0.0, 0.0, 3.0]}, "accepted magnitudes 1e-07 to 2.75"),   # bebop2's 0: mueller2014's
    (P, {"pusher_diameter": 1e150}, "vehicle_overrides['pusher_diameter']: 1e+150 is more than 1000 times off"),
    (P, {"wing_span": 5e-324}, "vehicle_overrides['wing_span']: 5e-324 is more than 1000 times off"),
])
def test_vehicle_overrides_out_of_range_fail_at_make(env_id, overrides, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make(env_id, vehicle_overrides=overrides)


def test_vehicle_overrides_out_of_range_fail_at_reset_too():
    env = gym.make(Q)
    with pytest.raises(ValueError, match=re.escape("reset options: vehicle_overrides['mass']: must be > 0")):
        env.reset(seed=0, options={"vehicle_overrides": {"mass": 0.0}})
    env.close()


@pytest.mark.parametrize("fault, message", [
    ({"kind": "sensor_bias", "target": "gyro", "magnitude": [1, 2]}, "faults[0].magnitude: expected 3 numbers"),
    ({"kind": "sensor_bias", "target": "gyro", "magnitude": "x"}, "faults[0].magnitude: expected a number"),
    ({"kind": "payload", "magnitude": -0.5}, "the payloads take the mass to -0.126 kg (vehicle 0.374 kg)"),
    ({"kind": "payload", "magnitude": 1e308}, "the payloads take the mass to 1e+308 kg (vehicle 0.374 kg); accepted: "
                                              "payloads that keep the mass above 0 and at most 1000 times"),
    ({"kind": "loe", "target": 0, "magnitude": 0.0}, "faults[0].magnitude: must be in (0, 1], got 0.0"),
    ({"kind": "rotor_loss", "target": 0, "magnitude": 0.5}, "rotor_loss is a total loss, so its magnitude is 1"),
    ({"kind": "loe", "target": [0, 0]}, "faults[0].target: [0, 0] is not accepted for loe"),
    ({"kind": "sensor_dropout", "target": "gyro", "magnitude": 2.0}, "sensor_dropout takes no magnitude"),
    ({"kind": "loe", "target": 0, "rate": "fast"}, "faults[0].rate: expected a number > 0"),
    ({"kind": "loe", "target": 9}, "faults[0].target: 9 is not accepted for loe"),
    ({"kind": ["loe"]}, "faults[0].kind: ['loe'] is not a fault kind"),
])
def test_fault_specs_are_checked_against_the_channel_and_the_physics(fault, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make(Q, faults=[fault])


def test_a_sensor_bias_of_the_channels_shape_is_applied_and_saturates_at_the_space():
    env = gym.make(Q, faults=[{"kind": "sensor_bias", "target": "gyro", "magnitude": [0.0, 0.0, 1e6]}])
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.full(4, 0.5))
    assert obs["gyro"][2] == env.observation_space["gyro"].high[2]
    assert env.observation_space.contains(obs)
    env.close()


def test_random_sensor_fault_draws_its_channel_from_the_seed():
    env = gym.make(Q, faults="random:sensor_bias")
    targets = {env.reset(seed=seed)[1]["faults"][0]["target"] for seed in range(12)}
    assert targets <= {"gyro", "accel", "attitude", "position", "velocity", "rotor_speed"} and len(targets) >= 3
    env.close()


def test_info_reports_the_mass_and_effectiveness_the_physics_applies():
    env = gym.make(Q, faults=[{"kind": "payload", "magnitude": -0.2},
                              {"kind": "loe", "target": [1, 2], "magnitude": 0.5}])
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.full(4, 0.5))
    base = env.unwrapped
    mass = p.getDynamicsInfo(base.world.body, -1, physicsClientId=base.world.client)[0]
    assert info["truth"]["mass"] == pytest.approx(0.174) == pytest.approx(mass)
    assert info["truth"]["rotor_effectiveness"].tolist() == [1.0, 0.5, 0.5, 1.0]
    env.close()


def test_a_sensor_fault_is_inactive_once_its_duration_has_ended():
    env = gym.make(Q, agent_hz=100, faults=[{"kind": "sensor_dropout", "target": "gyro", "time": 0.1,
                                             "duration": 0.2}])
    env.reset(seed=0)
    seen = []
    for _ in range(40):
        obs, _, _, _, info = env.step(np.full(4, 0.5))
        seen.append((round(info["time"], 2), info["fault"]["active"], info["fault"]["onset_time"],
                     bool(np.all(obs["gyro"] == 0))))
    assert {s[1:] for s in seen if s[0] < 0.1} == {(False, None, False)}
    assert {s[1:] for s in seen if 0.1 <= s[0] < 0.29} == {(True, 0.1, True)}
    assert {s[1:] for s in seen if s[0] > 0.31} == {(False, 0.1, False)}
    assert all(active == dropped for _, active, _, dropped in seen)   # info says what the readings get
    env.close()


@pytest.mark.parametrize("env_id, kwargs, message", [
    (Q, {"max_episode_seconds": "10"}, "max_episode_seconds: expected a number > 0, got str '10'"),
    (Q, {"max_episode_seconds": None}, "max_episode_seconds: expected a number > 0, got NoneType None"),
    (Q, {"sensors": {"gyro_noise": "0.1"}}, "sensors['gyro_noise']: expected a number in [0, 1e+06], got str"),
    (Q, {"sensors": {"position_hz": 0}}, "sensors['position_hz']: must be in [0.001, 1e+06], got 0"),
    (Q, {"sensors": [1, 2]}, "sensors: expected a dict"),
    (Q, {"wind": {"mean": [1e6, 0, 0]}}, "wind mean: its speed must be <= 50 m/s"),
    (Q, {"wind": {"turbulence": {"sigmas": [1, 1, 1], "lengths": [0.001, 1, 1]}}}, "wind lengths: must be in [1,"),
    (Q, {"physics_hz": 1e7, "agent_hz": 1}, "physics_hz: must be in [50, 20000], got 10000000.0"),
    (Q, {"physics_hz": 10000, "agent_hz": 1}, "agent_hz: physics_hz / agent_hz must be a whole number in [1, 1000]"),
    (Q, {"physics_hz": "500"}, "physics_hz: expected a number in [50, 20000], got str '500'"),
    (Q, {"task": {"name": "hover", "altitude": 500}}, "task: its altitude reaches 500, beyond this env's limit 100"),
    (Q, {"task": {"name": "hover", "yaw": 7}}, "task['yaw']: must be in [-3.14159, 3.14159], got 7"),
    (Q, {"task": {"name": "square", "excitation": 1}}, "task['excitation']: expected True or False, got 1"),
    (Q, {"task": ["hover"]}, "task: unknown task ['hover']"),
    (Q, {"vehicle": ["bebop2"]}, "vehicle: unknown parameter set ['bebop2']"),
    (AUTOPILOT, {"task": "square"}, "task: the autopilot flies a mission; accepted: 'mission'"),
    (Q, {"task": "mission"}, "task: QuadrotorEnv does not fly 'mission'; accepted: ['hover', 'goto', 'square']"),
    (Q, {"task": {"name": "goto", "step_time": -1}}, "task['step_time']: must be >= 0, got -1"),
    (Q, {"task": {"name": "goto", "step_altitude": -5}}, "task['step_altitude']: the set-point after the step must be"),
    (Q, {"task": {"name": "goto", "step_north": 200}}, "task: its horizontal reaches 200, beyond this env's limit 100"),
    (Q, {"vehical": "bebop2"},
     "gym.make keyword: unknown ['vehical'] (did you mean 'vehicle'?); accepted: ['agent_hz'"),
    (AUTOPILOT, {"wnd": {}}, "gym.make keyword: unknown ['wnd'] (did you mean 'wind'?)"),
])
def test_other_inputs_fail_at_make_naming_the_field(env_id, kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make(env_id, **kwargs)


@pytest.mark.parametrize("kwargs, message", [
    ({"faults": [{"kind": "loe", "target": 0, "time": 40}]},
     "faults[0].time: 40.0 s is not before the episode's end (max_episode_seconds = 30); the fault may not act"),
    ({"faults": "random:rotor_loss", "max_episode_seconds": 3}, "faults[0].time: (2.0, 5.0) s is not before"),
])
def test_a_fault_that_may_begin_after_the_episode_is_warned_about(kwargs, message):
    with pytest.warns(FaultAfterEndWarning, match=re.escape(message)):
        gym.make(Q, **kwargs).close()


def test_bad_reset_options_name_the_option():
    env = gym.make(Q)
    with pytest.raises(ValueError, match=re.escape("reset options: expected a dict")):
        env.reset(seed=0, options=["faults"])
    with pytest.raises(ValueError, match=re.escape("reset options: faults[0].target: 7 is not accepted")):
        env.reset(seed=0, options={"faults": [{"kind": "rotor_loss", "target": 7}]})
    with pytest.raises(ValueError, match=re.escape("reset options: faults: the payloads take the mass to")):
        env.reset(seed=0, options={"faults": [{"kind": "payload", "magnitude": -1.0}]})
    env.close()


@pytest.mark.parametrize("action", [np.zeros(4, complex), np.array(["0.5"] * 4), np.array([True] * 4),
                                    [0.5, None, 0.5, 0.5]])
def test_actions_that_are_not_real_numbers_are_refused(action):
    env = gym.make(Q)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action: expected real numbers"):
        env.step(action)
    assert env.unwrapped.time == 0.0
    env.close()


@pytest.mark.parametrize("dtype", [np.longdouble, np.float16, np.int64])
def test_actions_of_any_real_dtype_fly_as_their_float64_values(dtype):
    observations = []
    for action in (np.full(4, 1, dtype=dtype), np.full(4, 1.0)):
        env = gym.make(Q)
        env.reset(seed=0)
        observations.append(env.step(action)[0])
        env.close()
    assert all(np.array_equal(observations[0][key], observations[1][key]) for key in observations[1])


@pytest.mark.parametrize("env_id", [Q, AUTOPILOT, "ftcgym/RotorLossRecovery-v0", "ftcgym/AirspeedSource-v0"])
def test_step_and_reset_after_close_say_the_env_is_closed(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    env.close()
    with pytest.raises(RuntimeError, match="step: this env is closed"):
        env.step(env.action_space.sample())
    with pytest.raises(RuntimeError, match="reset: this env is closed"):
        env.reset(seed=0)


def rss_mib() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_failed_makes_hold_no_client_and_dropped_envs_release_theirs():
    before, rss_before = connected_clients(), rss_mib()
    bad = [{"faults": [{"kind": "loe", "target": 9}]}, {"sensors": {"gyro_noise": -1}},
           {"vehicle_overrides": {"omega_max": -1.0}}]
    for i in range(300):
        with contextlib.suppress(ValueError):
            gym.make(Q, **bad[i % 3])
    with contextlib.suppress(ValueError):
        gym.make(AUTOPILOT, task="square")
    assert connected_clients() == before
    assert rss_mib() - rss_before < 100.0          # each leaked client held ~34 MiB before
    envs = [gym.make(Q) for _ in range(50)]
    assert connected_clients() == before + 50
    del envs
    gc.collect()
    assert connected_clients() == before


def test_human_render_without_a_display_raises_before_connecting(monkeypatch):
    before = connected_clients()
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match=re.escape("render_mode='human': no display (DISPLAY='')")):
        gym.make(Q, render_mode="human")
    monkeypatch.setenv("DISPLAY", ":4321")           # no server listens there
    with pytest.raises(RuntimeError, match="the display ':4321' does not answer"):
        check_display()
    assert connected_clients() == before


@pytest.mark.parametrize("detector, env_id, message", [
    ("airdata_ekf", "ftcgym/Quadrotor-v0", "detector 'airdata_ekf': runs on the quad-plane (QuadPlane-v0, "
                                           "QuadPlaneAutopilot-v0), not on QuadrotorEnv (parameter set 'bebop2')"),
    ("propulsion_bayes", "ftcgym/Quadrotor-v0", "detector 'propulsion_bayes': runs on the quad-plane"),
    ("loe_kalman", "ftcgym/QuadPlane-v0", "detector 'loe_kalman': runs on the quadrotor (Quadrotor-v0), not on "
                                          "QuadPlaneEnv (parameter set 'vsqp')"),
    ("loe_cusum", "ftcgym/QuadPlane-v0", "detector 'loe_cusum': runs on the quadrotor"),
    ("aekf", "ftcgym/QuadPlaneAutopilot-v0", "detector 'aekf': runs on the quadrotor"),
    ("iv_change", "ftcgym/QuadPlane-v0", "detector 'iv_change': runs on the quadrotor"),
])
def test_a_detector_on_the_other_vehicle_says_which_it_runs_on(detector, env_id, message):
    from ftcgym.fdd import wrap_with_detector
    env = gym.make(env_id)
    with pytest.raises(ValueError, match=re.escape(message)):
        wrap_with_detector(detector, env)
    env.close()


def test_a_detector_moved_to_another_vehicle_or_rate_says_what_it_was_made_for():
    from ftcgym.fdd import DetectorWrapper, wrap_with_detector
    detector = wrap_with_detector("loe_kalman", gym.make("ftcgym/Quadrotor-v0")).detector
    DetectorWrapper(gym.make("ftcgym/Quadrotor-v0"), detector)          # another env of the same vehicle: fine
    with pytest.raises(ValueError, match=re.escape("detector 'loe_kalman' was made for bebop2 at 500 Hz; this env "
                                                   "flies mueller2014 at 500 Hz")):
        DetectorWrapper(gym.make("ftcgym/Quadrotor-v0", vehicle="mueller2014"), detector)
    with pytest.raises(ValueError, match="made for bebop2 at 500 Hz; this env flies bebop2 at 250 Hz"):
        DetectorWrapper(gym.make("ftcgym/Quadrotor-v0", agent_hz=250.0), detector)


def test_a_detector_needs_the_time_in_info():
    from ftcgym.fdd import wrap_with_detector
    with pytest.raises(ValueError, match=r"reads info\['time'\], which info_level='none' leaves out"):
        wrap_with_detector("loe_kalman", gym.make(Q, info_level="none"))
    env = wrap_with_detector("loe_kalman", gym.make(Q, info_level="minimal"))
    _, info = env.reset(seed=0)
    assert info["fdd"]["loe_kalman"]["alarm"] is False
    env.close()


@pytest.mark.parametrize("kwargs, message", [
    ({"observation_format": "flat"}, "observation_format: QuadPlaneAutopilot-v0 takes only 'dict'"),
    ({"info_level": "minimal"}, "info_level: QuadPlaneAutopilot-v0 takes only 'full'"),
])
def test_the_autopilot_env_refuses_what_its_autopilot_cannot_fly_with(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make(AUTOPILOT, **kwargs)


@pytest.mark.parametrize("policy, make, message", [
    ("nominal", lambda: gym.make(Q, observation_format="flat"),
     "policy: 'nominal' reads the observation by name: make the env with observation_format='dict'"),
    ("autopilot", lambda: gym.make("ftcgym/QuadPlane-v0", observation_format="flat"),
     "policy: 'autopilot' reads the observation by name"),
    ("ftc-spin", lambda: gym.make("ftcgym/RotorLossRecovery-v0"),
     "policy: 'ftc-spin' flies Quadrotor-v0, QuadPlane-v0 or QuadPlaneAutopilot-v0, not RotorLossRecoveryEnv"),
    ("nominal", lambda: None, "policy: 'nominal' flies Quadrotor-v0, QuadPlane-v0 or QuadPlaneAutopilot-v0, not "
                              "NoneType"),
])
def test_a_built_in_policy_says_which_envs_it_flies(policy, make, message):
    from ftcgym.agents import make_policy
    with pytest.raises(ValueError, match=re.escape(message)):
        make_policy(policy, make())


def test_a_step_after_the_end_warns_once_until_a_reset():
    from ftcgym.envs.flight_env import StepAfterEndWarning
    env = gym.make("ftcgym/Quadrotor-v0", max_episode_seconds=0.01)
    env.reset(seed=0)
    hover = np.full(4, 0.6, dtype=np.float32)
    for _ in range(5):
        _, _, terminated, truncated, _ = env.step(hover)
    assert truncated and not terminated
    with pytest.warns(StepAfterEndWarning, match="call reset"):
        env.step(hover)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.step(hover)                      # once per episode
        env.reset(seed=1)
        env.step(hover)                      # a new episode: no warning
    env.close()
