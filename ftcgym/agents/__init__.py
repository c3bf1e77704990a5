"""Controllers and policies with the interface `reset(obs, info)`, `act(obs, info)` (`base.Policy`).

`make_policy(name, env)` builds one by name: a built-in one (`catalogue.POLICIES`), an installed plug-in
(entry-point group `ftcgym.policies`) or a MODULE:ATTR reference (`ftcgym.registry`).
"""
from __future__ import annotations

from .airspeed_policies import (
                                AirspeedSwitchPolicy,
                                AutopilotPolicy,
                                OracleAirspeedPolicy,
                                PitotOnlyPolicy,
                                SyntheticOnlyPolicy,
)
from .base import Policy, policy_view, thrust_axis_reference
from .catalogue import POLICIES, flies_airspeed, is_quadplane, make_policy
from .quadrotor_control import ControllerGains, NominalController, allocation_matrix
from .relaxed_hover import relaxed_hover_equilibrium
from .spin_policies import OracleSpinPolicy, SpinAfterAlarmPolicy
from .spin_recovery import SpinRecoveryController, SpinRecoveryGains

__all__ = ["AirspeedSwitchPolicy", "AutopilotPolicy", "ControllerGains", "NominalController", "OracleAirspeedPolicy",
           "OracleSpinPolicy", "POLICIES", "PitotOnlyPolicy", "Policy", "SpinAfterAlarmPolicy",
           "SpinRecoveryController", "SpinRecoveryGains", "SyntheticOnlyPolicy", "allocation_matrix",
           "flies_airspeed", "is_quadplane", "make_policy", "policy_view", "relaxed_hover_equilibrium",
           "thrust_axis_reference"]
