"""The benchmark on a learned policy: `ftcgym evaluate MODEL` and the evaluation callback.

Episodes are flown and scored by `ftcgym.benchmark` (`make_env`, `roll_out`, `score_episode`,
`summarize`, `format_table`) with the benchmark's episode seeds, so a learned policy's numbers compare
with `ftcgym bench`'s for the same scenario and seed.
"""
from __future__ import annotations

from collections.abc import Callable

from ftcgym.benchmark import metrics
from ftcgym.benchmark.runner import _native, episode_seed, make_scored_env, roll_out, score_episode
from ftcgym.benchmark.scenarios import Scenario, get_scenario

DEFAULT_SCENARIO = "quad-rotor-loss-hover"
POLICY_NAME = "learned"    # a model of a task without a benchmark name (`policy.POLICY_NAMES`)


def score_policy(make_policy: Callable, scenario: Scenario | str = DEFAULT_SCENARIO, episodes: int | None = None,
                 seed: int = 0, env_overrides: dict | None = None, policy_name: str = POLICY_NAME) -> list[dict]:
    """Episode rows (EPISODE_FIELDS) of `make_policy(env)` over the scenario's episodes, in-process."""
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    rows = []
    for index in range(episodes or scenario.episodes):
        env, detector = make_scored_env(scenario, env_overrides)
        try:
            episode = episode_seed(seed, index)
            log = roll_out(env, make_policy(env), episode, detector)
            values = {"scenario": scenario.name, "policy": policy_name, "seed": int(episode), **score_episode(log)}
        finally:
            env.close()
        rows.append({name: _native(values[name]) for name in metrics.EPISODE_FIELDS})
    return rows


def default_scenario(path) -> str:
    """The scenario `ftcgym evaluate` flies the model at `path` through by default: its task's
    (`policy.DEFAULT_SCENARIOS`: quad-rotor-loss-hover, qp-pitot-incipient), else quad-rotor-loss-hover."""
    from ftcgym.training.policy import DEFAULT_SCENARIOS, trained_env_id
    return DEFAULT_SCENARIOS.get(trained_env_id(path), DEFAULT_SCENARIO)


def evaluate_model(path, scenario: Scenario | str | None = None, episodes: int | None = None, seed: int = 0,
                   env_overrides: dict | None = None) -> tuple[list[dict], list[dict]]:
    """(summary rows, episode rows) of the model saved at `path` on a benchmark scenario (default: its task's,
    `default_scenario`), flown by the benchmark policy of the env id it was trained on (`policy.load_policy`)
    under the benchmark's name (`learned-spin`, `learned-airspeed`)."""
    from ftcgym.training.policy import load_policy, policy_name, trained_env_id
    name = policy_name(trained_env_id(path))
    scenario = default_scenario(path) if scenario is None else scenario
    rows = score_policy(lambda env: load_policy(path, env), scenario, episodes, seed, env_overrides, name)
    return metrics.summarize(rows), rows
