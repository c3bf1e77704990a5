"""The simulation: PyBullet world, vehicle parameter sets, rotor, wind, sensor and fault models, Env classes."""
from .faults import FaultSpec
from .quadrotor import QuadrotorEnv
from .vehicles import VEHICLES, QuadrotorParams, make_params

__all__ = ["FaultSpec", "QuadrotorEnv", "QuadrotorParams", "VEHICLES", "make_params"]
