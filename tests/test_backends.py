"""Backends: local processes and Ray give the same rows; failed episodes and dead workers are retried."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from ftcgym.benchmark.backends import Callbacks, EpisodesFailed, Job, run_jobs
from ftcgym.benchmark.scenarios import get_scenario
from ftcgym.cli import main

ray = pytest.importorskip("ray")  # the `ray` extra; installed with `dev`


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance of 2 CPUs, as CI has; run_jobs uses it instead of starting its own."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    # The fake episodes below live in this test module, which Ray's workers cannot import: send them by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    ray.shutdown()


# ---- fake episodes (module-level, so they pickle to workers); their marker files count attempts ----

def fake_row(scenario, policy, seed) -> dict:
    return {"scenario": scenario.name, "policy": policy, "seed": seed}


def raises_once(scenario, policy, seed, env_overrides):
    """Fails on the first attempt of each seed listed in env_overrides["fail"], then succeeds."""
    _first_attempt_fails(env_overrides, seed, lambda: (_ for _ in ()).throw(RuntimeError(f"boom {seed}")))
    return fake_row(scenario, policy, seed)


def dies_once(scenario, policy, seed, env_overrides):
    """The worker process exits on the first attempt of each listed seed, as a segfaulting simulator would."""
    _first_attempt_fails(env_overrides, seed, lambda: os._exit(1))
    return fake_row(scenario, policy, seed)


def always_raises(scenario, policy, seed, env_overrides):
    if seed in env_overrides["fail"]:
        raise RuntimeError(f"broken episode {seed}")
    return fake_row(scenario, policy, seed)


def _first_attempt_fails(env_overrides, seed, fail) -> None:
    if seed not in env_overrides["fail"]:
        return
    marker = Path(env_overrides["marker_dir"]) / str(seed)
    if not marker.exists():
        marker.touch()
        fail()


def fake_jobs(tmp_path, n=6, fail=(1, 4)) -> list[Job]:
    overrides = {"fail": list(fail), "marker_dir": str(tmp_path)}
    scenario = get_scenario("quad-hover")
    return [Job(f"job{i}", scenario, "nominal", i, overrides) for i in range(n)]


BACKENDS = [("local", 1), ("local", 2), ("ray", 2)]


@pytest.fixture
def backend(request):
    """The parametrized backend name; "ray" brings up the module's local Ray instance."""
    if request.param == "ray":
        request.getfixturevalue("local_ray")
    return request.param


# ---- identical results ----

def test_local_and_ray_write_identical_results(tmp_path, local_ray):
    """The same 20-episode benchmark (rotor losses scored on loe_kalman, 3 s flights) on both backends."""
    def bench(backend):
        out = tmp_path / backend
        assert main(["bench", "--scenario", "quad-rotor-loss-hover", "--policy", "nominal", "--episodes", "20",
                     "--seed", "5", "--workers", "2", "--env-kwargs", '{"max_episode_seconds": 3}',
                     "--backend", backend, "--out", str(out)]) == 0
        return json.loads((out / "results.json").read_text())

    local, on_ray = bench("local"), bench("ray")
    assert len(local["episodes"]) == 20
    assert local["episodes"] == on_ray["episodes"]
    assert local["summary"] == on_ray["summary"]
    assert on_ray["config"]["backend"] == "ray"
    # The comparison covers detections, not only fault-free flights: rotor losses at 2-3 s are caught.
    detected = [row["detection_delay"] for row in local["episodes"] if row["detection_delay"] is not None]
    assert len(detected) >= 3 and all(0.0 < delay < 0.2 for delay in detected)


# ---- retries ----

@pytest.mark.parametrize("backend, workers", BACKENDS, indirect=["backend"])
def test_an_episode_that_raises_once_is_retried_and_reported(tmp_path, backend, workers):
    retried = []
    rows = run_jobs(fake_jobs(tmp_path), backend, workers, episode=raises_once, progress=False,
                    callbacks=Callbacks(retried=lambda job, attempt, error: retried.append((job.key, attempt))))
    assert [row["seed"] for row in rows] == list(range(6))
    assert sorted(retried) == [("job1", 1), ("job4", 1)]


@pytest.mark.parametrize("backend, workers", BACKENDS[1:], indirect=["backend"])
def test_a_worker_that_dies_is_replaced_and_its_episode_rerun(tmp_path, backend, workers):
    retried, finished = [], []
    callbacks = Callbacks(finished=lambda job, row: finished.append(job.key),
                          retried=lambda job, attempt, error: retried.append(job.key))
    rows = run_jobs(fake_jobs(tmp_path, fail=(3,)), backend, workers, episode=dies_once, progress=False,
                    callbacks=callbacks)
    assert [row["seed"] for row in rows] == list(range(6))
    assert sorted(finished) == [f"job{i}" for i in range(6)]
    assert "job3" in retried  # a broken local pool may also take down (and rerun) an episode beside it


@pytest.mark.parametrize("backend, workers", BACKENDS, indirect=["backend"])
def test_an_episode_failing_every_attempt_is_reported_after_the_others_finish(tmp_path, backend, workers):
    finished = []
    with pytest.raises(EpisodesFailed) as failure:
        run_jobs(fake_jobs(tmp_path, fail=(2,)), backend, workers, episode=always_raises, retries=1,
                 progress=False, callbacks=Callbacks(finished=lambda job, row: finished.append(job.key)))
    assert list(failure.value.failures) == ["job2"]
    assert "broken episode 2" in failure.value.failures["job2"]
    assert sorted(finished) == ["job0", "job1", "job3", "job4", "job5"]


def test_bad_backend_arguments_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="backend: unknown 'dask'; accepted: local, ray"):
        run_jobs(fake_jobs(tmp_path), "dask", 1, episode=raises_once)
    with pytest.raises(SystemExit):
        main(["bench", "--chunk", "0"])
