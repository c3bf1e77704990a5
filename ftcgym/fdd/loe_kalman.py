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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.special import erf

from ..models.constants import GRAVITY
from ..settings import updated
from . import kalman
from .base import AlarmLatch, Biquad

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
VARIANCE_CEILING = 1e6  # published k_var is clipped here (the unobservable direction's variance grows without bound)


def lowpass_coefficients(wn: float, zeta: float, dt: float):
    """Discrete (b, a) of the 000 Sec. IV-A low-pass by the bilinear (Tustin) transform."""
    b, a, _ = signal.cont2discrete(([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn]), dt, method="gbt", alpha=0.5)
    return np.ravel(b), np.ravel(a)


def failure_probability(k_hat, variance, k_threshold: float) -> np.ndarray:
    """(P_fail)_i = P(k_i < k_thres) = 0.5 (1 + erf((k_thres - k_hat_i) / (sigma_i sqrt(2)))), sigma_i = sqrt(P_ii).

    000 eq. (15) as printed computes P(k_i > k_thres) and divides by the variance instead of the standard
    deviation (erratum, docs/references.md); this is the intended value, the normal CDF at k_thres.
    """
    k_hat, variance = np.broadcast_arrays(np.asarray(k_hat, dtype=float), np.asarray(variance, dtype=float))
    return np.reshape(_failure_probability(k_hat.ravel().tolist(), variance.ravel().tolist(), k_threshold), k_hat.shape)


def _failure_probability(k_hat: list, variance: list, k_threshold: float) -> list:
    """`failure_probability` on lists of floats: the same operations per element as on arrays (math.sqrt and max
    round as np.sqrt and np.maximum do), without numpy's per-call cost; erf stays scipy's."""
    root2 = math.sqrt(2.0)
    return [0.5 * (1.0 + float(erf((k_threshold - k) / (math.sqrt(max(v, 1e-300)) * root2))))
            for k, v in zip(k_hat, variance)]


def _inverse_cholesky_factor(S: list, r: float) -> tuple:
    """M = L^-1 (rows of floats) for L the lower-triangular Cholesky factor of A = S + r I = L L^T, S a symmetric
    3 x 3 (rows of floats). L column by column, l_jj = sqrt(a_jj - sum_k<j l_jk^2), l_ij = (a_ij - sum_k<j l_ik l_jk)
    / l_jj (Golub & Van Loan, Matrix Computations, 4th ed., 2013, Sec. 4.2); then M, lower triangular, by forward
    substitution: m_ii = 1 / l_ii, m_ij = -m_ii sum_j<=k<i l_ik m_kj (ibid. Sec. 3.1)."""
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S
    l00 = math.sqrt(s00 + r)
    l10, l20 = s01 / l00, s02 / l00
    l11 = math.sqrt(s11 + r - l10 * l10)
    l21 = (s12 - l20 * l10) / l11
    l22 = math.sqrt(s22 + r - l20 * l20 - l21 * l21)
    m00, m11, m22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    m10 = -m11 * l10 * m00
    return (m00, 0.0, 0.0), (m10, m11, 0.0), (-m22 * (l20 * m00 + l21 * m10), -m22 * l21 * m11, m22)


def kalman_step(x, P, z, H, Q, R, k_bounds=(0.0, 1.5)):
    """One step of 000 Algorithm 1 (random-walk Kalman estimator), then the bound on k (Sec. IV-B)."""
    P = kalman.predict(P, Q)                    # P_k|k-1 = P_k-1 + Q
    x, P, _, _ = kalman.update(x, P, z - H @ x, H, R)
    return np.minimum(np.maximum(x, k_bounds[0]), k_bounds[1]), P


@dataclass(frozen=True)
class LoeKalmanSettings:
    """The parameters of `LoeKalmanDetector`; each `LoeKalmanDetector(..., **overrides)` keyword updates one."""

    G: tuple = TABLE_II["G"]            # (G_p, G_q, G_az) of eq. (9): 1/(kg m) for p_dot, q_dot; 1/kg for a_z
    effectiveness_matrix: tuple | None = None  # a (3, 4) B: [p_dot, q_dot, a_z] = B omega^2, replacing diag(G) S
    Q: float = Q_PER_SAMPLE            # process noise per sample, times I (see Q_PER_SAMPLE)
    R: float = TABLE_II["R"]           # measurement noise, times I (Table II)
    k_threshold: float = TABLE_II["k_threshold"]            # eq. (15)
    p_fail_threshold: float = TABLE_II["p_fail_threshold"]  # eq. (16)
    k_bounds: tuple = (0.0, 1.5)       # the bound on the estimates k (Sec. IV-B)
    filter_wn: float = 50.0            # rad/s, the low-pass's natural frequency (Sec. IV-A)
    filter_zeta: float = 0.55          # its damping (Sec. IV-A)
    takeoff_fraction: float = 0.5      # detection starts once the rotors carry this share of the weight (Sec. V-D)
    initial_variance: float = 0.01     # P_0 = this times I


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
        self._heave_row = self.B[2].tolist()
        self._omega2_rows = np.empty((3, 4))
        if not (math.isfinite(s.R) and s.R > 0):                   # S = H P H^T + R must be positive definite
            raise ValueError(f"R: must be a finite number > 0, got {s.R!r}")
        self.Q, self.r = s.Q * np.eye(4), float(s.R)
        self.k_threshold, self.p_fail_threshold = s.k_threshold, s.p_fail_threshold
        self.k_bounds = s.k_bounds
        self.takeoff_fraction = s.takeoff_fraction
        self.initial_variance = s.initial_variance
        self._coefficients = lowpass_coefficients(s.filter_wn, s.filter_zeta, self.dt)
        self._alarm = AlarmLatch()
        self.reset()

    def reset(self) -> None:
        self.x = np.ones(4)
        self.P = self.initial_variance * np.eye(4)
        self.p_fail = [0.0] * 4
        self._filter = Biquad(*self._coefficients)
        self._previous_rates = None
        self.armed = False
        self._alarm.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        gyro, accel = readings["gyro"].tolist(), readings["accel"].tolist()
        sample = [gyro[0], gyro[1], accel[2], *readings["rotor_speed"].tolist()]
        if not math.isfinite(sum(sample)):                           # one check; the key only on failure
            _reject_non_finite(readings)
        filtered = self._filter(sample)
        previous, self._previous_rates = self._previous_rates, filtered
        omega2 = [w * w for w in filtered[3:]]
        if not self.armed:
            self.armed = abs(sum(b * w for b, w in zip(self._heave_row, omega2))) >= self.takeoff_fraction * GRAVITY
        if previous is None or not self.armed:
            return
        z = [(filtered[0] - previous[0]) / self.dt,                  # eq. (10): p_dot, q_dot by backward difference
             (filtered[1] - previous[1]) / self.dt, filtered[2]]     # eq. (13): a_z itself
        self._omega2_rows[:] = omega2                                # omega^2 on every row: H without broadcasting
        k_hat = self._kalman_step(z, self.B * self._omega2_rows)     # eq. (12): H = B diag(omega^2)
        self.p_fail = _failure_probability(k_hat, self.P.diagonal().tolist(), self.k_threshold)
        worst = max(self.p_fail)
        if worst > self.p_fail_threshold:                           # eq. (16)
            self._alarm.trigger(time, self.p_fail.index(worst))

    def _kalman_step(self, z: list, H: np.ndarray) -> list:
        """`kalman_step` (000 Algorithm 1, then the bound on k; R = r I) with the gain through the Cholesky factor
        L of the innovation covariance instead of a solve; sets x and P, returns x as floats:
            P- = P + Q,  U = P- H^T,  S = H U + R = L L^T,  V = U L^-T  (the gain K = U S^-1 = V L^-1),
            x+ = x + V L^-1 (z - H x),  P+ = P- - K S K^T = P- - V V^T.
        For this gain P+ equals the Joseph form `kalman.update` uses (Simon 2006, eq. 5.19); here it is exactly
        symmetric (V V^T by a symmetric product). It differs from `kalman_step` by rounding only."""
        P = self.P + self.Q                                          # P_k|k-1 = P_k-1 + Q
        U = P.dot(H.T)
        L_inv = _inverse_cholesky_factor(H.dot(U).tolist(), self.r)
        V = U.dot(np.array(L_inv).T)
        (i00, _, _), (i10, i11, _), (i20, i21, i22) = L_inv
        (z0, z1, z2), (h0, h1, h2) = z, H.dot(self.x).tolist()
        y0, y1, y2 = z0 - h0, z1 - h1, z2 - h2                       # the innovation z - H x
        w0, w1, w2 = i00 * y0, i10 * y0 + i11 * y1, i20 * y0 + i21 * y1 + i22 * y2   # L^-1 (z - H x)
        lo, hi = self.k_bounds
        x = [min(max(k + v0 * w0 + v1 * w1 + v2 * w2, lo), hi) for k, (v0, v1, v2) in zip(self.x.tolist(), V.tolist())]
        self.x, self.P = np.array(x), P - V.dot(V.T)
        return x

    def outputs(self) -> dict:
        return {"k_hat": self.x.copy(), "k_var": np.minimum(self.P.diagonal(), VARIANCE_CEILING),
                "p_fail": np.array(self.p_fail)}

    def status(self) -> dict:
        return {**self._alarm.status(), "k_hat": self.x.tolist(), "p_fail": list(self.p_fail), "armed": self.armed}


def loe_kalman_wrapper(env, G="vehicle", G_scale: float = 1.0, **kwargs):
    """`env` wrapped with a LoeKalmanDetector at the env's agent rate.

    G="vehicle" takes eq. (9)'s G = (c_T b / Ix, c_T h / Iy, c_T / m) from the env's nominal parameter set
    (design data a user has, as 000 identified G for its Bebop); pass numbers to override it. G_scale
    multiplies G, e.g. 0.8 or 1.2 for 000 Fig. 11's +-20% sensitivity study.
    """
    from .wrapper import DetectorWrapper
    dt = 1.0 / env.get_wrapper_attr("agent_hz")
    if isinstance(G, str) and G == "vehicle":
        G = env.get_wrapper_attr("params").effectiveness_G
    return DetectorWrapper(env, LoeKalmanDetector(dt, G=tuple(np.asarray(G) * G_scale), **kwargs))


def _reject_non_finite(readings: dict) -> None:
    """Raise a ValueError naming the first reading with a NaN or infinity."""
    for key in ("gyro", "accel", "rotor_speed"):
        value = np.asarray(readings[key], dtype=float)
        if not np.all(np.isfinite(value)):
            raise ValueError(f"loe_kalman: reading {key!r} is not finite: {value.tolist()}")
