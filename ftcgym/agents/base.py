"""The policy interface: `reset(obs, info)` and `act(obs, info) -> action`, and what a policy may see."""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

#: what a policy must not see (docs/concepts.md, "Policies and oracles"): it learns of a fault from detectors
PRIVATE_INFO_KEYS = ("truth", "fault", "faults")
UP = np.array([0.0, 0.0, -1.0])  # NED: the thrust axis of a level vehicle


@runtime_checkable
class Policy(Protocol):
    """What the benchmark and the training code call. `info` never holds `truth`, `fault` or `faults`.

    Optional attributes the benchmark runner honours (read when present, defaults in brackets):

    - `uses_true_onset` (False): an oracle; its `info` also holds `oracle_onset_time` (the true onset, None
      before it) and `oracle_fault_target` (the faulty rotor or channel once the fault began).
    - `uses_true_airspeed` (False): an airspeed oracle; its `info` also holds `oracle_airspeed` (m/s).
    - `thrust_axis_reference` (straight up): the NED unit vector where the policy wants the thrust axis; the
      rotor-loss recovery criterion measures the thrust axis against it.

    By convention a policy that reads a detector names it in `detector` (e.g. "loe_kalman"): the key of
    `info["fdd"]` it reads. The runner does not act on it; the scenario or `--detector` wraps the env.
    """

    def reset(self, obs: dict, info: dict) -> None: ...

    def act(self, obs: dict, info: dict) -> np.ndarray: ...


def policy_view(info: dict, policy) -> dict:
    """A copy of `info` without ground truth, plus what an oracle policy is given (`Policy`)."""
    view = {key: value for key, value in info.items() if key not in PRIVATE_INFO_KEYS}
    if getattr(policy, "uses_true_airspeed", False):
        view["oracle_airspeed"] = info["truth"]["airspeed"]
    if getattr(policy, "uses_true_onset", False):
        onset = info["fault"]["onset_time"]
        view["oracle_onset_time"] = onset
        view["oracle_fault_target"] = info["fault"]["target"] if onset is not None else None
    return view


def thrust_axis_reference(policy) -> np.ndarray:
    """Where the policy wants the thrust axis (NED unit vector); straight up unless it says otherwise."""
    return np.array(getattr(policy, "thrust_axis_reference", UP), dtype=float)


def check_policy(policy, name: str):
    """`policy` if it has callable `reset` and `act`; else TypeError naming what `name` gave."""
    missing = [method for method in ("reset", "act") if not callable(getattr(policy, method, None))]
    if missing:
        raise TypeError(f"policy {name!r}: {type(policy).__name__} has no {' or '.join(missing)}(obs, info); a "
                        f"policy is a class or factory called with the env that returns an object with "
                        f"reset(obs, info) and act(obs, info)")
    return policy
