"""Controllers and policies with the interface of DESIGN.md: `reset(obs, info)`, `act(obs, info)`."""
from __future__ import annotations

from .base import Policy
from .quadrotor_control import ControllerGains, NominalController, allocation_matrix

POLICY_DESCRIPTIONS = {
    "nominal": "cascaded PID position/attitude/rate controller with model-based mixer; fault-unaware",
}
POLICY_NAMES = tuple(POLICY_DESCRIPTIONS)


def make_policy(name: str, env) -> Policy:
    """The named benchmark policy for `env` (a gymnasium env, wrapped or not)."""
    base = env.unwrapped
    if name == "nominal":
        return NominalController(base.params, base.agent_hz)
    raise ValueError(f"policy: unknown name {name!r}; accepted: {list(POLICY_NAMES)}")


__all__ = ["ControllerGains", "NominalController", "POLICY_DESCRIPTIONS", "POLICY_NAMES", "Policy", "allocation_matrix", "make_policy"]
