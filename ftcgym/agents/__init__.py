"""Controllers and policies with the interface of DESIGN.md: `reset(obs, info)`, `act(obs, info)`."""
from __future__ import annotations

from .base import Policy
from .quadrotor_control import ControllerGains, NominalController, allocation_matrix
from .relaxed_hover import relaxed_hover_equilibrium
from .spin_policies import OracleSpinPolicy, SpinAfterAlarmPolicy
from .spin_recovery import SpinRecoveryController, SpinRecoveryGains

POLICY_DESCRIPTIONS = {
    "nominal": "cascaded PID position/attitude/rate controller with model-based mixer; fault-unaware",
    "ftc-spin": "nominal until the loe_kalman alarm, then relaxed-hover spin recovery (scheduled LQR of the "
                "primary axis) without the isolated rotor; needs the loe_kalman detector",
    "oracle-spin": "upper bound: spin recovery from the true fault onset (benchmark oracle info), not flyable",
}
POLICY_NAMES = tuple(POLICY_DESCRIPTIONS)


def make_policy(name: str, env) -> Policy:
    """The named benchmark policy for `env` (a gymnasium env, wrapped or not)."""
    base = env.unwrapped
    if name == "nominal":
        return NominalController(base.params, base.agent_hz)
    if name == "ftc-spin":
        return SpinAfterAlarmPolicy(base.params, base.agent_hz)
    if name == "oracle-spin":
        return OracleSpinPolicy(base.params, base.agent_hz)
    raise ValueError(f"policy: unknown name {name!r}; accepted: {list(POLICY_NAMES)}")


__all__ = ["ControllerGains", "NominalController", "OracleSpinPolicy", "POLICY_DESCRIPTIONS", "POLICY_NAMES", "Policy",
           "SpinAfterAlarmPolicy", "SpinRecoveryController", "SpinRecoveryGains", "allocation_matrix", "make_policy",
           "relaxed_hover_equilibrium"]
