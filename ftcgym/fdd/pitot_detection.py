"""Pitot fault detection on the air-data EKF residual: 001 (Larocque 2023) Sec. 6.1 and Table 2.

The residual r = pitot reading - EKF airspeed is low-pass filtered and thresholded with two criteria
(001 Sec. 6.1, the two numbered conditions before eq. 40):

1. NORM:       |r_f| >= Z_norm  for T_norm
2. DERIVATIVE: |dr_f/dt| >= Z_deriv for T_deriv

Table 2 ("Pitot Tube Res." and "Pitot Tube Res. Derivative" rows): Z_norm = 5.5 m/s, T_norm = 0.25 s,
Z_deriv = 25 m/s^2, T_deriv = 0.12 s, both on the residual low-passed at 5 Hz. Table 2 gives only the
cutoff; the filter is taken as the same 2nd-order Butterworth as the EKF prefilter (Sec. 5). The detector runs
at the EKF rate (f_EKF = 25 Hz, Sec. 7.1), so "for T" means ceil(f_EKF T) consecutive samples, the
sequence length of eq. (40) (p_seq = p_single^(f_EKF T)): 7 samples for the norm, 3 for the derivative.
The derivative is the backward difference of the filtered residual times f_EKF.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

#: 001 Table 2, pitot rows: threshold, time threshold (s), cutoff (Hz).
TABLE_2_NORM = (5.5, 0.25, 5.0)
TABLE_2_DERIVATIVE = (25.0, 0.12, 5.0)


class ThresholdCriterion:
    """|s| >= threshold for `hold_time` s: fires on the ceil(sample_hz * hold_time)-th consecutive sample above
    (eq. 40's sequence length)."""

    def __init__(self, threshold: float, hold_time: float, sample_hz: float):
        if not (threshold > 0 and hold_time >= 0 and sample_hz > 0):
            raise ValueError(f"criterion: need threshold > 0, hold_time >= 0, sample_hz > 0; got "
                             f"{threshold!r}, {hold_time!r}, {sample_hz!r}")
        self.threshold, self.hold_time = float(threshold), float(hold_time)
        self.samples = max(1, math.ceil(sample_hz * hold_time - 1e-9))
        self.count = 0

    def reset(self) -> None:
        self.count = 0

    def __call__(self, value: float) -> bool:
        self.count = self.count + 1 if abs(value) >= self.threshold else 0
        return self.count >= self.samples


class PitotResidualDetector:
    """001 Sec. 6.1: low-pass the pitot residual, raise a latched alarm on the norm or derivative criterion.

    `update(residual, time, armed)` takes one residual sample at `sample_hz`; the filter always runs, the
    criteria only count while `armed` (the caller arms them once its airspeed estimate has converged).
    `alarm`, `alarm_time`, `criterion` ("norm" / "derivative"), `residual` (filtered), `derivative`.
    """

    def __init__(self, sample_hz: float = 25.0, norm=TABLE_2_NORM, derivative=TABLE_2_DERIVATIVE):
        for cutoff in (norm[2], derivative[2]):
            if not (0.0 < cutoff < 0.5 * sample_hz):
                raise ValueError(f"pitot detection: cutoff {cutoff!r} Hz must lie in (0, {0.5 * sample_hz}) Hz")
        self.sample_hz = float(sample_hz)
        self._norm_ba = signal.butter(2, norm[2], btype="low", fs=sample_hz)
        self._deriv_ba = signal.butter(2, derivative[2], btype="low", fs=sample_hz)
        self.norm = ThresholdCriterion(norm[0], norm[1], sample_hz)
        self.deriv = ThresholdCriterion(derivative[0], derivative[1], sample_hz)
        self.reset()

    def reset(self) -> None:
        self.norm.reset()
        self.deriv.reset()
        self._zn = self._zd = None
        self._last = None
        self.residual, self.derivative = 0.0, 0.0
        self.alarm, self.alarm_time, self.criterion = False, None, None

    @staticmethod
    def _filter(ba, z, x):
        b, a = ba
        if z is None:                      # start at steady state on the first sample
            z = signal.lfilter_zi(b, a) * x
        y = b[0] * x + z[0]
        return y, np.array([b[1] * x - a[1] * y + z[1], b[2] * x - a[2] * y])

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        r = float(residual)
        self.residual, self._zn = self._filter(self._norm_ba, self._zn, r)
        rd, self._zd = self._filter(self._deriv_ba, self._zd, r)
        self.derivative = 0.0 if self._last is None else (rd - self._last) * self.sample_hz
        self._last = rd
        if not armed:
            self.norm.reset()
            self.deriv.reset()
            return self.alarm
        hit_norm, hit_deriv = self.norm(self.residual), self.deriv(self.derivative)
        if not self.alarm and (hit_norm or hit_deriv):
            self.alarm, self.alarm_time = True, float(time)
            self.criterion = "derivative" if hit_deriv else "norm"
        return self.alarm
