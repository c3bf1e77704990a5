"""Loss-of-effectiveness detection with a Kalman estimator and a hypothesis test (000, Sec. IV).

Strack van Schijndel, Sun, de Visser, "Fast Loss of Effectiveness Detection on a Quadrotor Using Onboard
Sensors and a Kalman Estimation Approach", ICUAS 2023 (000).

Pipeline per sample (000 Fig. 3):
1. Second-order low-pass H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2), wn = 50 rad/s, zeta = 0.55 (Sec. IV-A),
   on p, q, a_z and the rotor speeds, discretised with the bilinear (Tustin) transform (scipy.signal).
2. Angular accelerations by backward difference of the filtered rates (eq. 10).
3. Kalman estimator of the effectiveness factors k (eq. 11-13, Algorithm 1): random walk x = k,
   z = [p_dot, q_dot, a_z] = H(omega) x with H = diag(G) S diag(omega^2) (eq. 9, 12), k bounded to [0, 1.5].
4. Failure probability P(k_i < k_thres) (eq. 15, corrected: see `failure_probability`) and decision eq. (16).
Detection starts once the rotors produce a set share of the weight (take-off gating, Sec. V-D).

The per-sample arithmetic of all four steps and the decision is one compiled function (numba: `_step`, on the
detector's state and constants packed in two arrays, as numba's call cost grows with each argument). It keeps the
operations of the plain-Python detector it replaced in the same order, numpy's BLAS products inside numba, and
scipy's erf (`_erf`), so every output keeps its bits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address
from scipy import signal
from scipy.special import erf

from ..models.checks import FRACTION, POSITIVE, Range, numbers
from ..models.constants import GRAVITY
from ..models.quadrotor import QuadrotorParams
from ..settings import accepts, updated
from . import kalman
from .base import (
    AlarmLatch,
    biquad_constants,
    biquad_step,
    check_reading,
    check_time,
    missing_reading,
    vehicle_params,
    within_limit,
)

#: 000 eq. (9): signs of each rotor's contribution to p_dot, q_dot and a_z for rotors r1..r4 of Fig. 2.
SIGNS_000 = np.array([[1.0, -1.0, -1.0, 1.0],
                      [1.0, 1.0, -1.0, -1.0],
                      [-1.0, -1.0, -1.0, -1.0]])
#: 000 Table II.
TABLE_II = {"G": (100e-6, 100e-6, 5e-6), "Q": 0.1, "R": 1.0, "k_threshold": 0.25, "p_fail_threshold": 0.9,
            "step_size": 0.02}
#: Process noise added per sample. Table II lists Q = 0.1 and a "step size" dT = 0.02 without saying how they
#: combine; we read the random walk's variance per sample as Q dT. Taken literally as 0.1 per sample at 500 Hz,
#: the variance along the direction eq. (12) cannot observe (3 measurements, 4 states) grows by 50 per second,
#: so P_fail cannot pass 0.9 until the rotor speeds have diverged (~160 ms in our simulator, beyond 000's
#: reported delays). With Q dT the delays fall within 000's reported range on tuning flights; see
#: docs/measurements.md, 'Tuning record: fdd/loe_kalman.py'.
Q_PER_SAMPLE = TABLE_II["Q"] * TABLE_II["step_size"]
#: the readings the rotor-loss detectors read
READINGS = ("gyro", "accel", "rotor_speed")
#: a probability or an effectiveness threshold strictly between 0 and 1
OPEN_FRACTION = Range(0.0, 1.0, open_low=True, open_high=True)
VARIANCE_CEILING = 1e6  # published k_var is clipped here (the unobservable direction's variance grows without bound)

#: The detector's state (`LoeKalmanDetector._state`): what `outputs` publishes (k_hat, k_var, p_fail), two flags
#: (1.0 true: the detection is armed, a sample was seen), the last filtered p and q, P (4 x 4, row-major) and the
#: low-pass's memory (2 x 7 channels: p, q, a_z, omega_1..4).
K_HAT, K_VAR, P_FAIL, OUTPUTS, ARMED, STARTED = slice(0, 4), slice(4, 8), slice(8, 12), slice(0, 12), 12, 13
LAST_P, LAST_Q, COVARIANCE, LOWPASS_MEMORY, STATE_SIZE = 14, 15, slice(16, 32), slice(32, 46), 46
#: Its constants (`LoeKalmanDetector._constants`): B (3 x 4, row-major), Q (4 x 4), the low-pass
#: (`biquad_constants`), then dt, r, k_thres, the P_fail threshold, the bounds on k and the thrust that arms it.
B_ROWS, Q_MATRIX, LOWPASS = slice(0, 12), slice(12, 28), slice(28, 36)
DT, R_NOISE, K_THRESHOLD, P_FAIL_THRESHOLD, K_LOW, K_HIGH, ARMING_THRUST = range(36, 43)
NO_ALARM, NON_FINITE = -1, -2          # `_step`'s answers besides the rotor it isolates

#: scipy.special.erf of a double, callable from compiled code: the C function of scipy's Cython API
#: (scipy.special.cython_special), bound by symbol name so numba can cache its callers. numba's math.erf, the C
#: library's, differs from it by 1-2 ulp on about a third of the values this detector meets.
llvm.add_symbol("ftcgym_scipy_erf", get_cython_function_address("scipy.special.cython_special", "__pyx_fuse_1erf"))
_erf = types.ExternalFunction("ftcgym_scipy_erf", types.float64(types.float64, types.intc))


def lowpass_coefficients(wn: float, zeta: float, dt: float):
    """Discrete (b, a) of the 000 Sec. IV-A low-pass by the bilinear (Tustin) transform."""
    b, a, _ = signal.cont2discrete(([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn]), dt, method="gbt", alpha=0.5)
    return np.ravel(b), np.ravel(a)


def failure_probability(k_hat, variance, k_threshold: float) -> np.ndarray:
    """(P_fail)_i = P(k_i < k_thres) = 0.5 (1 + erf((k_thres - k_hat_i) / (sigma_i sqrt(2)))), sigma_i = sqrt(P_ii).

    000 eq. (15) as printed computes P(k_i > k_thres) and divides by the variance instead of the standard
    deviation (erratum, docs/references.md); this is the intended value, the normal CDF at k_thres. The detector
    computes it compiled (`_failure_probability`), with the same bits.
    """
    k_hat, variance = np.asarray(k_hat, dtype=float), np.asarray(variance, dtype=float)
    return 0.5 * (1.0 + erf((k_threshold - k_hat) / (np.sqrt(np.maximum(variance, 1e-300)) * math.sqrt(2.0))))


@njit(cache=True)
def _failure_probability(k_hat, variance, k_threshold):  # pragma: no cover (compiled)
    """`failure_probability` of one rotor (eq. 15, corrected), its operations in the same order."""
    sigma = math.sqrt(1e-300 if variance < 1e-300 else variance)     # max(variance, 1e-300), NaN kept
    return 0.5 * (1.0 + _erf((k_threshold - k_hat) / (sigma * math.sqrt(2.0)), 0))


@njit(cache=True)
def _inverse_cholesky_factor(S, r):  # pragma: no cover (compiled)
    """M = L^-1 (3 x 3) for L the lower-triangular Cholesky factor of A = S + r I = L L^T, S a symmetric 3 x 3
    (its upper triangle is read). L column by column, l_jj = sqrt(a_jj - sum_k<j l_jk^2), l_ij = (a_ij - sum_k<j
    l_ik l_jk) / l_jj (Golub & Van Loan, Matrix Computations, 4th ed., 2013, Sec. 4.2); then M, lower triangular,
    by forward substitution: m_ii = 1 / l_ii, m_ij = -m_ii sum_j<=k<i l_ik m_kj (ibid. Sec. 3.1)."""
    l00 = math.sqrt(S[0, 0] + r)
    l10, l20 = S[0, 1] / l00, S[0, 2] / l00
    l11 = math.sqrt(S[1, 1] + r - l10 * l10)
    l21 = (S[1, 2] - l20 * l10) / l11
    l22 = math.sqrt(S[2, 2] + r - l20 * l20 - l21 * l21)
    M = np.zeros((3, 3))
    M[0, 0], M[1, 1], M[2, 2] = 1.0 / l00, 1.0 / l11, 1.0 / l22
    M[1, 0] = -M[1, 1] * l10 * M[0, 0]
    M[2, 0], M[2, 1] = -M[2, 2] * (l20 * M[0, 0] + l21 * M[1, 0]), -M[2, 2] * l21 * M[1, 1]
    return M


def kalman_step(x, P, z, H, Q, R, k_bounds=(0.0, 1.5)):
    """One step of 000 Algorithm 1 (random-walk Kalman estimator), then the bound on k (Sec. IV-B)."""
    P = kalman.predict(P, Q)                    # P_k|k-1 = P_k-1 + Q
    x, P, _, _ = kalman.update(x, P, z - H @ x, H, R)
    return np.minimum(np.maximum(x, k_bounds[0]), k_bounds[1]), P


@njit(cache=True)
def _kalman_step(x, P, z, H, Q, r, k_low, k_high):  # pragma: no cover (compiled)
    """`kalman_step` (000 Algorithm 1, then the bound on k; R = r I) with the gain through the Cholesky factor L
    of the innovation covariance instead of a solve; x and P in place:
        P- = P + Q,  U = P- H^T,  S = H U + R = L L^T,  V = U L^-T  (the gain K = U S^-1 = V L^-1),
        x+ = x + V L^-1 (z - H x),  P+ = P- - K S K^T = P- - V V^T.
    For this gain P+ equals the Joseph form `kalman.update` uses (Simon 2006, eq. 5.19); here it is exactly
    symmetric (V V^T is). It differs from `kalman_step` by rounding only."""
    P_prior = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            P_prior[i, j] = P[i, j] + Q[i, j]                    # P_k|k-1 = P_k-1 + Q
    U = np.dot(P_prior, H.T)
    L_inv = _inverse_cholesky_factor(np.dot(H, U), r)
    V = np.dot(U, L_inv.T)
    h = np.dot(H, x)
    y0, y1, y2 = z[0] - h[0], z[1] - h[1], z[2] - h[2]           # the innovation z - H x
    w0 = L_inv[0, 0] * y0                                        # L^-1 (z - H x)
    w1 = L_inv[1, 0] * y0 + L_inv[1, 1] * y1
    w2 = L_inv[2, 0] * y0 + L_inv[2, 1] * y1 + L_inv[2, 2] * y2
    for i in range(4):
        k = x[i] + V[i, 0] * w0 + V[i, 1] * w1 + V[i, 2] * w2
        k = k_low if k_low > k else k                            # the bound on k (Sec. IV-B), as Python's max, min
        x[i] = k_high if k_high < k else k
    VVt = np.dot(V, V.T)
    for i in range(4):
        for j in range(4):
            P[i, j] = P_prior[i, j] - VVt[i, j]


@dataclass(frozen=True)
class LoeKalmanSettings:
    """The parameters of `LoeKalmanDetector`; each `LoeKalmanDetector(..., **overrides)` keyword updates one."""

    # (G_p, G_q, G_az) of eq. (9): 1/(kg m) for p_dot, q_dot; 1/kg for a_z
    G: tuple = field(default=TABLE_II["G"], metadata=accepts(POSITIVE))
    effectiveness_matrix: tuple | None = None  # a (3, 4) B: [p_dot, q_dot, a_z] = B omega^2, replacing diag(G) S
    # process noise per sample, times I (see Q_PER_SAMPLE)
    Q: float = field(default=Q_PER_SAMPLE, metadata=accepts(POSITIVE))
    R: float = field(default=TABLE_II["R"], metadata=accepts(POSITIVE))    # measurement noise, times I (Table II)
    k_threshold: float = field(default=TABLE_II["k_threshold"], metadata=accepts(OPEN_FRACTION))         # eq. (15)
    p_fail_threshold: float = field(default=TABLE_II["p_fail_threshold"], metadata=accepts(OPEN_FRACTION))  # (16)
    k_bounds: tuple = (0.0, 1.5)       # the bound on the estimates k (Sec. IV-B), low < high
    filter_wn: float = field(default=50.0, metadata=accepts(POSITIVE))   # rad/s, the low-pass's (Sec. IV-A)
    filter_zeta: float = field(default=0.55, metadata=accepts(POSITIVE))  # its damping (Sec. IV-A)
    # detection starts once the rotors carry this share of the weight (Sec. V-D)
    takeoff_fraction: float = field(default=0.5, metadata=accepts(FRACTION))
    initial_variance: float = field(default=0.01, metadata=accepts(POSITIVE))   # P_0 = this times I


def effectiveness_matrix(settings) -> np.ndarray:
    """B = diag(G) S of 000 eq. (8)-(9) from `settings.G`, or `settings.effectiveness_matrix` when given;
    ValueError unless a finite (3, 4) array."""
    if settings.effectiveness_matrix is None:
        return np.diag(np.asarray(settings.G, dtype=float)) @ SIGNS_000
    B = np.asarray(settings.effectiveness_matrix, dtype=float)
    if B.shape != (3, 4) or not np.all(np.isfinite(B)):
        raise ValueError(f"effectiveness_matrix: must be a finite (3, 4) array, got shape {B.shape}")
    return B

class LoeKalmanDetector:
    """000's LOE detector. Readings (numpy arrays): `gyro` (rad/s, FRD), `accel` (specific force, m/s^2),
    `rotor_speed` (rad/s).

    Parameters: dt (sample time; 000 runs at 500 Hz) and the settings (`LoeKalmanSettings`, defaults 000 Table II
    and Sec. IV-A; each field also a keyword). `effectiveness_matrix` serves a vehicle with other geometry or
    motor numbering (e.g. identified from a log).
    """

    name = "loe_kalman"
    output_fields = {"k_hat": (0.0, 1.5, (4,)), "k_var": (0.0, VARIANCE_CEILING, (4,)), "p_fail": (0.0, 1.0, (4,))}

    def __init__(self, dt: float, settings: LoeKalmanSettings | None = None, **overrides):
        s = self.settings = updated(settings or LoeKalmanSettings(), overrides, "loe_kalman")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.dt = float(dt)
        self.B = effectiveness_matrix(s)
        if not (math.isfinite(s.R) and s.R > 0):                   # S = H P H^T + R must be positive definite
            raise ValueError(f"R: must be a finite number > 0, got {s.R!r}")
        k_low, k_high = s.k_bounds
        if not k_low < k_high:
            raise ValueError(f"k_bounds: must be (low, high) with low < high, got {s.k_bounds!r}")
        lowpass = biquad_constants(*lowpass_coefficients(s.filter_wn, s.filter_zeta, self.dt))
        self._constants = np.concatenate((self.B.ravel(), (s.Q * np.eye(4)).ravel(), lowpass, (
            self.dt, s.R, s.k_threshold, s.p_fail_threshold, k_low, k_high, s.takeoff_fraction * GRAVITY)))
        self._state = np.zeros(STATE_SIZE)
        self._alarm = AlarmLatch()
        self.reset()

    def reset(self) -> None:
        P = self.settings.initial_variance * np.eye(4)
        self._state[:] = 0.0
        self._state[K_HAT], self._state[COVARIANCE] = 1.0, P.ravel()
        self._state[K_VAR] = np.minimum(P.diagonal(), VARIANCE_CEILING)
        self._alarm.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        """One sample, compiled (`_step`); a reading beyond READING_LIMIT (NaN, inf), a non-finite time or a missing
        reading raises ValueError naming it, the state untouched."""
        check_time(time, self.name)
        try:
            gyro, accel, rotor_speed = readings["gyro"], readings["accel"], readings["rotor_speed"]
        except KeyError:
            raise missing_reading(readings, READINGS, self.name) from None
        rotor = _step(gyro, accel, rotor_speed, self._state, self._constants)
        if rotor >= 0:
            self._alarm.trigger(time, rotor)
        elif rotor == NON_FINITE:
            _reject_non_finite(readings)

    @property
    def x(self) -> np.ndarray:
        """k_hat, the effectiveness estimates (a view of the state)."""
        return self._state[K_HAT]

    @property
    def P(self) -> np.ndarray:
        """Their covariance (a view of the state)."""
        return self._state[COVARIANCE].reshape(4, 4)

    @property
    def armed(self) -> bool:
        """Whether the detection has started (Sec. V-D)."""
        return bool(self._state[ARMED])

    @property
    def p_fail(self) -> np.ndarray:
        """P_fail of each rotor (eq. 15; a view of the state)."""
        return self._state[P_FAIL]

    @property
    def k_threshold(self) -> float:
        """k_thres of eq. (15), from the settings (read-only: the compiled step holds it from construction)."""
        return self.settings.k_threshold

    @property
    def p_fail_threshold(self) -> float:
        """The P_fail threshold of eq. (16), from the settings (read-only, as `k_threshold`)."""
        return self.settings.p_fail_threshold

    def outputs(self) -> dict:
        published = self._state[OUTPUTS].copy()                     # one copy, three views of it
        return {"k_hat": published[K_HAT], "k_var": published[K_VAR], "p_fail": published[P_FAIL]}

    def status(self) -> dict:
        alarm, values = self._alarm, self._state[:ARMED + 1].tolist()
        return {"alarm": alarm.alarm, "alarm_time": alarm.alarm_time, "isolated": alarm.isolated,
                "k_hat": values[K_HAT], "p_fail": values[P_FAIL], "armed": values[ARMED] == 1.0}


@njit(cache=True)
def _step(gyro, accel, rotor_speed, state, constants):  # pragma: no cover (compiled)
    """One sample, in place on `state` (layout at STATE_SIZE): the low-pass (Sec. IV-A), the rates' backward
    difference (eq. 10), the Kalman step (Algorithm 1, `_kalman_step`), P_fail (eq. 15) and the decision
    (eq. 16). Returns the rotor the alarm isolates, NO_ALARM, or NON_FINITE (state untouched) for a reading
    beyond READING_LIMIT (NaN, inf)."""
    sample = _sample(gyro, accel, rotor_speed)
    if sample.size == 0:
        return NON_FINITE
    started = state[STARTED] == 1.0
    filtered = biquad_step(constants[LOWPASS], state[LOWPASS_MEMORY].reshape(2, 7), sample, not started)
    p_last, q_last = state[LAST_P], state[LAST_Q]
    state[LAST_P], state[LAST_Q], state[STARTED] = filtered[0], filtered[1], 1.0
    B, H = constants[B_ROWS].reshape(3, 4), np.empty((3, 4))
    for j in range(4):
        omega2 = filtered[3 + j] * filtered[3 + j]
        for i in range(3):
            H[i, j] = B[i, j] * omega2                            # eq. (12): H = B diag(omega^2)
    if state[ARMED] == 0.0:                                      # take-off gating (Sec. V-D)
        state[ARMED] = abs(H[2, 0] + H[2, 1] + H[2, 2] + H[2, 3]) >= constants[ARMING_THRUST]
    if not started or state[ARMED] == 0.0:
        return NO_ALARM
    dt = constants[DT]
    z = ((filtered[0] - p_last) / dt, (filtered[1] - q_last) / dt,   # eq. (10): p_dot, q_dot by backward difference
         filtered[2])                                                 # eq. (13): a_z itself
    P = state[COVARIANCE].reshape(4, 4)
    _kalman_step(state[K_HAT], P, z, H, constants[Q_MATRIX].reshape(4, 4), constants[R_NOISE], constants[K_LOW],
                 constants[K_HIGH])
    k_hat, k_var, p_fail = state[K_HAT], state[K_VAR], state[P_FAIL]
    for i in range(4):
        k_var[i] = VARIANCE_CEILING if P[i, i] > VARIANCE_CEILING else P[i, i]   # np.minimum: NaN kept
        p_fail[i] = _failure_probability(k_hat[i], P[i, i], constants[K_THRESHOLD])   # eq. (15)
    return _first_above(p_fail, constants[P_FAIL_THRESHOLD])                     # eq. (16)


@njit(cache=True)
def _sample(gyro, accel, rotor_speed):  # pragma: no cover (compiled)
    """The channels the detectors read, [p, q, a_z, omega_1..4], or an empty array if one is beyond READING_LIMIT
    (NaN, inf)."""
    sample = np.empty(7)
    sample[0], sample[1], sample[2] = gyro[0], gyro[1], accel[2]
    for i in range(4):
        sample[3 + i] = rotor_speed[i]
    return sample if within_limit(sample) else sample[:0]


@njit(cache=True)
def _first_above(p_fail, threshold):  # pragma: no cover (compiled)
    """Eq. (16): the rotor of the largest P_fail (the first of equals) if it passes the threshold, else NO_ALARM."""
    worst = 0
    for i in range(1, p_fail.size):
        if p_fail[i] > p_fail[worst]:
            worst = i
    return worst if p_fail[worst] > threshold else NO_ALARM


def loe_kalman_wrapper(env, G="vehicle", G_scale: float = 1.0, **kwargs):
    """`env` wrapped with a LoeKalmanDetector at the env's agent rate.

    G="vehicle" takes eq. (9)'s G = (c_T b / Ix, c_T h / Iy, c_T / m) from the env's nominal parameter set
    (design data a user has, as 000 identified G for its Bebop); pass numbers to override it. G_scale
    multiplies G, e.g. 0.8 or 1.2 for 000 Fig. 11's +-20% sensitivity study.
    """
    from .wrapper import DetectorWrapper
    params = vehicle_params(env, "loe_kalman", QuadrotorParams)
    dt = 1.0 / env.get_wrapper_attr("agent_hz")
    if isinstance(G, str) and G == "vehicle":
        G = params.effectiveness_G
    return DetectorWrapper(env, LoeKalmanDetector(dt, G=scaled_G(G, G_scale, "loe_kalman"), **kwargs))


def scaled_G(G, G_scale, where: str) -> tuple:
    """G times G_scale, both checked (three positive numbers; a positive factor or one per entry of G, as
    `ftcgym sweep fig11` scales them; ValueError naming them)."""
    scale = numbers(G_scale, f"{where}.G_scale", None, POSITIVE)
    if scale.shape not in ((), (3,)):
        raise ValueError(f"{where}.G_scale: expected a number > 0 or 3 of them, got {G_scale!r}")
    return tuple((numbers(G, f"{where}.G", (3,), POSITIVE) * scale).tolist())


def _reject_non_finite(readings: dict) -> None:
    """Raise a ValueError naming the first reading beyond READING_LIMIT (NaN, inf), as `_sample` rejects it."""
    for key in READINGS:
        check_reading("loe_kalman", key, readings[key])
