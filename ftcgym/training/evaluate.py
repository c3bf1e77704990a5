"""The benchmark on a learned policy: `ftcgym evaluate MODEL` and the evaluation callback.

Episodes are flown and scored by `ftcgym.benchmark` (`make_env`, `roll_out`, `score_episode`,
`summarize`, `format_table`) with the benchmark's episode seeds, so a learned policy's numbers compare
with `ftcgym bench`'s for the same scenario and seed.
"""
from __future__ import annotations

from collections.abc import Callable

from ftcgym.benchmark import metrics
from ftcgym.benchmark.runner import _native, episode_seed, make_env, roll_out, score_episode
from ftcgym.benchmark.scenarios import Scenario, get_scenario
from ftcgym.fdd import published_detector

DEFAULT_SCENARIO = "quad-rotor-loss-hover"
POLICY_NAME = "learned"


def score_policy(make_policy: Callable, scenario: Scenario | str = DEFAULT_SCENARIO, episodes: int | None = None,
                 seed: int = 0, env_overrides: dict | None = None, policy_name: str = POLICY_NAME) -> list[dict]:
    """Episode rows (EPISODE_FIELDS) of `make_policy(env)` over the scenario's episodes, in-process."""
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    rows = []
    for index in range(episodes or scenario.episodes):
        env = make_env(scenario, env_overrides)
        try:
            episode = episode_seed(seed, index)
            log = roll_out(env, make_policy(env), episode, published_detector(env, scenario.detector))
            values = {"scenario": scenario.name, "policy": policy_name, "seed": int(episode), **score_episode(log)}
        finally:
            env.close()
        rows.append({name: _native(values[name]) for name in metrics.EPISODE_FIELDS})
    return rows


def evaluate_model(path, scenario: Scenario | str = DEFAULT_SCENARIO, episodes: int | None = None, seed: int = 0,
                   env_overrides: dict | None = None) -> tuple[list[dict], list[dict]]:
    """(summary rows, episode rows) of the model saved at `path` on a benchmark scenario."""
    from ftcgym.training.policy import LearnedPolicy
    rows = score_policy(lambda env: LearnedPolicy.load(path, env), scenario, episodes, seed, env_overrides)
    return metrics.summarize(rows), rows
