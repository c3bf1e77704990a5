"""The pusher's speed reading checked against its current: which sensor an a_x innovation alarm blames.

001 Table 3 ties the air-data EKF's a_x innovation to two sensors, the pusher RPM and the skew, and 001 flies
the a_x test alone. The test also fires on large EKF errors of its own (an autopilot pitch oscillation in strong
wind, a model error after the transition; docs/measurements.md). A check
that does not use the EKF tells them apart. Departure from 001: the quad-plane measures the pusher current (003
uses it), and 003 eq. (1) ties the two:

    Theta dw/dt = k_e (I_e - I_0) - c_v w - Q_a(w, V)                       003 eq. (1)
    Q_a = rho D^5 (C_Q0 n^2 + C_Q1 n V / D + C_Q2 V^2 / D^2),  n = w / 2 pi   003 eq. (2)-(4), expanded

so a motor at the read speed w draws I_e = I_0 + (c_v w + Q_a(w, V) + Theta dw/dt) / k_e. The airspeed terms
lower Q_a (C_Q1, C_Q2 < 0), so V = 0 gives the largest current any airspeed allows, I_max(w), and the check
needs neither the pitot nor the EKF. A reading that fails low leaves the measured current far above it:

    excess = I_e - I_max(w) - allowance * (I_0 + (c_v w + Q_a(w, 0) + Theta |dw/dt|) / k_e)

is compared with `threshold` (A) for `hold` s. The allowance widens every term of the bound by that fraction:
1 doubles it, which covers the detector's model error (`coefficient_error` on k_e, Theta, C_Q, c_v, I_0: the
bound may read ~20% low) together with 003's faults (1.1 times nominal in our scenarios; icing at 1.5 times
even in static thrust, friction at 2 times).
Speed and current are low-passed at `cutoff` Hz (the EKF prefilter's 2nd-order Butterworth); dw/dt is the
filtered speed's backward difference. A reading stuck high is not covered (the modelled RPM fault reads zero).

A zeroed reading leaves a widened bound of 2 I_0, far below a cruise current. The allowance and the sizes of the
excess on recorded flights: docs/measurements.md, 'Tuning record: fdd/rpm_current.py'.

A check's sample is compiled (numba: `check_step`, on its state and constants packed in two arrays, which the
air-data EKF's own compiled sample step also runs) with the operations and their order of the plain-Python check
it replaced, so `excess` and `holding` keep their bits.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy import signal

from ..models.pusher import TWO_PI, aero_torque, pusher_constants
from .base import biquad_constants, biquad_scalar
from .pitot_detection import ThresholdCriterion
from .propulsion_bayes import PropulsionModel


def speed_from_current(model: PropulsionModel, current: float, airspeed: float) -> float:
    """The pusher speed (rad/s) that draws `current` (A) at `airspeed` (m/s) in steady state: 003 eq. (1) with
    dw/dt = 0, k_e (I_e - I_0) = c_v w + Q_a(w, V), and eq. (2)-(4) expanded in n = w / 2 pi, a quadratic
    a w^2 + b w + c = 0 in w (its positive root; 0 when the current cannot turn the propeller)."""
    _, c_v, i_0 = model.x_star.tolist()
    rho, d, (cq0, cq1, cq2) = model.rho, model.D, model.cq
    V = max(float(airspeed), 0.0)
    a = rho * d ** 5 * cq0 / (TWO_PI * TWO_PI)
    b = c_v + rho * d ** 4 * cq1 * V / TWO_PI
    c = rho * d ** 3 * cq2 * V * V - model.k_e * (float(current) - i_0)
    discriminant = b * b - 4.0 * a * c
    if a <= 0.0 or discriminant < 0.0:
        return 0.0
    return max((-b + math.sqrt(discriminant)) / (2.0 * a), 0.0)


class CurrentCheck(NamedTuple):
    """The settings of `RpmCurrentCheck`."""

    allowance: float    # share by which every term of the current bound is widened
    threshold: float    # A, the excess current that must hold ...
    hold: float         # s, ... for this long


RPM_CURRENT_CHECK = CurrentCheck(1.0, 2.0, 0.2)


#: `RpmCurrentCheck._state`: the two low-passes' memories (speed, current), whether they have started, the last
#: filtered speed and whether there is one, `excess`, `holding` (1.0 true) and the criterion's count.
SPEED_MEMORY, CURRENT_MEMORY, FILTERS_STARTED, LAST_SPEED, HAS_LAST_SPEED = slice(0, 2), slice(2, 4), 4, 5, 6
EXCESS, HOLDING, COUNT, CHECK_STATE_SIZE = 7, 8, 9, 10
#: `RpmCurrentCheck._constants`: the low-pass (`biquad_constants`), sample_hz, c_v*, I_0*, Theta, k_e, the
#: allowance, the criterion's threshold and samples, then the pusher's constants (`pusher_constants`).
CHECK_LOWPASS, SAMPLE_HZ, C_V, I_0, THETA, K_E, ALLOWANCE, THRESHOLD, SAMPLES, PUSHER = (
    slice(0, 8), 8, 9, 10, 11, 12, 13, 14, 15, slice(16, None))


class RpmCurrentCheck:
    """`update(speed, current)` at `sample_hz` returns whether the current has stayed above what the read speed
    can draw (`excess` >= threshold) for `hold` s; `excess` (A) is published for the threshold tool."""

    def __init__(self, params, sample_hz: float, allowance: float = RPM_CURRENT_CHECK[0],
                 threshold: float = RPM_CURRENT_CHECK[1], hold: float = RPM_CURRENT_CHECK[2], cutoff: float = 5.0,
                 coefficient_error: float = 0.10, error_seed: int | None = None):
        if not (allowance >= 0 and 0.0 < cutoff < 0.5 * sample_hz):
            raise ValueError(f"rpm current check: need allowance >= 0 and 0 < cutoff < {0.5 * sample_hz} Hz; "
                             f"got {allowance!r}, {cutoff!r}")
        self.model = PropulsionModel(params, coefficient_error, error_seed)
        self.sample_hz, self.allowance = float(sample_hz), float(allowance)
        self.criterion = ThresholdCriterion(threshold, hold, sample_hz, sign=1)
        _, self._c_v, self._i_0 = self.model.x_star.tolist()
        m = self.model
        self._constants = np.concatenate((
            biquad_constants(*signal.butter(2, cutoff, btype="low", fs=sample_hz)),
            (self.sample_hz, self._c_v, self._i_0, m.Theta, m.k_e, self.allowance, self.criterion.threshold,
             self.criterion.samples), pusher_constants(m.params)))
        self._state = np.zeros(CHECK_STATE_SIZE)
        self.reset()

    def reset(self) -> None:
        self._state[:] = 0.0

    @property
    def excess(self) -> float:
        """The current above the widened bound, A (the last sample's)."""
        return float(self._state[EXCESS])

    @property
    def holding(self) -> bool:
        """Whether the excess has held the threshold for `hold` s."""
        return bool(self._state[HOLDING])

    def update(self, speed: float, current: float) -> bool:
        if not check_step(self._state, self._constants, float(speed), float(current)):
            raise ValueError(f"rpm current check: pusher_speed {speed!r} and pusher_current {current!r} must be finite")
        return bool(self._state[HOLDING])


@njit(cache=True)
def check_step(state, constants, speed, current):  # pragma: no cover (compiled)
    """One sample of `RpmCurrentCheck` in place on `state`: both readings low-passed (2nd-order Butterworth, from
    steady state on the first sample), dw/dt the filtered speed's backward difference, excess = I_e - bound
    (`_bound`), then the criterion (one-sided, held `samples` samples). False (state untouched) if a reading is
    not finite."""
    if not (math.isfinite(speed) and math.isfinite(current)):
        return False
    first = state[FILTERS_STARTED] == 0.0
    w = biquad_scalar(constants, state, SPEED_MEMORY.start, speed, first)
    current = biquad_scalar(constants, state, CURRENT_MEMORY.start, current, first)
    state[FILTERS_STARTED] = 1.0
    w_dot = 0.0 if state[HAS_LAST_SPEED] == 0.0 else (w - state[LAST_SPEED]) * constants[SAMPLE_HZ]
    state[LAST_SPEED], state[HAS_LAST_SPEED] = w, 1.0
    excess = current - _bound(constants, 0.0 if w < 0.0 else w, w_dot)       # max(w, 0.0), as Python's
    state[EXCESS] = excess
    state[COUNT] = state[COUNT] + 1.0 if excess >= constants[THRESHOLD] else 0.0  # sign +1: the level is excess
    state[HOLDING] = state[COUNT] >= constants[SAMPLES]
    return True


@njit(cache=True)
def _bound(constants, w, w_dot):  # pragma: no cover (compiled)
    """I_max(w) (003 eq. 1 at V = 0, theta_1 = 1) widened by the allowance."""
    i_0, k_e = constants[I_0], constants[K_E]
    steady = constants[C_V] * w + aero_torque(constants[PUSHER], 1.0, w / TWO_PI, 0.0)    # 003 eq. (2)-(4)
    inertia = constants[THETA] * w_dot
    return i_0 + (steady + inertia) / k_e + constants[ALLOWANCE] * (i_0 + (steady + abs(inertia)) / k_e)
