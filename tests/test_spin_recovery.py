"""Spin recovery after a propeller loss: the controller, the ftc-spin / oracle-spin policies, and a
full flight: loss, detection, recovery, 10 s of position hold, landing."""
import numpy as np
import pytest
from conftest import make_env
from scipy.spatial.transform import Rotation

from ftcgym.agents import POLICIES, OracleSpinPolicy, SpinAfterAlarmPolicy, SpinRecoveryController, make_policy
from ftcgym.agents.spin_recovery import thrust_axis_reference_for
from ftcgym.benchmark import metrics
from ftcgym.fdd import wrap_with_detector
from ftcgym.models.quadrotor import GRAVITY


def test_spin_policies_are_registered():
    assert {"nominal", "ftc-spin", "oracle-spin"} <= set(POLICIES)
    env = wrap_with_detector("loe_kalman", make_env(vehicle="mueller2014"))
    assert isinstance(make_policy("ftc-spin", env), SpinAfterAlarmPolicy)
    oracle = make_policy("oracle-spin", env)
    assert isinstance(oracle, OracleSpinPolicy) and oracle.uses_true_onset


def _status(alarm: bool, isolated=None) -> dict:
    return {"fdd": {"loe_kalman": {"alarm": alarm, "alarm_time": 0.1 if alarm else None, "isolated": isolated}}}


def test_ftc_spin_flies_nominal_until_the_alarm_then_spins_without_the_isolated_rotor():
    env = make_env(vehicle="mueller2014")
    obs, info = env.reset(seed=0)
    policy = make_policy("ftc-spin", env)
    policy.reset(obs, info)
    policy.act(obs, {**info, **_status(False)})
    assert policy.spin.mode == "standby"
    command = policy.act(obs, {**info, **_status(True, 2)})
    assert policy.spin.mode == "hold" and policy.spin.failed_rotor == 2
    assert command[2] == 0.0                                    # the failed rotor idles
    with pytest.raises(ValueError, match="loe_kalman"):
        make_policy("ftc-spin", env).act(obs, info)             # no detector in info


def test_oracle_switches_at_the_true_onset_with_the_true_target():
    env = make_env(vehicle="mueller2014")
    obs, info = env.reset(seed=0)
    policy = make_policy("oracle-spin", env)
    policy.reset(obs, info)
    policy.act(obs, {**info, "oracle_onset_time": None, **_status(False)})
    assert policy.spin.mode == "standby"
    policy.act(obs, {**info, "time": 0.0, "oracle_onset_time": 0.0, "oracle_fault_target": 1, **_status(False)})
    assert policy.spin.failed_rotor == 1


def test_oracle_with_a_switch_delay_switches_that_long_after_the_onset():
    env = make_env(vehicle="mueller2014")
    obs, info = env.reset(seed=0)
    policy = make_policy("oracle-spin", env)
    policy.switch_delay = 0.02
    policy.reset(obs, info)
    for time, engaged in ((1.0, False), (1.019, False), (1.02, True)):
        policy.act(obs, {**info, "time": time, "oracle_onset_time": 1.0, "oracle_fault_target": 3, **_status(False)})
        assert (policy.spin.mode == "hold") is engaged, time


def test_thrust_axis_reference_is_within_the_primary_axis_error():
    """The reference is -z of the nearest attitude with the primary axis on target: on target it is the
    measured thrust axis, and it is never further from it than the primary axis is from its target."""
    rng = np.random.default_rng(0)
    n_target = np.array([0.19, 0.19, -0.96])
    n_target /= np.linalg.norm(n_target)
    for _ in range(50):
        R = Rotation.random(random_state=rng).as_matrix()
        assert thrust_axis_reference_for(R, n_target, n_target) == pytest.approx(-R[:, 2])
        n_body = Rotation.from_rotvec(rng.normal(0.0, 0.3, 3)).apply(n_target)
        axis_error = np.arccos(np.clip(n_body @ n_target, -1.0, 1.0))
        reference = thrust_axis_reference_for(R, n_body, n_target)
        assert np.linalg.norm(reference) == pytest.approx(1.0)
        assert np.arccos(np.clip(reference @ -R[:, 2], -1.0, 1.0)) <= axis_error + 1e-9
        assert reference @ (R @ n_body) == pytest.approx(-R[:, 2] @ (R @ n_target))   # same tilt from n_des


def test_controller_holds_the_relaxed_hover_it_starts_in(quiet_sensors):
    """Engaged at the equilibrium, the controller keeps the primary axis on target (< 1 deg) and the position."""
    failed = 3
    env = make_env(vehicle="mueller2014", faults=[{"kind": "rotor_loss", "target": failed, "time": 0.0}],
                   sensors=quiet_sensors, max_episode_seconds=5.0)
    env.reset(seed=0)
    u = env.unwrapped
    controller = SpinRecoveryController(u.params, u.agent_hz)
    eq = controller.equilibrium(failed)
    attitude = Rotation.align_vectors([[0.0, 0.0, -1.0]], [eq["n"]])[0]
    R = attitude.as_matrix()
    spin_world = R @ eq["body_rates"]
    accel = R @ np.array([0.0, 0.0, -eq["thrust"]]) / u.params.mass + np.array([0.0, 0.0, GRAVITY])
    circle_velocity = -np.cross(spin_world, accel) / (spin_world @ spin_world)
    u.world.reset(np.array([0.0, 0.0, -5.0]), attitude.as_quat(), circle_velocity, eq["body_rates"])
    u.rotors.omega[:] = eq["rotor_speeds"]
    u._read_state()
    obs = u._observe()
    controller.engage(failed, obs)
    for _ in range(1000):
        obs, _, _, _, info = env.step(controller.act(obs))
    axis = Rotation.from_quat(info["truth"]["attitude"]).apply(eq["n"])
    assert np.degrees(np.arccos(min(-axis[2], 1.0))) < 1.0
    assert np.linalg.norm(info["truth"]["position"] - [0.0, 0.0, -5.0]) < 0.1
    assert info["truth"]["body_rates"] == pytest.approx(eq["body_rates"], abs=0.3)


def test_recovers_holds_position_for_10_s_and_lands_softly():
    """mueller2014 loses r3's propeller in hover at 3 m: ftc-spin recovers (benchmark definition: altitude and
    thrust axis) within 1.5 s; the transient's tilt carries it up to ~2 m sideways, and it is back within 1 m of
    the set-point (0.8 m) 4 s after the loss. From there it holds the position within 1 m for 10 s, then lands,
    touching down slower than 1 m/s, without a crash."""
    env = wrap_with_detector("loe_kalman", make_env(
        vehicle="mueller2014", task={"name": "hover", "altitude": 3.0}, max_episode_seconds=30.0,
        faults=[{"kind": "rotor_loss", "target": 2, "time": 1.0}],
        wind={"mean": [0.0, 0.0, 0.0], "turbulence": "light"}))
    obs, info = env.reset(seed=5)
    policy = make_policy("ftc-spin", env)
    policy.reset(obs, info)
    world = env.unwrapped.world
    log = {"time": [], "attitude": [], "reference": [], "altitude": [], "error": []}
    recovered_at, touchdown_velocity = None, None
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs, info))
        truth = info["truth"]
        for key, value in (("time", info["time"]), ("attitude", truth["attitude"]),
                           ("reference", policy.thrust_axis_reference), ("altitude", -truth["position"][2]),
                           ("error", np.linalg.norm(truth["position"] - info["reference"]["position"]))):
            log[key].append(value)
        if recovered_at is None and info["time"] >= 4.0:
            axis_error = metrics.thrust_axis_error(np.array(log["attitude"]), np.array(log["reference"]))
            ok = metrics.hover_recovered(np.array(log["altitude"]), 3.0, axis_error)
            recovered_at = metrics.recovery_time(np.array(log["time"]), ok, 1.0)
            assert recovered_at is not None and recovered_at - 1.0 < 1.5
        if info["time"] >= 5.0 + 10.0 and policy.spin.mode == "hold":
            policy.land()
        if touchdown_velocity is None and world.touching_ground():
            touchdown_velocity = truth["velocity"].copy()
        if terminated or truncated or (policy.spin.mode == "landed" and touchdown_velocity is not None):
            break
    time, error = np.array(log["time"]), np.array(log["error"])
    back = time[np.argmax((time > recovered_at) & (error < 0.8))]
    assert back < 5.0
    hold = (time >= back) & (time < back + 10.0)
    assert time[hold][-1] - back > 9.9 and error[hold].max() < 1.0
    assert not info["crashed"] and policy.spin.mode == "landed"
    assert touchdown_velocity is not None and touchdown_velocity[2] < 1.0


def test_hover_rotor_loss_returns_to_the_set_point():
    """One seeded `quad-rotor-loss-hover` episode (a tuning seed): starting at the true onset the spin recovery
    drifts less than 0.7 m and is back within 0.5 m in 1.5 s; on the detector's alarm it recovers within 1.5 s,
    is back within 0.5 m in 2.5 s, within 0.2 m in 3.5 s, and loses less than 0.3 m of altitude."""
    from ftcgym.benchmark.runner import make_env as make_scenario_env
    from ftcgym.benchmark.runner import roll_out, score_episode
    from ftcgym.benchmark.scenarios import get_scenario
    scores = {}
    for name in ("ftc-spin", "oracle-spin"):
        env = make_scenario_env(get_scenario("quad-rotor-loss-hover"))
        scores[name] = score_episode(roll_out(env, make_policy(name, env), 1000, "loe_kalman"))
        env.close()
    ftc, oracle = scores["ftc-spin"], scores["oracle-spin"]
    assert not ftc["crashed"] and ftc["recovered"] and ftc["isolation_correct"]
    assert ftc["recovery_time"] - ftc["fault_onset"] < 1.5
    assert ftc["return_time_0_5m"] < 2.5 and ftc["return_time_0_2m"] < 3.5 and ftc["altitude_loss"] < 0.3
    assert ftc["final_position_error"] < 0.1
    assert not oracle["crashed"] and oracle["return_time_0_5m"] < 1.5 and oracle["max_position_error"] < 0.7


def test_commanded_axis_turns_no_faster_than_the_slew_limit():
    """A step of the outer loop's force direction reaches n_des at axis_slew_rate_deg: the inner loop can follow
    it (a moving set-point otherwise swings n_des faster than the spinning vehicle's axis, off the 10 deg band)."""
    env = make_env(vehicle="mueller2014")
    controller = SpinRecoveryController(env.unwrapped.params, env.unwrapped.agent_hz)
    rate = controller.gains.axis_slew_rate_deg
    up = np.array([0.0, 0.0, -1.0])
    tilted = np.array([np.sin(np.radians(20.0)), 0.0, -np.cos(np.radians(20.0))])
    assert np.allclose(controller._slew(up), up)                # the first command passes as it is
    steps = [controller._slew(tilted) for _ in range(int(0.5 * env.unwrapped.agent_hz))]
    angles = np.degrees(np.arccos(np.clip([-axis[2] for axis in steps], -1.0, 1.0)))
    assert angles[0] == pytest.approx(rate * controller.dt) and np.all(np.diff(angles) <= rate * controller.dt + 1e-9)
    assert np.allclose(steps[-1], tilted) and np.allclose(np.linalg.norm(steps, axis=1), 1.0)
