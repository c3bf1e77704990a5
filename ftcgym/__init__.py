"""ftcgym: Gymnasium environments, fault detectors and a benchmark for fault-tolerant flight control."""
from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

_ENVS = {
    "ftcgym/Quadrotor-v0": "ftcgym.envs.quadrotor:QuadrotorEnv",
    "ftcgym/QuadPlane-v0": "ftcgym.envs.quadplane:QuadPlaneEnv",
    "ftcgym/QuadPlaneAutopilot-v0": "ftcgym.task_envs.autopilot:QuadPlaneAutopilotEnv",
    "ftcgym/RotorLossRecovery-v0": "ftcgym.task_envs.rotor_loss_recovery:RotorLossRecoveryEnv",
    "ftcgym/AirspeedSource-v0": "ftcgym.task_envs.airspeed_source:AirspeedSourceEnv",
}
for _id, _entry in _ENVS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry)
