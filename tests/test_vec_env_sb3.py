"""ParallelVecEnv: DummyVecEnv's results through Stable-Baselines3's VecEnv interface, from envs on every core."""
import functools

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from ftcgym.training.train import make_env
from ftcgym.training.vec_env import ParallelVecEnv

#: random actions crash the vehicle within a second or two: episode ends, Monitor's episode info, resets
FACTORY = functools.partial(make_env, "ftcgym/Quadrotor-v0", {"agent_hz": 50.0, "max_episode_seconds": 2.0}, [])


def same(a, b, where):
    if isinstance(a, dict):
        assert set(a) == set(b), f"{where}: {sorted(set(a) ^ set(b))}"
        for key in a:
            if key not in ("t",):            # Monitor's wall-clock time of the episode end
                same(a[key], b[key], f"{where}/{key}")
    else:
        assert np.array_equal(np.asarray(a), np.asarray(b)), f"{where}: {a} != {b}"


def test_matches_dummy_vec_env_step_for_step():
    dummy, parallel = DummyVecEnv([FACTORY] * 3), ParallelVecEnv([FACTORY] * 3, workers=2)
    try:
        dummy.seed(5)
        parallel.seed(5)
        same(dummy.reset(), parallel.reset(), "reset")
        rng = np.random.default_rng(2)
        ends = episodes = 0
        for t in range(250):
            actions = rng.uniform(0.0, 1.0, (3, 4)).astype(np.float32)
            expected, got = dummy.step(actions), parallel.step(actions)
            for part, (x, y) in enumerate(zip(expected[:3], got[:3])):
                same(x, y, f"step {t} part {part}")
                assert np.asarray(x).dtype == np.asarray(y).dtype
            for k, (x, y) in enumerate(zip(expected[3], got[3])):
                same(x, y, f"step {t} info {k}")
            for k, (x, y) in enumerate(zip(dummy.reset_infos, parallel.reset_infos)):
                same(x, y, f"step {t} reset info {k}")           # what DAgger reads its labels from
            ends += int(expected[2].sum())
            episodes += sum("episode" in info and "terminal_observation" in info for info in got[3])
        assert ends >= 6 and episodes == ends         # each end carries Monitor's episode and the last observation
        assert parallel.env_is_wrapped(Monitor) == [True] * 3
        assert parallel.get_attr("agent_hz", indices=[1]) == [50.0]
        parallel.set_attr("info_level", "none", indices=[2])
        assert parallel.get_attr("info_level") == ["full", "full", "none"]
        assert parallel.env_method("get_episode_rewards", indices=0)[0] == dummy.env_method(
            "get_episode_rewards", indices=0)[0]
    finally:
        dummy.close()
        parallel.close()


def test_env_method_calls_only_the_chosen_envs():
    dummy, parallel = DummyVecEnv([FACTORY] * 3), ParallelVecEnv([FACTORY] * 3, workers=2)
    try:
        for venv in (dummy, parallel):
            venv.seed(5)
            venv.reset()
            for _ in range(10):
                venv.step(np.full((3, 4), 0.7, dtype=np.float32))
            venv.env_method("reset", indices=[2, 0])        # a worker's env and this process's, out of order
        times = [venv.get_attr("time") for venv in (dummy, parallel)]
        assert times[0] == times[1] == [0.0, 0.2, 0.0]      # env 1 was not reset (it was, as a side effect)
        assert parallel.env_method("get_episode_rewards", indices=[1, 2]) == dummy.env_method(
            "get_episode_rewards", indices=[1, 2])
    finally:
        dummy.close()
        parallel.close()


def test_ppo_learns_on_it(tmp_path):
    venv = ParallelVecEnv([FACTORY] * 2, workers=1)
    try:
        model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
        model.set_logger(configure(str(tmp_path), []))    # SB3's default leaves an SB3-<date> folder in /tmp
        model.learn(64)
        assert model.num_timesteps == 64
    finally:
        venv.close()


def test_different_reset_options_per_env_are_refused():
    venv = ParallelVecEnv([FACTORY] * 2, workers=1)
    try:
        venv.set_options([{"a": 1}, {"a": 2}])
        with pytest.raises(ValueError, match="different reset options per env"):
            venv.reset()
    finally:
        venv.close()
