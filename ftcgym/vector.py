"""`ParallelVectorEnv`: a Gymnasium vector env whose envs step on every core, meeting through shared memory.

Gymnasium's `AsyncVectorEnv` sends each step's actions and results through a pipe per worker and sleeps on it:
the round trip (about 100 us on a 2-core machine, process wake-ups included) costs more than a whole ftcgym
step, so two async envs step slower than one env alone (docs/performance.md). Here the calling process steps a
share of the envs itself while each worker process steps its own share, in lockstep. Actions, observations,
rewards and flags live in shared memory, and each side waits for the other by polling a semaphore for
`spin_seconds` before it sleeps on it: a step costs the slowest share plus a few microseconds, and a long pause
(a policy update) does not keep a core busy. After its first hundred polls (3 us) the waiting side yields its
core between polls (`os.sched_yield`), which costs nothing when the machine has a core to spare and, when other
processes want more cores than there are, lets the side it waits for run: polling without yielding made the pair
5 to 100 times slower than one env beside one busy process on 2 cores (docs/measurements.md, 'The parallel vector
env on a busy machine'); where the first polls go unanswered, the next waits yield at once (`_Waiter`). An
`info` travels through a pipe, and only when an env returned a non-empty one (`info_level="none"` sends nothing).

The semantics are those of `gymnasium.vector.SyncVectorEnv`: the autoreset modes next-step (the default) and
same-step, the same batched `info`, the same observations for the same seeds. Workers default to one per core
beyond the caller's, at most one per env beyond the first; `workers=0` steps everything in this process.

Every ftcgym env has it as its vector entry point (`make_parallel`), which `gym.make_vec(id, num_envs=N, ...)`
uses unless `vectorization_mode` says "sync" or "async". Gymnasium passes a vector entry point neither
`vector_kwargs` (give `copy=False` and the keywords below as plain keywords) nor `wrappers`: to wrap each env,
build the vector env from env-building functions, `ParallelVectorEnv([make_wrapped_env] * N)`.
"""
from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import time
import traceback
from copy import deepcopy

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import (
    CloudpickleWrapper,
    batch_space,
    create_shared_memory,
    read_from_shared_memory,
)

#: the commands a worker reads from its slot of `_Shared.command` when woken
STEP, RESET, CALL, CLOSE = range(4)
#: how long a waiting side polls before it sleeps (s): longer than a step, shorter than a policy update
SPIN_SECONDS = 0.002
#: the keywords of `make_parallel` that are the vector env's own (the rest build each env)
VECTOR_KEYWORDS = ("workers", "autoreset_mode", "copy", "spin_seconds", "context")


class ParallelVectorEnv(VectorEnv):
    """`num_envs` envs stepped in lockstep by this process and `workers` worker processes (module docstring).

    `env_fns`: callables that each build one env. `workers`: worker processes (None: one per core beyond this
    one's, at most num_envs - 1). `autoreset_mode`: an `AutoresetMode` (or its value), NEXT_STEP (Gymnasium's
    default) or SAME_STEP. `copy`: return copies of the batched observations (False: views that the next step
    overwrites). `context`: the multiprocessing start method (None: the platform's default).
    """

    def __init__(self, env_fns, workers: int | None = None,
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP, copy: bool = True,
                 spin_seconds: float = SPIN_SECONDS, context: str | None = None):
        self.closed = True
        env_fns = list(env_fns)
        if not env_fns:
            raise ValueError("ParallelVectorEnv: env_fns is empty; give at least one env-building callable")
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.num_envs, self.copy, self.spin_seconds = len(env_fns), bool(copy), float(spin_seconds)
        workers = _worker_count(workers, self.num_envs)
        bounds = np.linspace(0, self.num_envs, workers + 2).round().astype(int)
        self._shares = [range(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self._starts = [share.start for share in self._shares[1:]]     # each worker's first env
        own = self._shares[0]
        self._own = _Share([env_fns[k] for k in own], own, self.autoreset_mode)
        first = self._own.envs[0]
        self.metadata = {**first.metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode, self.spec = first.render_mode, first.spec
        self.single_observation_space, self.single_action_space = first.observation_space, first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        ctx = mp.get_context(context)
        self._shared = _Shared(ctx, self.single_observation_space, self.single_action_space, self.num_envs, workers)
        self._observations = read_from_shared_memory(self.single_observation_space, self._shared.observations,
                                                     self.num_envs)
        self._workers = []
        try:
            for w, share in enumerate(self._shares[1:]):
                self._workers.append(_Worker.start(ctx, w, [env_fns[k] for k in share], share, self._shared,
                                                   self.autoreset_mode, self.spin_seconds))
            self.closed = False
            self._gather()                # each worker answers once its envs are built
        except BaseException:
            self.closed = False
            self.close()
            raise

    # ------------------------------------------------------------------ the Gymnasium API
    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        """Reset every env: `seed` an int (env i gets seed + i), a list of one per env, or None."""
        obs, infos = self.reset_each(seed=seed, options=options)
        return obs, self._batched([(0, infos)])

    def step(self, actions):
        obs, rewards, terminations, truncations, answers = self._step(actions)
        return obs, rewards, terminations, truncations, self._batched(answers)

    def reset_each(self, *, seed: int | list | None = None, options: dict | None = None):
        """`reset` with the infos as a list, one dict per env (Stable-Baselines3's form)."""
        self._check_open("reset")
        seeds = _seeds(seed, self.num_envs)
        for worker, share in zip(self._workers, self._shares[1:]):
            worker.order(RESET, ([seeds[k] for k in share], options))
        infos = self._gather(self._own_part(self._own.reset, [seeds[k] for k in self._shares[0]], options,
                                            self._shared))
        return self._observations_out(), infos      # after the workers answered: their observations are in

    def step_each(self, actions):
        """`step` with the infos as a list, one dict per env (Stable-Baselines3's form)."""
        obs, rewards, terminations, truncations, answers = self._step(actions)
        return obs, rewards, terminations, truncations, self._per_env([infos for _, infos in answers])

    def _step(self, actions):
        """One step of every env: the batched observations, rewards and flags, and per share (start index,
        its infos or None where all were empty)."""
        if self.closed:
            self._check_open("step")
        shared = self._shared
        try:
            _copy_batch(self.single_action_space, shared.action_view, actions)
        except ValueError as error:          # numpy's broadcast message, which does not say what it was copying
            raise ValueError(f"actions: expected a batch of {self.num_envs} actions of shape "
                             f"{self.single_action_space.shape} ({self.action_space.shape}); {error}") from None
        for worker in self._workers:
            worker.order(STEP)
        answers = [(0, self._own_part(self._own.step, shared))]
        if self._workers:
            answers += zip(self._starts, self._answers())
        return (self._observations_out(), shared.rewards.copy(), shared.terminations.copy(),
                shared.truncations.copy(), answers)

    def call(self, name, *args, **kwargs) -> tuple:
        """`getattr(env, name)` of every env, called with the arguments where it is callable; `name` may also
        be a picklable function, called as name(env, *args, **kwargs)."""
        return self.call_at(None, name, *args, **kwargs)

    def call_at(self, indices, name, *args, **kwargs) -> tuple:
        """`call` on the envs of `indices` only (None: every env), their results in batch order; the others are
        not touched (Stable-Baselines3's `env_method(..., indices=...)`)."""
        self._check_open("call")
        only = None if indices is None else frozenset(int(k) for k in indices)
        for worker in self._workers:
            worker.order(CALL, (name, args, kwargs, only))
        results = self._own_part(self._own.call, name, args, kwargs, only)
        for answer in self._answers():
            results.extend(answer or [])
        return tuple(results)

    def get_attr(self, name: str) -> tuple:
        return self.call(name)

    def set_attr(self, name: str, values) -> None:
        """Set `name` on every env: one value for all, or a list or tuple of one per env."""
        self._check_open("set_attr")
        values = list(values) if isinstance(values, list | tuple) else [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(f"ParallelVectorEnv.set_attr: {len(values)} values; accepted: one value or "
                             f"{self.num_envs}")
        for worker, share in zip(self._workers, self._shares[1:]):
            worker.order(CALL, ("__setattr__", (name, [values[k] for k in share]), {}, None))
        self._own_part(self._own.call, "__setattr__", (name, [values[k] for k in self._shares[0]]), {}, None)
        self._answers()

    def __del__(self):
        """A vector env dropped without `close` still stops its workers (as Gymnasium's AsyncVectorEnv does)."""
        if not getattr(self, "closed", True):
            self.close()

    def close_extras(self, **kwargs) -> None:
        if self.closed:
            return
        self.closed = True
        for worker in self._workers:
            worker.stop()
        self._own.close()

    # ------------------------------------------------------------------ internals
    def _check_open(self, what: str) -> None:
        if self.closed:
            raise RuntimeError(f"ParallelVectorEnv.{what} after close()")

    def _observations_out(self):
        return _copied(self._observations) if self.copy else self._observations

    def _batched(self, answers: list) -> dict:
        """Gymnasium's batched info of the per-env infos, given per share as (its first env, its infos or None);
        most steps have none."""
        infos = {}
        for start, share_infos in answers:
            if share_infos:
                for k, info in enumerate(share_infos, start):
                    if info:
                        infos = self._add_info(infos, info, k)
        return infos

    def _own_part(self, work, *args):
        """This process's share of a command; if it raises, the workers' answers are collected first, so the
        next command starts in step."""
        try:
            return work(*args)
        except BaseException:
            with contextlib.suppress(RuntimeError):
                self._answers()
            raise

    def _answers(self) -> list:
        """Every worker's answer, in order, once all have answered; the first error of one is raised then."""
        answers, error = [], None
        for worker in self._workers:
            try:
                answers.append(worker.answer())
            except RuntimeError as raised:
                answers.append(None)
                error = error or raised
        if error is not None:
            raise error
        return answers

    def _gather(self, own: list | None = None) -> list:
        """Wait for every worker; the infos of every env, this process's `own` first (`_per_env`)."""
        return self._per_env([own, *self._answers()])

    def _per_env(self, share_infos: list) -> list:
        """The infos of every env from each share's list of infos (None where a worker sent none: a fresh empty
        dict per env)."""
        infos = []
        for part, share in zip(share_infos, self._shares):
            infos.extend(part or [{} for _ in share])
        return infos


def make_parallel(env_id: str, num_envs: int = 1, **kwargs) -> ParallelVectorEnv:
    """A `ParallelVectorEnv` of `num_envs` `gym.make(env_id, **kwargs)` envs; the keywords of
    `VECTOR_KEYWORDS` go to the vector env. The vector entry point of every ftcgym env."""
    vector = {key: kwargs.pop(key) for key in VECTOR_KEYWORDS if key in kwargs}
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs: expected a whole number >= 1, got {num_envs!r}")
    return ParallelVectorEnv([_EnvMaker(env_id, kwargs)] * int(num_envs), **vector)


class _EnvMaker:
    """`gym.make(env_id, **kwargs)` as a picklable callable."""

    def __init__(self, env_id: str, kwargs: dict):
        self.env_id, self.kwargs = env_id, kwargs

    def __call__(self) -> gym.Env:
        import ftcgym  # noqa: F401 - registers the env ids in a freshly spawned worker
        return gym.make(self.env_id, **self.kwargs)


def _autoreset_mode(mode) -> AutoresetMode:
    accepted = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
    try:
        mode = AutoresetMode(mode)
    except ValueError:
        mode = None
    if mode not in accepted:
        raise ValueError(f"ParallelVectorEnv: autoreset_mode; accepted: {[m.value for m in accepted]}")
    return mode


def _worker_count(workers, num_envs: int) -> int:
    if workers is None:
        return min(max((os.cpu_count() or 1) - 1, 0), num_envs - 1)
    if isinstance(workers, bool) or not isinstance(workers, int | np.integer) or not 0 <= workers < num_envs:
        raise ValueError(f"ParallelVectorEnv: workers={workers!r}; accepted: None or an int from 0 to "
                         f"num_envs - 1 = {num_envs - 1}")
    return int(workers)


def _seeds(seed, num_envs: int) -> list:
    if seed is None or (isinstance(seed, int | np.integer) and not isinstance(seed, bool)):
        return [None if seed is None else int(seed) + k for k in range(num_envs)]
    seeds = list(seed)
    if len(seeds) != num_envs:
        raise ValueError(f"ParallelVectorEnv.reset: seed has {len(seeds)} entries; accepted: an int, None or "
                         f"a list of one per env ({num_envs})")
    return seeds


def _copied(batch):
    """What `deepcopy` gives of a batch of observations (arrays, and dicts and tuples of them), at a fraction of its
    cost on a Dict (it keeps a memo of every object it copies)."""
    if type(batch) is np.ndarray:
        return batch.copy(order="K")
    if isinstance(batch, dict):
        return type(batch)((key, _copied(value)) for key, value in batch.items())
    if type(batch) is tuple:
        return tuple(_copied(value) for value in batch)
    return deepcopy(batch)


def _copy_batch(space, view, batch) -> None:
    """Copy a batch of `space` into its shared view (Dict and Tuple batches are dicts and tuples of batches)."""
    if type(view) is np.ndarray:
        view[...] = batch
    elif isinstance(space, spaces.Dict):
        for key, sub in space.spaces.items():
            _copy_batch(sub, view[key], batch[key])
    elif isinstance(space, spaces.Tuple):
        for sub, part, value in zip(space.spaces, view, batch):
            _copy_batch(sub, part, value)


def _writer(space, view, k: int):
    """A function that writes a value of `space` into entry k of its shared batch view."""
    if isinstance(space, spaces.Dict):
        parts = [(key, _writer(sub, view[key], k)) for key, sub in space.spaces.items()]

        def write(value):
            for key, part in parts:
                part(value[key])
        return write
    if isinstance(space, spaces.Tuple):
        parts = [_writer(sub, part, k) for sub, part in zip(space.spaces, view)]

        def write(value):
            for part, item in zip(parts, value):
                part(item)
        return write
    if view.ndim > 1:
        row = view[k]            # a view of entry k: written whole
        return lambda value: row.__setitem__(Ellipsis, value)
    return lambda value: view.__setitem__(k, value)


def _item(space, batch, k: int):
    """Entry k of a batch of `space` (Dict and Tuple batches are dicts and tuples of batches)."""
    if isinstance(space, spaces.Dict):
        return {key: _item(sub, batch[key], k) for key, sub in space.spaces.items()}
    if isinstance(space, spaces.Tuple):
        return tuple(_item(sub, part, k) for sub, part in zip(space.spaces, batch))
    return batch[k]


class _Shared:
    """What the processes share: the batched actions and observations, rewards, flags, a command slot per worker
    and the semaphores each side waits on."""

    def __init__(self, ctx, observation_space, action_space, num_envs: int, workers: int):
        self.observation_space, self.action_space, self.num_envs = observation_space, action_space, num_envs
        self.observations = create_shared_memory(observation_space, num_envs, ctx)
        self.actions = create_shared_memory(action_space, num_envs, ctx)
        self.numbers = ctx.RawArray("d", num_envs)
        self.flags = ctx.RawArray("b", 2 * num_envs)
        # per worker: the command, whether it answered; these and the per-env numbers are read and written through
        # ctypes, at a fraction of the cost of a numpy item
        self.commands = ctx.RawArray("b", 2 * max(workers, 1))
        self.go = [ctx.Semaphore(0) for _ in range(workers)]
        self.done = [ctx.Semaphore(0) for _ in range(workers)]
        self._views()

    def _views(self) -> None:
        self.action_view = read_from_shared_memory(self.action_space, self.actions, self.num_envs)
        self.observation_view = read_from_shared_memory(self.observation_space, self.observations, self.num_envs)
        self.rewards = np.frombuffer(self.numbers, dtype=np.float64)
        flags = np.frombuffer(self.flags, dtype=np.bool_)
        self.terminations, self.truncations = flags[:self.num_envs], flags[self.num_envs:]

    def write_outcome(self, k: int, reward, terminated, truncated) -> None:
        self.numbers[k] = reward
        self.flags[k] = 1 if terminated else 0
        self.flags[self.num_envs + k] = 1 if truncated else 0

    def __getstate__(self):      # to a spawned worker: the shared buffers, not the numpy views of them
        views = ("action_view", "observation_view", "rewards", "terminations", "truncations")
        return {key: value for key, value in self.__dict__.items() if key not in views}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._views()


class _Share:
    """The envs one process steps (`indices` of the batch), with SyncVectorEnv's autoreset rules; the results
    go to the shared memory, the infos are returned."""

    def __init__(self, env_fns, indices: range, autoreset_mode: AutoresetMode):
        self.envs, self.indices = [], indices
        self._same_step = autoreset_mode == AutoresetMode.SAME_STEP
        for fn in env_fns:
            self.envs.append(fn())
        self._needs_reset = [False] * len(self.envs)
        self._bound = None

    def _bind(self, shared: _Shared) -> None:
        """Per env: its action (a view into the shared batch where the space allows) and a writer of its
        observation into the shared batch."""
        self._bound = shared
        box = isinstance(shared.action_space, spaces.Box)
        actions = [_item(shared.action_space, shared.action_view, k) if box else None for k in self.indices]
        self._writers = [_writer(shared.observation_space, shared.observation_view, k) for k in self.indices]
        self._stepping = list(zip(self.indices, self.envs, self._writers, actions))

    def reset(self, seeds, options, shared: _Shared) -> list:
        infos = []
        for i, (k, env) in enumerate(zip(self.indices, self.envs)):
            obs, info = env.reset(seed=seeds[i], options=options)
            self._needs_reset[i] = False
            self._write(shared, k, obs, 0.0, False, False)
            infos.append(info)
        return infos

    def step(self, shared: _Shared) -> list | None:
        """Step this share's envs on the shared actions; their infos, None where every one is empty (the common
        case, which then costs the calling process nothing to batch)."""
        if self._bound is not shared:
            self._bind(shared)
        infos, any_info, needs_reset, same_step = [], False, self._needs_reset, self._same_step
        rewards, flags, n_envs = shared.numbers, shared.flags, shared.num_envs     # `write_outcome`, inline
        for i, (k, env, write, action) in enumerate(self._stepping):
            if needs_reset[i]:                # next-step autoreset: this step only resets
                obs, info = env.reset()
                reward, terminated, truncated = 0.0, False, False
            else:
                if action is None:            # a Dict or Tuple action: its entry, gathered anew
                    action = _item(shared.action_space, shared.action_view, k)
                obs, reward, terminated, truncated, info = env.step(action)
                if (terminated or truncated) and same_step:
                    final = {"final_obs": obs, "final_info": info}
                    obs, info = env.reset()
                    info = {**info, **final}
            needs_reset[i] = (terminated or truncated) and not same_step
            write(obs)
            rewards[k] = reward
            flags[k] = 1 if terminated else 0
            flags[n_envs + k] = 1 if truncated else 0
            infos.append(info)
            any_info = any_info or bool(info)
        return infos if any_info else None

    def _write(self, shared: _Shared, k: int, obs, reward, terminated, truncated) -> None:
        if self._bound is not shared:
            self._bind(shared)
        self._writers[k - self.indices.start](obs)
        shared.write_outcome(k, reward, terminated, truncated)

    def call(self, name: str, args, kwargs, only: frozenset | None = None) -> list:
        """Call `name` on this share's envs, or on those whose batch index is in `only`."""
        if name == "__setattr__":
            attribute, values = args
            for env, value in zip(self.envs, values):
                env.set_wrapper_attr(attribute, value)
            return [None] * len(self.envs)
        results = []
        for k, env in zip(self.indices, self.envs):
            if only is not None and k not in only:
                continue
            if callable(name):
                results.append(name(env, *args, **kwargs))
                continue
            attribute = env.get_wrapper_attr(name)
            results.append(attribute(*args, **kwargs) if callable(attribute) else attribute)
        return results

    def close(self) -> None:
        for env in self.envs:
            env.close()


class _Worker:
    """The calling side of one worker process: wake it with a command, wait for its answer."""

    def __init__(self, index: int, process, pipe, go, done, shared: _Shared, spin_seconds: float):
        self.index, self.process, self.pipe, self.go = index, process, pipe, go
        self._commands, self._slot = shared.commands, 2 * index      # its command, then whether it answered
        self._wait = _Waiter(done, spin_seconds, process.is_alive)

    @classmethod
    def start(cls, ctx, index: int, env_fns, share: range, shared: _Shared, autoreset_mode, spin_seconds):
        pipe, child = ctx.Pipe()
        process = ctx.Process(target=_work, daemon=True, name=f"ftcgym-vector-worker-{index + 1}",
                              args=(index, CloudpickleWrapper(env_fns), share, shared, child, autoreset_mode,
                                    spin_seconds, os.getpid()))
        process.start()
        child.close()
        return cls(index, process, pipe, shared.go[index], shared.done[index], shared, spin_seconds)

    def order(self, command: int, payload=None) -> None:
        self._commands[self._slot] = command
        if payload is not None:
            self.pipe.send(payload)
        self.go.release()

    def answer(self):
        """What the worker sent (infos or results), None if nothing; raises what it raised."""
        if not self._wait():
            raise RuntimeError(f"ParallelVectorEnv: worker process {self.index + 1} died "
                               f"(exit code {self.process.exitcode})")
        if not self._commands[self._slot + 1]:
            return None
        self._commands[self._slot + 1] = 0
        kind, value = self.pipe.recv()
        if kind == "error":
            raise RuntimeError(f"ParallelVectorEnv worker {self.index + 1} raised:\n{value}")
        return value

    def stop(self) -> None:
        if self.process.is_alive():
            self.order(CLOSE)
            self.process.join(timeout=5.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=1.0)
        self.pipe.close()


#: gives up the core to any other runnable process (module docstring); where the OS has no sched_yield, a
#: zero sleep does the same
_yield = getattr(os, "sched_yield", lambda: time.sleep(0))
#: polls of a waiting side before its first yield, about 3 us: a poll costs 0.03 us, a yield 0.5 us
BUSY_POLLS = 100
#: the most waits in a row that start yielding at once after the busy polls went unanswered
MOST_RESTS = 256


class _Waiter:
    """Acquires one semaphore: polls it `BUSY_POLLS` times, then polls it for `spin_seconds` yielding the core
    between polls, then sleeps on it, asking `alive()` every half second whether the other side is still there
    (`spin_seconds=0`: one poll, then the sleep).

    Where the busy polls went unanswered, the next waits yield from their first poll: one wait after the first
    such miss, twice as many after each miss that follows (at most `MOST_RESTS`), until the busy polls are
    answered again. On an idle machine they miss only when the other side resets or pauses; on a machine with no
    core to spare they would keep the core from the side they wait for, and there they back off
    (docs/measurements.md, 'The parallel vector env's hand-over, timed')."""

    def __init__(self, semaphore, spin_seconds: float, alive):
        self.semaphore, self.spin_seconds, self.alive = semaphore, spin_seconds, alive
        self._polls, self._rests, self._backoff = BUSY_POLLS if spin_seconds > 0 else 1, 0, 1

    def __call__(self) -> bool:
        """Acquire the semaphore; False if the other side is gone."""
        acquire = self.semaphore.acquire
        if self._rests:
            self._rests -= 1
            if acquire(False):
                return True
        else:
            for _ in range(self._polls):
                if acquire(False):
                    self._backoff = 1
                    return True
            self._rests, self._backoff = self._backoff, min(2 * self._backoff, MOST_RESTS)
        deadline = time.perf_counter() + self.spin_seconds
        while time.perf_counter() < deadline:
            _yield()
            if acquire(False):
                return True
        while not acquire(timeout=0.5):
            if not self.alive():
                return False
        return True


def _work(index: int, env_fns, share: range, shared: _Shared, pipe, autoreset_mode, spin_seconds, parent: int):
    """A worker process: build its envs and answer, then run the calling process's commands until CLOSE."""
    go, done = shared.go[index], shared.done[index]
    commands, slot = shared.commands, 2 * index       # its command, then whether it answered (`_Worker`)
    wait = _Waiter(go, spin_seconds, lambda: os.getppid() == parent)

    def answer(kind: str, value) -> None:
        pipe.send((kind, value))
        commands[slot + 1] = 1

    envs = None
    try:
        envs = _Share(env_fns.fn, share, autoreset_mode)
    except Exception:  # noqa: BLE001 - sent to the calling process, which raises it
        answer("error", traceback.format_exc())
    done.release()

    while envs is not None:
        if not wait():
            break                        # the calling process is gone
        command = commands[slot]
        if command == CLOSE:
            break
        try:
            if command == STEP:
                infos = envs.step(shared)
            elif command == RESET:
                seeds, options = pipe.recv()
                infos = envs.reset(seeds, options, shared)
            else:
                answer("result", envs.call(*pipe.recv()))
                infos = []
            if infos and any(infos):
                answer("infos", infos)
        except Exception:  # noqa: BLE001 - sent to the calling process, which raises it
            answer("error", traceback.format_exc())
        done.release()
    if envs is not None:
        envs.close()
    pipe.close()
