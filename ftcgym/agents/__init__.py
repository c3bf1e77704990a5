"""Controllers and policies with the interface of DESIGN.md: `reset(obs, info)`, `act(obs, info)`."""
from __future__ import annotations

from .airspeed_policies import (AirspeedSwitchPolicy, AutopilotPolicy, OracleAirspeedPolicy, PitotOnlyPolicy,
                                SyntheticOnlyPolicy)
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
    "autopilot": "quad-plane mission autopilot on QuadPlane-v0's actuators, scheduled on the pitot reading",
    "pitot-only": "QuadPlaneAutopilot-v0: feeds the autopilot the pitot reading, faulty or not",
    "oracle-airspeed": "QuadPlaneAutopilot-v0 upper bound: feeds the true airspeed (benchmark oracle info)",
    "airspeed-switch": "QuadPlaneAutopilot-v0: the pitot reading until the first airdata_ekf pitot alarm (Table 2 "
                       "or CUSUM), then the EKF airspeed; needs the airdata_ekf detector",
    "synthetic-only": "QuadPlaneAutopilot-v0: always the airdata_ekf EKF airspeed; needs the airdata_ekf detector",
    "learned-spin": "shipped SB3 policy (task rotor-loss-recovery): nominal until the loe_kalman alarm, then "
                    "motor commands from the trained model; needs the loe_kalman detector",
    "learned-airspeed": "shipped SB3 policy (task airspeed-source) on QuadPlaneAutopilot-v0: the airspeed it feeds "
                        "the autopilot from the pitot and detector outputs; needs the airdata_ekf detector",
}
QUADPLANE_POLICIES = ("autopilot", "pitot-only", "oracle-airspeed", "airspeed-switch", "synthetic-only")
POLICY_NAMES = tuple(POLICY_DESCRIPTIONS)


def is_quadplane(base) -> bool:
    """Whether an unwrapped env flies the quad-plane (its parameter set has hover rotors)."""
    return hasattr(base.params, "hover_thrust_coefficient")


def flies_airspeed(base) -> bool:
    """Whether an unwrapped env is QuadPlaneAutopilot-v0, whose action is the airspeed the autopilot uses."""
    return hasattr(base, "autopilot")


def make_policy(name: str, env) -> Policy:
    """The named benchmark policy for `env` (a gymnasium env, wrapped or not)."""
    if name in ("learned-spin", "learned-airspeed"):
        from ftcgym.training.shipped import load_shipped
        return load_shipped(name, env)
    base = env.unwrapped
    if name in QUADPLANE_POLICIES or is_quadplane(base):
        return _quadplane_policy(name, base)
    if name == "nominal":
        return NominalController(base.params, base.agent_hz)
    if name == "ftc-spin":
        return SpinAfterAlarmPolicy(base.params, base.agent_hz)
    if name == "oracle-spin":
        return OracleSpinPolicy(base.params, base.agent_hz)
    raise ValueError(f"policy: unknown name {name!r}; accepted: {list(POLICY_NAMES)}")


def _quadplane_policy(name: str, base) -> Policy:
    autopilot_env = flies_airspeed(base)
    airspeed = {"pitot-only": PitotOnlyPolicy, "oracle-airspeed": OracleAirspeedPolicy,
                "airspeed-switch": AirspeedSwitchPolicy, "synthetic-only": SyntheticOnlyPolicy}
    wanted = False if name == "autopilot" else (True if name in airspeed else None)
    if wanted is None or wanted != autopilot_env:
        accepted = list(airspeed) if autopilot_env else ["autopilot"]
        raise ValueError(f"policy: {name!r} does not fly {type(base).__name__}; accepted: {accepted}")
    if name == "autopilot":
        return AutopilotPolicy(base.params, base.agent_hz, base.task)
    return airspeed[name]()


__all__ = ["AirspeedSwitchPolicy", "SyntheticOnlyPolicy", "AutopilotPolicy", "OracleAirspeedPolicy", "PitotOnlyPolicy", "ControllerGains", "NominalController", "OracleSpinPolicy", "POLICY_DESCRIPTIONS", "POLICY_NAMES", "Policy",
           "SpinAfterAlarmPolicy", "SpinRecoveryController", "SpinRecoveryGains", "allocation_matrix", "make_policy",
           "relaxed_hover_equilibrium"]
