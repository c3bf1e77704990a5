"""The plant models, pure numpy: importable without PyBullet, so detectors and controllers share them.

Vehicle parameter sets (`quadrotor`, `vsqp`), rotor and pusher propulsion (`rotors`, `pusher`), the
quad-plane's aerodynamics (`quadplane_aero`), rotations (`geometry`), wind (`wind`), sensors (`sensors`),
reference tasks (`tasks`) and fault injection (`faults`). The PyBullet side is `ftcgym.envs`.
"""
from .constants import GRAVITY
from .faults import FaultSpec
from .quadrotor import VEHICLES, QuadrotorParams, make_params
from .vsqp import QUADPLANE_VEHICLES, VsqpParams, make_vsqp_params
from .wind import DrydenWind

__all__ = ["GRAVITY", "DrydenWind", "FaultSpec", "QUADPLANE_VEHICLES", "QuadrotorParams", "VEHICLES", "VsqpParams",
           "make_params", "make_vsqp_params"]
