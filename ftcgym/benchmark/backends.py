"""Where benchmark episodes run: in this process, in local worker processes, or as Ray tasks.

Every backend calls the same episode function (`runner.run_episode` unless told otherwise) on the same
`Job`s, and episodes are seeded per episode, so the backends give identical rows. They differ in where
the work runs and in how a failure is retried:

- `local`: one process (workers=1) or a `ProcessPoolExecutor`. An episode that raises is submitted again;
  a worker process that dies breaks the pool, which is rebuilt for the episodes it took down.
- `ray`: Ray tasks of `chunk` episodes each, on a local Ray instance of `workers` CPUs or on the cluster at
  `ray_address`. Ray itself retries a task that raises or whose worker dies (`max_retries`,
  `retry_exceptions`) and prints each retry on the driver's console.

Each attempt past the first counts against `retries`; an episode that still fails is reported in
`EpisodesFailed` once every other episode has finished, so one bad episode never costs the rest.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tqdm import tqdm

if TYPE_CHECKING:  # at run time only as an annotation: this module stays light for the CLI's parser
    from ftcgym.benchmark.scenarios import Scenario

BACKENDS = ("local", "ray")
DEFAULT_RETRIES = 2


@dataclass(frozen=True)
class Job:
    """One episode to fly. `key` names it uniquely within a run: results and resumption go by it."""

    key: str
    scenario: Scenario
    policy: str
    seed: int
    env_overrides: dict | None = None

    def arguments(self) -> tuple:
        return self.scenario, self.policy, self.seed, self.env_overrides


class EpisodesFailed(RuntimeError):
    """Episodes that failed on every attempt: `failures` maps their keys to the last error."""

    def __init__(self, failures: dict[str, str]):
        self.failures = failures
        listing = "\n".join(f"  {key}: {error}" for key, error in failures.items())
        super().__init__(f"{len(failures)} episode(s) failed on every attempt:\n{listing}")


@dataclass
class Callbacks:
    """What a backend reports as it goes. `finished(job, row)` on each success, `retried(job, attempt, error)`
    when an attempt failed and the episode is run again (attempt 1 = the first retry)."""

    finished: Callable[[Job, dict], None] = lambda job, row: None
    retried: Callable[[Job, int, str], None] = lambda job, attempt, error: None


def add_backend_arguments(parser) -> None:
    """The backend options shared by `ftcgym bench` and `ftcgym sweep`."""
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local: worker processes on this machine (default); ray: Ray tasks")
    parser.add_argument("--ray-address", metavar="ADDR",
                        help="address of a running Ray cluster, e.g. 10.0.0.5:6379 or 'auto' "
                             "(default: start a local Ray instance of --workers CPUs)")
    parser.add_argument("--chunk", type=int_at_least(1), default=1, metavar="N",
                        help="episodes per Ray task (default: 1)")
    parser.add_argument("--retries", type=int_at_least(0), default=DEFAULT_RETRIES, metavar="N",
                        help=f"times a failed episode is run again (default: {DEFAULT_RETRIES})")


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer >= minimum."""
    def parse(text: str) -> int:
        if not text.lstrip("-").isdigit() or int(text) < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return int(text)
    return parse


def run_jobs(jobs: list[Job], backend: str = "local", workers: int = 1, *, ray_address: str | None = None,
             chunk: int = 1, retries: int = DEFAULT_RETRIES, callbacks: Callbacks | None = None,
             episode: Callable | None = None, keep_trajectory: bool = True, progress: bool = True) -> list[dict]:
    """Run every job; return the rows in job order. Raises EpisodesFailed after the others finished.

    `episode(scenario, policy, seed, env_overrides) -> row` (default `runner.run_episode`) must be a
    module-level function: it is pickled to the workers. Without `keep_trajectory` the rows lose
    "trajectory" in the worker, which saves moving it between processes when only the metrics are wanted.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend: unknown {backend!r}; accepted: {', '.join(BACKENDS)}")
    if chunk < 1 or retries < 0 or workers < 1:
        raise ValueError(f"chunk and workers must be >= 1 and retries >= 0, got {chunk}, {workers}, {retries}")
    if not jobs:  # e.g. a resumed sweep with nothing left: start no pool and no Ray instance
        return []
    if episode is None:
        from ftcgym.benchmark.runner import run_episode as episode  # here: the runner imports this module
    callbacks = callbacks or Callbacks()
    rows: list[dict | None] = [None] * len(jobs)
    failures: dict[str, str] = {}
    with tqdm(total=len(jobs), desc=backend, unit="episode", disable=not progress) as bar:
        def finished(index: int, row: dict) -> None:
            rows[index] = row
            callbacks.finished(jobs[index], row)
            bar.update()

        def failed(index: int, error: str) -> None:
            failures[jobs[index].key] = error
            bar.update()

        runner = _run_on_ray if backend == "ray" else _run_locally
        runner(_Work(jobs, episode, keep_trajectory, retries, finished, failed, callbacks.retried),
               workers=workers, ray_address=ray_address, chunk=chunk)
    if failures:
        raise EpisodesFailed(failures)
    return rows


@dataclass
class _Work:
    """The jobs and what to do with their outcomes, handed to a backend."""

    jobs: list[Job]
    episode: Callable
    keep_trajectory: bool
    retries: int
    finished: Callable[[int, dict], None]
    failed: Callable[[int, str], None]
    retried: Callable[[Job, int, str], None]


def run_chunk(episode: Callable, jobs: list[Job], keep_trajectory: bool) -> list[dict]:
    """Fly `jobs` one after the other in this process (the unit of work of a worker or a Ray task)."""
    rows = [episode(*job.arguments()) for job in jobs]
    if not keep_trajectory:
        for row in rows:
            row.pop("trajectory", None)
    return rows


# ---- local: this process, or a process pool ----

def _run_locally(work: _Work, workers: int, **_) -> None:
    if workers == 1 or len(work.jobs) <= 1:
        for index in range(len(work.jobs)):
            _run_in_process(work, index)
        return
    todo = list(range(len(work.jobs)))
    attempts = [0] * len(work.jobs)
    while todo:  # each round runs in a fresh pool: a worker that died leaves its pool broken
        todo = _pool_round(work, todo, attempts, min(workers, len(todo)))


def _run_in_process(work: _Work, index: int) -> None:
    for attempt in range(work.retries + 1):
        try:
            [row] = run_chunk(work.episode, [work.jobs[index]], work.keep_trajectory)
        except Exception as error:  # an episode's bug or a simulator fault: retry, then report
            if attempt == work.retries:
                work.failed(index, _describe(error))
            else:
                work.retried(work.jobs[index], attempt + 1, _describe(error))
            continue
        work.finished(index, row)
        return


def _pool_round(work: _Work, todo: list[int], attempts: list[int], workers: int) -> list[int]:
    """Run `todo` in one pool, resubmitting episodes that raised; return those a broken pool took down."""
    broken: list[int] = []
    pool = ProcessPoolExecutor(workers, initializer=_exit_with_parent, initargs=(os.getpid(),))
    running: dict = {}

    def submit(index: int) -> None:
        try:
            running[pool.submit(run_chunk, work.episode, [work.jobs[index]], work.keep_trajectory)] = index
        except BrokenProcessPool:
            broken.append(index)

    try:
        for index in todo:
            submit(index)
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                index, error = running.pop(future), future.exception()
                if error is None:
                    work.finished(index, future.result()[0])
                    continue
                attempts[index] += 1
                if attempts[index] > work.retries:
                    work.failed(index, _describe(error))
                    continue
                work.retried(work.jobs[index], attempts[index], _describe(error))
                if isinstance(error, BrokenProcessPool):
                    broken.append(index)  # the pool is gone: the next round's pool runs it
                else:
                    submit(index)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)  # Ctrl-C: leave no queued episode behind
        raise
    pool.shutdown()
    return broken


def _exit_with_parent(parent: int) -> None:
    """Pool worker initializer: end this worker once its parent is gone. A driver killed outright (SIGKILL,
    the OOM killer) cannot shut its pool down, and the workers would otherwise wait on its queue forever.

    Also one torch thread per worker, if the parent loaded torch (a learned policy built by `check_setup`):
    a thread pool torch started before the fork does not exist in the child, whose first parallel operation
    then waits on it for ever; and with a worker per core, more threads would only compete."""
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def _describe(error: BaseException) -> str:
    if isinstance(error, BrokenProcessPool):
        return "a worker process died (BrokenProcessPool)"
    return "".join(traceback.format_exception_only(type(error), error)).strip()


# ---- Ray ----

def _run_on_ray(work: _Work, workers: int, ray_address: str | None, chunk: int) -> None:
    import ray  # the optional extra `ftcgym[ray]`

    started_here = not ray.is_initialized()
    if started_here:
        # No address: a private local instance of `workers` CPUs; with one: join that cluster, whose size rules.
        if ray_address:
            ray.init(address=ray_address)
        else:
            ray.init(num_cpus=workers, include_dashboard=False)
    try:
        _submit_and_collect(ray, work, chunk)
    finally:
        if started_here:
            ray.shutdown()


def _submit_and_collect(ray, work: _Work, chunk: int) -> None:
    """One task per chunk; rows are handed on as tasks finish (ray.wait), so none is lost to a later failure."""
    task = ray.remote(_ray_task).options(num_cpus=1, max_retries=work.retries, retry_exceptions=True)
    chunks = [list(range(start, min(start + chunk, len(work.jobs)))) for start in range(0, len(work.jobs), chunk)]
    pending = {task.remote(work.episode, [work.jobs[i] for i in indices], work.keep_trajectory): indices
               for indices in chunks}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        indices = pending.pop(ready[0])
        try:
            rows, attempt = ray.get(ready[0])
        except ray.exceptions.RayError as error:  # failed on every attempt (raised, or its worker died)
            for index in indices:
                work.failed(index, _describe_ray_error(error))
            continue
        for index, row in zip(indices, rows):
            if attempt:  # Ray printed each failed attempt; say which episodes it took more than one for
                work.retried(work.jobs[index], attempt, "failed attempt(s) printed by Ray on the console")
            work.finished(index, row)


def _ray_task(episode: Callable, jobs: list[Job], keep_trajectory: bool) -> tuple[list[dict], int]:
    """A Ray task: the chunk's rows and the attempt that produced them (0 = the first)."""
    return run_chunk(episode, jobs, keep_trajectory), _ray_attempt_number()


def _ray_attempt_number() -> int:
    # Ray has no public accessor for a task's attempt number; its core worker has one. 0 if it goes away.
    try:
        import ray
        return int(ray._private.worker.global_worker.core_worker.get_current_task_attempt_number())
    except Exception:  # noqa: BLE001 - only the report loses the count
        print("ftcgym: could not read the Ray task attempt number", file=sys.stderr)
        return 0


def _describe_ray_error(error: BaseException) -> str:
    cause = getattr(error, "cause", None)
    return _describe(cause) if isinstance(cause, BaseException) else type(error).__name__
