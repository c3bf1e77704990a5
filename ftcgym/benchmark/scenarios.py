"""The scenario catalogue: what `ftcgym bench` flies, by name.

A scenario is an env id with its `gym.make` keyword arguments, the policies and number of episodes
flown by default, and the detector whose alarm the benchmark scores. Add one with `register`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

QUADROTOR = "ftcgym/Quadrotor-v0"
LIGHT_TURBULENCE = {"mean": [0.0, 0.0, 0.0], "turbulence": "light"}


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario.

    `detector` names the `info["fdd"]` entry whose alarm is scored (None: no detection metrics);
    the env must carry that detector, e.g. through `wrappers`: callables env -> env applied in order
    after `gym.make` (module-level, so episodes can run in worker processes). `default` scenarios
    are those `ftcgym bench` runs when no `--scenario` is given.
    """

    name: str
    env_id: str
    env_kwargs: dict = field(default_factory=dict)
    policies: tuple[str, ...] = ("nominal",)
    episodes: int = 4
    detector: str | None = None
    description: str = ""
    default: bool = False
    wrappers: tuple[Callable, ...] = ()


SCENARIOS: dict[str, Scenario] = {}


def register(scenario: Scenario) -> Scenario:
    """Add `scenario` to the catalogue; a name can be registered once."""
    if scenario.name in SCENARIOS:
        raise ValueError(f"scenario {scenario.name!r} is already registered")
    SCENARIOS[scenario.name] = scenario
    return scenario


def get_scenario(name: str) -> Scenario:
    """The registered scenario called `name`."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; registered: {', '.join(SCENARIOS)}") from None


def default_scenarios() -> list[Scenario]:
    """The scenarios `ftcgym bench` runs with no arguments, in registration order."""
    return [scenario for scenario in SCENARIOS.values() if scenario.default]


# Episode counts keep `ftcgym bench` to a few minutes on 2 cores (about 2,000-4,000 env steps/s
# with the controller in the loop at 500 Hz).
register(Scenario(
    name="quad-hover",
    env_id=QUADROTOR,
    env_kwargs={"task": "hover", "max_episode_seconds": 20.0,
                "wind": {"mean": [1.0, -1.0, 0.0], "turbulence": "light"}},
    episodes=4,
    description="Quadrotor hover for 20 s in a 1.4 m/s wind with light turbulence, no fault.",
    default=True,
))
register(Scenario(
    name="quad-square",
    env_id=QUADROTOR,
    env_kwargs={"task": "square", "max_episode_seconds": 45.0, "wind": LIGHT_TURBULENCE},
    episodes=4,
    description="Quadrotor flies a square for 45 s in light turbulence, no fault.",
    default=True,
))
register(Scenario(
    name="quad-rotor-loss-hover",
    env_id=QUADROTOR,
    env_kwargs={"task": "hover", "max_episode_seconds": 10.0, "wind": LIGHT_TURBULENCE,
                "faults": "random:rotor_loss"},
    episodes=8,
    description="Quadrotor hover in light turbulence; one random rotor loses its propeller at 2-5 s.",
    default=True,
))
