"""Policies for the quad-plane: which airspeed the autopilot schedules on (QuadPlaneAutopilot-v0), and the
autopilot itself as an actuator-level policy (QuadPlane-v0)."""
from __future__ import annotations

import numpy as np

from .quadplane_autopilot import QuadPlaneAutopilot


class PitotOnlyPolicy:
    """`pitot-only`: feeds the pitot reading, whatever it says (the autopilot without fault tolerance)."""

    def reset(self, obs: dict, info: dict) -> None:
        pass

    def act(self, obs: dict, info: dict) -> np.ndarray:
        return np.array([obs["pitot_airspeed"][0]], dtype=np.float32)


class OracleAirspeedPolicy:
    """`oracle-airspeed`: feeds the true airspeed, an upper bound rather than a flyable policy; the benchmark
    hands it `info["oracle_airspeed"]` (`uses_true_airspeed`)."""

    uses_true_airspeed = True

    def reset(self, obs: dict, info: dict) -> None:
        pass

    def act(self, obs: dict, info: dict) -> np.ndarray:
        if "oracle_airspeed" not in info:
            raise ValueError("oracle-airspeed needs info['oracle_airspeed'] (the benchmark runner provides it)")
        return np.array([info["oracle_airspeed"]], dtype=np.float32)


class AutopilotPolicy:
    """`autopilot`: the mission autopilot flying QuadPlane-v0's actuators on the pitot reading."""

    def __init__(self, params, agent_hz: float, task):
        self.autopilot = QuadPlaneAutopilot(params, agent_hz, task)

    def reset(self, obs: dict, info: dict) -> None:
        self.autopilot.reset(obs, info)

    def act(self, obs: dict, info: dict) -> np.ndarray:
        return self.autopilot.act(obs, info)
