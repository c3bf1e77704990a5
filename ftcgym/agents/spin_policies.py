"""Rotor-loss policies: `ftc-spin` (spin recovery on the detector's alarm) and `oracle-spin` (at the true onset)."""
from __future__ import annotations

import numpy as np

from ..models.quadrotor import QuadrotorParams
from .quadrotor_control import NominalController
from .spin_recovery import SpinRecoveryController, SpinRecoveryGains


class SpinAfterAlarmPolicy:
    """`ftc-spin`: the nominal controller until the `loe_kalman` detector alarms, then spin recovery without
    the rotor it isolated. The env must be wrapped with the detector (the rotor-loss scenarios are). `detector`
    names another detector whose `info["fdd"]` status it reads instead (`loe_cusum`)."""

    detector = "loe_kalman"

    def __init__(self, params: QuadrotorParams, agent_hz: float, gains: SpinRecoveryGains | None = None,
                 detector: str | None = None):
        if detector is not None:
            self.detector = detector
        self.nominal = NominalController(params, agent_hz)
        self.spin = SpinRecoveryController(params, agent_hz, gains)

    @property
    def thrust_axis_reference(self) -> np.ndarray:
        active = self.nominal if self.spin.mode == "standby" else self.spin
        return active.thrust_axis_reference

    def reset(self, obs: dict, info: dict) -> None:
        self.nominal.reset(obs, info)
        self.spin.reset(obs, info)

    def act(self, obs: dict, info: dict) -> np.ndarray:
        if self.spin.mode == "standby":
            failed = self._failed_rotor(info)
            if failed is None:
                return self.nominal.act(obs, info)
            self.spin.engage(failed, obs)
        return self.spin.act(obs, info)

    def land(self) -> None:
        """Land with the spin recovery (after a fault; before one the nominal controller flies)."""
        self.spin.land()

    def _failed_rotor(self, info: dict):
        status = info.get("fdd", {}).get(self.detector)
        if status is None:
            raise ValueError(f"ftc-spin needs the env wrapped with the {self.detector!r} detector")
        return status["isolated"] if status["alarm"] else None


class OracleSpinPolicy(SpinAfterAlarmPolicy):
    """`oracle-spin`: switches at the true fault onset, an upper bound rather than a flyable policy.

    The benchmark gives an oracle `info["oracle_onset_time"]`. The failed rotor comes from
    `info["oracle_fault_target"]` where the runner provides it (a one-line change to
    `ftcgym.benchmark.runner.policy_view`); without it, from the detector's isolation once it alarms, and the
    oracle then switches no earlier than `ftc-spin`. `switch_delay` (s, default 0) makes it switch that long after
    the onset: the best a detector with that latency could give (docs/measurements.md, 'Recovery against switch
    delay').
    """

    uses_true_onset = True
    switch_delay = 0.0

    def _failed_rotor(self, info: dict):
        onset = info.get("oracle_onset_time")
        if onset is None or info["time"] < onset + self.switch_delay:
            return None
        target = info.get("oracle_fault_target")
        if target is not None:
            return target
        status = info.get("fdd", {}).get(self.detector, {})
        return status.get("isolated") if status.get("alarm") else None
