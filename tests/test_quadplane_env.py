"""QuadPlane-v0 and QuadPlaneAutopilot-v0: the Gymnasium contract, determinism, bad input, the
faults' effect on what the vehicle senses, and the autopilot flying the mission."""
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import ftcgym  # noqa: F401
from ftcgym.agents import make_policy
from ftcgym.benchmark.runner import roll_out, score_episode
from ftcgym.envs.flight_env import PHYSICS_HZ
from ftcgym.envs.quadplane import QuadPlaneEnv

IDS = ("ftcgym/QuadPlane-v0", "ftcgym/QuadPlaneAutopilot-v0")


def hover_action(env) -> np.ndarray:
    """Hover-rotor commands that carry the weight, everything else neutral."""
    p = env.unwrapped.params
    command = (p.hover_omega - p.hover_omega_min) / (p.hover_omega_max - p.hover_omega_min)
    return np.array([command] * 4 + [0.0, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_gymnasium_and_sb3(env_id):
    check_env(gym.make(env_id, max_episode_seconds=2.0).unwrapped, skip_render_check=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(gym.make(env_id, max_episode_seconds=2.0).unwrapped)
    # The contract (docs/concepts.md) fixes the action spaces (commands in [0, 1] and [-1, 1]; an airspeed in m/s)
    assert [str(w.message) for w in caught if "symmetric and normalized Box" not in str(w.message)] == []


def test_same_seed_same_trajectory_other_seed_differs():
    def fly(seed):
        env = gym.make("ftcgym/QuadPlane-v0", wind={"mean": [2.0, 1.0, 0.0], "turbulence": "light"})
        policy = make_policy("autopilot", env)
        obs, info = env.reset(seed=seed)
        policy.reset(obs, info)
        for _ in range(600):    # take-off, 6 s
            obs, *_, info = env.step(policy.act(obs, info))
        return np.concatenate([info["truth"]["position"], info["truth"]["attitude"], obs["gyro"]])

    assert np.array_equal(fly(3), fly(3))
    assert not np.allclose(fly(3), fly(4))


def test_bad_input_names_the_field():
    env = gym.make("ftcgym/QuadPlane-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action: expected shape \\(9,\\)"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="action: must be finite"):
        env.step(np.full(9, np.nan))
    with pytest.raises(ValueError, match="vehicle_overrides.*wing_span_typo"):
        gym.make("ftcgym/QuadPlane-v0", vehicle_overrides={"wing_span_typo": 2.0})
    with pytest.raises(ValueError, match="not a fault kind of this vehicle"):
        gym.make("ftcgym/QuadPlane-v0", faults=[{"kind": "payload"}])
    autopilot = gym.make("ftcgym/QuadPlaneAutopilot-v0")
    autopilot.reset(seed=0)
    with pytest.raises(ValueError, match="airspeed must be finite"):
        autopilot.step(np.array([np.inf]))


def open_loop_cruise_roll_rate(physics_hz: float, airspeed: float) -> float:
    """|p| after 1 s of trimmed wings-level cruise at `airspeed`, controls held, a 0.2 rad/s roll-rate start."""
    from ftcgym.agents.quadplane_trim import trim
    from ftcgym.models.geometry import quat_from_euler
    from ftcgym.models.pusher import throttle_for_speed
    env = gym.make("ftcgym/QuadPlane-v0", task={"name": "hover", "altitude": 5.0}, physics_hz=physics_hz,
                   agent_hz=50.0).unwrapped
    p = env.params
    point = trim(p, airspeed)
    alpha = point["alpha"]
    env.reset(seed=0)
    env.world.reset(np.array([0.0, 0.0, -200.0]), quat_from_euler(0.0, alpha, 0.0), np.array([airspeed, 0.0, 0.0]),
                    np.array([0.2, 0.0, 0.0]))
    env._read_state()
    env._motion[0], env._motion[2] = math.pi / 2, point["elevator"]
    forward = airspeed * math.cos(alpha)
    env.pusher.reset(point["pusher_omega"], forward)
    action = np.zeros(9, dtype=np.float32)
    action[4] = throttle_for_speed(p, point["pusher_omega"], forward)
    action[6], action[8] = point["elevator"] / p.surface_limit[1], 1.0
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(action)
    env.close()
    return abs(info["truth"]["body_rates"][0])


def test_the_stiff_roll_mode_needs_250_hz_physics(monkeypatch):
    with pytest.raises(ValueError, match=r"physics_hz: must be in \[250, 20000\], got 200"):
        gym.make("ftcgym/QuadPlane-v0", physics_hz=200.0)
    assert open_loop_cruise_roll_rate(250.0, 26.0) < 0.2          # the roll is damped at the lowest rate
    monkeypatch.setattr(QuadPlaneEnv, "PHYSICS_HZ", PHYSICS_HZ)   # the range every env accepts
    assert open_loop_cruise_roll_rate(100.0, 22.0) > 10.0         # why: explicit loads diverge at 100 Hz


def test_rests_on_the_ground_nose_into_the_wind_and_hovers_on_the_trim_speed():
    env = gym.make("ftcgym/QuadPlane-v0", wind={"mean": [0.0, -4.0, 0.0], "turbulence": "none"})
    obs, info = env.reset(seed=0)
    x, y, z, w = info["truth"]["attitude"]
    heading = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    assert heading == pytest.approx(math.pi / 2, abs=0.03)       # the wind blows west: nose east, into it
    for _ in range(50):
        obs, _, terminated, _, info = env.step(np.zeros(9, np.float32))
    assert not terminated and abs(info["truth"]["position"][2] + 0.125) < 0.01   # resting, motors off
    # the four rotors at the trim speed carry 6.5 kg: after spin-up the vertical acceleration is ~0
    for _ in range(100):
        obs, _, _, _, info = env.step(hover_action(env))
    assert abs(obs["accel"][2] + 9.81) < 0.6 and abs(info["truth"]["velocity"][2]) < 0.5


def test_pitot_blockage_zero_and_incipient_and_gnss_fault_reach_the_observation():
    faults = [{"kind": "pitot_blockage", "time": 1.0}, {"kind": "gnss", "time": 1.0}]
    env = gym.make("ftcgym/QuadPlane-v0", faults=faults, wind={"mean": [0.0, 0.0, 0.0], "turbulence": "none"})
    env.reset(seed=0)
    env.unwrapped.world.reset(np.array([0.0, 0.0, -30.0]), np.array([0, 0, 0, 1.0]), np.array([15.0, 0, 0]),
                              np.zeros(3))
    env.unwrapped._read_state()
    readings = []
    for _ in range(150):
        obs, *_ = env.step(hover_action(env))
        readings.append((obs["pitot_airspeed"][0], obs["gnss_velocity"][0]))
    before, after = np.array(readings[60:95]), np.array(readings[105:])
    assert before[:, 0].mean() > 10 and before[:, 1].mean() > 10      # flying at ~15 m/s
    assert np.all(after == 0.0)
    incipient = gym.make("ftcgym/QuadPlane-v0", faults=[{"kind": "pitot_blockage", "time": 0.0, "rate": 2.5}])
    incipient.reset(seed=0)
    schedule = incipient.unwrapped._faults
    assert schedule.apply_to_pitot(2.0, 18.0) == pytest.approx(13.0)   # 001 Sec. 7.2.2: -2.5 m/s^2


def test_propeller_icing_raises_the_pusher_current_at_the_same_speed():
    """003's signature: with theta_1 up 10% the motor draws more current to hold the same speed."""
    def current(faults):
        env = gym.make("ftcgym/QuadPlane-v0", faults=faults, wind={"mean": [0.0, 0.0, 0.0], "turbulence": "none"})
        env.reset(seed=0)
        action = np.zeros(9, np.float32)
        action[4] = 0.6
        for _ in range(300):        # 3 s at a fixed throttle on the ground: the speed settles
            obs, *_, info = env.step(action)
        return info["truth"]["pusher"]

    nominal = current(None)
    iced = current([{"kind": "propeller_icing", "time": 0.0, "magnitude": 1.1, "duration": 1e-3}])
    assert iced["theta_1"] == pytest.approx(1.1)
    assert iced["omega"] < nominal["omega"]                    # more torque at the same voltage: slower
    assert iced["current"] > nominal["current"]


@pytest.fixture(scope="module")
def calm_mission():
    env = gym.make("ftcgym/QuadPlaneAutopilot-v0", wind={"mean": [0.0, 0.0, 0.0], "turbulence": "light"})
    log = roll_out(env, make_policy("oracle-airspeed", env), seed=11)
    return score_episode(log), log


def test_oracle_mission_completes_both_transitions_and_tracks_the_cruise_airspeed(calm_mission):
    scores, log = calm_mission
    assert scores["mission_complete"] and not scores["crashed"]
    assert log.skew.max() > math.radians(85) and log.skew[-1] < math.radians(5)    # out and back
    assert scores["time_forward_flight"] > 40.0 and scores["time_transition"] > 2.0
    assert scores["cruise_airspeed_rmse"] < 1.0                 # < 1 m/s
    assert scores["airspeed_error_rmse"] < 0.1                  # the oracle feeds the truth


def _cruise_entry_sag(seed: int, blend_time: float | None = None) -> tuple[float, float]:
    """Largest altitude drop (peak to trough, m) and sink rate (m/s) in the first 2 s of cruise, upwind in a 7 m/s
    wind, where the transition ends with the nose down and the wing short of the weight (truth)."""
    env = gym.make("ftcgym/QuadPlaneAutopilot-v0", wind={"mean": [5.0, 5.0, 0.0], "turbulence": "light"},
                   max_episode_seconds=32.0)
    if blend_time is not None:
        env.unwrapped.autopilot.gains.transition_blend_time = blend_time
    samples = []                                   # (time, in cruise, altitude, sink rate)
    roll_out(env, make_policy("oracle-airspeed", env), seed=seed, on_step=lambda obs, info: samples.append(
        (info["time"], info["mission"]["phase"] == "cruise", -info["truth"]["position"][2],
         info["truth"]["velocity"][2])))
    time, cruise, altitude, sink = np.array(samples, dtype=float).T
    entry = time[np.argmax(cruise > 0)]
    assert cruise.any() and 20.0 < entry < 30.0
    window = (time >= entry) & (time <= entry + 2.0)
    return float((np.maximum.accumulate(altitude[window]) - altitude[window]).max()), float(sink[window].max())


def test_the_rotors_hand_over_to_the_wing_without_a_dive_at_the_end_of_the_transition():
    """The hover rotors must keep carrying what the wing does not until the nose is up
    (AutopilotGains.transition_blend_time). On seeds 1-3 the hand-over gives drops of 0.28-0.40 m and sinks of
    0.48-0.68 m/s (means 0.36 m, 0.59 m/s); cut in one step (blend time 0), 0.46-0.68 m and 0.77-1.14 m/s
    (means 0.58 m, 0.94 m/s). Single flights overlap, so the means over the three are compared."""
    drops, sinks = zip(*(_cruise_entry_sag(seed) for seed in (1, 2, 3)))
    assert np.mean(drops) < 0.45 and np.mean(sinks) < 0.7


def test_the_cruise_entry_sag_check_fails_without_the_hand_over():
    drops, sinks = zip(*(_cruise_entry_sag(seed, blend_time=0.0) for seed in (1, 2, 3)))
    assert np.mean(drops) > 0.45 and np.mean(sinks) > 0.7


def test_cruise_in_a_strong_wind_keeps_the_nose_in_the_flow_and_the_altitude():
    """A 8.5 m/s mean wind, 100 s (about 1.5 laps of cruise). The build before the autopilot left the heading to
    the fin, took alpha from the path angle through the air and kept the rotors for what the wing cannot carry
    flew this one with sideslip up to 14.7 deg, the rudder at its 0.44 rad throw, the hover rotors switched on
    18 times after the hand-over (on 38% of the time), pitch rates up to 1.8 rad/s and the altitude 4.1 m off."""
    env = gym.make("ftcgym/QuadPlaneAutopilot-v0", wind={"mean": [6.0, 6.0, 0.0], "turbulence": "light"},
                   max_episode_seconds=100.0)
    rows = []                  # time, sideslip, rudder, pitch rate, altitude, fastest hover rotor in cruise (truth)
    roll_out(env, make_policy("oracle-airspeed", env), seed=2, on_step=lambda obs, info: rows.append(
        (info["time"], math.atan2(info["truth"]["air_velocity_body"][1], info["truth"]["air_velocity_body"][0]),
         info["truth"]["surfaces"][2], info["truth"]["body_rates"][1], -info["truth"]["position"][2],
         max(info["truth"]["rotor_speed"])))
        if info["mission"]["phase"] == "cruise" else None)
    time, sideslip, rudder, pitch_rate, altitude, rotor = np.array(rows).T
    assert len(rows) > 5000                        # > 50 s of cruise at 100 Hz
    assert math.degrees(np.abs(sideslip).max()) < 7.0
    assert np.abs(rudder).max() < 0.5 * env.unwrapped.params.surface_limit[2]
    assert np.abs(pitch_rate).max() < 1.6 and np.abs(altitude - 30.0).max() < 1.5
    rotors_on = rotor[time > time[0] + 3.0] > 20.0             # rad/s, after the hand-over
    assert np.sum(np.diff(rotors_on.astype(int)) == 1) <= 3


def test_a_zero_pitot_in_cruise_degrades_pitot_only_against_the_oracle():
    kwargs = {"wind": {"mean": [0.0, 0.0, 0.0], "turbulence": "light"}, "max_episode_seconds": 70.0,
              "faults": [{"kind": "pitot_blockage", "time": 40.0}]}
    scores = {}
    for policy in ("pitot-only", "oracle-airspeed"):
        env = gym.make("ftcgym/QuadPlaneAutopilot-v0", **kwargs)
        scores[policy] = score_episode(roll_out(env, make_policy(policy, env), seed=5))
    pitot, oracle = scores["pitot-only"], scores["oracle-airspeed"]
    assert oracle["recovered"] and oracle["airspeed_error_rmse"] < 0.2
    assert not pitot["recovered"] and pitot["airspeed_error_rmse"] > 5.0
    # believing it has stopped, the autopilot retracts the wing and ends its forward flight early
    assert pitot["time_forward_flight"] < oracle["time_forward_flight"] - 10.0


def test_policies_refuse_the_wrong_env():
    with pytest.raises(ValueError, match="accepted: \\['autopilot'\\]"):
        make_policy("pitot-only", gym.make("ftcgym/QuadPlane-v0"))
    with pytest.raises(ValueError, match="pitot-only"):
        make_policy("nominal", gym.make("ftcgym/QuadPlaneAutopilot-v0"))


def test_trim_cli_prints_hover_and_forward_trims(capsys):
    """Hover with every rotor below 85% of its top speed; forward flight from the stall speed to
    22 m/s with the angle of attack in [0, 10] deg."""
    from ftcgym.cli import main

    assert main(["trim", "--airspeeds", "0", "13.6", "18", "22"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()[2:]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    hover, *forward = cells
    assert hover[1] == "hover" and float(hover[9]) < 85.0
    assert [row[1] for row in forward] == ["wing-borne"] * 3
    assert all(0.0 <= float(row[3]) <= 10.0 for row in forward)


def test_a_seeded_reset_steps_the_same_whatever_ran_before():
    """The vehicle starts on the ground: Bullet's contact caches survived restoreState, so the first episode
    after construction stepped differently from later ones (accel differed by ~1e-2 m/s^2) and gymnasium's
    check_env failed at random, depending on the unseeded actions of its earlier checks."""
    env = gym.make("ftcgym/QuadPlane-v0", max_episode_seconds=2.0).unwrapped
    env.action_space.seed(123)
    action = env.action_space.sample()
    steps = []
    for _ in range(2):
        env.reset(seed=123)
        steps.append(env.step(action)[0])
        for _ in range(20):
            env.step(env.action_space.sample())            # leave a different history behind
    env.close()
    for key in steps[0]:
        np.testing.assert_array_equal(steps[0][key], steps[1][key], err_msg=key)


def test_turbulence_that_follows_the_vehicle_takes_its_speed_through_the_mean_wind():
    """`wind={"airspeed": "vehicle"}`: each agent step's Dryden V_a is the speed through the mean wind at the step's
    start (`DrydenWind.follow`), so in cruise it is the cruise airspeed, not the 5 m/s of the wind."""
    mean = np.array([3.0, 4.0, 0.0])
    env = gym.make("ftcgym/QuadPlaneAutopilot-v0", max_episode_seconds=60.0,
                   wind={"mean": mean.tolist(), "turbulence": "light", "airspeed": "vehicle"})
    wind = env.unwrapped.plane.wind
    rows, speed_before = [], [5.0]                 # V_a used, |v - mean| at the step's start, airspeed, cruising
    def record(obs, info):
        rows.append((wind.airspeed, speed_before[0], info["truth"]["airspeed"], info["mission"]["phase"] == "cruise"))
        speed_before[0] = float(np.linalg.norm(info["truth"]["velocity"] - mean))
    log = roll_out(env, make_policy("oracle-airspeed", env), seed=4, on_step=record)
    used, expected, airspeed, cruise = np.array(rows).T
    np.testing.assert_allclose(used[1:], np.maximum(np.round(expected[1:], 1), 1.0), atol=1e-9)
    cruise = cruise.astype(bool)
    assert cruise.sum() > 2000 and not score_episode(log)["crashed"]
    assert abs(np.median(used[cruise]) - np.median(airspeed[cruise])) < 1.0 and np.median(used[cruise]) > 15.0
