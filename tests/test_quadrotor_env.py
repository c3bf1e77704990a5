"""Quadrotor-v0's Gymnasium contract: check_env, seeding, info, faults and bad input."""
import warnings

import numpy as np
import pytest
from conftest import LIGHT_WIND, hover_command, make_env
from gymnasium.utils.env_checker import check_env

from ftcgym.agents import make_policy
from ftcgym.models import FaultSpec
from ftcgym.models.tasks import make_task


def test_gymnasium_check_env():
    env = make_env(wind=LIGHT_WIND, faults="random:rotor_loss")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        check_env(env.unwrapped, skip_render_check=True)


def test_sb3_check_env():
    """SB3's checker passes; its only remark is the advice to use [-1, 1] actions, while the contract
    (docs/concepts.md) fixes Box(0, 1) rotor commands (training wraps the env with gymnasium's RescaleAction)."""
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(make_env(wind=LIGHT_WIND).unwrapped, warn=True)
    remarks = [str(w.message) for w in caught if "symmetric and normalized Box action space" not in str(w.message)]
    assert remarks == []


def _rollout(seed: int, steps: int, env=None):
    env = env or make_env(wind=LIGHT_WIND, faults=[{"kind": "loe", "target": 1, "time": 3.0, "rate": 0.1}],
                          max_episode_seconds=60)
    obs, info = env.reset(seed=seed)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    out = []
    for _ in range(steps):
        obs, reward, term, trunc, info = env.step(policy.act(obs, info))
        out.append(np.concatenate([*obs.values(), [reward]]))
        assert not term
    return np.array(out)


def test_same_seed_bit_identical_over_5000_steps_and_seeds_differ():
    a = _rollout(7, 5000)
    b = _rollout(7, 5000)
    assert np.array_equal(a, b)
    assert not np.array_equal(a[:100], _rollout(8, 100))


def test_reset_restores_the_world_exactly():
    """A second episode with the same seed on the same env repeats the first (the world is rebuilt on reset)."""
    env = make_env(wind=LIGHT_WIND, max_episode_seconds=60)
    first = _rollout(3, 500, env)
    _rollout(4, 300, env)
    assert np.array_equal(first, _rollout(3, 500, env))


def test_observation_space_matches_and_info_contract():
    env = make_env(faults=[{"kind": "rotor_loss", "target": 2, "time": 0.01}], wind=LIGHT_WIND)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert {"gyro", "accel", "attitude", "position", "velocity", "rotor_speed"} <= set(obs)
    assert info["time"] == 0.0 and info["fault"]["onset_time"] is None and info["fault"]["active"] is False
    assert info["faults"] == [{"kind": "rotor_loss", "target": 2, "time": 0.01, "magnitude": 1.0,
                               "rate": None, "duration": None}]
    truth_keys = {"position", "velocity", "attitude", "body_rates", "wind", "airspeed", "mass", "rotor_effectiveness"}
    assert truth_keys <= set(info["truth"])
    cmd = np.full(4, hover_command(env.unwrapped.params), dtype=np.float32)
    obs, _, _, _, info2 = env.step(cmd)
    obs, _, _, _, info3 = env.step(cmd)
    assert info3 is not info2 and info3["truth"] is not info2["truth"] and info3["fault"] is not info2["fault"]
    for _ in range(5):
        obs, _, _, _, info = env.step(cmd)
    assert info["fault"] == {"active": True, "kind": "rotor_loss", "target": 2, "onset_time": 0.01, "magnitude": 1.0}
    assert info["truth"]["rotor_effectiveness"].tolist() == [1.0, 1.0, 0.0, 1.0]
    assert np.isclose(info["time"], 7 / 500)


def test_random_fault_is_drawn_from_the_seed():
    env = make_env(faults="random:rotor_loss")
    draws = [env.reset(seed=s)[1]["faults"][0] for s in range(20)]
    assert all(2.0 <= d["time"] <= 5.0 for d in draws)
    assert {d["target"] for d in draws} == {0, 1, 2, 3}
    assert env.reset(seed=5)[1]["faults"] == env.reset(seed=5)[1]["faults"]


def _truth_at(faults, times, seconds=8.0):
    """Fly hover under the nominal controller; truth (effectiveness, mass) at the given times."""
    env = make_env(faults=faults, max_episode_seconds=seconds)
    obs, info = env.reset(seed=0)
    policy = make_policy("nominal", env)
    seen = {}
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs, info))
        t = round(info["time"], 3)
        if t in times:
            seen[t] = (info["truth"]["rotor_effectiveness"].copy(), info["truth"]["mass"])
        if term or trunc:
            return seen, info


def test_loe_ramp_follows_002():
    """002 Sec. 5.2: a 0.1/s ramp capped at 0.5 on the pitch pair; the controller keeps flying."""
    seen, info = _truth_at([FaultSpec("loe", target=[0, 1], time=1.0, magnitude=0.5, rate=0.1)], (2.0, 7.0))
    assert np.allclose(seen[2.0][0], [0.9, 0.9, 1, 1]) and np.allclose(seen[7.0][0], [0.5, 0.5, 1, 1])
    assert not info["crashed"]


def test_payload_ramp_follows_004():
    """004 Sec. 5.1: +0.5 kg over 2 s."""
    seen, info = _truth_at([{"kind": "payload", "time": 1.0, "magnitude": 0.5, "duration": 2.0}], (2.0, 7.0))
    assert np.isclose(seen[2.0][1], 0.374 + 0.25) and np.isclose(seen[7.0][1], 0.874)
    assert not info["crashed"]


@pytest.mark.parametrize("kind", ["sensor_bias", "sensor_stuck", "sensor_dropout"])
def test_sensor_faults(kind):
    env = make_env(faults=[{"kind": kind, "target": "gyro", "time": 0.1, "magnitude": 0.3} if kind == "sensor_bias"
                           else {"kind": kind, "target": "gyro", "time": 0.1}],
                   sensors={"gyro_noise": 0.0, "gyro_vibration": 0.0, "gyro_bias": 0.0})
    env.reset(seed=0)
    cmd = np.full(4, hover_command(env.unwrapped.params), dtype=np.float32)
    cmd[0] += 0.02  # a slow roll/pitch, so the true rates change while a stuck gyro does not
    readings = []
    for _ in range(100):
        obs, _, _, _, info = env.step(cmd)
        readings.append((obs["gyro"].copy(), info["truth"]["body_rates"]))
    after = readings[60:]
    if kind == "sensor_bias":
        assert all(np.allclose(g - r, 0.3) for g, r in after)
    elif kind == "sensor_dropout":
        assert all(np.all(g == 0) for g, _ in after)
    else:
        assert all(np.array_equal(g, after[0][0]) for g, _ in after)
        assert not np.allclose(after[-1][1], after[0][1])


@pytest.mark.parametrize("faults, field", [
    ([{"kind": "rotor_los", "target": 0}], "faults[0].kind"),
    ([{"kind": "rotor_loss", "target": 4}], "faults[0].target"),
    ([{"kind": "rotor_loss", "target": 1, "time": -1}], "faults[0].time"),
    ([{"kind": "rotor_loss", "target": 1, "time": float("nan")}], "faults[0].time"),
    ([{"kind": "rotor_loss", "target": 1, "onset": 2}], "faults[0] key: unknown ['onset']"),
    ([{"kind": "loe", "target": 1, "magnitude": 1.5}], "faults[0].magnitude"),
    ([{"kind": "sensor_bias", "target": "compass"}], "faults[0].target"),
    ("random:icing", "faults[0]"),
    (42, "faults"),
])
def test_malformed_fault_specs_name_the_field(faults, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        make_env(faults=faults)


@pytest.mark.parametrize("kwargs, field", [
    ({"vehicle": "bebop3"}, "vehicle"),
    ({"vehicle_overrides": {"mass_kg": 1.0}}, "vehicle_overrides"),
    ({"vehicle_overrides": {"mass": float("nan")}}, "vehicle_overrides"),
    ({"wind": {"mean": [1, 2]}}, "mean"),
    ({"wind": {"turbulence": "hurricane"}}, "turbulence"),
    ({"task": "loop"}, "task"),
    ({"task": {"name": "square", "speed": float("inf")}}, "task"),
    ({"physics_hz": 500, "agent_hz": 300}, "agent_hz"),
    ({"max_episode_seconds": 0}, "max_episode_seconds"),
    ({"sensors": {"gyro_noise": -1}}, "sensors"),
])
def test_bad_constructor_arguments_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        make_env(**kwargs)


def test_bad_actions_raise_and_never_reach_the_physics():
    env = make_env()
    env.reset(seed=0)
    base = env.unwrapped
    for bad in ([0.5, 0.5, 0.5], [0.5, np.nan, 0.5, 0.5], [np.inf, 0.5, 0.5, 0.5]):
        with pytest.raises(ValueError, match="action"):
            env.step(np.array(bad, dtype=np.float32))
    assert base.time == 0.0  # nothing advanced
    assert np.all(np.isfinite(base.rotors.omega))


def test_out_of_range_actions_are_clipped():
    a, b = make_env(), make_env()
    a.reset(seed=0)
    b.reset(seed=0)
    oa, *_ = a.step(np.array([1.7, -3.0, 0.5, 0.5], dtype=np.float32))
    ob, *_ = b.step(np.array([1.0, 0.0, 0.5, 0.5], dtype=np.float32))
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)


def test_rgb_array_render():
    env = make_env(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8 and frame.std() > 1.0


def test_goto_task_steps_its_set_point_after_step_time_and_starts_at_the_first():
    task = make_task({"name": "goto", "altitude": 4.0, "north": 2.0, "step_north": 1.0, "step_east": -3.0,
                      "step_altitude": 1.5, "step_time": 1.0})
    np.testing.assert_allclose(task.reference(1.0).position, [2.0, 0.0, -4.0])
    np.testing.assert_allclose(task.reference(1.002).position, [3.0, -3.0, -5.5])
    assert not task.reference(5.0).velocity.any()
    assert task.extent() == {"horizontal": 3.0, "altitude": 5.5, "speed": 0.0}
    env = make_env(task="goto")          # default: (1, 1, 0) m right after the start
    try:
        obs, info = env.reset(seed=0)
        np.testing.assert_allclose(info["reference"]["position"], [0.0, 0.0, -5.0])
        assert np.linalg.norm(info["truth"]["position"] - [0.0, 0.0, -5.0]) < 0.1
        _, _, _, _, info = env.step(np.full(4, 0.5))
        np.testing.assert_allclose(info["reference"]["position"], [1.0, 1.0, -5.0])
    finally:
        env.close()
