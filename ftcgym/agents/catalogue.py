"""The policy catalogue: built-in policies by name, installed plug-ins and MODULE:ATTR (`ftcgym.registry`).

A policy entry is a class or factory called with the env (wrapped or not) that returns an object with
`reset(obs, info)` and `act(obs, info)` (`base.Policy`). The built-in entries are the factories below;
`learned-spin` and `learned-airspeed` live in `ftcgym.training.shipped` and load only when asked for.
"""
from __future__ import annotations

import inspect

from gymnasium import spaces

from ftcgym.registry import Entry, Registry

from ..models.vsqp import VsqpParams
from .airspeed_policies import (
    AirspeedSwitchPolicy,
    AutopilotPolicy,
    OracleAirspeedPolicy,
    PitotOnlyPolicy,
    SyntheticOnlyPolicy,
)
from .base import Policy, check_policy
from .quadrotor_control import NominalController
from .spin_policies import OracleSpinPolicy, SpinAfterAlarmPolicy

_HERE = "ftcgym.agents.catalogue"
POLICIES = Registry("policy", "ftcgym.policies", {
    "nominal": Entry(f"{_HERE}:nominal",
                     "cascaded PID position/attitude/rate controller with model-based mixer; fault-unaware"),
    "ftc-spin": Entry(f"{_HERE}:ftc_spin",
                      "nominal until the loe_kalman (or loe_cusum) alarm, then relaxed-hover spin recovery "
                      "(scheduled LQR of the primary axis) without the isolated rotor; needs one of those detectors"),
    "oracle-spin": Entry(f"{_HERE}:oracle_spin",
                         "upper bound: spin recovery from the true fault onset (benchmark oracle info), not flyable"),
    "autopilot": Entry(f"{_HERE}:autopilot",
                       "quad-plane mission autopilot on QuadPlane-v0's actuators, scheduled on the pitot reading"),
    "pitot-only": Entry(f"{_HERE}:pitot_only",
                        "QuadPlaneAutopilot-v0: feeds the autopilot the pitot reading, faulty or not"),
    "oracle-airspeed": Entry(f"{_HERE}:oracle_airspeed",
                             "QuadPlaneAutopilot-v0 upper bound: feeds the true airspeed (benchmark oracle info)"),
    "airspeed-switch": Entry(f"{_HERE}:airspeed_switch",
                             "QuadPlaneAutopilot-v0: the pitot reading until the first airdata_ekf pitot alarm "
                             "(Table 2, CUSUM or ramp test), then the EKF airspeed; needs the airdata_ekf detector"),
    "synthetic-only": Entry(f"{_HERE}:synthetic_only",
                            "QuadPlaneAutopilot-v0: always the airdata_ekf EKF airspeed; needs the airdata_ekf "
                            "detector"),
    "learned-spin": Entry("ftcgym.training.shipped:learned_spin",
                          "shipped SB3 policy (task rotor-loss-recovery): nominal until the loe_kalman alarm, then "
                          "motor commands from the trained model; needs the loe_kalman detector"),
    "learned-airspeed": Entry("ftcgym.training.shipped:learned_airspeed",
                              "shipped SB3 policy (task airspeed-source) on QuadPlaneAutopilot-v0: the airspeed it "
                              "feeds the autopilot from the pitot and detector outputs; needs the airdata_ekf "
                              "detector"),
})


def make_policy(name: str, env) -> Policy:
    """The policy `name` (a built-in name, an installed plug-in or MODULE:ATTR) for `env`."""
    target = POLICIES.load(name)
    if not callable(target):
        raise TypeError(f"policy {name!r}: a {type(target).__name__} is neither a class nor a factory called with "
                        f"the env")
    try:
        inspect.signature(target).bind(env)
    except TypeError as error:
        raise TypeError(f"policy {name!r}: it is called with the env as its one argument, and {error}") from None
    except ValueError:        # no signature to read (a builtin): let the call say
        pass
    return check_policy(target(env), name)


def is_quadplane(env) -> bool:
    """Whether an env (wrapped or not) flies the quad-plane."""
    return isinstance(env.unwrapped.params, VsqpParams)


def flies_airspeed(env) -> bool:
    """Whether an env (wrapped or not) is QuadPlaneAutopilot-v0, whose action is the airspeed the autopilot uses."""
    return getattr(env.unwrapped, "controls", None) == "airspeed"


def check_flown_env(env, name: str):
    """`env`'s base env, if a built-in policy can fly it: a simulator env (Quadrotor-v0, QuadPlane-v0,
    QuadPlaneAutopilot-v0) with its Dict observation, which the policies read by name; else a ValueError."""
    base = getattr(env, "unwrapped", None)
    if not hasattr(base, "params") or not hasattr(base, "agent_hz"):
        raise ValueError(f"policy: {name!r} flies Quadrotor-v0, QuadPlane-v0 or QuadPlaneAutopilot-v0, not "
                         f"{type(base if base is not None else env).__name__}")
    if not isinstance(env.observation_space, spaces.Dict):
        raise ValueError(f"policy: {name!r} reads the observation by name: make the env with "
                         f"observation_format='dict' (the default), not {type(env.observation_space).__name__}")
    return base


def _quadrotor(env, name: str):
    base = check_flown_env(env, name)
    if is_quadplane(env):
        raise ValueError(f"policy: {name!r} flies the quadrotor, not {type(base).__name__}; accepted: "
                         f"{_accepted(env)}")
    return base


def _quadplane(env, name: str, airspeed: bool):
    base = check_flown_env(env, name)
    if not is_quadplane(env) or flies_airspeed(env) != airspeed:
        raise ValueError(f"policy: {name!r} does not fly {type(base).__name__}; accepted: {_accepted(env)}")
    return base


def _accepted(env) -> list[str]:
    if not is_quadplane(env):
        return ["nominal", "ftc-spin", "oracle-spin", "learned-spin"]
    if flies_airspeed(env):
        return ["pitot-only", "oracle-airspeed", "airspeed-switch", "synthetic-only", "learned-airspeed"]
    return ["autopilot"]


def nominal(env) -> NominalController:
    base = _quadrotor(env, "nominal")
    return NominalController(base.params, base.agent_hz)


#: rotor-loss detectors the spin policies can act on, in order of preference when an env carries several
ROTOR_LOSS_DETECTORS = ("loe_kalman", "loe_cusum")


def rotor_loss_detector(env) -> str:
    """The rotor-loss detector `env` is wrapped with (ROTOR_LOSS_DETECTORS, the first found); "loe_kalman" when
    none is (the policy then says it needs it)."""
    import gymnasium as gym

    from ..fdd.wrapper import DetectorWrapper
    found = set()
    while isinstance(env, gym.Wrapper):
        if isinstance(env, DetectorWrapper):
            found.add(env.detector.name)
        env = env.env
    return next((name for name in ROTOR_LOSS_DETECTORS if name in found), ROTOR_LOSS_DETECTORS[0])


def ftc_spin(env) -> SpinAfterAlarmPolicy:
    base = _quadrotor(env, "ftc-spin")
    return SpinAfterAlarmPolicy(base.params, base.agent_hz, detector=rotor_loss_detector(env))


def oracle_spin(env) -> OracleSpinPolicy:
    base = _quadrotor(env, "oracle-spin")
    return OracleSpinPolicy(base.params, base.agent_hz, detector=rotor_loss_detector(env))


def autopilot(env) -> AutopilotPolicy:
    base = _quadplane(env, "autopilot", airspeed=False)
    return AutopilotPolicy(base.params, base.agent_hz, base.task)


def _airspeed_policy(cls, name: str):
    """The factory of a QuadPlaneAutopilot-v0 policy class that takes no arguments."""
    def factory(env):
        _quadplane(env, name, airspeed=True)
        return cls()
    factory.__doc__ = cls.__doc__.splitlines()[0]
    return factory


pitot_only = _airspeed_policy(PitotOnlyPolicy, "pitot-only")
oracle_airspeed = _airspeed_policy(OracleAirspeedPolicy, "oracle-airspeed")
airspeed_switch = _airspeed_policy(AirspeedSwitchPolicy, "airspeed-switch")
synthetic_only = _airspeed_policy(SyntheticOnlyPolicy, "synthetic-only")
