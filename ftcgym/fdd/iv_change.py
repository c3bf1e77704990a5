"""`IvChangeDetector`: payload (mass) change detection: 004's sensor-to-sensor IV model and a wind-aware drag test.

Ho, Hendeby, Enqvist, "A sensor-to-sensor model-based change detection approach for quadcopters"
(004). The submodel (28) links the gyro's roll and pitch rates to the accelerometer's x and y
specific force through c = lambda_1 / m alone (no thrust, wind or attitude), so a heavier vehicle shows
as a change of c. Its prediction errors r1, r2 (29) feed the instrumental-variables cost (30), whose
instruments come from a model driven by the reference only (Sec. 4.2) and therefore do not correlate
with the wind. `SixDofResidual` is the plain simulation-model residual of Sec. 4.1, which the wind
masks; it is here for comparison.

The alarm comes from a second test beside the paper's, `WindDragTest` (default `test="wind"`): the
accelerometer's drag per mass against the measured attitude, ground velocity and rotor speeds, with the wind
as a Kalman-filter state modelled on Dryden turbulence (004 eq. 14) and a CUSUM of the log-likelihood ratio of
two filters, one per mass. Why: slow Dryden turbulence (L_u / V ~ 46 s) biases the IV estimate of c over the
same 5-15 s the mass change needs to show in it (below), and no threshold on the IV statistics kept both the
misses and the false alarms away; in the wind test the turbulence is part of the noise model. It reads three
more observations than (28) needs (`attitude`, `velocity`, `rotor_speed`), so it is no longer sensor-to-sensor
in the paper's sense. It picks the turbulence intensity, up to 004's light turbulence, from the fault-free
hypothesis' fit (`WindDragTest`). The IV estimate, its CUSUM and J (30) are still computed and published;
`test="iv"` makes the IV CUSUM the alarm again.

Where the IV part departs from the paper, and why (ftcgym's square task, 004 Sec. 5.1; the measurements behind each
choice are in docs/measurements.md, 'Tuning record: fdd/iv_change.py'):
- The test statistic is the IV *estimate* of c, not the IV cost J (30). (29) is linear in c, so the IV
  estimator of c alone is c_hat = sum lam^(t-i) zeta y / sum lam^(t-i) zeta phi_c (`IvEstimate`), with
  y, phi_c the left side and c-regressor of (29) and zeta = Z . d(theta)/dc built from the instruments Z
  of (30). c_hat - c_0 is the paper's sum S of (30) projected on the parameter direction and divided by
  the instruments' excitation D. Why: J = ||S|| scales with the excitation of the moment (corners, the
  speed profile) and slow turbulence biases it about as much as the mass change does, so no single
  threshold on J serves the square both with and without heading changes.
  J (30) with the paper's lam = 0.999, N_w = 500 is still computed and published (`J`), and
  `threshold` re-enables the paper's plain test on it.
- The decision is a one-sided CUSUM (Page 1954; Basseville & Nikiforov, Detection of Abrupt Changes,
  1993, ch. 2) on the increments of the same IV sums, not a threshold on c_hat or on J (30). Each grid
  sample adds e = T (c_1 zeta.phi_c - zeta.y / c_0) / P_z with c_1 = `cusum_ratio` c_0 (0.8, between
  the nominal 1 and the ~0.58 of twice the mass) and P_z the instruments' mean power zeta.zeta over the
  warm-up (a unit only: e is in seconds of typical excitation); g = max(0, g + e), alarm when
  g > `cusum_threshold` (4.3 s). E[e] ~ (c_1 - c) zeta.phi_c / (c_0 P_z): negative drift at c_0,
  positive after the payload change; g is max over windows ending now of D_w (c_1 - c_hat_w) / (c_0 P_z),
  so long windows of weak evidence count as much as short ones of strong evidence. Why: a threshold rule
  (c_hat < 0.6 c_0 for 0.5 s, still available as `ratio_threshold`) needs the forgetting-factor estimate
  to fall below nearly its final value (0.58), which takes 5-20 s of post-onset data without heading
  changes. `cusum_ratio` and `cusum_threshold` were chosen on recorded tuning flights replayed offline.
  The margin is thin on both sides: slow Dryden turbulence (L_u / V ~ 46 s) mimics a change of c for as
  long as the straight legs without heading changes, weakly excited, need to show a real one.
- The estimate's sums forget with lam_estimate = 0.999 (5 s memory at 200 Hz) and no window cut (the
  paper's N_w = 500 keeps 2.5 s, too little to average the turbulence out).
- The model runs at the paper's T = 5 ms (200 Hz). Inputs at the agent rate are filtered, one filter
  for every signal (so (29) holds for the filtered signals too), and resampled onto the 200 Hz grid.
  The filter is a 4th-order 2 Hz Butterworth low-pass (our IMU has motor vibration and ~50x the
  paper's accelerometer noise) times a first-order 0.2 Hz low-pass, the IV prefilter. Why the second:
  the wind enters (29) as c w'' (a = -c (u - w)), and Dryden turbulence (004 eq. 14, L_u / V ~ 46 s)
  has a velocity spectrum ~ 1/omega^2 above 0.02 rad/s, so w'' is "blue"; the first-order low-pass
  acts as ~1/s above 0.2 Hz and flattens it there, which is the noise-model prefilter of optimal/refined
  IV (Soderstrom & Stoica, System Identification, 1989, ch. 8; Young 1976). The defaults sit inside a
  plateau of cutoffs, prefilters and thresholds that score alike on the tuning flights.
  `mueller2014`'s lambda_1 / m is ~8x smaller than 004 Table 1's, so the mass shows ~8x more weakly.
- The yaw-rate coupling that (28) linearises away is kept; it is parameter-free (see `_grid_step`).
- The accelerometer's x, y bias is estimated and taken out of that coupling (`AccelBiasEstimate`): the
  coupling stands for r times the body air velocity -(a - b) / c, and a per-flight constant bias b (our
  IMU: sigma 0.05 m/s^2, of the order of the drag signal c V ~ 0.1-0.2 m/s^2) turns with the body, so every
  heading step would leave T b Delta r in (29), in step with the instruments, which turn too. Estimated
  online (IV with the model's yaw-rate difference as instrument, no forgetting, ridge
  `accel_bias_prior` = 1e-9, ~1/40 of one heading step's excitation). Without heading changes r_hat = 0
  and b stays 0: nothing changes. The CUSUM's thresholds were not re-tuned for it.
- Samples are left out of the sums while the measured roll/pitch rate exceeds `max_rate` (and for
  `gate_hold` s after, the filter's memory): the small-angle, slow-rate linearisation (23)-(24) behind
  (28) does not hold there (the nominal controller swings to ~3 rad/s at corners and heading steps).
  Caveat: the heavier vehicle turns more slowly, so after the payload change some corners stay under
  `max_rate` and enter the sums. `gate="reference"` gates on the reference model's rates instead, which
  no mass change can move; it did not help with the J test and has not been measured with c_hat.
- On `mueller2014` twice the mass gives c x 0.58, not x 0.5: the rotors' drag k omega (in lambda_1)
  grows with the hover speed.

The detector's per-sample arithmetic is one compiled call (numba: `_sample`, with `_grid_step` per grid sample,
on the detector's state and constants packed in two arrays); only the wind test's Kalman step
(`WindDragTest.filter_step`, every `period` s) stays numpy. The compiled functions carry out the operations of
`ReferenceModel`, `LowPassBank`, `IvCost`, `IvEstimate`, `AccelBiasEstimate` and the plain-float steps they
replaced, in the same order, with the same BLAS product and LAPACK solve (numba's `dot`, `solve`) and CPython's
`math.remainder` (`_remainder`), so every output keeps its bits; the classes stay as the readable reference
(the tests check the recursions on them).
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.core.errors import TypingError
from scipy import signal

from ..models.checks import POSITIVE
from ..models.constants import GRAVITY
from ..models.geometry import euler_from_quat, rotation_matrix
from ..models.quadrotor import QuadrotorParams, rotor_wrench_matrix
from ..settings import accepts, updated
from .base import ARRAY_TYPES, AlarmLatch, check_reading, check_time, vehicle_params, within_limit
from .wrapper import DetectorWrapper

READ_KEYS = ("gyro", "accel", "reference_position", "reference_velocity", "reference_yaw")
WIND_TEST_KEYS = ("attitude", "velocity", "rotor_speed")   # read too by the wind test


def drag_and_mass(params) -> tuple[float, float]:
    """(lambda_1, m) of a parameter set: horizontal drag (004 eq. 9) and mass, read by attribute name.

    lambda_1 is the body's linear drag plus the rotors' drag k omega_i v, which is linear in v at fixed
    rotor speed, taken at hover: k * sum(omega_hover)."""
    n_rotors = len(params.rotor_positions)
    lambda_1 = float(params.body_drag[0]) + params.rotor_drag_coefficient * n_rotors * params.hover_omega
    return lambda_1, float(params.mass)


class LowPassBank:
    """One Butterworth low-pass applied to a vector of channels (state space: one matrix product a step).

    Built from scipy's second-order sections chained in state space, which stays exact at a cutoff a
    thousand times below the sample rate (a single high-order polynomial would not). `weight_hz` adds a
    first-order low-pass section (the IV prefilter of `IvChangeDetector`)."""

    def __init__(self, cutoff_hz: float, order: int, dt: float, weight_hz: float | None = None):
        sections = signal.butter(order, cutoff_hz, fs=1.0 / dt, output="sos")
        if weight_hz is not None:
            sections = np.vstack([sections, signal.butter(1, weight_hz, fs=1.0 / dt, output="sos")])
        A, B, C, D = np.zeros((0, 0)), np.zeros(0), np.zeros(0), 1.0
        for b0, b1, b2, _, a1, a2 in sections:
            # One section (transposed direct form II) fed by the chain so far.
            As, Cs = np.array([[-a1, 1.0], [-a2, 0.0]]), np.array([1.0, 0.0])
            Bs = np.array([b1 - a1 * b0, b2 - a2 * b0])
            n = len(B)
            A = np.block([[A, np.zeros((n, 2))], [np.outer(Bs, C), As]])
            B = np.concatenate([B, Bs * D])
            C = np.concatenate([b0 * C, Cs])
            D = b0 * D
        # y = C x + D u and x <- A x + B u as one product: [y; x] <- [C; A] x + [D; B] u
        self._CA, self._DB = np.vstack([C, A]), np.concatenate([[D], B])
        self._steady = np.linalg.solve(np.eye(len(B)) - A, B)   # state for a unit constant input
        self.x = None

    def start(self, u: np.ndarray) -> None:
        """Settle on the constant input u (no start-up transient)."""
        self.x = np.outer(self._steady, u)

    def step(self, u: np.ndarray) -> np.ndarray:
        # ndarray.dot and ufunc.outer: the BLAS call and products of `@` and np.outer, less their per-call cost. The
        # stacked product's rows are the floats of C.dot(x) and A.dot(x) (0 differences in 2.4e5 random samples).
        yx = self._CA.dot(self.x)
        yx += np.multiply.outer(self._DB, u)
        self.x = yx[1:]
        return yx[0]


class ReferenceModel:
    """The nominal closed loop driven by the reference alone: the instruments' source (004 Sec. 4.2).

    Position loop: PD on the reference position and velocity (kp, kd) asks for a horizontal
    acceleration; attitude loop: the thrust tilt tau follows it as a first-order lag (k_att); vehicle:
    (25) in still air with T_z = m g, v' = g tau - c v. The body axes follow the reference yaw with a lag
    (k_yaw). Outputs in body axes, as the sensors would read them without wind or noise: the submodel's
    (28) accelerometer a_hat = -c V_B and the rates p_hat, q_hat. Nothing here sees a measurement.
    """

    def __init__(self, c: float, dt: float, kp: float, kd: float, k_att: float, k_yaw: float):
        self.c, self.dt, self.kp, self.kd, self.k_att, self.k_yaw = c, dt, kp, kd, k_att, k_yaw

    def start(self, position, velocity, yaw: float) -> None:
        self.x, self.y = position[0], position[1]
        self.vx, self.vy = velocity[0], velocity[1]
        self.tx = self.ty = 0.0
        self.psi = yaw

    def yaw_rate(self, yaw: float) -> float:
        """The model's yaw rate toward the reference yaw (what `step` will apply)."""
        return self.k_yaw * math.remainder(yaw - self.psi, 2.0 * math.pi)

    def step(self, position, velocity, yaw: float) -> tuple:
        """Advance one dt toward the reference; return (a_hat_x, a_hat_y, p_hat, q_hat) before the step."""
        c, g, dt = self.c, GRAVITY, self.dt
        dtx = self.k_att * ((self.kp * (position[0] - self.x) + self.kd * (velocity[0] - self.vx)) / g - self.tx)
        dty = self.k_att * ((self.kp * (position[1] - self.y) + self.kd * (velocity[1] - self.vy)) / g - self.ty)
        cs, sn = math.cos(self.psi), math.sin(self.psi)
        # Pitch theta = -(tilt forward), roll phi = tilt right. For small tilt the yaw rate cancels from
        # q = theta' + psi' phi and p = phi' - psi' theta, leaving the tilt rate turned into body axes.
        out = (-c * (cs * self.vx + sn * self.vy), -c * (cs * self.vy - sn * self.vx),
               cs * dty - sn * dtx, -(cs * dtx + sn * dty))
        self.x += dt * self.vx
        self.y += dt * self.vy
        self.vx += dt * (g * self.tx - c * self.vx)
        self.vy += dt * (g * self.ty - c * self.vy)
        self.tx += dt * dtx
        self.ty += dt * dty
        self.psi += dt * self.k_yaw * math.remainder(yaw - self.psi, 2.0 * math.pi)
        return out


class IvCost:
    """004 eq. (30) for the two axes' models at once: S(t) = sum_{i=t-N_w+1}^{t} lam^(t-i) Z(i) r(i), J = ||S||_2.

    Recursive: S(t) = lam S(t-1) + Z(t) r(t) - lam^N_w Z(t-N_w) r(t-N_w), the last N_w products kept in
    a ring buffer, so a sample costs the same whatever the window. Plain floats: Z is 2 x 3 (three instruments
    per axis), and numpy's per-call cost would outweigh six products.
    """

    def __init__(self, lam: float, n_w: int):
        self.lam, self.n_w = float(lam), int(n_w)
        self._lam_n = self.lam ** self.n_w
        self.reset()

    def reset(self) -> None:
        self._products = [(0.0,) * 6] * self.n_w
        self._k = 0
        self.S = (0.0,) * 6          # S row by row: axis x's three instruments, then axis y's

    def update(self, Z, r) -> tuple:
        """Add Z(t) (2 x 3) times r(t) (2,); return J(t) (2,)."""
        (z0, z1, z2), (z3, z4, z5) = Z
        r_x, r_y = r
        zr = (z0 * r_x, z1 * r_x, z2 * r_x, z3 * r_y, z4 * r_y, z5 * r_y)
        slot = self._k % self.n_w
        lam, lam_n = self.lam, self._lam_n
        self.S = S = tuple(lam * s + p - lam_n * q for s, p, q in zip(self.S, zr, self._products[slot]))
        self._products[slot] = zr
        self._k += 1
        # ||S_row||^2 summed as the einsum this replaced did, (s_0^2 + s_2^2) + s_1^2: the same floats
        return (math.sqrt(S[0] * S[0] + S[2] * S[2] + S[1] * S[1]),
                math.sqrt(S[3] * S[3] + S[5] * S[5] + S[4] * S[4]))


class IvEstimate:
    """The IV estimate of the one parameter c = lambda_1 / m of (29), with exponential forgetting.

    (29) is linear in c: with y(t) = a(t) - 2 a(t-1) + a(t-2) and
    phi_c(t) = T [g T q(t-2) - (a(t-1) - a(t-2))] (x axis; -p and a_y on y), r(t) = y(t) - c phi_c(t).
    The instrument is phi_c built from the reference model's signals, zeta = Z . d(theta)/dc (Z of (30)).
    c_hat(t) = N(t) / D(t), N = sum lam^(t-i) zeta y, D = sum lam^(t-i) zeta phi_c, both axes pooled
    (theta_x = theta_y in (29)). Then c_hat - c_0 = -(sum lam^(t-i) zeta r_0) / D with r_0 the residual at
    the nominal c_0: the IV sum S of (30) projected on the parameter direction and divided by the
    instruments' excitation D (standard IV estimator, e.g. Soderstrom & Stoica, System Identification,
    1989, ch. 8; consistent when the noise is uncorrelated with the instruments).
    """

    def __init__(self, lam: float):
        self.lam = float(lam)
        self.reset()

    def reset(self) -> None:
        self.N = self.D = self.D_peak = 0.0

    def update(self, zeta, y, phi) -> None:
        """One grid sample; zeta, y, phi are (x, y)-axis pairs."""
        self.N = self.lam * self.N + (zeta[0] * y[0] + zeta[1] * y[1])
        self.D = self.lam * self.D + (zeta[0] * phi[0] + zeta[1] * phi[1])
        self.D_peak = max(self.D_peak, self.D)


class AccelBiasEstimate:
    """The accelerometer's x, y bias b, estimated jointly with c by IV on (29) with the yaw coupling.

    The coupling term r a of `IvChangeDetector._grid_step` stands for r times the body air velocity
    -(a - b) / c: a constant bias b is fixed in the body while the velocity turns with it, so it leaves
    T b_y Delta r on the x axis and -T b_x Delta r on the y axis, a model error wherever the yaw rate changes
    (a heading step). With Delta r the filtered measured yaw rate's grid difference and Delta r_hat the
    reference model's (its instrument), (29) reads y_x = c phi_x - b_y T Delta r, y_y = c phi_y + b_x T Delta r:
    three parameters, linear, IV-estimated from sums without forgetting (b is a per-flight constant). A ridge
    `prior` pulls b to 0 until the yaw excitation sum T^2 Delta r Delta r_hat outweighs it; without heading
    changes r_hat stays 0 and so does b.
    """

    def __init__(self, prior: float):
        self.prior = float(prior)
        self.reset()

    def reset(self) -> None:
        # The ridge toward theta_0 = (c, 0, 0) sits in the sums from the start: it adds prior on b's diagonal
        # and nothing to B (its c entry is 0). A's entries (1, 2) and (2, 1) stay 0, its (1, 1) and (2, 2) are
        # the same sum (`_bb`).
        self._a00 = self._a01 = self._a02 = self._a10 = self._a20 = 0.0
        self._bb = self.prior
        self.B = (0.0, 0.0, 0.0)
        self.bias = (0.0, 0.0)

    def update(self, zeta, phi, y, dr: float, dr_hat: float) -> None:
        # instruments (zeta_x, 0, -dr_hat), (zeta_y, dr_hat, 0) times regressors (phi_x, 0, -dr), (phi_y, dr, 0)
        self._a00 += zeta[0] * phi[0] + zeta[1] * phi[1]
        self._a01 += zeta[1] * dr
        self._a02 += -zeta[0] * dr
        self._a10 += dr_hat * phi[1]
        self._a20 += -dr_hat * phi[0]
        self._bb += dr_hat * dr
        B0, B1, B2 = self.B
        self.B = (B0 + (zeta[0] * y[0] + zeta[1] * y[1]), B1 + dr_hat * y[1], B2 + -dr_hat * y[0])
        if self._a00 > 0.0:
            bb = self._bb
            A = np.array(((self._a00, self._a01, self._a02), (self._a10, bb, 0.0), (self._a20, 0.0, bb)))
            self.bias = tuple(np.linalg.solve(A, np.array(self.B))[1:].tolist())

    def correction(self, dr: float) -> tuple:
        """What the bias leaves in y (x, y axes), to subtract: (-b_y T Delta r, b_x T Delta r)."""
        return -self.bias[1] * dr, self.bias[0] * dr


class WindDragTest:
    """The payload test on the air-relative drag, with the wind as a state: a CUSUM of the log-likelihood ratio
    of two Kalman filters, one per mass hypothesis.

    The accelerometer's x, y read the horizontal drag per mass (004 eq. 9, 17):
    a_B = -(lambda(t) / m) [R^T (v - w)]_xy + b, with lambda(t) = lambda_1 + k (sum omega_i(t) - n omega_hover)
    the body drag plus the rotors' drag k omega_i v at the measured rotor speeds, R the measured attitude, v the
    measured (ground) velocity, w the wind (NED) and b the accelerometer bias. Given m it is linear in
    x = [w_N, w_E, w_D, b_x, b_y]: z = a_B + (lambda / m) [R^T v]_xy = (lambda / m) [R^T]_xy w + b. Every
    signal is low-passed by one filter before the products are formed (so the relation holds for the filtered
    channels while w is slow against the filter) and the filters step every `period` s. The wind model
    follows Dryden (004 eq. 14) in 004 Sec. 5.1's light turbulence: the horizontal components as random walks
    of intensity `wind_intensity`, what the spectra tend to above V / L (2 sigma_u^2 V / L_u = 0.052 m^2/s^3 for
    the first-order u filter, 3 sigma_v^2 V / L_v = 0.095 for the second-order v filter, with V = 1.41 m/s, the
    airspeed `models/wind.py` scales them with: the mean wind's), the vertical one as a first-order process
    (`vertical_sigma` = sigma_w, `vertical_time` = L_w / V = 2 s); b constant with the prior `bias_sigma`.
    H0: m = m_0; H1: m = `mass_ratio` m_0. Each filter gives the Gaussian log-likelihood of its innovation
    nu, S: l_j = -0.5 (nu' S^-1 nu + log det S); the test is Page's CUSUM of l_1 - l_0, g = max(0, g + l_1 - l_0),
    alarm when g > `wind_threshold` (Basseville & Nikiforov, Detection of Abrupt Changes, 1993: ch. 2 for the
    CUSUM of log-likelihood ratios, Part II for the likelihood ratio of two models' innovations; Gustafsson,
    Adaptive Filtering and Change Detection, 2000, for change detection with Kalman filter banks). The
    turbulence sits in the test's noise model: a slow wind change is what both filters predict. What tells the
    masses apart is the drag's response to the flight's own speed changes, faster than the turbulence, and the
    size of the accelerometer's response to the turbulence itself (a heavier vehicle's is smaller: the log det S
    term).
    The turbulence intensity: that last part holds only at the intensity the air has (calm air also answers
    less, and with the light intensity alone the test alarmed in calm air). So the pair of filters runs at each
    of `turbulence_levels` times the light intensities (`wind_intensity` and `vertical_sigma` squared), and the
    CUSUM takes the increment of the level whose H0 filter has the highest log-likelihood over the last
    `level_memory` s (exponential forgetting, counted from `level_settle` s after the first sample, the light
    level before): the intensity as a nuisance parameter, estimated under H0 by maximum likelihood from a
    grid. No level is above the light one: the fault-free flights' likelihood prefers 4x (the wind state also
    takes up model error), where the log det term favours H1 throughout.
    Departure: the filters run from the start, not from each candidate change time (a two-model CUSUM, not a
    GLR).
    """

    def __init__(self, mass: float, lambda_1: float, rotor_drag: tuple, settings, dt: float):
        s = settings
        self.lambda_1, (self.k, self.hover_sum) = float(lambda_1), (float(v) for v in rotor_drag)
        self.levels = tuple(float(v) for v in s.turbulence_levels)
        self.period, self.settle = float(s.period), float(s.level_settle)
        self.forget = math.exp(-self.period / s.level_memory)
        # One filter per (turbulence level, hypothesis), stacked: index 2 i + j for level i, mass hypothesis j.
        self.theta = np.tile((1.0 / mass, 1.0 / (s.mass_ratio * mass)), len(self.levels))
        fd = math.exp(-self.period / s.vertical_time)
        f = np.array((1.0, 1.0, fd, 1.0, 1.0))
        self.FF = np.outer(f, f)                      # F P F' = P * FF for the diagonal F
        self.f = f
        self.Q = np.array([np.diag((c * s.wind_intensity * self.period, c * s.wind_intensity * self.period,
                                    c * s.vertical_sigma ** 2 * (1.0 - fd * fd), 0.0, 0.0))
                           for c in self.levels for _ in range(2)])
        self.r = s.accel_noise ** 2
        self.P0 = np.array([np.diag((s.wind_sigma ** 2, s.wind_sigma ** 2, c * s.vertical_sigma ** 2,
                                     s.bias_sigma ** 2, s.bias_sigma ** 2)) for c in self.levels for _ in range(2)])
        self._eye2 = np.broadcast_to(np.eye(2), (len(self.theta), 2, 2))
        self._filter = (s.air_cutoff_hz, s.filter_order, float(dt))
        self.reset()

    def reset(self) -> None:
        self.lowpass = LowPassBank(*self._filter)
        self.x = np.zeros((len(self.theta), 5))
        self.P = self.P0.copy()
        self.fit = np.zeros(len(self.levels))   # H0's log-likelihood per level, forgetting over `level_memory`
        self.level = len(self.levels) - 1       # the level in use (the largest until `level_settle` + 1 s)
        self.llr = 0.0                          # l_1 - l_0 of the last filter step, at `level`
        self._start = self._next = None

    def drag(self, rotor_speed) -> float:
        """lambda(t): the body drag plus the rotors' k omega_i at the measured rotor speeds."""
        return self.lambda_1 + (self.k * (sum(rotor_speed) - self.hover_sum) if self.k else 0.0)

    def update(self, accel, attitude, velocity, rotor_speed, time: float) -> bool:
        """Filter one reading; every `period` s step the Kalman filters. True when `llr` is new."""
        qx, qy, qz, qw = attitude
        lam = self.drag(rotor_speed)
        # Rows x, y of R^T (the body x and y axes in NED), times lambda.
        r0 = (lam * (1.0 - 2.0 * (qy * qy + qz * qz)), lam * 2.0 * (qx * qy + qz * qw),
              lam * 2.0 * (qx * qz - qy * qw))
        r1 = (lam * 2.0 * (qx * qy - qz * qw), lam * (1.0 - 2.0 * (qx * qx + qz * qz)),
              lam * 2.0 * (qy * qz + qx * qw))
        vn, ve, vd = velocity
        u = np.array((accel[0], accel[1], r0[0] * vn + r0[1] * ve + r0[2] * vd,
                      r1[0] * vn + r1[1] * ve + r1[2] * vd, *r0, *r1))
        if self._next is None:
            self.lowpass.start(u)
            self._start = self._next = time
        f = self.lowpass.step(u)
        if time < self._next - 1e-9:
            return False
        self._next += self.period
        self.filter_step(f, time, self._start)
        return True

    def filter_step(self, f, time: float, start: float) -> None:
        """The Kalman filters' step on the filtered channels f (10), `start` the first sample's time; sets `llr`."""
        a, lam_v, lam_r = f[0:2], f[2:4], f[4:10].reshape(2, 3)
        theta = self.theta
        # H_b = [theta_b lambda R^T_xy, I]; z_b = a + theta_b lambda [R^T v]_xy.
        H = np.concatenate((theta[:, None, None] * lam_r, self._eye2), axis=2)
        x = self.x * self.f
        P = self.P * self.FF + self.Q
        nu = a + theta[:, None] * lam_v - np.einsum("bij,bj->bi", H, x)
        PHt = P @ H.transpose(0, 2, 1)
        S = H @ PHt
        S[:, 0, 0] += self.r
        S[:, 1, 1] += self.r
        S_inv = np.linalg.inv(S)
        K = PHt @ S_inv
        self.x = x + np.einsum("bij,bj->bi", K, nu)
        IKH = np.eye(5) - K @ H   # Joseph form, as the Kalman updates of `fdd/kalman.py`
        self.P = IKH @ P @ IKH.transpose(0, 2, 1) + self.r * (K @ K.transpose(0, 2, 1))
        ll = -0.5 * (np.einsum("bi,bij,bj->b", nu, S_inv, nu) + np.log(np.linalg.det(S)))
        ll = ll.reshape(-1, 2)
        if time - start >= self.settle + 1.0:
            self.level = int(np.argmax(self.fit))
        if time - start >= self.settle - 1e-9:
            self.fit = self.forget * self.fit + ll[:, 0]
        self.llr = float(ll[self.level, 1] - ll[self.level, 0])


@dataclass(frozen=True)
class IvChangeSettings:
    """The parameters of `IvChangeDetector`; each `IvChangeDetector(..., **overrides)` keyword updates one."""

    T: float = 0.005                   # s, the model's sample time (004: 200 Hz grid)
    lam: float = 0.999                 # forgetting factor of the IV cost J (004 eq. 30)
    n_w: int = 500                     # window of the IV cost J, grid samples (004 eq. 30)
    lam_estimate: float = 0.999        # forgetting factor of the IV estimate of c
    cusum_ratio: float = 0.8           # the CUSUM's target c_1 / c_0 (a lighter c: a heavier vehicle)
    cusum_threshold: float = 4.3       # s, the CUSUM's alarm threshold
    ratio_threshold: float | None = None   # alarm when c_hat / c_0 stays below this for alarm_hold s (None: off)
    alarm_hold: float = 0.5            # s, hold of the ratio rule
    min_excitation: float = 0.05       # share of the peak instrument excitation below which c_hat is not updated
    threshold: float | None = None     # the paper's plain test J1 or J2 > threshold (None: off)
    warmup: float = 10.0               # s before any test: the instruments' mean power is measured over it
    cutoff_hz: float = 2.0             # Hz, Butterworth low-pass of every input
    filter_order: int = 4              # order of that low-pass
    weight_hz: float | None = 0.2      # Hz, the first-order IV prefilter (None: off)
    max_rate: float = 1.8              # rad/s, roll/pitch rate above which samples are left out ...
    gate_hold: float = 3.0             # s, ... and for this long after
    gate: str = "measured"             # "measured", "reference" (the reference model's rates) or "none"
    max_yaw_rate: float = math.inf     # rad/s, also gate on the yaw rate (off by default)
    yaw_coupling: bool = True          # keep the yaw-rate coupling (28) linearises away
    accel_bias_prior: float | None = 1e-9  # ridge of the accelerometer-bias estimate (None: no estimate)
    kp: float = 1.6                    # 1/s^2, the reference model's position gain
    kd: float = 2.4                    # 1/s, its velocity gain
    k_att: float = 7.0                 # 1/s, its thrust-tilt lag
    k_yaw: float = 2.5                 # 1/s, its heading lag
    test: str = "wind"                 # the alarm's test: "wind" (`WindDragTest`) or "iv" (the IV CUSUM)
    mass_ratio: float = 1.6            # the wind test's alternative m_1 / m_0
    wind_threshold: float = 14.0       # the wind test's CUSUM threshold (log-likelihood ratio)
    wind_intensity: float = 0.05       # m^2/s^3, random-walk intensity of the horizontal wind
    vertical_sigma: float = 0.42       # m/s, the vertical wind's standard deviation ...
    vertical_time: float = 2.0         # s, ... and time constant
    wind_sigma: float = 3.0            # m/s, prior of the horizontal wind
    bias_sigma: float = 0.05           # m/s^2, prior of the accelerometer's x, y bias
    accel_noise: float = 0.004         # m/s^2, the filtered accelerometer's noise at the test's rate
    air_cutoff_hz: float = 2.0         # Hz, Butterworth low-pass of the wind test's channels
    period: float = 0.1                # s, the wind test's filter step
    # the wind test's turbulence intensities, x the above (any number of them)
    turbulence_levels: tuple = field(default=(0.0625, 0.25, 1.0), metadata=accepts(POSITIVE, any_length=True))
    level_memory: float = 30.0         # s, memory of the likelihood that picks the level ...
    level_settle: float = 5.0          # s, ... counted from this long after the first sample

class IvChangeDetector:
    """Payload change detector of 004: IV estimate of c = lambda_1 / m from the residuals r1, r2 (29).

    Reads `gyro`, `accel` (body FRD) and the task's `reference_position`, `reference_velocity`,
    `reference_yaw` (for the instruments). Symbols as in 004: c = lambda_1 / m,
    theta = [-2 + cT, 1 - cT, c g T^2] (29) at the nominal mass, lam and N_w (30).
    Outputs: the IV costs J1, J2 of (30) (`J`, with the paper's lam and N_w), the residuals r1, r2 (29)
    at the nominal c, the IV estimate `c_hat` (`IvEstimate`, forgetting factor `lam_estimate`) and the
    CUSUM statistic `cusum` (s), and the wind test's CUSUM `wind_cusum`.
    Alarm (`test="wind"`, the default): the CUSUM `wind_cusum` of `WindDragTest`'s log-likelihood ratio exceeds
    `wind_threshold`, counted from `warmup` s after the first sample; the test reads `attitude`, `velocity` and
    `rotor_speed` too, and `rotor_drag` = (k, n omega_hover) gives the rotors' part of the drag
    (`from_params` fills it in). `turbulence_levels`, `level_memory` and `level_settle` set its choice of
    turbulence intensity. `mass_ratio` and `wind_threshold` were chosen on recorded tuning flights;
    `wind_intensity`, `vertical_sigma` and `vertical_time` come from 004 Sec. 5.1's light turbulence
    (`WindDragTest`), `accel_noise` is the residual of the drag model with the simulated wind on a tuning flight.
    Alarm with `test="iv"`: the one-sided CUSUM `cusum` of the IV increments toward c = `cusum_ratio` c_0 exceeds
    `cusum_threshold` (seconds of typical excitation), counted from `warmup` s after the first sample.
    Optional (off by default): c_hat / c_0 < `ratio_threshold` for `alarm_hold` s while the instruments'
    excitation D is at least `min_excitation` times its peak so far. A heavier vehicle lowers c (twice
    the mass: c x 0.58 on `mueller2014`, whose rotor drag grows with the hover speed).
    `threshold` (None by default) adds the paper's plain test J1 or J2 > threshold.
    `cusum_ratio`, `cusum_threshold`, `lam_estimate`, `cutoff_hz`, `weight_hz` were tuned on recorded flights
    of the square task, both variants, replayed offline (docs/measurements.md, 'Tuning record: fdd/iv_change.py').
    `gate`: "measured" (measured p, q, r; default), "reference" (the reference model's p_hat, q_hat and
    yaw rate) or "none"; `max_yaw_rate` (rad/s) also gates on the yaw rate (off by default).
    `accel_bias_prior`: ridge of the accelerometer-bias estimate (`AccelBiasEstimate`) that the yaw coupling
    needs; None leaves the bias out. `status()["accel_bias"]` reports the estimate.
    """

    name = "iv_change"
    output_fields = {"J": (0.0, np.inf, (2,)), "residual": (-np.inf, np.inf, (2,)),
                     "c_hat": (-np.inf, np.inf, (1,)), "cusum": (0.0, np.inf, (1,)),
                     "wind_cusum": (0.0, np.inf, (1,))}

    def __init__(self, mass: float, lambda_1: float, dt: float, settings: IvChangeSettings | None = None, *,
                 rotor_drag: tuple = (0.0, 0.0), **overrides):
        s = self.settings = updated(settings or IvChangeSettings(), overrides, "iv_change")
        for label, value in (("mass", mass), ("lambda_1", lambda_1), ("dt", dt), ("T", s.T)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"IvChangeDetector: {label} must be a finite number > 0, got {value!r}")
        if not (0.0 < s.lam <= 1.0 and s.n_w >= 1 and 0.0 < s.lam_estimate < 1.0):
            raise ValueError(f"IvChangeDetector: need 0 < lam <= 1, n_w >= 1 and 0 < lam_estimate < 1, got "
                             f"lam={s.lam!r}, n_w={s.n_w!r}, lam_estimate={s.lam_estimate!r}")
        if not ((s.ratio_threshold is None or 0.0 < s.ratio_threshold < 1.0) and s.alarm_hold >= 0.0
                and 0.0 <= s.min_excitation < 1.0):
            raise ValueError("IvChangeDetector: need 0 < ratio_threshold < 1 (or None), alarm_hold >= 0 and "
                             f"0 <= min_excitation < 1, got {s.ratio_threshold!r}, {s.alarm_hold!r}, "
                             f"{s.min_excitation!r}")
        if not (0.0 < s.cusum_ratio < 1.0 and s.cusum_threshold > 0.0):
            raise ValueError("IvChangeDetector: need 0 < cusum_ratio < 1 and cusum_threshold > 0, got "
                             f"{s.cusum_ratio!r}, {s.cusum_threshold!r}")
        if s.test not in ("wind", "iv"):
            raise ValueError(f"IvChangeDetector: test must be 'wind' or 'iv', got {s.test!r}")
        wind_values = {name: getattr(s, name) for name in (
            "mass_ratio", "wind_threshold", "wind_intensity", "vertical_sigma", "vertical_time", "wind_sigma",
            "bias_sigma", "accel_noise", "air_cutoff_hz", "period")}
        if not (all(math.isfinite(v) and v > 0.0 for v in wind_values.values()) and s.mass_ratio > 1.0
                and s.air_cutoff_hz < 0.5 / dt and len(rotor_drag) == 2
                and all(math.isfinite(v) and v >= 0.0 for v in rotor_drag)):
            raise ValueError("IvChangeDetector: the wind test needs finite values > 0, mass_ratio > 1, "
                             "air_cutoff_hz below the Nyquist rate and rotor_drag = (k >= 0, n omega_hover >= 0); "
                             f"got {wind_values}, rotor_drag={rotor_drag!r}")
        levels = s.turbulence_levels
        if not (isinstance(levels, (tuple, list)) and len(levels) >= 1
                and all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0 for v in levels)
                and math.isfinite(s.level_memory) and s.level_memory > 0.0
                and math.isfinite(s.level_settle) and s.level_settle >= 0.0):
            raise ValueError("IvChangeDetector: need turbulence_levels a non-empty sequence of numbers > 0, "
                             f"level_memory > 0 and level_settle >= 0, got {levels!r}, {s.level_memory!r}, "
                             f"{s.level_settle!r}")
        self.c = c = lambda_1 / mass
        self.dt, self.T = float(dt), float(s.T)
        self.theta = (-2.0 + c * s.T, 1.0 - c * s.T, c * GRAVITY * s.T * s.T)   # 004 eq. (29)
        self.threshold = None if s.threshold is None else float(s.threshold)
        self.ratio_threshold = None if s.ratio_threshold is None else float(s.ratio_threshold)
        self.alarm_hold = float(s.alarm_hold)
        self.cusum_ratio, self.cusum_threshold = float(s.cusum_ratio), float(s.cusum_threshold)
        self.min_excitation, self.warmup = float(s.min_excitation), float(s.warmup)
        self.max_rate, self.gate_hold = float(s.max_rate), float(s.gate_hold)
        if s.gate not in ("measured", "reference", "none"):
            raise ValueError(f"IvChangeDetector: gate must be 'measured', 'reference' or 'none', got {s.gate!r}")
        self.gate, self.max_yaw_rate = s.gate, float(s.max_yaw_rate)
        self.yaw_coupling = bool(s.yaw_coupling)
        # None: no accelerometer-bias estimate (it only matters through the yaw coupling)
        self._bias_prior = (float(s.accel_bias_prior)
                            if s.yaw_coupling and s.accel_bias_prior is not None else None)
        self.test, self.wind_threshold = s.test, float(s.wind_threshold)
        self.wind_test = WindDragTest(mass, lambda_1, rotor_drag, s, self.dt) if s.test == "wind" else None
        self._keys = READ_KEYS + (WIND_TEST_KEYS if self.wind_test is not None else ())
        self._gather = operator.itemgetter(*self._keys)
        self.latch = AlarmLatch()
        lowpass = LowPassBank(s.cutoff_hz, s.filter_order, self.dt, s.weight_hz)
        air = LowPassBank(s.air_cutoff_hz, s.filter_order, self.dt) if self.wind_test is not None else None
        n, n_air = len(lowpass._steady), 0 if air is None else len(air._steady)
        ring, lowpass_at = HEADER, HEADER + 6 * s.n_w
        ca = K_HEADER
        air_ca = ca + (n + 1) * (n + 1) + n      # after [C; A], [D; B] and the steady state
        wind = self.wind_test
        head = np.zeros(K_HEADER)
        head[[K_C, K_T, K_DT, K_KP, K_KD, K_ATT, K_YAW, K_MAX_RATE, K_GATE_HOLD, K_GATE, K_MAX_YAW_RATE]] = (
            c, self.T, self.dt, s.kp, s.kd, s.k_att, s.k_yaw, self.max_rate, self.gate_hold, GATES[s.gate],
            self.max_yaw_rate)
        head[[K_YAW_COUPLING, K_HAS_BIAS, K_LAM, K_LAM_N, K_N_W, K_LAM_ESTIMATE, K_MIN_EXCITATION, K_WARMUP]] = (
            self.yaw_coupling, self._bias_prior is not None, float(s.lam), float(s.lam) ** int(s.n_w), s.n_w,
            float(s.lam_estimate), self.min_excitation, self.warmup)
        head[[K_CUSUM_RATIO, K_CUSUM_THRESHOLD, K_TEST_IV, K_RATIO_THRESHOLD, K_ALARM_HOLD, K_THRESHOLD]] = (
            self.cusum_ratio, self.cusum_threshold, s.test == "iv",
            math.nan if self.ratio_threshold is None else self.ratio_threshold, self.alarm_hold,
            math.nan if self.threshold is None else self.threshold)
        head[[K_WIND, K_LAMBDA_1, K_ROTOR_K, K_HOVER_SUM, K_PERIOD, K_N, K_AIR_N, K_RING, K_LOWPASS]] = (
            wind is not None, 0.0 if wind is None else wind.lambda_1, 0.0 if wind is None else wind.k,
            0.0 if wind is None else wind.hover_sum, 0.0 if wind is None else wind.period, n, n_air, ring,
            lowpass_at)
        head[[K_AIR_LOWPASS, K_CA, K_AIR_CA]] = lowpass_at + 12 * n, ca, air_ca
        banks = [bank for bank in (lowpass, air) if bank is not None]
        self._constants = np.concatenate([head] + [np.concatenate((b._CA.ravel(), b._DB, b._steady)) for b in banks])
        self._state = np.zeros(lowpass_at + 12 * n + 10 * n_air)
        self.reset()

    @classmethod
    def from_params(cls, params, dt: float = 0.002, **kwargs) -> IvChangeDetector:
        """From a vehicle parameter set (attributes read by name: mass, body_drag, rotor_drag_coefficient,
        hover_omega, rotor_positions); `dt` is the sample period of the readings."""
        lambda_1, mass = drag_and_mass(params)
        rotor_drag = (params.rotor_drag_coefficient, len(params.rotor_positions) * params.hover_omega)
        return cls(mass, lambda_1, dt, rotor_drag=rotor_drag, **kwargs)

    # ------------------------------------------------------------------------------------- protocol
    def reset(self) -> None:
        self.latch.reset()
        state = self._state
        state[:] = 0.0
        state[[BELOW_SINCE, SCALE, WIND_NEXT]] = math.nan       # None: not below the ratio, no scale, no step yet
        state[GATE_UNTIL] = -math.inf
        state[C_HAT] = self.c          # the nominal value until the instruments have excited the model
        if self._bias_prior is not None:
            state[BIAS_SUMS + 5] = self._bias_prior             # the ridge sits in the sums from the start
        if self.wind_test is not None:
            self.wind_test.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        """One reading, compiled (`_sample`; the wind test's Kalman step, every `period` s, in numpy); a reading
        beyond READING_LIMIT (NaN, inf) raises ValueError naming it, the state untouched. The wind test's CUSUM
        (before the grid samples, whose alarms come later in the latch) and the alarm latch are here."""
        check_time(time, self.name)
        state, values = self._state, self._readings(readings)
        try:
            answer = _sample(state, self._constants, *values, time)
        except TypingError:                    # an array numba cannot take (object, complex): converted here
            answer = _sample(state, self._constants, *map(_array, values), time)
        if answer == WIND_DUE:
            wind = self.wind_test
            wind.filter_step(state[WIND_F:WIND_F + 10].copy(), time, state[WIND_START])
            if time - state[T0] >= self.warmup - 1e-9:
                state[WIND_CUSUM] = max(0.0, state[WIND_CUSUM] + wind.llr)
                if state[WIND_CUSUM] > self.wind_threshold:
                    self.latch.trigger(time)
            answer = _iv_samples(state, self._constants, time)
        if answer == answer:                   # not NOTHING (NaN): an alarm time, or a rejected reading
            if answer == NON_FINITE:
                _finite(readings, self._keys)
            else:
                self.latch.trigger(answer)

    def _readings(self, readings: dict) -> tuple:
        """The readings `_sample` takes, in `_keys`' order: arrays as they come (it converts them as `_array` does,
        so the bits are the same), anything else through `_array`; the wind test's empty where it is off."""
        try:
            values = self._gather(readings)
        except KeyError:
            _finite(readings, self._keys)      # raises the KeyError of the missing reading
            raise
        if not ARRAY_TYPES.issuperset(map(type, values)):
            values = tuple(map(_array, values))
        return values if self.wind_test is not None else values + (_EMPTY, _EMPTY, _EMPTY)

    @property
    def J(self) -> tuple:
        """The IV costs J1, J2 of (30)."""
        return tuple(self._state[J_0:J_0 + 2].tolist())

    @property
    def residual(self) -> tuple:
        """r1, r2 of (29) at the nominal c."""
        return tuple(self._state[RESIDUAL_0:RESIDUAL_0 + 2].tolist())

    @property
    def c_hat(self) -> float:
        """The IV estimate of c."""
        return float(self._state[C_HAT])

    @property
    def cusum(self) -> float:
        """The CUSUM g (s) of the IV increments toward c = cusum_ratio c_0."""
        return float(self._state[CUSUM])

    @property
    def wind_cusum(self) -> float:
        """The CUSUM of the wind test's log-likelihood ratio."""
        return float(self._state[WIND_CUSUM])

    def outputs(self) -> dict:
        published = self._state[OUTPUTS].copy()                 # one copy, five views of it
        return {"J": published[0:2], "residual": published[2:4], "c_hat": published[4:5],
                "cusum": published[5:6], "wind_cusum": published[6:7]}

    def status(self) -> dict:
        J0, J1, _, _, c_hat, cusum, wind_cusum = self._state[OUTPUTS].tolist()
        bias = self._state[BIAS:BIAS + 2].tolist()
        return {**self.latch.status(), "J": [J0, J1], "c_hat": c_hat, "c_nominal": self.c,
                "accel_bias": bias,
                "c_ratio": c_hat / self.c, "cusum": cusum, "cusum_threshold": self.cusum_threshold,
                "wind_cusum": wind_cusum, "wind_threshold": self.wind_threshold,
                "wind_level": None if self.wind_test is None else self.wind_test.levels[self.wind_test.level],
                "ratio_threshold": self.ratio_threshold, "threshold": self.threshold}


class SixDofResidual:
    """The plain simulation-model residual of 004 Sec. 4.1, for comparison: the wind masks it.

    The linearised 6-DOF model runs from the known inputs with the nominal mass and no wind: body rates
    from the measured rotor speeds through (5)-(7) and (26); body velocity from (25) driven by the
    measured roll and pitch (the attitude estimate: integrating (24), (27) open loop drifts without
    bound, as 004 Fig. 6 shows). The residual is measured minus simulated [p, q, a_x, a_y] (004 Fig. 7),
    with the simulated accelerometer a_s = -(lambda_1 / m) V_B of (17) without wind.
    """

    def __init__(self, params, dt: float):
        self.lambda_1, self.m = drag_and_mass(params)
        self.I = np.asarray(params.inertia, dtype=float)
        self.Delta = np.asarray(params.rotational_drag, dtype=float)
        pos = np.asarray(params.rotor_positions, dtype=float)
        c_t, c_q = params.thrust_coefficient, params.torque_coefficient
        # [tau_phi, tau_theta, tau_psi] = M omega^2: 004 eq. (5)-(7) for our X geometry (FRD).
        self.M = rotor_wrench_matrix(pos, c_t, c_q)[1:]
        self.dt = float(dt)
        self.reset()

    def reset(self) -> None:
        self.omega_s = None   # simulated body rates p, q, r
        self.V_s = None       # simulated body velocity u, v

    def update(self, readings: dict) -> np.ndarray:
        """One step; returns [p - p_s, q - q_s, a_x - a_x_s, a_y - a_y_s]."""
        gyro, accel, omega = (np.array(v) for v in _finite(readings, ("gyro", "accel", "rotor_speed")))
        attitude, velocity = _finite(readings, ("attitude", "velocity"))
        phi, theta, _ = euler_from_quat(attitude)
        if self.omega_s is None:   # start from the measured state
            self.omega_s = gyro.copy()
            R = rotation_matrix(attitude)
            self.V_s = (R.T @ velocity)[:2]
        k1, g = self.lambda_1 / self.m, GRAVITY
        (p, q, _), (u, v) = self.omega_s, self.V_s
        residual = np.array((gyro[0] - p, gyro[1] - q, accel[0] + k1 * u, accel[1] + k1 * v))
        tau = self.M @ (omega * omega)
        self.omega_s = self.omega_s + self.dt * (tau - self.Delta * self.omega_s) / self.I      # (26)
        self.V_s = self.V_s + self.dt * np.array((-k1 * u - g * theta, -k1 * v + g * phi))  # (25)
        return residual


def iv_change_wrapper(env, **kwargs) -> DetectorWrapper:
    """`env` wrapped with an `IvChangeDetector` built from its parameter set and agent rate."""
    params = vehicle_params(env, "iv_change", QuadrotorParams)
    return DetectorWrapper(env, IvChangeDetector.from_params(params, 1.0 / env.get_wrapper_attr("agent_hz"),
                                                             **kwargs))


# ----------------------------------------------------------------------------------------- helpers
def _finite(readings: dict, keys: tuple) -> list:
    """[readings[key] as a list of floats for each key]; a reading beyond READING_LIMIT (NaN, inf) raises
    ValueError naming its key, as `_sample` rejects it."""
    values = [_floats(readings[key]) for key in keys]
    for key, value in zip(keys, values):
        check_reading("iv_change", key, value)
    return values


_FLOAT64 = np.dtype(np.float64)


def _floats(value) -> list:
    """A reading as a flat list of floats (a 1-D float64 array, the env's, without the conversion's cost)."""
    if type(value) is np.ndarray and value.ndim == 1 and value.dtype == _FLOAT64:
        return value.tolist()
    return np.asarray(value, dtype=np.float64).ravel().tolist()


def _array(value) -> np.ndarray:
    """A reading as a 1-D float64 array (the env's own arrays as they are)."""
    if type(value) is np.ndarray and value.ndim == 1 and value.dtype == _FLOAT64:
        return value
    return np.asarray(value, dtype=np.float64).ravel()


# ---------------------------------------------------------------------------------------- compiled
#: The detector's state (`IvChangeDetector._state`): scalars (NaN for None), then the ring of IV-cost products
#: (n_w x 6), the IV low-pass's state (n x 12 channels) and the wind test's (n_air x 10) at the offsets in the
#: constants. OUTPUTS is what `outputs` publishes: J (2), the residuals (2), c_hat, the CUSUM, the wind CUSUM.
LAST_TIME, HAS_LAST, T0, GRID_K, GATE_UNTIL, BELOW_SINCE, Z2_SUM, Z2_N, SCALE = range(9)
OUTPUTS, J_0, RESIDUAL_0, C_HAT, CUSUM, WIND_CUSUM = slice(9, 16), 9, 11, 13, 14, 15
COST_K, COST_S, N_SUM, D_SUM, D_PEAK = 16, 17, 23, 24, 25       # IvCost: count, S (6); IvEstimate: N, D, D_peak
BIAS_SUMS, BIAS_B, BIAS = 26, 32, 35        # AccelBiasEstimate: a00, a01, a02, a10, a20, bb; B (3); bias (2)
REFERENCE = 37                              # ReferenceModel: x, y, vx, vy, tx, ty, psi
GRID, GRID_N, LAST_F = 44, 80, 81           # the last three grid samples (3 x 12), how many, the last filtered u
WIND_NEXT, WIND_START, WIND_F = 93, 94, 95        # the wind test's next step time (NaN: none yet), start, filtered u
CURRENT_F, HEADER = 105, 117                       # this sample's filtered channels (12)
#: Its constants (`IvChangeDetector._constants`): scalars (flags 1.0 true; NaN for None), then the low-passes'
#: matrices ([C; A] row-major, [D; B], the steady state) at the offsets given.
(K_C, K_T, K_DT, K_KP, K_KD, K_ATT, K_YAW, K_MAX_RATE, K_GATE_HOLD, K_GATE, K_MAX_YAW_RATE, K_YAW_COUPLING,
 K_HAS_BIAS, K_LAM, K_LAM_N, K_N_W, K_LAM_ESTIMATE, K_MIN_EXCITATION, K_WARMUP, K_CUSUM_RATIO, K_CUSUM_THRESHOLD,
 K_TEST_IV, K_RATIO_THRESHOLD, K_ALARM_HOLD, K_THRESHOLD, K_WIND, K_LAMBDA_1, K_ROTOR_K, K_HOVER_SUM, K_PERIOD,
 K_N, K_AIR_N, K_RING, K_LOWPASS, K_AIR_LOWPASS, K_CA, K_AIR_CA, K_HEADER) = range(38)
GATES = {"measured": 0.0, "reference": 1.0, "none": 2.0}
NOTHING, WIND_DUE, NON_FINITE = math.nan, -math.inf, math.inf   # `_sample`'s answers besides an alarm time
_EMPTY = np.empty(0)


@njit(cache=True)
def _remainder(x, y):  # pragma: no cover (compiled)
    """math.remainder(x, y) for finite x and y != 0, as CPython computes it (Modules/mathmodule.c, m_remainder)."""
    absx, absy = abs(x), abs(y)
    m = np.fmod(absx, absy)
    c = absy - m
    if m < c:
        r = m
    elif m > c:
        r = -c
    else:
        r = m - 2.0 * np.fmod(0.5 * (absx - m), absy)
    return math.copysign(1.0, x) * r


@njit(cache=True)
def _lowpass(state, constants, offset, matrices, n, u, start):  # pragma: no cover (compiled)
    """`LowPassBank.start` (if `start`) and `step` on the state block at `offset` (n x channels) with the
    matrices at `matrices`: the same product (BLAS) and sums."""
    channels = u.size
    x = state[offset:offset + n * channels].reshape(n, channels)
    CA = constants[matrices:matrices + (n + 1) * n].reshape(n + 1, n)
    DB = constants[matrices + (n + 1) * n:matrices + (n + 1) * (n + 1)]
    if start:
        steady = constants[matrices + (n + 1) * (n + 1):matrices + (n + 1) * (n + 1) + n]
        for i in range(n):
            for j in range(channels):
                x[i, j] = steady[i] * u[j]
    yx = np.dot(CA, x)
    for i in range(n + 1):
        for j in range(channels):
            yx[i, j] += DB[i] * u[j]
    x[:] = yx[1:]
    return yx[0].copy()


@njit(cache=True)
def _flat(reading):  # pragma: no cover (compiled)
    """A reading as `_array` makes it: 1-D, float64 (the env's arrays as they are)."""
    return np.asarray(reading, np.float64).ravel()


@njit(cache=True)
def _sample(state, constants, gyro, accel, position, velocity, yaw_reading, attitude, ground_velocity,
            rotor_speed, time):  # pragma: no cover (compiled)
    """`IvChangeDetector.update` up to the wind test's filter step, then `_iv_samples` (if the wind test has no step
    due): the reference model (Sec. 4.2), the gate, the channels, the wind test's per-sample low-pass. Returns the
    time of an alarm the IV tests raise, NOTHING, WIND_DUE (the wind test's step is due: its filtered channels in
    the state, the IV part left to `_iv_samples`), or NON_FINITE (state untouched) for a reading beyond
    READING_LIMIT (NaN, inf)."""
    gyro, accel, position, velocity = _flat(gyro), _flat(accel), _flat(position), _flat(velocity)
    yaw_reading, attitude, ground_velocity, rotor_speed = (_flat(yaw_reading), _flat(attitude),
                                                            _flat(ground_velocity), _flat(rotor_speed))
    if not (within_limit(gyro) and within_limit(accel) and within_limit(position) and within_limit(velocity)
            and within_limit(yaw_reading) and within_limit(attitude) and within_limit(ground_velocity)
            and within_limit(rotor_speed)):
        return NON_FINITE
    c = constants
    p, q, r = gyro[0], gyro[1], gyro[2]
    a_x, a_y = accel[0], accel[1]
    yaw = yaw_reading[0]
    first = state[HAS_LAST] == 0.0
    ref = state[REFERENCE:REFERENCE + 7]                       # ReferenceModel: x, y, vx, vy, tx, ty, psi
    if first:
        ref[0], ref[1], ref[2], ref[3], ref[4], ref[5], ref[6] = (position[0], position[1], velocity[0],
                                                                  velocity[1], 0.0, 0.0, yaw)
    two_pi = 2.0 * math.pi
    yaw_rate_hat = c[K_YAW] * _remainder(yaw - ref[6], two_pi)
    # ReferenceModel.step
    g, dt, cc = GRAVITY, c[K_DT], c[K_C]
    dtx = c[K_ATT] * ((c[K_KP] * (position[0] - ref[0]) + c[K_KD] * (velocity[0] - ref[2])) / g - ref[4])
    dty = c[K_ATT] * ((c[K_KP] * (position[1] - ref[1]) + c[K_KD] * (velocity[1] - ref[3])) / g - ref[5])
    cs, sn = math.cos(ref[6]), math.sin(ref[6])
    i0, i1 = -cc * (cs * ref[2] + sn * ref[3]), -cc * (cs * ref[3] - sn * ref[2])
    i2, i3 = cs * dty - sn * dtx, -(cs * dtx + sn * dty)
    ref[0] += dt * ref[2]
    ref[1] += dt * ref[3]
    ref[2] += dt * (g * ref[4] - cc * ref[2])
    ref[3] += dt * (g * ref[5] - cc * ref[3])
    ref[4] += dt * dtx
    ref[5] += dt * dty
    ref[6] += dt * c[K_YAW] * _remainder(yaw - ref[6], two_pi)
    if c[K_GATE] == 0.0:
        gate_p, gate_q, gate_r = p, q, r
    else:
        gate_p, gate_q, gate_r = i2, i3, yaw_rate_hat
    if c[K_GATE] != 2.0 and (gate_p * gate_p + gate_q * gate_q > c[K_MAX_RATE] * c[K_MAX_RATE]
                             or abs(gate_r) > c[K_MAX_YAW_RATE]):
        state[GATE_UNTIL] = time + c[K_GATE_HOLD]
    u = np.array((a_x, a_y, p, q, r * a_y, r * a_x, i0, i1, i2, i3, r, yaw_rate_hat))
    if first:
        state[T0] = time
    state[CURRENT_F:CURRENT_F + 12] = _lowpass(state, constants, int(c[K_LOWPASS]), int(c[K_CA]), int(c[K_N]),
                                               u, first)
    if c[K_WIND] == 1.0 and _wind_sample(state, constants, accel, attitude, ground_velocity, rotor_speed, time):
        return WIND_DUE
    return _iv_samples(state, constants, time)


@njit(cache=True)
def _wind_sample(state, constants, accel, attitude, velocity, rotor_speed, time):  # pragma: no cover (compiled)
    """`WindDragTest.update` up to its filter step: the channels and their low-pass. True when the step is due
    (the filtered channels in the state at WIND_F)."""
    c = constants
    qx, qy, qz, qw = attitude[0], attitude[1], attitude[2], attitude[3]
    total = 0.0
    for w in rotor_speed:
        total += w                                             # Python's sum, from 0
    lam = c[K_LAMBDA_1] + (c[K_ROTOR_K] * (total - c[K_HOVER_SUM]) if c[K_ROTOR_K] != 0.0 else 0.0)
    r00, r01, r02 = (lam * (1.0 - 2.0 * (qy * qy + qz * qz)), lam * 2.0 * (qx * qy + qz * qw),
                     lam * 2.0 * (qx * qz - qy * qw))
    r10, r11, r12 = (lam * 2.0 * (qx * qy - qz * qw), lam * (1.0 - 2.0 * (qx * qx + qz * qz)),
                     lam * 2.0 * (qy * qz + qx * qw))
    vn, ve, vd = velocity[0], velocity[1], velocity[2]
    u = np.array((accel[0], accel[1], r00 * vn + r01 * ve + r02 * vd, r10 * vn + r11 * ve + r12 * vd,
                  r00, r01, r02, r10, r11, r12))
    first = math.isnan(state[WIND_NEXT])
    if first:
        state[WIND_START] = state[WIND_NEXT] = time
    state[WIND_F:WIND_F + 10] = _lowpass(state, constants, int(c[K_AIR_LOWPASS]), int(c[K_AIR_CA]),
                                         int(c[K_AIR_N]), u, first)
    if time < state[WIND_NEXT] - 1e-9:
        return False
    state[WIND_NEXT] += c[K_PERIOD]
    return True


@njit(cache=True)
def _iv_samples(state, constants, time):  # pragma: no cover (compiled)
    """The rest of `IvChangeDetector.update`: resample the filtered channels onto the model's grid t0 + k T by
    linear interpolation and run `_grid_step` on each grid sample. Returns the first alarm time or NOTHING."""
    f = state[CURRENT_F:CURRENT_F + 12]
    if state[HAS_LAST] == 1.0:
        t_last, f_last = state[LAST_TIME], state[LAST_F:LAST_F + 12].copy()
    else:
        t_last, f_last = time, f.copy()
    alarm = NOTHING
    while True:
        t_k = state[T0] + int(state[GRID_K]) * constants[K_T]
        if not t_k <= time + 1e-9:
            break
        w = (t_k - t_last) / (time - t_last) if time > t_last else 1.0
        s = np.empty(12)
        for i in range(12):
            s[i] = f_last[i] + w * (f[i] - f_last[i])
        t_alarm = _grid_step(state, constants, s, t_k)
        if math.isnan(alarm):
            alarm = t_alarm
    state[LAST_TIME], state[HAS_LAST] = time, 1.0
    state[LAST_F:LAST_F + 12] = f
    return alarm


@njit(cache=True)
def _grid_step(state, constants, s0, t_k):  # pragma: no cover (compiled)
    """`IvChangeDetector._grid_step` (004 eq. 29-30, the IV estimate, the bias estimate, the CUSUM), the same
    operations in the same order; returns the alarm time t_k or NOTHING."""
    c = constants
    state[GRID_K] += 1.0
    grid = state[GRID:GRID + 36].reshape(3, 12)
    n = int(state[GRID_N])
    if n < 3:
        grid[n] = s0
        state[GRID_N] = n + 1
        if n + 1 < 3:
            return NOTHING
    else:
        grid[0] = grid[1]
        grid[1] = grid[2]
        grid[2] = s0
    s2, s1, s0 = grid[0], grid[1], grid[2]
    T = c[K_T]
    gT = GRAVITY * T
    y_x, y_y = s0[0] - 2.0 * s1[0] + s2[0], s0[1] - 2.0 * s1[1] + s2[1]
    if c[K_YAW_COUPLING] == 1.0:
        y_x -= T * (s1[4] - s2[4])
        y_y -= T * -(s1[5] - s2[5])
    phi0, phi1 = T * (gT * s2[3] - (s1[0] - s2[0])), T * (-gT * s2[2] - (s1[1] - s2[1]))
    zeta0, zeta1 = T * (gT * s2[9] - (s1[6] - s2[6])), T * (-gT * s2[8] - (s1[7] - s2[7]))
    gate_until = state[GATE_UNTIL]
    if c[K_HAS_BIAS] == 1.0:                  # AccelBiasEstimate.update and .correction
        dr = T * (s1[10] - s2[10])
        a = state[BIAS_SUMS:BIAS_SUMS + 6]
        B = state[BIAS_B:BIAS_B + 3]
        bias = state[BIAS:BIAS + 2]
        if t_k >= gate_until:
            dr_hat = T * (s1[11] - s2[11])
            a[0] += zeta0 * phi0 + zeta1 * phi1
            a[1] += zeta1 * dr
            a[2] += -zeta0 * dr
            a[3] += dr_hat * phi1
            a[4] += -dr_hat * phi0
            a[5] += dr_hat * dr
            B[0], B[1], B[2] = B[0] + (zeta0 * y_x + zeta1 * y_y), B[1] + dr_hat * y_y, B[2] + -dr_hat * y_x
            if a[0] > 0.0:
                bb = a[5]
                A = np.array(((a[0], a[1], a[2]), (a[3], bb, 0.0), (a[4], 0.0, bb)))
                solution = np.linalg.solve(A, B.copy())
                bias[0], bias[1] = solution[1], solution[2]
        bias_x, bias_y = -bias[1] * dr, bias[0] * dr
        y_x, y_y = y_x - bias_x, y_y - bias_y
    cc = c[K_C]
    r_x, r_y = y_x - cc * phi0, y_y - cc * phi1
    state[RESIDUAL_0], state[RESIDUAL_0 + 1] = r_x, r_y
    kept = 0.0 if t_k < gate_until else 1.0
    # IvCost.update: Z (2 x 3) times r
    z0, z1, z2, z3, z4, z5 = -s1[6], -s2[6], s2[9], -s1[7], -s2[7], -s2[8]
    kr_x, kr_y = kept * r_x, kept * r_y
    n_w = int(c[K_N_W])
    k = int(state[COST_K])
    ring = state[int(c[K_RING]):int(c[K_RING]) + 6 * n_w].reshape(n_w, 6)
    slot = k % n_w
    zr = (z0 * kr_x, z1 * kr_x, z2 * kr_x, z3 * kr_y, z4 * kr_y, z5 * kr_y)
    S = state[COST_S:COST_S + 6]
    lam, lam_n = c[K_LAM], c[K_LAM_N]
    for i in range(6):
        S[i] = lam * S[i] + zr[i] - lam_n * ring[slot, i]
        ring[slot, i] = zr[i]
    state[COST_K] = k + 1
    J0 = math.sqrt(S[0] * S[0] + S[2] * S[2] + S[1] * S[1])
    J1 = math.sqrt(S[3] * S[3] + S[5] * S[5] + S[4] * S[4])
    state[J_0], state[J_0 + 1] = J0, J1
    kz0, kz1 = kept * zeta0, kept * zeta1
    # IvEstimate.update
    lam_e = c[K_LAM_ESTIMATE]
    state[N_SUM] = lam_e * state[N_SUM] + (kz0 * y_x + kz1 * y_y)
    state[D_SUM] = lam_e * state[D_SUM] + (kz0 * phi0 + kz1 * phi1)
    D = state[D_SUM]
    if state[D_PEAK] < D:
        state[D_PEAK] = D
    excited = D > 0.0 and c[K_MIN_EXCITATION] * state[D_PEAK] <= D
    if excited:
        state[C_HAT] = state[N_SUM] / D
    if t_k - state[T0] < c[K_WARMUP]:
        state[Z2_SUM] += kz0 * kz0 + kz1 * kz1
        state[Z2_N] += 1.0
        return NOTHING
    if math.isnan(state[SCALE]):
        state[SCALE] = state[Z2_SUM] / state[Z2_N] if state[Z2_SUM] > 0.0 else math.inf
    e = T * (c[K_CUSUM_RATIO] * (kz0 * phi0 + kz1 * phi1) - (kz0 * y_x + kz1 * y_y) / cc) / state[SCALE]
    g = state[CUSUM] + e
    state[CUSUM] = g if g > 0.0 else 0.0                      # max(0.0, g)
    alarm = NOTHING
    if c[K_TEST_IV] == 1.0 and state[CUSUM] > c[K_CUSUM_THRESHOLD]:
        alarm = t_k
    ratio = c[K_RATIO_THRESHOLD]
    if not math.isnan(ratio) and excited and state[C_HAT] < ratio * cc:
        if math.isnan(state[BELOW_SINCE]):
            state[BELOW_SINCE] = t_k
        if t_k - state[BELOW_SINCE] >= c[K_ALARM_HOLD] - 1e-9 and math.isnan(alarm):
            alarm = t_k
    else:
        state[BELOW_SINCE] = math.nan
    threshold = c[K_THRESHOLD]
    if not math.isnan(threshold) and (J1 if J1 > J0 else J0) > threshold and math.isnan(alarm):
        alarm = t_k
    return alarm
