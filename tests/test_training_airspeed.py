"""Task airspeed-source: the AirspeedSource-v0 env, a short `ftcgym train` run that loads and acts
deterministically as `LearnedAirspeedPolicy`, and the shipped `learned-airspeed` policy."""
import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import ftcgym  # noqa: F401
from ftcgym.cli import main
from ftcgym.task_envs.airspeed_source import (
    N_FEATURES,
    AirspeedSourceEnv,
    airspeed_features,
    airspeed_reward,
    blend,
    to_weight,
)
from ftcgym.training.config import builtin_tasks, load_config
from ftcgym.training.policy import LearnedAirspeedPolicy

pytest.importorskip("stable_baselines3")

# The detector armed 2 s after the EKF starts (not 20 s) and faults a few seconds later: seconds per episode.
FAST_DETECTOR = {"detection_delay": 2.0}
FAST_TASK = {"onset": [5.0, 7.0], "horizon_seconds": 2.0, "action_repeat": 5, "detector_kwargs": FAST_DETECTOR}


def _fast_env(**kwargs) -> AirspeedSourceEnv:
    return AirspeedSourceEnv(**{**FAST_TASK, **kwargs})


def test_builtin_config():
    assert "airspeed-source" in builtin_tasks()
    config = load_config("airspeed-source")
    assert (config.algo, config.env_id, config.n_envs) == ("PPO", "ftcgym/AirspeedSource-v0", 1)
    assert config.env_kwargs["action_repeat"] == 10 and config.eval["scenario"] == "qp-pitot-incipient"


def test_env_passes_checkers_starts_armed_and_is_reproducible():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("ftcgym/AirspeedSource-v0", **FAST_TASK)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=True)
    assert env.observation_space.shape == (N_FEATURES,)
    kinds = set()
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        again, info2 = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, again)
        assert info == info2
        kinds.add(info["fault"])
        # the agent starts on the first armed step: the EKF started on take-off, +2 s
        assert 2.0 < info["armed_time"] < 5.0 and 5.0 <= info["onset_time"] <= 7.0
        assert set(obs[12:].tolist()) <= {0.0, 1.0} and obs[12:].sum() == 1.0   # the mission phase, one-hot
        assert obs[11] == 0.0                         # the previous weight starts on the pitot
    assert len(kinds) > 1
    env.close()


def test_env_blends_at_each_step_and_rewards_the_truth():
    env = _fast_env(fault_mix={"zero": 1.0})
    obs, info = env.reset(seed=3)
    assert info["fault"] == "zero"
    rewards, weights = [], []
    while True:
        # the pitot until 0.2 s after the onset, then the EKF airspeed
        action = np.array([1.0 if info["time"] > info["onset_time"] + 0.2 else -1.0], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append((info["time"], reward))
        weights.append(info["weight"])
        if terminated or truncated:
            break
    assert truncated and info["time"] == pytest.approx(info["onset_time"] + 2.0, abs=0.06)
    assert weights[-1] == 1.0 and obs[11] == 1.0
    assert info["airspeed_used"] == pytest.approx(float(env._obs["fdd/airdata_ekf/airspeed"][0]), abs=1.0)
    # a zero reading fed just after the onset costs reward against the truth; the EKF airspeed less
    stuck_on_zero = [r for t, r in rewards if info["onset_time"] + 0.05 < t <= info["onset_time"] + 0.2]
    assert stuck_on_zero and max(stuck_on_zero) < 0.5
    with pytest.raises(ValueError, match="action"):
        env.step(np.array([np.nan]))
    env.close()


def test_reward_weight_blend_and_validation():
    assert airspeed_reward(18.0, 18.0, False) == 1.0
    assert airspeed_reward(17.0, 18.0, False) == pytest.approx(0.9)
    assert airspeed_reward(15.0, 18.0, False) == pytest.approx(1.0 - 0.3 - 0.5)   # outside the 2 m/s tolerance
    assert airspeed_reward(0.0, 18.0, False) == pytest.approx(-0.5)
    assert airspeed_reward(18.0, 18.0, True) == -100.0
    assert (to_weight([-1.0]), to_weight([0.0]), to_weight([1.0]), to_weight([7.0])) == (0.0, 0.5, 1.0, 1.0)
    obs = {"pitot_airspeed": np.array([10.0]), "fdd/airdata_ekf/airspeed": np.array([18.0])}
    assert blend(obs, 0.25)[0] == pytest.approx(12.0)
    for kwargs, field in (({"fault_mix": {"ice": 1.0}}, "fault_mix"), ({"fault_mix": {"zero": -1.0}}, "fault_mix"),
                          ({"onset": [10.0, 5.0]}, "onset"), ({"incipient_rate": [0.0, 2.0]}, "incipient_rate"),
                          ({"wind_speed": "calm"}, "wind_speed"), ({"horizon_seconds": 0.0}, "horizon_seconds"),
                          ({"action_repeat": 2.5}, "action_repeat"),
                          ({"max_episode_seconds": -1.0}, "max_episode_seconds")):
        with pytest.raises(ValueError, match=field):
            AirspeedSourceEnv(**kwargs)


def _fly_benchmark_env(policy, seconds=8.0, seed=0):
    """Fly QuadPlaneAutopilot-v0 (pitot zeroed at 5 s, detector armed after 2 s) with `policy`; the fed airspeeds."""
    from ftcgym.benchmark.runner import policy_view
    from ftcgym.fdd import wrap_with_detector

    env = wrap_with_detector("airdata_ekf", gym.make(
        "ftcgym/QuadPlaneAutopilot-v0", max_episode_seconds=seconds,
        faults=[{"kind": "pitot_blockage", "time": 5.0}]).unwrapped, **FAST_DETECTOR)
    obs, info = env.reset(seed=seed)
    policy.reset(obs, policy_view(info, policy))
    fed, engaged_at = [], None
    while True:
        action = policy.act(obs, policy_view(info, policy))
        if engaged_at is None and policy.engaged:
            engaged_at = info["time"]
        fed.append(float(action[0]))
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            env.close()
            return np.array(fed), engaged_at


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("train_airspeed")
    document = yaml.safe_load(Path(load_config("airspeed-source").source).read_text())
    body = document["airspeed-source"]
    body["env_kwargs"].update(FAST_TASK)
    body["eval"] = None
    body["checkpoint_freq"] = 1024
    body["PPO"].update(n_timesteps=1024, n_steps=256, batch_size=64, n_epochs=2, policy_kwargs={"net_arch": [16, 16]})
    config = tmp_path / "fast.yaml"
    config.write_text(yaml.safe_dump(document))
    out = tmp_path / "run"
    assert main(["train", "--config", str(config), "--seed", "4", "--out", str(out), "--no-progress"]) == 0
    return out


def test_short_training_run_loads_and_acts_deterministically(trained):
    from ftcgym.fdd import wrap_with_detector
    from ftcgym.training.policy import load_policy

    manifest = json.loads((trained / "manifest.json").read_text())
    assert manifest["steps"] >= 1024 and manifest["config"]["env_id"] == "ftcgym/AirspeedSource-v0"
    assert manifest["seed"] == 4 and manifest["wall_time_s"] > 0
    env = wrap_with_detector("airdata_ekf", gym.make("ftcgym/QuadPlaneAutopilot-v0").unwrapped)
    first, second = load_policy(trained, env), load_policy(trained / "model.zip", env)
    assert isinstance(first, LearnedAirspeedPolicy) and first.action_repeat == 5   # the task's decision rate
    features = np.random.default_rng(0).uniform(-1, 1, (6, N_FEATURES)).astype(np.float32)
    actions = np.array([first.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [first.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [second.predict(f) for f in features])
    assert actions.shape == (6, 1) and len(np.unique(actions)) > 1      # it reads its input
    fed, engaged_at = _fly_benchmark_env(first)
    again, _ = _fly_benchmark_env(second)
    np.testing.assert_array_equal(fed, again)                           # same flight, same airspeeds fed
    assert engaged_at is not None and 2.0 < engaged_at < 5.0             # the model flies once the detector is armed
    env.close()


def test_policy_feeds_the_pitot_until_the_detector_is_armed(trained):
    policy = LearnedAirspeedPolicy.load(trained)
    obs = {"pitot_airspeed": np.array([3.0]), "fdd/airdata_ekf/airspeed": np.array([9.0])}
    info = {"time": 1.0, "fdd": {"airdata_ekf": {"detection_armed": False}}}
    policy.reset()
    assert policy.act(obs, info)[0] == 3.0 and not policy.engaged
    with pytest.raises(ValueError, match="airdata_ekf"):
        policy.act(obs, {"time": 1.0})


def test_shipped_learned_airspeed_loads_and_is_deterministic():
    from ftcgym.agents import make_policy
    from ftcgym.fdd import wrap_with_detector
    from ftcgym.training.shipped import shipped_path

    folder = shipped_path("learned-airspeed")
    manifest = json.loads((folder / "manifest.json").read_text())
    for key in ("command", "seed", "steps", "wall_time_s", "git_commit"):
        assert manifest[key] is not None, key
    assert manifest["config"]["env_id"] == "ftcgym/AirspeedSource-v0"
    assert sum(f.stat().st_size for f in folder.iterdir() if f.is_file()) < 300_000
    env = wrap_with_detector("airdata_ekf", gym.make("ftcgym/QuadPlaneAutopilot-v0").unwrapped)
    first, second = make_policy("learned-airspeed", env), make_policy("learned-airspeed", env)
    assert isinstance(first, LearnedAirspeedPolicy) and first.action_repeat == manifest["config"]["env_kwargs"][
        "action_repeat"]
    features = np.random.default_rng(1).uniform(-1, 1, (8, N_FEATURES)).astype(np.float32)
    actions = [first.predict(f) for f in features]
    np.testing.assert_array_equal(actions, [second.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [first.predict(f) for f in features])
    # What it learnt: in cruise, a pitot reading zero beside an EKF airspeed of 18 m/s and a latched pitot alarm
    # -> (nearly) all EKF airspeed.
    cruise = {"pitot_airspeed": np.array([0.0]), "fdd/airdata_ekf/airspeed": np.array([18.0]),
              "gnss_velocity": np.array([18.0, 0.0, 0.0]), "skew": np.array([np.pi / 2]),
              "mission_phase": np.array([3.0])}
    status = {"pitot_residual": -18.0, "pitot_residual_derivative": 0.0, "cusum_statistic": 18.0,
              "pitot_alarm": True, "pitot_alarm_time": 44.0, "time": 46.0, "innovation_alarms": {}}
    assert to_weight(first.predict(airspeed_features(cruise, status, 1.0))) > 0.9
    env.close()


@pytest.mark.parametrize("kwargs, message", [
    ({"fault_mx": {}}, "gym.make keyword: unknown ['fault_mx'] (did you mean 'fault_mix'?)"),
    ({"horizon_seconds": "5"}, "horizon_seconds: expected a number > 0, got str '5'"),
    ({"turbulence": "storm"}, "wind turbulence: unknown preset 'storm'"),
    ({"detector_kwargs": {"wind_boost": float("nan")}}, "airdata_ekf.wind_boost: must be finite"),
])
def test_the_airspeed_task_checks_its_keywords_at_make(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make("ftcgym/AirspeedSource-v0", **kwargs)


@pytest.mark.parametrize("substep", [1, 5])
def test_a_crash_gives_the_whole_penalty_whatever_the_substep(substep):
    from test_training import crash_on_substep
    env = _fast_env()
    env.reset(seed=0)
    crash_on_substep(env, substep)
    _, reward, terminated, truncated, info = env.step(np.array([0.0]))
    assert (reward, terminated, truncated) == (-100.0, True, False)   # was -100 / the substeps run
    env.close()

