"""The training pipeline: configs, the rotor-loss-recovery task env, a short `ftcgym train` run
(model, VecNormalize statistics, checkpoints, benchmark evaluations, manifest), `LearnedPolicy` and
`ftcgym evaluate`. Kept short: a few thousand steps in all."""
import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import ftcgym  # noqa: F401
from ftcgym.benchmark.report import TERMINAL_FIELDS
from ftcgym.cli import main
from ftcgym.task_envs.rotor_loss_recovery import N_FEATURES, RotorLossRecoveryEnv
from ftcgym.training.config import builtin_tasks, load_config

pytest.importorskip("stable_baselines3")

FAST_TASK = {"onset": [0.5, 1.0], "horizon_seconds": 1.0, "action_repeat": 2}
SHORT_EVAL = {"max_episode_seconds": 3.0, "faults": [{"kind": "rotor_loss", "target": 1, "time": 1.0}]}


def _config(tmp_path, n_envs=1, steps=1024):
    """A copy of the built-in config, shrunk to seconds of training."""
    document = yaml.safe_load(Path(load_config("rotor-loss-recovery").source).read_text())
    body = document["rotor-loss-recovery"]
    body["env_kwargs"].update(FAST_TASK)
    body.pop("pretrain")                        # PPO alone here; tests/test_imitation.py covers DAgger
    body["checkpoint_freq"] = 512
    body["eval"] = {"scenario": "quad-rotor-loss-hover", "episodes": 1, "freq": 512, "env_kwargs": SHORT_EVAL}
    body["PPO"].update(n_envs=n_envs, n_timesteps=steps, n_steps=256, batch_size=64, n_epochs=2,
                       policy_kwargs={"net_arch": [32, 32], "activation_fn": "relu"})
    path = tmp_path / "fast.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("train")
    out = tmp_path / "run"
    assert main(["train", "--config", str(_config(tmp_path)), "--seed", "3", "--out", str(out),
                 "--no-progress"]) == 0
    return out


def test_builtin_config_and_overrides():
    assert "rotor-loss-recovery" in builtin_tasks()
    ppo = load_config("rotor-loss-recovery")
    assert (ppo.algo, ppo.env_id, ppo.policy) == ("PPO", "ftcgym/RotorLossRecovery-v0", "MlpPolicy")
    assert ppo.hyperparams["n_steps"] == 2048 and "n_envs" not in ppo.hyperparams
    sac = load_config("rotor-loss-recovery", algo="sac", n_envs=1, total_steps=10, seed=7)
    assert (sac.algo, sac.n_envs, sac.total_steps, sac.seed) == ("SAC", 1, 10, 7)
    assert "buffer_size" in sac.hyperparams and "n_steps" not in sac.hyperparams
    with pytest.raises(ValueError, match="built-in"):
        load_config("no-such-task")


def test_config_names_the_activation_and_rejects_an_unknown_one(tmp_path):
    document = yaml.safe_load(Path(load_config("rotor-loss-recovery").source).read_text())
    document["rotor-loss-recovery"]["PPO"]["policy_kwargs"]["activation_fn"] = "sigmoidish"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ValueError, match=r"policy_kwargs.activation_fn: 'sigmoidish'; accepted: \['tanh', 'relu'"):
        load_config(str(path))


@pytest.mark.parametrize(("vec_env", "n_envs", "expected"), [("auto", 1, "DummyVecEnv"), ("auto", 2, "SubprocVecEnv"),
                                                         ("dummy", 2, "DummyVecEnv"), ("subproc", 1, "SubprocVecEnv"),
                                                         ("parallel", 2, "ParallelVecEnv")])
def test_vec_env_picks_sb3s_vector_env(tmp_path, vec_env, n_envs, expected):
    from ftcgym.training.train import build_vec_env
    document = yaml.safe_load(_config(tmp_path, n_envs=n_envs).read_text())
    document["rotor-loss-recovery"]["vec_env"] = vec_env
    path = tmp_path / "vec.yaml"
    path.write_text(yaml.safe_dump(document))
    venv = build_vec_env(load_config(str(path)), normalize=False)
    try:
        assert type(venv).__name__ == expected and venv.num_envs == n_envs
    finally:
        venv.close()


def test_vec_env_is_validated(tmp_path):
    document = yaml.safe_load(_config(tmp_path).read_text())
    document["rotor-loss-recovery"]["vec_env"] = "threads"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ValueError, match=r"vec_env: 'threads'; accepted: \['auto', 'subproc', 'dummy', 'parallel'\]"):
        load_config(str(path))


def test_task_env_passes_checkers_and_starts_at_the_alarm():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("ftcgym/RotorLossRecovery-v0", **FAST_TASK)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=True)
    assert env.observation_space.shape == (N_FEATURES,) and env.action_space.low.min() == -1.0
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        again, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, again)                 # seeded reset is reproducible
        assert info["alarm_time"] >= info["onset_time"]           # the agent only sees post-alarm steps
        assert 0.02 < info["alarm_time"] - info["onset_time"] < 0.2
        # one-hot of the isolated rotor, in the canonical order: a lost r3 / r4 reads as r1 / r2 (rotor_order)
        assert obs[-4:].tolist() == np.eye(4)[info["failed_rotor"] % 2].tolist()
    env.close()


def test_task_env_draws_its_task_per_episode():
    square = {"name": "square", "speed": 2.5}
    env = RotorLossRecoveryEnv(task=["hover", square], **{**FAST_TASK, "onset": [3.0, 3.5]})
    speeds = {}
    for seed in range(8):
        obs, info = env.reset(seed=seed)
        base = env.env.unwrapped
        speeds.setdefault(info["task"], []).append(float(np.linalg.norm(base.task.reference(info["time"]).velocity)))
    assert set(speeds) == {"hover", "square"}                      # both drawn in 8 episodes
    assert max(speeds["hover"]) == 0.0 and min(speeds["square"]) > 1.0   # at the alarm the square is under way
    for bad in ([], ["hover", {"name": "sqaure"}], ["hover", {"name": "square", "speed": -1.0}]):
        with pytest.raises(ValueError, match="task"):
            RotorLossRecoveryEnv(task=bad)
    env.close()


def test_task_env_draws_its_onset_from_windows():
    env = RotorLossRecoveryEnv(**{**FAST_TASK, "onset": [[0.5, 0.6], [1.5, 1.6]]})
    assert env.onset == (0.5, 1.6)                                 # the span sizes the simulator's episode
    onsets = [env.reset(seed=seed)[1]["onset_time"] for seed in range(8)]
    assert all(0.5 <= t <= 0.6 or 1.5 <= t <= 1.6 for t in onsets)
    assert min(onsets) <= 0.6 and max(onsets) >= 1.5               # both windows drawn in 8 episodes
    plain, listed = RotorLossRecoveryEnv(**FAST_TASK), RotorLossRecoveryEnv(**{**FAST_TASK, "onset": [[0.5, 1.0]]})
    for seed in range(3):                                          # one window draws no pick: the same episodes
        assert plain.reset(seed=seed)[1]["onset_time"] == listed.reset(seed=seed)[1]["onset_time"]
    for bad in ([[1.0, 0.5]], [[0.5, 1.0], [2.0]], [[0.5, 1.0], "late"]):
        with pytest.raises(ValueError, match=r"onset"):
            RotorLossRecoveryEnv(onset=bad)
    for each in (env, plain, listed):
        each.close()


def test_task_env_rewards_holding_altitude_and_ends_on_horizon_or_crash():
    env = RotorLossRecoveryEnv(failed_rotor=2, **FAST_TASK)
    obs, info = env.reset(seed=0)
    rewards, steps = [], 0
    while True:
        obs, reward, terminated, truncated, info = env.step(np.ones(4))  # full thrust: climbs away
        rewards.append(reward)
        steps += 1
        if terminated or truncated:
            break
    assert info["failed_rotor"] == 2
    # Climbing at full thrust leaves the altitude set-point: the reward falls below the alive bonus.
    assert rewards[0] > rewards[-1] and rewards[-1] < 0.5
    assert terminated or steps == pytest.approx(FAST_TASK["horizon_seconds"] * 500 / 2, abs=1)
    with pytest.raises(ValueError):
        env.step(np.array([np.nan, 0, 0, 0]))
    env.close()


def test_train_writes_model_statistics_checkpoints_evaluations_and_manifest(trained):
    manifest = json.loads((trained / "manifest.json").read_text())
    assert manifest["steps"] >= 1024 and manifest["total_steps"] == 1024
    assert (manifest["seed"], manifest["algo"], manifest["n_envs"]) == (3, "PPO", 1)
    assert manifest["command"].startswith("ftcgym train --config") and manifest["wall_time_s"] > 0
    assert manifest["config"]["env_kwargs"]["horizon_seconds"] == 1.0
    assert manifest["config"]["policy_kwargs"]["activation_fn"] == "relu"   # named in the config, a class in torch
    from stable_baselines3 import PPO
    assert type(PPO.load(trained / "model.zip").policy.mlp_extractor.policy_net[1]).__name__ == "ReLU"
    assert manifest["git_commit"] is None or len(manifest["git_commit"]) >= 40
    assert manifest["ftcgym_version"]
    from ftcgym.training.policy import load_normalizer
    normalizer = load_normalizer(trained / "vecnormalize.pkl")
    assert normalizer.obs_rms.mean.shape == (N_FEATURES,) and normalizer.obs_rms.count > 1000
    assert sorted(p.name for p in (trained / "checkpoints").iterdir())[:2] == [
        "model_1024_steps.zip", "model_512_steps.zip"]
    evaluations = [json.loads(line) for line in (trained / "evaluations.jsonl").read_text().splitlines()]
    assert [e["timesteps"] for e in evaluations] == [512, 1024]
    for evaluation in evaluations:
        assert evaluation["episodes"] == 1 and evaluation["success_rate"] in (0.0, 1.0)
        assert evaluation["crash_rate"] in (0.0, 1.0) and evaluation["isolation_accuracy"] == 1.0
    assert (trained / "best" / "model.zip").is_file() and (trained / "best" / "vecnormalize.pkl").is_file()
    curves = (trained / "logs" / "progress.csv").read_text().splitlines()
    assert "time/total_timesteps" in curves[0] and len(curves) >= 3   # header + one row per PPO update (2)
    assert "eval/success_rate" in curves[0]


def test_deterministic_action_is_sb3s_predict_bit_for_bit(trained):
    """The lean path of `SavedModelPolicy.predict` gives `model.predict`'s deterministic action, bits and
    dtype, for float32 and float64 observations and ones far outside the clip range; other shapes go through
    `model.predict` itself."""
    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    from ftcgym.training.policy import LearnedPolicy
    from ftcgym.training.saved import deterministic_action

    model = LearnedPolicy.load(trained, make_env(get_scenario("quad-rotor-loss-hover"), SHORT_EVAL)).model
    rng = np.random.default_rng(2)
    for scale, dtype in ((1.0, np.float32), (3.0, np.float64), (100.0, np.float32)):
        for obs in (scale * rng.standard_normal((50, N_FEATURES))).astype(dtype):
            expected, _ = model.predict(obs, deterministic=True)
            action = deterministic_action(model, obs)
            assert action.dtype == expected.dtype and np.array_equal(action, expected)
    batch = rng.standard_normal((3, N_FEATURES)).astype(np.float32)
    np.testing.assert_array_equal(deterministic_action(model, batch), model.predict(batch, deterministic=True)[0])


def test_deterministic_action_of_a_discrete_action_space_is_sb3s_predict():
    """A Box observation with a Discrete action space goes through `model.predict` (no clip to Box bounds)."""
    from stable_baselines3 import PPO

    from ftcgym.training.saved import deterministic_action

    model = PPO("MlpPolicy", gym.make("CartPole-v1"), seed=0, device="cpu")
    for obs in np.random.default_rng(3).standard_normal((20, 4)).astype(np.float32):
        expected, _ = model.predict(obs, deterministic=True)
        assert np.array_equal(deterministic_action(model, obs), expected)


def test_a_saved_model_is_read_once_per_process_until_its_files_change(trained, tmp_path):
    """The benchmark makes a learned policy per episode: the second load shares the first's model and
    statistics; a model file rewritten on disk is read anew."""
    import os
    import shutil

    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    from ftcgym.training.policy import LearnedPolicy

    folder = tmp_path / "copy"
    shutil.copytree(trained, folder, ignore=shutil.ignore_patterns("checkpoints", "logs", "best"))
    env = make_env(get_scenario("quad-rotor-loss-hover"), SHORT_EVAL)
    first, second = LearnedPolicy.load(folder, env), LearnedPolicy.load(folder / "model.zip", env)
    assert second.model is first.model and second.normalizer is first.normalizer
    stat = (folder / "model.zip").stat()
    os.utime(folder / "model.zip", ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    third = LearnedPolicy.load(folder, env)
    assert third.model is not first.model
    features = np.random.default_rng(1).uniform(-1, 1, (3, N_FEATURES)).astype(np.float32)
    np.testing.assert_array_equal([third.predict(f) for f in features], [first.predict(f) for f in features])


def test_learned_policy_loads_and_acts_deterministically(trained):
    from ftcgym.agents import make_policy
    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    from ftcgym.training.policy import LearnedPolicy

    env = make_env(get_scenario("quad-rotor-loss-hover"), SHORT_EVAL)
    obs, info = env.reset(seed=0)
    first, second = LearnedPolicy.load(trained, env), LearnedPolicy.load(trained / "model.zip", env)
    features = np.random.default_rng(0).uniform(-1, 1, (5, N_FEATURES)).astype(np.float32)
    actions = np.array([first.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [first.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [second.predict(f) for f in features])
    assert actions.shape == (5, 4) and np.all(np.abs(actions) <= 1)
    assert len({tuple(a) for a in actions}) > 1                    # it reads its input
    # Before the alarm the nominal controller flies; after it the model, as motor commands in [0, 1].
    view = {"time": 0.0, "fdd": {"loe_kalman": {"alarm": False, "isolated": None}}}
    first.reset(obs, view)
    nominal = make_policy("nominal", env)          # stateful (integrators): a fresh one to compare with
    nominal.reset(obs, view)
    np.testing.assert_array_equal(first.act(obs, view), nominal.act(obs, view))
    alarmed = {"time": 0.002, "fdd": {"loe_kalman": {"alarm": True, "isolated": 1}}}
    command = first.act(obs, alarmed)
    assert first.engaged and np.all((command >= 0) & (command <= 1))
    np.testing.assert_array_equal(command, first.act(obs, alarmed))   # held for action_repeat = 2
    checkpoint = LearnedPolicy.load(trained / "checkpoints" / "model_1024_steps.zip", env)
    # A checkpoint loads with its own statistics (saved before the run's last PPO update).
    assert checkpoint.normalizer.obs_rms.count <= first.normalizer.obs_rms.count
    assert np.all(np.abs(checkpoint.predict(features[0])) <= 1)
    env.close()


def test_evaluate_prints_the_benchmark_summary(trained, capsys):
    assert main(["evaluate", str(trained), "--episodes", "1", "--seed", "5",
                 "--env-kwargs", json.dumps(SHORT_EVAL)]) == 0
    out = capsys.readouterr().out
    header, _, row = out.splitlines()[:3]
    assert header.split()[:3] == ["scenario", "policy", "n"]
    assert row.split()[:3] == ["quad-rotor-loss-hover", "learned-spin", "1"]
    crash = row.split()[TERMINAL_FIELDS.index("crash_rate")]   # one word per cell in a row
    assert crash in ("0", "1") and "1 episodes in" in out


def test_train_with_two_subprocess_envs(tmp_path):
    out = tmp_path / "run2"
    config = _config(tmp_path, n_envs=2, steps=512)
    text = yaml.safe_load(config.read_text())
    text["rotor-loss-recovery"]["eval"] = None
    config.write_text(yaml.safe_dump(text))
    assert main(["train", "--config", str(config), "--out", str(out), "--no-progress"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["n_envs"] == 2 and manifest["steps"] >= 512
    assert (out / "model.zip").is_file() and (out / "vecnormalize.pkl").is_file()
    assert not (out / "evaluations.jsonl").exists()


def _broken(tmp_path, change) -> str:
    """The shipped rotor-loss-recovery config with `change(body)` applied, written to a file."""
    document = yaml.safe_load((Path(ftcgym.__file__).parent / "training/configs/rotor-loss-recovery.yaml").read_text())
    change(document["rotor-loss-recovery"])
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(document))
    return str(path)


@pytest.mark.parametrize("change, message", [
    (lambda b: b.pop("env_id"), "env_id is missing"),
    (lambda b: b.__setitem__("env_id", "ftcgym/NoSuch-v0"), "env_id: Environment `NoSuch` doesn't exist"),
    (lambda b: b.__setitem__("env_id", 5), "env_id: expected text, got 5"),
    (lambda b: b.__setitem__("PPO", 3), "PPO: expected a mapping, got 3"),
    (lambda b: b.__setitem__("env_kwargs", [1, 2]), "env_kwargs: expected a mapping, got [1, 2]"),
    (lambda b: b.__setitem__("wrappers", "loe_kalman"), "wrappers: expected a list, got 'loe_kalman'"),
    (lambda b: b.__setitem__("eval", 5), "eval: expected a mapping, got 5"),
    (lambda b: b.__setitem__("checkpoint_frequency", 3),
     "key: unknown ['checkpoint_frequency'] (did you mean 'checkpoint_freq'?)"),
    (lambda b: b.__setitem__("checkpoint_freq", -1), "checkpoint_freq: must be >= 1, got -1"),
    (lambda b: b["PPO"].__setitem__("n_timesteps", "abc"), "PPO.n_timesteps: expected a whole number >= 0, got 'abc'"),
    (lambda b: b["PPO"].pop("n_timesteps"), "PPO.n_timesteps is missing"),
    (lambda b: b["PPO"].__setitem__("policy_kwargs", [1]), "PPO.policy_kwargs: expected a mapping"),
    (lambda b: b["PPO"].__setitem__("normalize", {"norm_obs": "maybe"}),
     "PPO.normalize.norm_obs: expected true or false, got 'maybe'"),
    (lambda b: b["quick"].__setitem__("PP0", {}), "quick: key: unknown ['PP0'] (did you mean 'PPO'?)"),
])
def test_a_broken_config_is_refused_naming_the_key(tmp_path, change, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        load_config(_broken(tmp_path, change))


def test_a_misspelt_algorithm_keyword_is_refused_before_any_env_is_built(tmp_path):
    pytest.importorskip("stable_baselines3")
    from ftcgym.training.train import check_hyperparams
    config = load_config(_broken(tmp_path, lambda b: b["PPO"].__setitem__("learning_rte", 1e-3)))
    with pytest.raises(ValueError, match=r"PPO keyword: unknown \['learning_rte'\] \(did you mean 'learning_rate'\?\)"):
        check_hyperparams(config)
    check_hyperparams(load_config("rotor-loss-recovery"))          # the shipped config passes


@pytest.mark.parametrize("kwargs, message", [
    ({"vehical": "bebop2"}, "gym.make keyword: unknown ['vehical'] (did you mean 'vehicle'?)"),
    ({"vehicle": None}, "vehicle: expected a parameter set or a list of them"),
    ({"horizon_seconds": "5"}, "horizon_seconds: expected a number > 0, got str '5'"),
    ({"onset": "3"}, "onset: expected a number or [lo, hi] with 0 <= lo <= hi, got '3'"),
    ({"failed_rotor": True}, "failed_rotor: expected 'random', a rotor index 0-3 or a list of them, got True"),
    ({"expert": "no"}, "expert: expected true or false, got 'no'"),
    ({"action_repeat": 2.5}, "action_repeat: expected a whole number >= 1, got 2.5"),
    ({"detector_kwargs": [1]}, "detector_kwargs: expected a dict of loe_kalman settings, got [1]"),
    ({"detector_kwargs": {"Q": float("nan")}}, "loe_kalman.Q: must be finite"),
    ({"wind": {"mean": [90, 0, 0]}}, "wind mean: its speed must be <= 50 m/s"),
])
def test_the_rotor_loss_task_checks_its_keywords_at_make(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        gym.make("ftcgym/RotorLossRecovery-v0", **kwargs)


def test_the_rotor_loss_task_refuses_options_and_odd_actions():
    env = gym.make("ftcgym/RotorLossRecovery-v0", **FAST_TASK)
    with pytest.raises(ValueError, match="reset options: RotorLossRecovery-v0 draws each episode"):
        env.reset(options={"faults": "garbage"})
    env.reset(seed=0)
    for action in (["0.5"] * 4, [True] * 4, 0.5):
        with pytest.raises(ValueError, match="action: "):
            env.step(action)
    env.close()


@pytest.mark.parametrize("damage, message", [
    (("model.zip", "garbage"), "model.zip: not a model saved by ftcgym train or SB3"),
    (("manifest.json", "{not json"), "manifest.json: not a training manifest (JSON: "),
    (("manifest.json", '{"config": "oops"}'), "manifest.json: not a training manifest (expected a JSON object"),
])
def test_evaluate_names_a_damaged_model_file(tmp_path, capsys, damage, message):
    pytest.importorskip("stable_baselines3")
    import shutil
    folder = tmp_path / "model"
    shutil.copytree(Path(ftcgym.__file__).parent / "training/shipped/rotor-loss-recovery", folder)
    name, text = damage
    (folder / name).write_text(text)
    assert main(["evaluate", str(folder), "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def crash_on_substep(env, k: int) -> None:
    """Make the simulator under a training task report a crash on the k-th simulator step from now."""
    inner, calls = env.env, []
    step = inner.step

    def crashing(action):
        obs, reward, terminated, truncated, info = step(action)
        calls.append(1)
        if len(calls) == k:
            info = {**info, "crashed": True}
            return obs, -100.0, True, False, info
        return obs, reward, terminated, truncated, info
    inner.step = crashing


@pytest.mark.parametrize("substep", [1, 2])
def test_a_crash_gives_the_whole_penalty_whatever_the_substep(substep):
    env = RotorLossRecoveryEnv(failed_rotor=2, **FAST_TASK)
    env.reset(seed=0)
    crash_on_substep(env, substep)
    _, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert (reward, terminated, truncated) == (-100.0, True, False)   # was -100 / action_repeat, or mean with it
    env.close()
