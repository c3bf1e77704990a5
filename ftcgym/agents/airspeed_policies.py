"""Policies for the quad-plane: which airspeed the autopilot schedules on (QuadPlaneAutopilot-v0), and the
autopilot itself as an actuator-level policy (QuadPlane-v0)."""
from __future__ import annotations

import numpy as np

from .quadplane_autopilot import QuadPlaneAutopilot

#: The `airdata_ekf` pitot tests, as named in its status (`alarm_time_<test>`).
PITOT_TESTS = ("table2", "cusum", "ramp")


class PitotOnlyPolicy:
    """`pitot-only`: feeds the pitot reading, whatever it says (the autopilot without fault tolerance)."""

    def reset(self, obs: dict, info: dict) -> None:
        pass

    def act(self, obs: dict, info: dict) -> np.ndarray:
        return np.array([obs["pitot_airspeed"][0]], dtype=np.float32)


class AirspeedSwitchPolicy:
    """`airspeed-switch`: feeds the pitot reading until the first of the `airdata_ekf` detector's pitot tests
    alarms, then the EKF's synthetic airspeed (`obs["fdd/airdata_ekf/airspeed"]`) for good (001 Sec. 7.2.1:
    "switch to the synthetic airspeed estimation"). The env must be wrapped with the `airdata_ekf` detector.

    `tests`: the pitot tests it switches on, by default all three that the detector runs on the residual: 001's
    Table 2 thresholds (Sec. 6.1), the CUSUM that Sec. 7.2.2 and 8.1 recommend for incipient faults and the
    ramp-onset GLR (`pitot_detection.RampGlr`), the last two set to the same false-alarm budget. Table 2 alone
    alarms on the -2.5 m/s^2 ramp ~2.45 s after onset, when the reading is ~6 m/s low, and the autopilot flying
    on it until then rolls past 45 deg in most flights; the CUSUM alarms ~0.7 s sooner, the ramp test ~1.5 s
    sooner. Measured on tuning flights; see docs/measurements.md, 'Tuning record: agents/airspeed_policies.py'
    and 'Tuning record: fdd/pitot_detection.py'.
    """

    detector = "airdata_ekf"

    def __init__(self, tests: tuple[str, ...] = PITOT_TESTS):
        unknown = [t for t in tests if t not in PITOT_TESTS]
        if unknown or not tests:
            raise ValueError(f"airspeed-switch: tests {list(tests)!r}; accepted: a non-empty subset of "
                             f"{list(PITOT_TESTS)}")
        self.tests = tuple(tests)
        self.switched_at = None

    def reset(self, obs: dict, info: dict) -> None:
        self.switched_at = None

    def _status(self, info: dict) -> dict:
        status = info.get("fdd", {}).get(self.detector)
        if status is None:
            raise ValueError(f"{type(self).__name__}: needs the env wrapped with the {self.detector!r} detector "
                             f"(e.g. `ftcgym bench --detector {self.detector}`)")
        return status

    def _synthetic(self, obs: dict) -> np.ndarray:
        return np.array([obs[f"fdd/{self.detector}/airspeed"][0]], dtype=np.float32)

    def act(self, obs: dict, info: dict) -> np.ndarray:
        status = self._status(info)
        # the pitot tests only: a GNSS or pusher-RPM alarm of the same detector leaves the pitot healthy
        # (and the synthetic airspeed degraded), so it is no reason to switch
        alarms = [status[f"alarm_time_{test}"] for test in self.tests if status[f"alarm_time_{test}"] is not None]
        if self.switched_at is None and alarms:
            self.switched_at = min(alarms)
        if self.switched_at is None:
            return np.array([obs["pitot_airspeed"][0]], dtype=np.float32)
        return self._synthetic(obs)


class SyntheticOnlyPolicy(AirspeedSwitchPolicy):
    """`synthetic-only`: always feeds the EKF's synthetic airspeed, never the pitot (needs `airdata_ekf`)."""

    def act(self, obs: dict, info: dict) -> np.ndarray:
        self._status(info)
        return self._synthetic(obs)


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
