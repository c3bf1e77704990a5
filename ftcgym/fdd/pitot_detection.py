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
The derivative is the backward difference of the filtered residual times f_EKF. The thesis author's public
MATLAB detector (github.com/frlarocque/airspeed_kalman_filter, kalman_filter_based/residual_fault_detector.m)
counts the same way (a fault once more than T/dt consecutive samples exceed the threshold: 7 and 3 at 25 Hz),
with the same 2nd-order Butterworth and backward difference; so the floor of the incipient delay (a -2.5 m/s^2
ramp reaches 5.5 m/s at 2.2 s, plus the filter's lag, the sample phase and the hold: ~2.50 s) is 001's too.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import signal

from .base import Biquad


class ThresholdTest(NamedTuple):
    """A residual criterion of 001 Sec. 6.1 / Table 2: the residual, low-passed at `cutoff_hz` (2nd-order
    Butterworth), at or above `threshold` for `hold` s."""

    threshold: float    # m/s for a residual, m/s^2 for its derivative or an acceleration innovation
    hold: float         # s, Table 2's "time threshold"
    cutoff_hz: float    # Hz


class CusumTest(NamedTuple):
    """The one-sided CUSUM on the residual's drop (`ResidualCusum`)."""

    drift: float        # m/s^2, the drift allowance nu
    threshold: float    # m/s, h
    cutoff_hz: float    # Hz, its own low-pass of the residual


class RampTest(NamedTuple):
    """The GLR for a ramp onset in the raw residual (`RampGlr`)."""

    threshold: float    # the standardised slope z (in sigmas) at or above which it alarms
    sigma: float        # m/s, the residual's noise level the statistic is scaled by
    reference: float    # s, the baseline window before a candidate onset
    horizon: float      # s, the longest ramp considered (candidate onsets this far back)


class ConfirmationTest(NamedTuple):
    """An innovation burst confirmed by the pitot (`PitotConfirmation`)."""

    level: float        # m/s^2, the innovation level that opens the window
    window: float       # s the window stays open after the level
    residual: float     # m/s, the pitot residual that must hold while it is open ...
    hold: float         # s, ... for this long


#: 001 Table 2, pitot rows.
TABLE_2_NORM = ThresholdTest(5.5, 0.25, 5.0)
TABLE_2_DERIVATIVE = ThresholdTest(25.0, 0.12, 5.0)
#: The CUSUM on the residual's drop (`ResidualCusum`): drift allowance nu (m/s^2), threshold h (m/s), cutoff (Hz).
#: It runs on the residual low-passed at 0.5 Hz, not at Table 2's 5 Hz: a ramp passes with ~0.5 s lag, the
#: residual's fast noise does not. nu = 1.0 m/s^2, below 001's 2.5 m/s^2 ramp; h = 1.9 m/s, the threshold for 0.1%
#: false detection per flight hour (001 Sec. 6.1's budget, run-rate method, `ftcgym thresholds`) rounded up.
#: Chosen on fault-free tuning flights; see docs/measurements.md, 'Tuning record: fdd/pitot_detection.py'.
CUSUM_DEFAULT = CusumTest(1.0, 1.9, 0.5)
#: The ramp-onset GLR (`RampGlr`): threshold on z, sigma (the pitot's noise, `models/sensors.py`), reference
#: and horizon (s). Set on fault-free tuning flights; see docs/measurements.md, 'Tuning record:
#: fdd/pitot_detection.py'.
RAMP_DEFAULT = RampTest(16.0, 0.3, 3.0, 2.0)
#: m/s, the EKF forward airspeed below which the ramp test does not run: near hover the simulated pitot reads
#: its floor (forward flow only, clipped at 0) and the residual is not the Gaussian the GLR assumes; Table 2 and
#: the CUSUM still run there. Set with RAMP_DEFAULT.
RAMP_MIN_AIRSPEED = 8.0


class ThresholdCriterion:
    """|s| >= threshold for `hold_time` s: fires on the ceil(sample_hz * hold_time)-th consecutive sample above
    (eq. 40's sequence length). `sign` +1 / -1 makes it one-sided (s >= threshold / -s >= threshold)."""

    def __init__(self, threshold: float, hold_time: float, sample_hz: float, sign: int = 0):
        if not (threshold > 0 and hold_time >= 0 and sample_hz > 0):
            raise ValueError(f"criterion: need threshold > 0, hold_time >= 0, sample_hz > 0; got "
                             f"{threshold!r}, {hold_time!r}, {sample_hz!r}")
        self.threshold, self.hold_time = float(threshold), float(hold_time)
        if sign not in (-1, 0, 1):
            raise ValueError(f"criterion: sign {sign!r}; accepted: [-1, 0, 1]")
        self.samples = max(1, math.ceil(sample_hz * hold_time - 1e-9))
        self.sign, self.count = sign, 0

    def reset(self) -> None:
        self.count = 0

    def level(self, value: float) -> float:
        """What the threshold is compared with: |value|, or sign * value when one-sided."""
        return abs(value) if self.sign == 0 else self.sign * value

    def __call__(self, value: float) -> bool:
        self.count = self.count + 1 if self.level(value) >= self.threshold else 0
        return self.count >= self.samples


class PitotResidualDetector:
    """001 Sec. 6.1: low-pass the pitot residual, raise a latched alarm on the norm or derivative criterion.

    `update(residual, time, armed)` takes one residual sample at `sample_hz`; the filter always runs, the
    criteria only count while `armed` (the caller arms them once its airspeed estimate has converged).
    `alarm`, `alarm_time`, `criterion` ("norm" / "derivative"), `residual` (filtered), `derivative`.
    """

    def __init__(self, sample_hz: float = 25.0, norm=TABLE_2_NORM, derivative=TABLE_2_DERIVATIVE, sign: int = 0):
        for cutoff in (norm[2], derivative[2]):
            if not (0.0 < cutoff < 0.5 * sample_hz):
                raise ValueError(f"pitot detection: cutoff {cutoff!r} Hz must lie in (0, {0.5 * sample_hz}) Hz")
        self.sample_hz = float(sample_hz)
        self._norm_filter = Biquad(*signal.butter(2, norm[2], btype="low", fs=sample_hz))
        self._deriv_filter = Biquad(*signal.butter(2, derivative[2], btype="low", fs=sample_hz))
        self.norm = ThresholdCriterion(norm[0], norm[1], sample_hz, sign)   # `sign`: a one-sided norm criterion
        self.deriv = ThresholdCriterion(derivative[0], derivative[1], sample_hz)
        self.reset()

    def reset(self) -> None:
        self.norm.reset()
        self.deriv.reset()
        self._norm_filter.reset()
        self._deriv_filter.reset()
        self._last = None
        self.residual, self.derivative = 0.0, 0.0
        self.alarm, self.alarm_time, self.criterion = False, None, None

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        r = float(residual)
        self.residual, rd = self._norm_filter(r), self._deriv_filter(r)
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


class ResidualCusum:
    """One-sided CUSUM (Page) on the drop of the low-passed residual: the test on the residual that 001
    Sec. 7.2.2 and 8.1 recommend over thresholding for incipient faults.

    A blocked pitot reads low (001 Sec. 7.2.2: water blockage, a ramp down; Sec. 7.2.1: a step to zero), so the
    residual r = pitot - EKF airspeed falls. With r_f the residual low-passed at `cutoff` Hz (2nd-order
    Butterworth as Table 2's, slower) and d_k = r_f[k-1] - r_f[k] its drop over one sample,

        g_k = max(0, g_{k-1} + d_k - nu / f),      alarm when g_k >= h,

    i.e. g_k is the largest drop of r_f over any window ending now, less nu times the window's length: a
    slow drift below nu m/s^2 (the wind estimate converging) never builds up, a ramp of rate a > nu alarms
    after about h / (a - nu) s, a step of more than h at once. One-sided because the pitot faults modelled
    lower the reading; an EKF airspeed falling after a GNSS or pusher-RPM fault raises r and is left to the
    innovation detectors. `statistic` is g, armed only while `armed` (reset to 0 otherwise).
    """

    def __init__(self, sample_hz: float = 25.0, drift: float = CUSUM_DEFAULT[0], threshold: float = CUSUM_DEFAULT[1],
                 cutoff: float = CUSUM_DEFAULT[2]):
        # cutoff: its own low-pass (CUSUM_DEFAULT: 0.5 Hz), not Table 2's 5 Hz
        if not (drift >= 0 and threshold > 0 and 0.0 < cutoff < 0.5 * sample_hz):
            raise ValueError(f"cusum: need drift >= 0, threshold > 0, 0 < cutoff < {0.5 * sample_hz} Hz; got "
                             f"{drift!r}, {threshold!r}, {cutoff!r}")
        self.sample_hz, self.drift, self.threshold = float(sample_hz), float(drift), float(threshold)
        self._filter = Biquad(*signal.butter(2, cutoff, btype="low", fs=sample_hz))
        self.reset()

    def reset(self) -> None:
        self._filter.reset()
        self._last = None
        self.statistic = 0.0
        self.alarm, self.alarm_time = False, None

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        r = self._filter(float(residual))
        if armed and self._last is not None:
            self.statistic = max(0.0, self.statistic + (self._last - r) - self.drift / self.sample_hz)
        else:
            self.statistic = 0.0
        self._last = r
        if armed and not self.alarm and self.statistic >= self.threshold:
            self.alarm, self.alarm_time = True, float(time)
        return self.alarm


class PitotConfirmation:
    """An innovation burst confirmed by the pitot: the second criterion of the pusher-RPM detector (a departure
    from 001 Table 3, where only the a_x innovation is tied to the pusher RPM; see `INNOVATION_DETECTORS`).

    A sensor fault that makes the EKF underestimate the airspeed shows first as a burst of its innovation, then
    as the EKF airspeed falling below a sound pitot: the pitot residual r = pitot - EKF airspeed rises. A
    blocked pitot can only lower r (its reading falls), so a rising r blames the EKF's inputs, not the pitot
    (a pitot reading high, a fault not modelled here, would be blamed on them too if an innovation rose with it).
    Fires when the innovation `level_signal` reached `level` within the last `window` s and r, low-passed at
    `cutoff` Hz (Table 2's 2nd-order Butterworth), has stayed >= `residual` for `hold` s. `statistic` is the
    filtered r while the window holds, else 0 (the signal `ftcgym thresholds` scores).
    """

    def __init__(self, level: float, window: float, residual: float, hold: float, sample_hz: float,
                 cutoff: float = TABLE_2_NORM[2]):
        if not (level > 0 and window > 0 and 0.0 < cutoff < 0.5 * sample_hz):
            raise ValueError(f"pitot confirmation: need level > 0, window > 0, 0 < cutoff < {0.5 * sample_hz} Hz; "
                             f"got {level!r}, {window!r}, {cutoff!r}")
        self.level, self.window_samples = float(level), math.ceil(window * sample_hz - 1e-9)
        self.criterion = ThresholdCriterion(residual, hold, sample_hz, sign=1)
        self._filter = Biquad(*signal.butter(2, cutoff, btype="low", fs=sample_hz))
        self.reset()

    def reset(self) -> None:
        self.criterion.reset()
        self._filter.reset()
        self._since_level = math.inf
        self.residual, self.statistic = 0.0, 0.0

    def update(self, level_signal: float, residual: float, armed: bool = True) -> bool:
        self.residual = self._filter(float(residual))
        self._since_level = 0 if level_signal >= self.level else self._since_level + 1
        in_window = self._since_level < self.window_samples
        self.statistic = self.residual if in_window else 0.0
        if not armed:
            self.criterion.reset()
            return False
        return self.criterion(self.statistic)


class RampGlr:
    """The generalised likelihood ratio test for a ramp onset in the raw pitot residual: a detector matched to
    the incipient blockage of 001 Sec. 7.2.2, whose reading drifts down at a constant rate.

    Model (Basseville and Nikiforov 1993, ch. 2: the GLR for a change of unknown magnitude at an unknown time;
    ch. 7: an additive change with a known profile, here a ramp): over the last `reference` + `horizon` s, the
    residual is r_i = b + e_i before an onset theta and r_i = b + a (t_i - theta) + e_i after it, e_i white with
    standard deviation sigma. For each candidate theta (every sample of the last `horizon` s) the baseline b and
    the rate a are fitted by least squares over the window [theta - reference, now] with x_i = max(0, t_i -
    theta):

        a_hat = S_xr / S_xx,  S_xx = sum (x_i - x_bar)^2,  S_xr = sum (x_i - x_bar)(r_i - r_bar),

    and the log-likelihood ratio of the ramp against no change is a_hat^2 S_xx / (2 sigma^2). The statistic is
    its signed square root maximised over theta, z = max_theta (-a_hat) sqrt(S_xx) / sigma, one-sided because a
    blocked pitot reads low (as `ResidualCusum`); it alarms when z >= `threshold`. Departure: the residual is not
    white (the wind estimate wanders with the turbulence), so sigma only scales z; the threshold is set from
    fault-free flights by the run-rate method of `ftcgym thresholds` (001 eq. 40-41 do not hold for a correlated
    statistic). The baseline is fitted per candidate, so a slowly wandering residual mean does not build up
    evidence the way a fixed reference would. `statistic` is z, 0 until the window is full or while not `armed`.
    """

    def __init__(self, sample_hz: float, threshold: float, sigma: float, reference: float, horizon: float):
        if not (threshold > 0 and sigma > 0 and reference > 0 and horizon > 0):
            raise ValueError(f"ramp test: need threshold, sigma, reference and horizon > 0; got {threshold!r}, "
                             f"{sigma!r}, {reference!r}, {horizon!r}")
        self.sample_hz, self.threshold, self.sigma = float(sample_hz), float(threshold), float(sigma)
        self._reference = max(2, round(reference * sample_hz))
        self._onsets = max(2, round(horizon * sample_hz))
        size = self._reference + self._onsets
        # candidate j: onset `after[j]` samples before the newest, its window `after[j] + reference` samples long
        after = np.arange(2, self._onsets + 1, dtype=float)
        n = after + self._reference
        sum_x = after * (after - 1) / 2 / self.sample_hz               # x = 0, 1/f, ..., (m - 1)/f after onset
        sum_xx = (after - 1) * after * (2 * after - 1) / 6 / self.sample_hz**2
        self._n, self._sum_x = n, sum_x
        self._s_xx = sum_xx - sum_x**2 / n
        self._sqrt_s_xx = np.sqrt(self._s_xx)
        # samples newest first: candidate j's m = after[j] newest end at index m - 1, its window at m + reference - 1
        self._m_minus_1 = after - 1
        self._onset_end = self._m_minus_1.astype(int)
        self._window_end = self._onset_end + self._reference
        self._size, self._index = size, np.arange(size, dtype=float)     # samples before the newest
        # each sample stored twice, newest at the lowest slot, so the last `size` are one slice, newest first
        self._ring = np.zeros(2 * size)
        self.reset()

    def reset(self) -> None:
        self._count = 0
        self.statistic = 0.0
        self.alarm, self.alarm_time = False, None

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        slot = (-1 - self._count) % self._size
        self._ring[slot] = self._ring[slot + self._size] = residual
        self._count += 1
        if not armed:                           # the window refills with armed samples only
            self._count, self.statistic = 0, 0.0
            return self.alarm
        if self._count < self._size:
            self.statistic = 0.0
            return self.alarm
        self.statistic = self._z(slot)
        if not self.alarm and self.statistic >= self.threshold:
            self.alarm, self.alarm_time = True, float(time)
        return self.alarm

    def _z(self, newest: int) -> float:
        r = self._ring[newest:newest + self._size]                      # newest first
        # running sums (np.cumsum's, less its wrapper's cost)
        sum_r, sum_ir = np.add.accumulate(r), np.add.accumulate(self._index * r)
        onset = self._onset_end
        # sum over the m newest samples of x_i r_i, x_i = (m - 1 - index_i) / f
        sum_xr = (self._m_minus_1 * sum_r[onset] - sum_ir[onset]) / self.sample_hz
        s_xr = sum_xr - self._sum_x * sum_r[self._window_end] / self._n
        slope = s_xr / self._s_xx
        # max over onsets of -slope sqrt(S_xx) / sigma, as -min(slope sqrt(S_xx)) / sigma: the same floats
        return float(-np.minimum.reduce(slope * self._sqrt_s_xx) / self.sigma)
