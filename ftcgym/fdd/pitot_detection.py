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

Each test's sample is compiled (numba: `residual_step`, `cusum_step`, `confirmation_step`, `ramp_step`, on the
test's state and constants packed in two arrays; the air-data EKF runs its innovation tests in one compiled call,
`innovation_bank`) with the operations and their order of the plain-Python tests they replaced (np.add.accumulate's
running sums, elementwise products and quotients), so every statistic and alarm keeps its bits.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import signal

from .base import biquad_constants, biquad_scalar


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
RAMP_DEFAULT = RampTest(20.0, 0.3, 3.0, 2.0)
#: m/s, the EKF forward airspeed below which the ramp test does not run: the end of the transition (14.5 m/s,
#: `vsqp.py`). Near hover the simulated pitot reads its floor (forward flow only, clipped at 0) and the residual is
#: not the Gaussian the GLR assumes; in the transitions the EKF's model errs most. Table 2 and the CUSUM still
#: run there. Set with RAMP_DEFAULT.
RAMP_MIN_AIRSPEED = 14.5


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
        self.norm = ThresholdCriterion(norm[0], norm[1], sample_hz, sign)   # `sign`: a one-sided norm criterion
        self.deriv = ThresholdCriterion(derivative[0], derivative[1], sample_hz)
        self._constants = np.concatenate((
            biquad_constants(*signal.butter(2, norm[2], btype="low", fs=sample_hz)),
            biquad_constants(*signal.butter(2, derivative[2], btype="low", fs=sample_hz)),
            (self.sample_hz, self.norm.threshold, self.norm.samples, self.norm.sign, self.deriv.threshold,
             self.deriv.samples)))
        self._state = np.zeros(RESIDUAL_STATE_SIZE)
        self.reset()

    def reset(self) -> None:
        self._state[:] = 0.0

    residual = property(lambda self: float(self._state[R_RESIDUAL]), doc="The low-passed residual (norm filter).")
    derivative = property(lambda self: float(self._state[R_DERIVATIVE]), doc="Its derivative (derivative filter).")
    alarm = property(lambda self: bool(self._state[R_ALARM]), doc="Whether a criterion has fired (latched).")

    @property
    def alarm_time(self) -> float | None:
        return float(self._state[R_ALARM_TIME]) if self._state[R_ALARM] else None

    @property
    def criterion(self) -> str | None:
        """The criterion of the alarm: "norm" or "derivative" (None: no alarm yet)."""
        return CRITERIA[int(self._state[R_CRITERION])]

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        return residual_step(self._state, self._constants, float(residual), float(time), armed)


#: `PitotResidualDetector._state`: the filtered residual, its derivative, the last derivative-filter output and
#: whether there is one, the alarm (1.0), its time, its criterion (index into CRITERIA), the two criteria's
#: counts, whether the filters have started, the norm filter's memory, the derivative filter's.
(R_RESIDUAL, R_DERIVATIVE, R_LAST, R_HAS_LAST, R_ALARM, R_ALARM_TIME, R_CRITERION, R_NORM_COUNT, R_DERIV_COUNT,
 R_STARTED, R_NORM_MEMORY, R_DERIV_MEMORY, RESIDUAL_STATE_SIZE) = (*range(10), 10, 12, 14)
#: `PitotResidualDetector._constants`: the norm filter (`biquad_constants`), the derivative filter, sample_hz,
#: the norm criterion's threshold, samples and sign, the derivative criterion's threshold and samples.
R_NORM_FILTER, R_DERIV_FILTER, R_SAMPLE_HZ, R_NORM_THRESHOLD, R_NORM_SAMPLES, R_NORM_SIGN = (
    slice(0, 8), slice(8, 16), 16, 17, 18, 19)
R_DERIV_THRESHOLD, R_DERIV_SAMPLES, RESIDUAL_CONSTANTS_SIZE = 20, 21, 22
CRITERIA = (None, "norm", "derivative")


@njit(cache=True)
def criterion_level(value, sign):  # pragma: no cover (compiled)
    """`ThresholdCriterion.level`: |value|, or sign * value when one-sided."""
    return abs(value) if sign == 0.0 else sign * value


@njit(cache=True)
def residual_step(state, constants, r, time, armed):  # pragma: no cover (compiled)
    """`PitotResidualDetector.update` in place on its state: both low-passes, the derivative by backward
    difference times sample_hz, then (while armed; else the counts restart) the norm and derivative criteria
    (`ThresholdCriterion`); the first that fires latches the alarm. Returns the alarm."""
    first = state[R_STARTED] == 0.0
    state[R_STARTED] = 1.0
    state[R_RESIDUAL] = residual = biquad_scalar(constants[R_NORM_FILTER], state, R_NORM_MEMORY, r, first)
    rd = biquad_scalar(constants[R_DERIV_FILTER], state, R_DERIV_MEMORY, r, first)
    derivative = 0.0 if state[R_HAS_LAST] == 0.0 else (rd - state[R_LAST]) * constants[R_SAMPLE_HZ]
    state[R_DERIVATIVE], state[R_LAST], state[R_HAS_LAST] = derivative, rd, 1.0
    if not armed:
        state[R_NORM_COUNT] = state[R_DERIV_COUNT] = 0.0
        return state[R_ALARM] == 1.0
    level = criterion_level(residual, constants[R_NORM_SIGN])
    norm_count = state[R_NORM_COUNT] + 1.0 if level >= constants[R_NORM_THRESHOLD] else 0.0
    deriv_count = state[R_DERIV_COUNT] + 1.0 if abs(derivative) >= constants[R_DERIV_THRESHOLD] else 0.0
    state[R_NORM_COUNT], state[R_DERIV_COUNT] = norm_count, deriv_count
    hit_norm, hit_deriv = norm_count >= constants[R_NORM_SAMPLES], deriv_count >= constants[R_DERIV_SAMPLES]
    if state[R_ALARM] == 0.0 and (hit_norm or hit_deriv):
        state[R_ALARM], state[R_ALARM_TIME], state[R_CRITERION] = 1.0, time, 2.0 if hit_deriv else 1.0
    return state[R_ALARM] == 1.0


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
        self._constants = np.concatenate((biquad_constants(*signal.butter(2, cutoff, btype="low", fs=sample_hz)),
                                          (self.sample_hz, self.drift, self.threshold)))
        self._state = np.zeros(CUSUM_STATE_SIZE)
        self.reset()

    def reset(self) -> None:
        self._state[:] = 0.0

    statistic = property(lambda self: float(self._state[C_STATISTIC]), doc="g, the CUSUM statistic.")
    alarm = property(lambda self: bool(self._state[C_ALARM]), doc="Whether g has reached h (latched).")

    @property
    def alarm_time(self) -> float | None:
        return float(self._state[C_ALARM_TIME]) if self._state[C_ALARM] else None

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        return cusum_step(self._state, self._constants, float(residual), float(time), armed)


#: `ResidualCusum._state`: g, the last filtered residual and whether there is one, the alarm, its time, whether
#: the filter has started, its memory. `_constants`: the filter (`biquad_constants`), sample_hz, nu, h.
C_STATISTIC, C_LAST, C_HAS_LAST, C_ALARM, C_ALARM_TIME, C_STARTED, C_MEMORY, CUSUM_STATE_SIZE = (*range(7), 8)
C_FILTER, C_SAMPLE_HZ, C_DRIFT, C_THRESHOLD, CUSUM_CONSTANTS_SIZE = slice(0, 8), 8, 9, 10, 11


@njit(cache=True)
def cusum_step(state, constants, residual, time, armed):  # pragma: no cover (compiled)
    """`ResidualCusum.update` in place on its state: g_k = max(0, g_k-1 + d_k - nu / f) while armed (else 0), the
    alarm when g_k >= h. Returns the alarm."""
    first = state[C_STARTED] == 0.0
    state[C_STARTED] = 1.0
    r = biquad_scalar(constants[C_FILTER], state, C_MEMORY, residual, first)
    if armed and state[C_HAS_LAST] == 1.0:
        g = state[C_STATISTIC] + (state[C_LAST] - r) - constants[C_DRIFT] / constants[C_SAMPLE_HZ]
        state[C_STATISTIC] = g if g > 0.0 else 0.0                  # max(0.0, g), as Python's
    else:
        state[C_STATISTIC] = 0.0
    state[C_LAST], state[C_HAS_LAST] = r, 1.0
    if armed and state[C_ALARM] == 0.0 and state[C_STATISTIC] >= constants[C_THRESHOLD]:
        state[C_ALARM], state[C_ALARM_TIME] = 1.0, time
    return state[C_ALARM] == 1.0


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
        self._constants = np.concatenate((biquad_constants(*signal.butter(2, cutoff, btype="low", fs=sample_hz)),
                                          (self.level, self.window_samples, self.criterion.threshold,
                                           self.criterion.samples)))
        self._state = np.zeros(CONFIRMATION_STATE_SIZE)
        self.reset()

    def reset(self) -> None:
        self._state[:] = 0.0
        self._state[P_SINCE_LEVEL] = math.inf

    residual = property(lambda self: float(self._state[P_RESIDUAL]), doc="The low-passed pitot residual.")
    statistic = property(lambda self: float(self._state[P_STATISTIC]), doc="It while the window holds, else 0.")

    def update(self, level_signal: float, residual: float, armed: bool = True) -> bool:
        return confirmation_step(self._state, self._constants, float(level_signal), float(residual), armed)


#: `PitotConfirmation._state`: the filtered residual, the statistic, samples since the level was reached, the
#: criterion's count, whether the filter has started, its memory. `_constants`: the filter (`biquad_constants`),
#: the level, the window (samples), the criterion's residual threshold and samples.
P_RESIDUAL, P_STATISTIC, P_SINCE_LEVEL, P_COUNT, P_STARTED, P_MEMORY, CONFIRMATION_STATE_SIZE = (*range(6), 7)
P_FILTER, P_LEVEL, P_WINDOW, P_THRESHOLD, P_SAMPLES, CONFIRMATION_CONSTANTS_SIZE = slice(0, 8), 8, 9, 10, 11, 12


@njit(cache=True)
def confirmation_step(state, constants, level_signal, residual, armed):  # pragma: no cover (compiled)
    """`PitotConfirmation.update` in place on its state; returns whether the criterion holds."""
    first = state[P_STARTED] == 0.0
    state[P_STARTED] = 1.0
    state[P_RESIDUAL] = r = biquad_scalar(constants[P_FILTER], state, P_MEMORY, residual, first)
    state[P_SINCE_LEVEL] = 0.0 if level_signal >= constants[P_LEVEL] else state[P_SINCE_LEVEL] + 1.0
    state[P_STATISTIC] = statistic = r if state[P_SINCE_LEVEL] < constants[P_WINDOW] else 0.0
    if not armed:
        state[P_COUNT] = 0.0
        return False
    state[P_COUNT] = state[P_COUNT] + 1.0 if statistic >= constants[P_THRESHOLD] else 0.0   # sign +1
    return state[P_COUNT] >= constants[P_SAMPLES]


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
        # the compiled step's constants: sample_hz, sigma, the threshold, the window's size, the candidates'
        # count, then `_index` and, per candidate, m - 1, its onset's and its window's end, sum x, n, S_xx, sqrt S_xx
        self._constants = np.concatenate((
            (self.sample_hz, self.sigma, self.threshold, size, after.size), self._index, self._m_minus_1,
            self._onset_end, self._window_end, self._sum_x, self._n, self._s_xx, self._sqrt_s_xx))
        # the count of samples in the window, z, the alarm, its time, then each sample stored twice, newest at
        # the lowest slot, so the last `size` are one slice, newest first
        self._state = np.zeros(G_RING + 2 * size)
        self.reset()

    def reset(self) -> None:
        self._state[:G_RING] = 0.0

    statistic = property(lambda self: float(self._state[G_STATISTIC]), doc="z, 0 until the window is full.")
    alarm = property(lambda self: bool(self._state[G_ALARM]), doc="Whether z has reached the threshold (latched).")

    @property
    def alarm_time(self) -> float | None:
        return float(self._state[G_ALARM_TIME]) if self._state[G_ALARM] else None

    def update(self, residual: float, time: float, armed: bool = True) -> bool:
        return ramp_step(self._state, self._constants, float(residual), float(time), armed)


G_COUNT, G_STATISTIC, G_ALARM, G_ALARM_TIME, G_RING = range(5)           # `RampGlr._state`
G_SAMPLE_HZ, G_SIGMA, G_THRESHOLD, G_SIZE, G_CANDIDATES, G_INDEX = range(6)  # `RampGlr._constants`


@njit(cache=True)
def ramp_step(state, constants, residual, time, armed):  # pragma: no cover (compiled)
    """`RampGlr.update` in place on its state: the sample into the ring, then z (`_ramp_z`) once the window is
    full and while armed (else the window refills). Returns the alarm."""
    size, count = int(constants[G_SIZE]), int(state[G_COUNT])
    slot = (-1 - count) % size
    state[G_RING + slot] = state[G_RING + slot + size] = residual
    state[G_COUNT] = count + 1
    if not armed:                           # the window refills with armed samples only
        state[G_COUNT], state[G_STATISTIC] = 0.0, 0.0
    elif count + 1 < size:
        state[G_STATISTIC] = 0.0
    else:
        state[G_STATISTIC] = _ramp_z(state[G_RING + slot:G_RING + slot + size], constants)
        if state[G_ALARM] == 0.0 and state[G_STATISTIC] >= constants[G_THRESHOLD]:
            state[G_ALARM], state[G_ALARM_TIME] = 1.0, time
    return state[G_ALARM] == 1.0


@njit(cache=True)
def _ramp_z(r, constants):  # pragma: no cover (compiled)
    """z of the window r (newest first): the running sums of r and index * r (as np.add.accumulate, left to
    right), then per candidate the least-squares slope a_hat = S_xr / S_xx and z = max (-a_hat) sqrt(S_xx) / sigma
    as -min(a_hat sqrt(S_xx)) / sigma, each operation as the array form of `RampGlr` had it."""
    size, candidates = r.size, int(constants[G_CANDIDATES])
    index = constants[G_INDEX:G_INDEX + size]
    sum_r, sum_ir = np.empty(size), np.empty(size)
    sum_r[0], sum_ir[0] = r[0], index[0] * r[0]
    for i in range(1, size):
        sum_r[i] = sum_r[i - 1] + r[i]
        sum_ir[i] = sum_ir[i - 1] + index[i] * r[i]
    at = G_INDEX + size
    m_minus_1, onset_end = constants[at:at + candidates], constants[at + candidates:at + 2 * candidates]
    window_end = constants[at + 2 * candidates:at + 3 * candidates]
    sum_x, n = constants[at + 3 * candidates:at + 4 * candidates], constants[at + 4 * candidates:at + 5 * candidates]
    s_xx, sqrt_s_xx = constants[at + 5 * candidates:at + 6 * candidates], constants[at + 6 * candidates:]
    sample_hz, lowest = constants[G_SAMPLE_HZ], 0.0
    for j in range(candidates):
        onset, end = int(onset_end[j]), int(window_end[j])
        # sum over the m newest samples of x_i r_i, x_i = (m - 1 - index_i) / f
        sum_xr = (m_minus_1[j] * sum_r[onset] - sum_ir[onset]) / sample_hz
        s_xr = sum_xr - sum_x[j] * sum_r[end] / n[j]
        value = s_xr / s_xx[j] * sqrt_s_xx[j]
        if j == 0 or (lowest == lowest and not value >= lowest):    # np.minimum.reduce: a NaN propagates
            lowest = value
    return -lowest / constants[G_SIGMA]
