"""The simulation: PyBullet world, vehicle parameter sets, rotor, wind, sensor and fault models, Env classes."""
from .faults import FaultSpec
from .quadplane import QuadPlaneEnv
from .quadrotor import QuadrotorEnv
from .vehicles import VEHICLES, QuadrotorParams, make_params
from .vsqp import VsqpParams, make_vsqp_params

__all__ = ["FaultSpec", "QuadPlaneEnv", "QuadrotorEnv", "QuadrotorParams", "VEHICLES", "VsqpParams", "make_params",
           "make_vsqp_params"]
