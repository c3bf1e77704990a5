"""What a benchmark run records, assembled in one place: `results.json` = {"summary", "episodes", "config"}
(docs/concepts.md, "Benchmark metrics"), the document every report and table is made from."""
from __future__ import annotations

import dataclasses

from ftcgym.benchmark.metrics import EPISODE_FIELDS, summarize
from ftcgym.benchmark.scenarios import Scenario


def with_detector(scenario: Scenario, detector: str | None = None, detector_kwargs: dict | None = None) -> Scenario:
    """`scenario` scored on `detector` (any name `ftcgym.fdd.wrap_with_detector` takes) built with
    `detector_kwargs`; kwargs alone update the scenario's own detector's. ValueError for kwargs without any."""
    if detector is None and not detector_kwargs:
        return scenario
    name = detector or scenario.detector
    if name is None:
        raise ValueError(f"detector_kwargs: scenario {scenario.name!r} has no detector; name one")
    own = scenario.detector_kwargs if name == scenario.detector else {}
    return dataclasses.replace(scenario, detector=name, detector_kwargs={**own, **(detector_kwargs or {})})


def run_config(command: str, version: str, scenarios: list[Scenario], *, seed: int, episodes: int | None,
               policies: list[str] | None, workers: int, backend: str, env_overrides: dict,
               wall_time_s: float) -> dict:
    """The run's settings as results.json records them: enough to repeat it. Names are kept as given; `workers` is
    the number of processes that flew (the command keeps the number asked for)."""
    return {
        "command": command,
        "ftcgym_version": version,
        "seed": seed,
        "episodes": episodes,
        "policies": policies,
        "workers": workers,
        "backend": backend,
        "env_overrides": env_overrides,
        "scenarios": [{
            "name": scenario.name,
            "env_id": scenario.env_id,
            "env_kwargs": {**scenario.env_kwargs, **env_overrides},
            "policies": list(policies or scenario.policies),
            "episodes": episodes or scenario.episodes,
            "detector": scenario.detector,
            "detector_kwargs": scenario.detector_kwargs,
            "description": scenario.description,
            "fault_wrappers": [_qualified_name(wrap) for wrap in scenario.fault_wrappers],
            "wrappers": [_qualified_name(wrap) for wrap in scenario.wrappers],
        } for scenario in scenarios],
        "wall_time_s": wall_time_s,
    }


def _qualified_name(function) -> str:
    """MODULE:NAME of a wrapper callable (its repr where it has none), so results.json says what wrapped the env."""
    module, name = getattr(function, "__module__", None), getattr(function, "__qualname__", None)
    return f"{module}:{name}" if module and name else repr(function)


def results_document(episodes: list[dict], config: dict) -> dict:
    """{"summary": per scenario and policy, "episodes": rows of EPISODE_FIELDS, "config": config}."""
    return {"summary": summarize(episodes),
            "episodes": [{field: episode[field] for field in EPISODE_FIELDS} for episode in episodes],
            "config": config}
