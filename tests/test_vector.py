"""ParallelVectorEnv: SyncVectorEnv's results, step for step, from envs split over processes; clear errors."""
import os
import signal

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import ftcgym  # noqa: F401
from ftcgym.vector import ParallelVectorEnv, make_parallel

QUADROTOR = "ftcgym/Quadrotor-v0"
#: random actions crash the vehicle within a second or two: every episode end and autoreset is exercised
FAST = {"agent_hz": 50.0, "max_episode_seconds": 3.0}


def assert_same(a, b, where=""):
    """Equal to the bit: arrays, dicts of them and nested infos."""
    if isinstance(a, dict):
        assert set(a) == set(b), f"{where}: keys {sorted(set(a) ^ set(b))}"
        for key in a:
            assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, tuple | list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert a.shape == b.shape, where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert np.array_equal(np.asarray(a), np.asarray(b)), f"{where}: {a} != {b}"


def fly_both(mode, num_envs=3, workers=2, steps=150, **kwargs):
    """Sync and parallel vector envs side by side with the same seeds and actions; returns the episode ends."""
    fns = [lambda: gym.make(QUADROTOR, **FAST, **kwargs)] * num_envs
    sync = SyncVectorEnv(fns, autoreset_mode=mode)
    parallel = ParallelVectorEnv(fns, workers=workers, autoreset_mode=mode)
    try:
        assert_same(sync.reset(seed=7), parallel.reset(seed=7), "reset")
        rng = np.random.default_rng(1)
        ends = 0
        for t in range(steps):
            actions = rng.uniform(0.0, 1.0, (num_envs, 4)).astype(np.float32)
            expected, got = sync.step(actions), parallel.step(actions)
            assert_same(expected, got, f"step {t}")
            ends += int(expected[2].sum() + expected[3].sum())
        return ends
    finally:
        sync.close()
        parallel.close()


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_matches_sync_vector_env_through_crashes_and_autoresets(mode):
    assert fly_both(mode) >= 6          # every env ended at least twice


def test_flat_observations_without_info_match_too():
    assert fly_both(AutoresetMode.NEXT_STEP, num_envs=2, workers=1, observation_format="flat",
                    info_level="none") >= 4


def test_infos_of_a_silent_worker_are_one_fresh_dict_per_env():
    envs = make_parallel(QUADROTOR, num_envs=4, workers=1, info_level="none", **FAST)   # two envs each
    try:
        envs.reset(seed=0)
        assert [len(share) for share in envs._shares] == [2, 2]
        *_, infos = envs.step_each(np.full((4, 4), 0.6, dtype=np.float32))
        assert infos == [{}] * 4 and len({id(info) for info in infos}) == 4
        assert envs.step(np.full((4, 4), 0.6, dtype=np.float32))[4] == {}
    finally:
        envs.close()


@pytest.mark.parametrize("copy", [True, False])
def test_copies_are_fresh_arrays_and_views_are_the_shared_batch(copy):
    envs = make_parallel(QUADROTOR, num_envs=2, workers=1, copy=copy, **FAST)
    try:
        envs.reset(seed=0)
        hover = np.full((2, 4), 0.6, dtype=np.float32)
        first = envs.step(hover)[0]
        kept = {key: value.copy() for key, value in first.items()}
        second = envs.step(hover)[0]
        assert type(first) is type(envs.observation_space.sample()) and list(first) == list(envs.observation_space)
        for key, value in first.items():
            assert value.dtype == envs.observation_space[key].dtype
            assert value.shape == (2, *envs.single_observation_space[key].shape)
            assert np.shares_memory(value, second[key]) is not copy
        assert np.array_equal(first["gyro"], kept["gyro"]) is copy      # a view shows the next step's readings
    finally:
        envs.close()


def test_in_process_only_and_make_vec_default():
    envs = gym.make_vec(QUADROTOR, num_envs=2, workers=0, **FAST)
    try:
        assert isinstance(envs, ParallelVectorEnv) and envs._workers == []
        obs, _ = envs.reset(seed=0)
        assert obs["position"].shape == (2, 3)
        obs, reward, *_ = envs.step(np.full((2, 4), 0.6, dtype=np.float32))
        assert reward.shape == (2,) and np.all(np.isfinite(obs["gyro"]))
    finally:
        envs.close()


def test_attributes_across_processes():
    envs = make_parallel(QUADROTOR, num_envs=3, workers=2, **FAST)
    try:
        assert envs.get_attr("physics_hz") == (500.0, 500.0, 500.0)
        envs.set_attr("info_level", ["none", "full", "none"])
        assert envs.get_attr("info_level") == ("none", "full", "none")
        envs.reset(seed=0)
        _, _, _, _, info = envs.step(np.full((3, 4), 0.6, dtype=np.float32))
        assert list(info["_time"]) == [False, True, False]      # only env 1 still reports
    finally:
        envs.close()


class RaisesOnce(gym.Wrapper):
    """Raises at its first step, then steps normally."""

    raised = False

    def step(self, action):
        if not self.raised:
            self.raised = True
            raise ArithmeticError("deliberate failure in step")
        return self.env.step(action)


def test_errors_are_raised_in_the_calling_process():
    with pytest.raises(ValueError, match="workers=3; accepted"):
        make_parallel(QUADROTOR, num_envs=3, workers=3)
    with pytest.raises(ValueError, match="autoreset_mode; accepted"):
        make_parallel(QUADROTOR, num_envs=2, autoreset_mode="Disabled")
    with pytest.raises(RuntimeError, match="worker 1 raised:(.|\n)*unknown"):
        ParallelVectorEnv([lambda: gym.make(QUADROTOR), lambda: gym.make(QUADROTOR, vehical="bebop2")], workers=1)
    hover = np.full((2, 4), 0.6, dtype=np.float32)
    for failing, error, match in ((1, RuntimeError, "worker 1 raised:(.|\n)*deliberate failure"),
                                  (0, ArithmeticError, "deliberate failure")):
        fns = [lambda: gym.make(QUADROTOR)] * 2
        fns[failing] = lambda: RaisesOnce(gym.make(QUADROTOR))
        envs = ParallelVectorEnv(fns, workers=1)
        try:
            envs.reset(seed=0)
            with pytest.raises(error, match=match):
                envs.step(hover)
            obs, reward, *_ = envs.step(hover)            # the processes are still in step with each other
            assert np.all(np.isfinite(obs["position"])) and np.all(reward > 0.0)
            assert envs.get_attr("physics_hz") == (500.0, 500.0)
        finally:
            envs.close()
    with pytest.raises(RuntimeError, match="step after close"):
        envs.step(np.full((2, 4), 0.6, dtype=np.float32))


def test_a_dead_worker_is_an_error_not_a_hang():
    envs = make_parallel(QUADROTOR, num_envs=2, workers=1)
    try:
        envs.reset(seed=0)
        os.kill(envs._workers[0].process.pid, signal.SIGKILL)
        envs._workers[0].process.join(timeout=5.0)
        with pytest.raises(RuntimeError, match="died"):
            envs.step(np.full((2, 4), 0.6, dtype=np.float32))
    finally:
        envs.close()


def test_spawned_workers_give_the_same_results():
    """The start method of macOS and Windows: the worker gets the shared buffers by pickling, not by fork."""
    fns = [lambda: gym.make(QUADROTOR, **FAST)] * 2
    sync, spawned = SyncVectorEnv(fns), ParallelVectorEnv(fns, workers=1, context="spawn")
    try:
        assert_same(sync.reset(seed=3), spawned.reset(seed=3), "reset")
        for t in range(20):
            actions = np.full((2, 4), 0.55 + 0.005 * t, dtype=np.float32)
            assert_same(sync.step(actions), spawned.step(actions), f"step {t}")
    finally:
        sync.close()
        spawned.close()


class _Slow:
    """A semaphore that is free from its `free_from`-th poll on (counting from one; never with None); a blocking
    acquire gets it where `wakes` (the other side answered while this one slept)."""

    def __init__(self, free_from: int | None, wakes: bool = False):
        self.free_from, self.wakes, self.polls = free_from, wakes, 0

    def acquire(self, block=True, timeout=None):
        self.polls += 1
        if block:
            return self.wakes
        return self.free_from is not None and self.polls >= self.free_from


@pytest.fixture
def waiter_polls(monkeypatch):
    """`_Waiter` with 3 busy polls and at most 4 rests, and the yields it makes, counted."""
    import ftcgym.vector as vector
    yields = []
    monkeypatch.setattr(vector, "_yield", lambda: yields.append(1))
    monkeypatch.setattr(vector, "BUSY_POLLS", 3)
    monkeypatch.setattr(vector, "MOST_RESTS", 4)
    return vector, yields


def test_a_waiting_side_polls_then_yields_its_core_between_polls(waiter_polls):
    vector, yields = waiter_polls
    semaphore = _Slow(free_from=2)
    assert vector._Waiter(semaphore, 1.0, lambda: True)()
    assert semaphore.polls == 2 and not yields                  # answered within the busy polls
    semaphore = _Slow(free_from=6)
    assert vector._Waiter(semaphore, 1.0, lambda: True)()
    assert semaphore.polls == 6 and len(yields) == 3            # 3 busy polls, then a yield before each poll
    semaphore = _Slow(free_from=None)                           # the other side is gone
    assert not vector._Waiter(semaphore, 1e-4, lambda: False)()
    assert semaphore.polls >= 5 and len(yields) == 3 + semaphore.polls - 4      # then one blocking acquire
    semaphore, yields[:] = _Slow(free_from=None), []            # no polling time: one poll, then the sleep
    assert not vector._Waiter(semaphore, 0.0, lambda: False)()
    assert semaphore.polls == 2 and not yields


def test_after_unanswered_busy_polls_a_waiting_side_yields_at_once_backing_off(waiter_polls):
    vector, _ = waiter_polls
    semaphore = _Slow(free_from=None, wakes=True)
    waiter = vector._Waiter(semaphore, 1e-9, lambda: True)
    busy = []
    for _ in range(14):                        # every wait misses its polls: the rests double up to MOST_RESTS
        before = semaphore.polls
        assert waiter()
        busy.append(semaphore.polls - before > 3)          # 3 busy polls and a sleep; a rest: 1 and a sleep
    assert busy == [True, False, True, False, False, True, False, False, False, False, True, False, False, False]
    semaphore.free_from = 0                    # answered at once: after the rests left, the busy polls are back
    for _ in range(4):
        assert waiter()
    assert waiter._rests == 0 and waiter._backoff == 1


@pytest.mark.parametrize("num_envs", ["2", -1, 0, 2.5, True])
def test_num_envs_must_be_a_whole_number_of_envs(num_envs):
    with pytest.raises(ValueError, match=f"num_envs: expected a whole number >= 1, got {num_envs!r}"):
        gym.make_vec(QUADROTOR, num_envs=num_envs)


def test_a_batch_of_the_wrong_shape_is_named_as_the_actions():
    envs = gym.make_vec(QUADROTOR, num_envs=2, workers=0, observation_format="flat", info_level="none")
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions: expected a batch of 2 actions of shape \(4,\) \(\(2, 4\)\); could "
                                         r"not broadcast"):
        envs.step(np.zeros((2, 3)))
    envs.close()


def test_a_dropped_vector_env_stops_its_workers():
    import gc
    vector_env = make_parallel(QUADROTOR, num_envs=2, workers=1)
    vector_env.reset(seed=0)
    processes = [worker.process for worker in vector_env._workers]
    del vector_env
    gc.collect()
    for process in processes:
        process.join(timeout=10)
    assert [process.is_alive() for process in processes] == [False]
