"""The PyBullet side of the simulation: the world of one rigid body and the Env classes.

The numpy models these envs assemble (parameter sets, rotors, aerodynamics, wind, sensors, faults) are in
`ftcgym.models`; they are re-exported here for convenience.
"""
from ..models import VEHICLES, FaultSpec, QuadrotorParams, VsqpParams, make_params, make_vsqp_params
from .quadplane import QuadPlaneEnv
from .quadrotor import QuadrotorEnv

__all__ = ["FaultSpec", "QuadPlaneEnv", "QuadrotorEnv", "QuadrotorParams", "VEHICLES", "VsqpParams", "make_params",
           "make_vsqp_params"]
