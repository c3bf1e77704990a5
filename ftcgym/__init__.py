"""ftcgym: Gymnasium environments, fault detectors and a benchmark for fault-tolerant flight control."""
from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

if "ftcgym/Quadrotor-v0" not in registry:
    register(id="ftcgym/Quadrotor-v0", entry_point="ftcgym.envs.quadrotor:QuadrotorEnv")
