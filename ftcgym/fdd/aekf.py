"""`AugmentedEkfDetector` ("aekf"): actuator loss-of-effectiveness estimation with an augmented EKF.

Lu, van Kampen, Yu, *Actuator Fault Detection and Diagnosis for Quadrotors* (002): the rigid-body
model (eq. 19-27) is augmented with the loss of effectiveness l_i of each rotor as a random-walk state
(eq. 43-44) and estimated by an EKF (eq. 6-18, Joseph-form covariance eq. 18) from position, velocity and
attitude measurements (eq. 28-36); a threshold on the accumulated innovation raises the alarm (eq. 41-42).

State x = [p (3, NED m), v (3, NED m/s), eta = (phi, theta, psi) (3, rad), omega = (p, q, r) (3, FRD
rad/s), b_g (3, gyro bias rad/s), l (4, LOE of r1..r4), d (2, horizontal NED acceleration, m/s^2)].

Where ftcgym departs from or adapts the paper (also noted at the code):
- Frames: NED / FRD (docs/concepts.md, 'Frames and units'), so eq. (24) reads
  m dv_z/dt = -U cos(phi) cos(theta) + m g; the full ZYX rotation R(eta) replaces the expanded products of
  eq. (22)-(24).
- Attitude as ZYX Euler angles, as 002: eq. (34)-(36) stay linear, so H is a selection matrix and the
  Joseph update eq. (18) is exact. A quadrotor the env has not declared crashed is within 60 deg of level,
  far from the pitch singularity; the yaw innovation and state are wrapped to [-pi, pi). (A quaternion
  with a 3-state error would avoid the singularity at the cost of a nonlinear H and a reset step.)
- Rotation: eq. (25)-(27) (J eta_ddot = tau) become Euler's equation J omega_dot = M - omega x J omega,
  with the rotor moments of 000 eq. (4) (X frame), drag torques with the yaw signs of 004 eq. (7),
  propeller gyroscopic and spin-up torques, and linear damping: the same terms as the simulator's rotors.
- Inputs: 002's inputs are PWM commands through the first-order actuator of eq. (37)-(39). Our ESCs report
  the rotor speeds Omega_i (obs["rotor_speed"]), the output of that lag, so they are the inputs: thrust
  T_i = c_T k_i Omega_i^2 and drag torque c_Q k_i Omega_i^2 with effectiveness k_i = 1 - l_i, the factor
  eq. (40) puts on the actuator input. The speeds of a sample act over the step that ends at it (as the
  simulator, which steps its motors before the forces); the spin-up torque uses the speed difference over
  the step, a momentum change, so ESC noise in it does not accumulate. `command` is not needed.
- Gyro: a measurement of omega + b_g, not an input. The rotor moments act on the body rates, so the rates
  must be states for the four l_i to be observable; as inputs, the gyro would leave only the collective
  thrust, one equation for four unknowns. The bias states keep a constant gyro bias out of l.
- Wind: not in 002. The detector knows no wind, and the drag of a 1.4 m/s wind (~0.2 m/s^2) alone drove the
  innovation alarm within 1 s of every windy flight. A horizontal acceleration d (random walk, like l)
  absorbs it. Only horizontal: a vertical one could not be told from a collective LOE.
- Measurements: eq. (28)-(36) plus the gyro. Position and velocity are sample-and-hold (100 Hz): they update
  the filter only when their value changes, so one noisy sample is not counted five times.
- Discretisation at the constructor's dt: Phi = I + F dt + (F dt)^2 / 2 (eq. 8 to second order),
  Q_d = Q dt (first term of eq. 10), the state by the second-order Taylor step of eq. (6).
- Detection: eq. (41) as printed (H x - H x_hat) needs the unknown true state; we use the innovation
  gamma = y - H x_hat of eq. (17). Eq. (42)'s accumulation: per channel, gamma_j / sqrt(S_jj) is summed
  over an exponential window and scaled to unit variance; the statistic is the largest |z_j|, compared
  with T_0. Isolation: the rotor whose LOE estimate is largest above `isolation_threshold`.
- The LOE estimates are not clipped to [0, 1]: clipping would bias them, and 002 values their unbiasedness.

Each `update` is one compiled call (numba: `_step`, on the filter's state and constants packed in two arrays,
as numba's call cost grows with each argument), the detection and the outputs included. The products use the
filter's structure: the random walks' rows of F are zero, so only the first N_MOVING rows of Phi are multiplied
(`_predict`); H selects states, so H x, H P and H P H^T are picks of entries (`_correct`); S is symmetric positive
definite, so the gain comes from a Cholesky factor (`_gain`). The rest are BLAS products. This equals the dense
eq. (7) and (18) up to rounding: against the dense filter, the LOE estimates moved by at most 2.5e-14 and the
alarm times not at all (docs/measurements.md, 'Step cost: aekf by its structure').
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.core.errors import TypingError

from ..models.checks import NON_NEGATIVE, POSITIVE, Range, number
from ..models.constants import GRAVITY
from ..models.geometry import euler_from_quat, rotation_from_euler, skew_matrix
from ..models.quadrotor import YAW_SIGNS, QuadrotorParams, rotor_wrench_matrix
from ..settings import accepts, updated
from .base import (
    ARRAY_TYPES,
    BEYOND_LIMIT,
    READING_LIMIT,
    AlarmLatch,
    beyond_limit,
    check_reading,
    check_time,
    vehicle_params,
    within_limit,
)
from .wrapper import DetectorWrapper

N_X = 21
POS, VEL, ETA, OMEGA, BIAS, LOE, DIST = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                                         slice(15, 19), slice(19, 21))
PSI, BIAS_0, LOE_0 = 8, 12, 15            # the yaw state, the first bias and LOE states
#: the states with dynamics; the rest (biases, LOE, d) are random walks, whose rows of F are zero
N_MOVING = 12
_NO_COMMAND = np.empty(0)
#: The detector's state (`AugmentedEkfDetector._state`): x, P (row-major), the previous sample's rotor speeds and
#: held position and velocity, the innovation accumulators of eq. (42) (acc, acc_w, z), what `outputs` publishes
#: (the LOE estimates, their standard deviations, the statistic), the first sample's time and two flags (1.0
#: true): the alarm has fired, it has fired without isolating a rotor yet.
X, COVARIANCE, OMEGA_PREV, HELD = slice(0, 21), slice(21, 462), slice(462, 466), slice(466, 472)
ACC, ACC_W, Z = slice(472, 484), slice(484, 496), slice(496, 508)
PUBLISHED, LOE_OUT, LOE_STD, STATISTIC = slice(508, 517), slice(508, 512), slice(512, 516), 516
START, ALARMED, PENDING, STATE_SIZE = 517, 518, 519, 520
LOE_OUT_0, LOE_STD_0 = 508, 512
#: Its constants (`AugmentedEkfDetector._constants`): Q_d (21 x 21), the diagonal of R (12), the model constants
#: (`_model`, 41), then dt, the window's forgetting factor, T_0, the isolation threshold and the warm-up.
Q_MATRIX, R_DIAGONAL, MODEL = slice(0, 441), slice(441, 453), slice(453, 494)
DT, FORGET, THRESHOLD, ISOLATION_THRESHOLD, WARMUP = range(494, 499)
#: y's rows (eq. 28-36 plus the gyro, `_measurement`): the state each reads, and the gyro rows' bias state
MEASURED = np.array((6, 7, 8, 9, 10, 11, 0, 1, 2, 3, 4, 5))
#: `_step`'s answers besides a rotor the new alarm isolates: nothing new, a reading beyond READING_LIMIT (state
#: untouched), an alarm isolating nothing, and ISOLATED_LATER + i: the first isolation (rotor i) after such an alarm
NOTHING, REJECTED, ALARM_WITHOUT_ROTOR, DIVERGED, ISOLATED_LATER = -1, -2, -3, -4, 10
#: the constants of f(x, u) in the one array the compiled functions read (`AugmentedEkfDetector._model`): mass,
#: thrust coefficient c_T, rotor drag coefficient k_d, propeller inertia I_p, linear body drag (FRD) and rotational
#: drag, inertia J, yaw signs s, the moment matrix A (3 x 4, row-major) and -A / J
MASS, C_T, K_D, I_P = range(4)
BODY_DRAG, ROTATIONAL_DRAG, INERTIA, SIGNS, MOMENTS, MOMENTS_OVER_J = (
    slice(4, 7), slice(7, 10), slice(10, 13), slice(13, 17), slice(17, 29), slice(29, 41))


@dataclass(frozen=True)
class QuadrotorModel:
    """The detector's knowledge of the vehicle: nominal numbers only (SI, body FRD, rotors r1..r4)."""

    mass: float
    inertia: tuple                      # (Ixx, Iyy, Izz)
    rotor_positions: tuple              # 4 x (x, y, z) in body FRD
    thrust_coefficient: float           # c_T: T_i = c_T k_i Omega_i^2
    torque_coefficient: float           # c_Q: drag torque c_Q k_i Omega_i^2
    yaw_signs: tuple = YAW_SIGNS
    propeller_inertia: float = 0.0      # gyroscopic and spin-up torques
    rotor_drag_coefficient: float = 0.0  # in-plane rotor drag k_d k_i Omega_i v
    body_drag: tuple = (0.0, 0.0, 0.0)   # N s/m, linear, FRD
    rotational_drag: tuple = (0.0, 0.0, 0.0)  # N m s, linear

    @classmethod
    def from_params(cls, params) -> QuadrotorModel:
        """Read a `QuadrotorParams`-like object by attribute name (no simulator import)."""
        return cls(
            mass=float(params.mass), inertia=tuple(map(float, params.inertia)),
            rotor_positions=tuple(map(tuple, np.asarray(params.rotor_positions, dtype=float))),
            thrust_coefficient=float(params.thrust_coefficient),
            torque_coefficient=float(params.torque_coefficient),
            yaw_signs=tuple(getattr(params, "yaw_signs", YAW_SIGNS)),
            propeller_inertia=float(getattr(params, "propeller_inertia", 0.0)),
            rotor_drag_coefficient=float(getattr(params, "rotor_drag_coefficient", 0.0)),
            body_drag=tuple(map(float, getattr(params, "body_drag", (0.0, 0.0, 0.0)))),
            rotational_drag=tuple(map(float, getattr(params, "rotational_drag", (0.0, 0.0, 0.0)))))


@dataclass(frozen=True)
class AekfSettings:
    """The parameters of `AugmentedEkfDetector`; each `AugmentedEkfDetector(..., **overrides)` keyword updates one."""

    # the detector's c_T is (1 + model_error) times the nominal one
    model_error: float = field(default=0.0, metadata=accepts(Range(-1.0, open_low=True)))
    # 1/sqrt(s), sigma of the LOE random walk w' (eq. 43)
    loe_walk: float = field(default=0.05, metadata=accepts(POSITIVE))
    # s, time constant of the innovation accumulation window (eq. 42)
    window: float = field(default=0.5, metadata=accepts(POSITIVE))
    # T_0 of eq. (42), standard deviations of the accumulated innovation
    threshold: float = field(default=3.0, metadata=accepts(POSITIVE))
    # LOE estimate above which a rotor may be isolated
    isolation_threshold: float = field(default=0.1, metadata=accepts(Range(0.0, 1.0, open_low=True, open_high=True)))
    warmup: float = field(default=1.0, metadata=accepts(NON_NEGATIVE))   # s after the first sample without alarms
    q_sigma: dict | None = None        # overrides of Q_SIGMA entries
    r_sigma: dict | None = None        # overrides of R_SIGMA entries

class AugmentedEkfDetector:
    """002's augmented EKF (see the module docstring), fed one sample at a time; the arithmetic compiled.

    model:               the vehicle's nominal numbers (`QuadrotorModel`, or use `from_params`)
    dt:                  the update interval (s) the model is discretised at: one `update` per dt
    settings:            `AekfSettings` (each field also a keyword)

    Defaults chosen on tuning flights with the env's default sensors; see docs/measurements.md,
    'Tuning record: fdd/aekf.py'.
    """

    name = "aekf"
    output_fields = {
        "loe": (-np.inf, np.inf, (4,)),          # l_i estimates (not clipped)
        "loe_std": (0.0, np.inf, (4,)),          # sqrt(P_ii) of the LOE states
        "innovation": (0.0, np.inf, (1,)),       # the detection statistic max_j |z_j|
    }
    # Process noise densities, per sqrt(s): unmodelled acceleration (vel), angular acceleration (omega).
    Q_SIGMA = {"pos": 0.01, "vel": 0.03, "eta": 1e-3, "omega": 1.5, "bias": 1e-3, "dist": 0.1}
    # Measurement noise sigmas: the env's sensors.py levels (gyro: its noise plus motor vibration).
    R_SIGMA = {"position": 0.01, "velocity": 0.02, "attitude": np.deg2rad(0.2), "gyro": 0.05}
    P0_SIGMA = {"pos": 0.01, "vel": 0.02, "eta": np.deg2rad(0.5), "omega": 0.05, "bias": 0.01, "loe": 0.05,
                "dist": 0.3}
    KEYS = ("position", "velocity", "attitude", "gyro", "rotor_speed")

    def __init__(self, model: QuadrotorModel, dt: float, settings: AekfSettings | None = None, **overrides):
        s = self.settings = updated(settings or AekfSettings(), overrides, "aekf")
        for name, value in (("dt", dt), ("window", s.window), ("loe_walk", s.loe_walk)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
        if not (math.isfinite(s.model_error) and s.model_error > -1):
            raise ValueError(f"model_error: must be a finite number > -1, got {s.model_error!r}")
        self.model, self.dt = model, float(dt)
        self.threshold, self.isolation_threshold, self.warmup = s.threshold, s.isolation_threshold, s.warmup
        self._forget = math.exp(-self.dt / s.window)
        self._use_model(model, s.model_error)
        q = _override(self.Q_SIGMA, s.q_sigma, "q_sigma")
        q_c = _blocks(q["pos"], q["vel"], q["eta"], q["omega"], q["bias"], s.loe_walk, q["dist"]) ** 2
        self.Q = np.diag(q_c * self.dt)                        # eq. (10), first term, G = I
        p0 = self.P0_SIGMA
        self._P0 = np.diag(_blocks(*(p0[k] for k in ("pos", "vel", "eta", "omega", "bias", "loe", "dist"))) ** 2)
        # Eq. (28)-(36) plus the gyro, ordered so that a step without fresh position/velocity is a prefix:
        # y = [eta (3), gyro (3) | p (3), v (3)].
        r = _override(self.R_SIGMA, s.r_sigma, "r_sigma")
        self.R_full = np.diag(np.repeat([r["attitude"], r["gyro"], r["position"], r["velocity"]], 3) ** 2)
        self.H_full = np.zeros((12, N_X))
        for row, block in ((0, ETA), (3, OMEGA), (3, BIAS), (6, POS), (9, VEL)):
            self.H_full[row:row + 3, block] = np.eye(3)
        self._constants = np.concatenate((self.Q.ravel(), self.R_full.diagonal(), self._model, (
            self.dt, self._forget, self.threshold, self.isolation_threshold, self.warmup)))
        self._state = np.zeros(STATE_SIZE)
        self._gather = operator.itemgetter(*self.KEYS)
        self.reset()

    @classmethod
    def from_params(cls, params, dt: float, **kwargs) -> AugmentedEkfDetector:
        """A detector for a `QuadrotorParams`-like object (attributes read by name)."""
        return cls(QuadrotorModel.from_params(params), dt, **kwargs)

    def _use_model(self, m: QuadrotorModel, model_error: float) -> None:
        """Constants of f(x, u), with c_T scaled by (1 + model_error)."""
        c_T = m.thrust_coefficient * (1.0 + model_error)
        J, s = np.asarray(m.inertia, dtype=float), np.asarray(m.yaw_signs, dtype=float)
        # Moment per unit effective Omega^2 (000 eq. 4; yaw row 004 eq. 7): columns are rotors.
        A = rotor_wrench_matrix(np.asarray(m.rotor_positions, dtype=float), c_T, m.torque_coefficient, s)[1:]
        self._model = np.concatenate(((m.mass, c_T, m.rotor_drag_coefficient, m.propeller_inertia), m.body_drag,
                                      m.rotational_drag, J, s, A.ravel(), (-A / J[:, None]).ravel()))

    # ------------------------------------------------------------------------------------ protocol
    def reset(self) -> None:
        self._state[:] = 0.0
        self._state[COVARIANCE] = self._P0.ravel()
        self._state[ACC_W] = 1.0        # sum of squared window weights: var of acc if the model fits
        _publish(self._state)
        self._latch = AlarmLatch()
        self._start = None

    def update(self, readings: dict, time: float, command: np.ndarray | None = None) -> None:
        """One sample: predict from the previous one (eq. 6-12), correct with this one (eq. 13-18), detect (eq. 41-42),
        compiled (`_step`); the first sample initialises. A reading or command beyond READING_LIMIT (NaN, inf) or a
        non-finite time raises ValueError naming it, with the state untouched."""
        command = _NO_COMMAND if command is None else np.asarray(command, np.float64)
        if self._start is None or not math.isfinite(time):
            values = _floats(readings, self.KEYS)
            _check_finite(values, self.KEYS, command, time)  # raises for a non-finite time: only the first gets on
            self._initialise(*values, time)
            return
        try:
            answer = self._compiled_step(readings, command, time)
        except np.linalg.LinAlgError:
            answer = DIVERGED
        if answer == NOTHING:
            return
        if answer == REJECTED:
            _check_finite(_floats(readings, self.KEYS), self.KEYS, command, time)
        elif answer == DIVERGED:
            raise ValueError(f"aekf: the filter diverged at t = {time}: its state left the finite numbers within "
                             f"+-{READING_LIMIT:g}, after readings far outside its model in this or a recent sample "
                             f"(this one's gyro {np.asarray(readings['gyro']).tolist()}); reset() it before feeding "
                             f"it again")
        elif answer >= ISOLATED_LATER:
            self._latch.isolated = answer - ISOLATED_LATER     # the first isolation after the alarm is kept
        else:
            self._latch.trigger(time, None if answer == ALARM_WITHOUT_ROTOR else answer)

    def _compiled_step(self, readings: dict, command, time: float) -> int:
        """`_step` on the readings as they come where they are arrays numba takes (it converts them to float64 as
        `np.asarray` does, so the bits are those of `_floats`' arrays), else on `_floats`' arrays."""
        try:
            parts = self._gather(readings)
        except KeyError:
            _floats(readings, self.KEYS)                      # names the missing readings
            raise
        if ARRAY_TYPES.issuperset(map(type, parts)):
            try:
                return _step(self._state, self._constants, *parts, command, time)
            except TypingError:                               # an object or complex array: converted below
                pass
        return _step(self._state, self._constants, *_floats(readings, self.KEYS), command, time)

    def outputs(self) -> dict:
        published = self._state[PUBLISHED].copy()              # one copy, three views of it
        return {"loe": published[0:4], "loe_std": published[4:8], "innovation": published[8:9]}

    def status(self) -> dict:
        return {**self._latch.status(), "loe": self._state[LOE_OUT].tolist()}

    @property
    def x(self) -> np.ndarray:
        """The state estimate (a view of the packed state; assigning copies into it)."""
        return self._state[X]

    @x.setter
    def x(self, value) -> None:
        self._state[X] = value

    @property
    def P(self) -> np.ndarray:
        """Its covariance (a view of the packed state; assigning copies into it)."""
        return self._state[COVARIANCE].reshape(N_X, N_X)

    @P.setter
    def P(self, value) -> None:
        self._state[COVARIANCE] = np.asarray(value, dtype=float).ravel()

    @property
    def _Omega(self) -> np.ndarray:
        """The previous sample's rotor speeds (a view; assigning copies into it)."""
        return self._state[OMEGA_PREV]

    @_Omega.setter
    def _Omega(self, value) -> None:
        self._state[OMEGA_PREV] = value

    @property
    def z(self) -> np.ndarray:
        """The accumulated normalised innovation per channel (eq. 42; a view)."""
        return self._state[Z]

    @property
    def statistic(self) -> float:
        """The detection statistic max_j |z_j|."""
        return float(self._state[STATISTIC])

    # ------------------------------------------------------------------------------------ filter
    def _initialise(self, position, velocity, attitude, gyro, Omega, time: float) -> None:
        """x(0|0) from the first sample (002 assumes all states measured, eq. 28-36); no faults."""
        self._start = self._state[START] = float(time)
        self.x[POS], self.x[VEL] = position, velocity
        self.x[ETA] = euler_from_quat(attitude)
        self.x[OMEGA] = gyro
        self._state[OMEGA_PREV], self._state[HELD][:3], self._state[HELD][3:] = Omega, position, velocity
        _publish(self._state)

    def predict(self, Omega: np.ndarray) -> None:
        """Eq. (6)-(12) from the previous sample's rotor speeds `_Omega`, in place on x and P (`_predict`)."""
        _predict(self.x, self.P, self.Q, np.asarray(Omega, dtype=np.float64), self._Omega, self.dt, self._model)
        _publish(self._state)

    def correct(self, y: np.ndarray) -> None:
        """Eq. (13)-(18) for y = [eta, gyro] or [eta, gyro, p, v], in place on x and P (`_correct`)."""
        _correct(self.x, self.P, np.asarray(y, dtype=np.float64), self.R_full.diagonal().copy())
        _publish(self._state)

    def dynamics(self, x: np.ndarray, Omega: np.ndarray, Omega_dot: np.ndarray):
        """f(x, u) of eq. (43) and its Jacobian F (eq. 9), N_X x N_X (`_dynamics`, which computes its nonzero rows)."""
        f, F_moving = _dynamics(np.asarray(x, dtype=np.float64), np.asarray(Omega, dtype=np.float64),
                                np.asarray(Omega_dot, dtype=np.float64), self._model)
        F = np.zeros((N_X, N_X))
        F[:N_MOVING] = F_moving
        return f, F


def aekf_wrapper(env, **kwargs) -> DetectorWrapper:
    """`env` wrapped with an `AugmentedEkfDetector` built from its nominal parameters and agent rate."""
    params = vehicle_params(env, "aekf", QuadrotorParams)
    return DetectorWrapper(env, AugmentedEkfDetector.from_params(params, 1.0 / env.get_wrapper_attr("agent_hz"),
                                                                 **kwargs))


# ---------------------------------------------------------------------------------------- helpers
def _floats(readings: dict, keys) -> list:
    """The readings of `keys` as float arrays; a missing one raises ValueError."""
    try:
        return [np.asarray(readings[key], np.float64) for key in keys]
    except KeyError:
        missing = [key for key in keys if key not in readings]
        raise ValueError(f"readings: missing {missing} (the aekf detector needs {list(keys)})") from None


def _check_finite(values: list, keys, command: np.ndarray, time: float) -> None:
    """ValueError naming the first reading beyond READING_LIMIT (NaN, inf), else the command, as `_step` rejects
    them, else a non-finite time."""
    for key, value in zip(keys, values):
        check_reading("aekf", key, value)
    if beyond_limit(command):
        raise ValueError(f"aekf: the command {BEYOND_LIMIT}: {command.tolist()}")
    check_time(time, "aekf")


def _override(defaults: dict, overrides: dict | None, name: str) -> dict:
    """The noise levels `defaults` with `overrides` (a dict of some of their keys, each a number > 0)."""
    if overrides is not None and not isinstance(overrides, dict):
        raise ValueError(f"aekf.{name}: expected a dict of some of {sorted(defaults)}, got {overrides!r}")
    unknown = set(overrides or {}) - set(defaults)
    if unknown:
        raise ValueError(f"aekf.{name}: unknown key(s) {sorted(unknown)}; accepted: {sorted(defaults)}")
    return {**defaults, **{key: number(value, f"aekf.{name}.{key}", POSITIVE)
                           for key, value in (overrides or {}).items()}}


def _blocks(pos, vel, eta, omega, bias, loe, dist) -> np.ndarray:
    """A per-state vector from one value per block of x."""
    return np.repeat([pos, vel, eta, omega, bias, loe, dist], [3, 3, 3, 3, 3, 4, 2]).astype(float)


# ---------------------------------------------------------------------------------------- compiled
@njit(cache=True)
def _step(state, constants, position, velocity, attitude, gyro, Omega, command, time):  # pragma: no cover (compiled)
    """One sample after the first, in place on `state` (layout at STATE_SIZE): predict (eq. 6-12) from the previous
    sample's speeds, correct (eq. 13-18) with the measurement, accumulate the innovation (eq. 42), publish the
    outputs and detect (`_detect`); keeps this sample's speeds and held position and velocity. Returns
    `_detect`'s answer, REJECTED (nothing changed) if a reading or the command is beyond READING_LIMIT, or DIVERGED
    if x or the outputs left the finite numbers within READING_LIMIT (the state is then spent)."""
    position, velocity, attitude, gyro, Omega = (              # as `_floats` converts them
        np.asarray(position, np.float64), np.asarray(velocity, np.float64), np.asarray(attitude, np.float64),
        np.asarray(gyro, np.float64), np.asarray(Omega, np.float64))
    if not (within_limit(position) and within_limit(velocity) and within_limit(attitude) and within_limit(gyro)
            and within_limit(Omega) and within_limit(command)):
        return REJECTED
    x, P, held = state[X], state[COVARIANCE].reshape(N_X, N_X), state[HELD]
    _predict(x, P, constants[Q_MATRIX].reshape(N_X, N_X), Omega, state[OMEGA_PREV], constants[DT],
             constants[MODEL])
    fresh = _changed(position, held[:3]) or _changed(velocity, held[3:])   # sample-and-hold: a new sample?
    gamma, S = _correct(x, P, _measurement(position, velocity, attitude, gyro, fresh), constants[R_DIAGONAL])
    state[OMEGA_PREV] = Omega
    held[:3], held[3:] = position, velocity
    state[STATISTIC] = _accumulate(state[ACC], state[ACC_W], state[Z], gamma, S, constants[FORGET])
    _publish(state)
    if not (within_limit(x) and np.isfinite(state[PUBLISHED]).all()):   # readings its model cannot follow
        return DIVERGED
    return _detect(state, constants, time)


@njit(cache=True)
def _publish(state):  # pragma: no cover (compiled)
    """The outputs' block of the state: the LOE estimates and sqrt(P_ii) of their states (the statistic is
    written by `_step`)."""
    P = state[COVARIANCE].reshape(N_X, N_X)
    for i in range(4):
        state[LOE_OUT_0 + i] = state[LOE_0 + i]
        state[LOE_STD_0 + i] = np.sqrt(P[LOE_0 + i, LOE_0 + i])


@njit(cache=True)
def _detect(state, constants, time):  # pragma: no cover (compiled)
    """Eq. (41)-(42): alarm when a channel's windowed innovation (`_accumulate`) reaches T_0 sigma, from `warmup` s
    after the first sample. Returns the rotor a new alarm isolates (the largest LOE estimate, if above the
    isolation threshold), ALARM_WITHOUT_ROTOR, ISOLATED_LATER + i for the first isolation after such an alarm, or
    NOTHING."""
    if state[STATISTIC] >= constants[THRESHOLD] and time - state[START] >= constants[WARMUP]:
        if state[ALARMED] == 1.0:
            return NOTHING
        rotor = _isolate(state, constants)
        state[ALARMED], state[PENDING] = 1.0, 1.0 if rotor < 0 else 0.0
        return ALARM_WITHOUT_ROTOR if rotor < 0 else rotor
    if state[ALARMED] == 1.0 and state[PENDING] == 1.0:
        rotor = _isolate(state, constants)
        if rotor >= 0:
            state[PENDING] = 0.0
            return ISOLATED_LATER + rotor
    return NOTHING


@njit(cache=True)
def _isolate(state, constants):  # pragma: no cover (compiled)
    """The rotor of the largest LOE estimate (the first of equals) if above the isolation threshold, else -1."""
    loe = state[LOE]
    i = np.argmax(loe)
    return i if loe[i] > constants[ISOLATION_THRESHOLD] else -1


@njit(cache=True)
def _changed(new, old):  # pragma: no cover (compiled)
    """Whether the finite values `new` differ from `old` in their bits (0.0 and -0.0 differ)."""
    changed = False
    for i in range(new.size):
        changed |= new[i] != old[i] or math.copysign(1.0, new[i]) != math.copysign(1.0, old[i])
    return changed


@njit(cache=True)
def _measurement(position, velocity, attitude, gyro, fresh):  # pragma: no cover (compiled)
    """y of eq. (28)-(36) plus the gyro, ordered so that a step without fresh position/velocity is a prefix:
    [eta (3), gyro (3) | p (3), v (3)]."""
    y = np.empty(12 if fresh else 6)
    y[:3], y[3:6] = euler_from_quat(attitude), gyro
    if fresh:
        y[6:9], y[9:] = position, velocity
    return y


@njit(cache=True)
def _predict(x, P, Q, Omega, Omega_prev, dt, c):  # pragma: no cover (compiled)
    """Eq. (6)-(12), in place: x(k+1|k) by a second-order Taylor step, P(k+1|k) = Phi P Phi^T + Q_d.

    F's rows from N_MOVING on are zero (the random walks of eq. 43), so Phi = [T; 0 I] with T its first N_MOVING
    rows, and Phi P Phi^T = [T P T^T, (T P)_r; (T P)_r^T, P_rr] (r: the random walks' states): only T P and
    T P T^T are products, and only T P T^T is symmetrised, the other blocks being mirrored exactly."""
    f, F = _dynamics(x, Omega, (Omega - Omega_prev) / dt, c)   # F at x(k|k), eq. (9): its first N_MOVING rows
    Fdt = F * dt
    for i in range(N_MOVING):                                 # eq. (6): x + dt f + (dt / 2) F dt f
        Fdt_f = 0.0
        for k in range(N_X):
            Fdt_f += Fdt[i, k] * f[k]
        x[i] = x[i] + dt * f[i] + (0.5 * dt) * Fdt_f
    x[PSI] = _wrap(x[PSI])
    T = _sparse_times(Fdt, Fdt)                               # eq. (8), to second order: I + F dt + (F dt)^2 / 2
    for i in range(N_MOVING):
        for j in range(N_X):
            T[i, j] = (i == j) + Fdt[i, j] + 0.5 * T[i, j]
    TP = np.dot(T, P)
    TPT = np.dot(TP, T.T)
    n = N_MOVING
    for i in range(N_X):                                      # eq. (7)
        for j in range(i + 1):
            if i < n:
                value = 0.5 * (TPT[i, j] + TPT[j, i])
            elif j < n:
                value = TP[j, i]
            else:
                value = P[i, j]
            P[i, j] = value + Q[i, j]
            P[j, i] = value + Q[j, i]


@njit(cache=True)
def _sparse_times(A, B):  # pragma: no cover (compiled)
    """A B for an A (N_MOVING x N_X) with many zeros and B's rows from N_MOVING on zero: sums of B's rows over
    A's nonzero entries."""
    out = np.zeros(A.shape)
    for i in range(A.shape[0]):
        for k in range(N_MOVING):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[k, j]
    return out


@njit(cache=True)
def _correct(x, P, y, r):  # pragma: no cover (compiled)
    """Eq. (13)-(18) for y = H x + v (H constant, so eq. 15 is exact; R = diag(r)), in place; returns the
    innovation gamma (eq. 17) and its covariance S.

    H selects states (and, for the gyro, adds the rate and bias states: MEASURED), so H x, P H^T, H P H^T and K H
    pick and add entries instead of dense products. The gain solves S K^T = H P (Cholesky, `_gain`). The Joseph
    form of eq. (18) is expanded with H's structure: with A = I - K H, A P = P - K (H P), and
    A P A^T + K R K^T = A P + (K R - A P H^T) K^T."""
    m = y.size
    gamma = np.empty(m)
    for j in range(m):
        gamma[j] = y[j] - _measured(x, j)                     # eq. (17)
    gamma[2] = _wrap(gamma[2])                                # yaw innovation across +-pi
    HP = np.empty((m, N_X))                                   # H P = (P H^T)^T, P symmetric
    for j in range(m):
        for k in range(N_X):
            HP[j, k] = _measured(P[:, k], j)
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            S[i, j] = _measured(HP[j], i) + r[i] * (i == j)    # eq. (14)
    Kt = _gain(S, HP)                                         # eq. (13): K^T = S^-1 H P
    AP = P - np.dot(np.ascontiguousarray(Kt.T), HP)
    C = np.empty((N_X, m))                                    # K R - A P H^T
    for i in range(N_X):
        for j in range(m):
            C[i, j] = Kt[j, i] * r[j] - _measured(AP[i], j)
    P_new = AP + np.dot(C, Kt)                                # eq. (18)
    for j in range(m):                                        # eq. (16)
        for i in range(N_X):
            x[i] += gamma[j] * Kt[j, i]
    for i in range(N_X):
        for j in range(i + 1):
            P[i, j] = P[j, i] = 0.5 * (P_new[i, j] + P_new[j, i])
    x[PSI] = _wrap(x[PSI])
    return gamma, S


@njit(cache=True)
def _gain(S, B):  # pragma: no cover (compiled)
    """S^-1 B for the innovation covariance S (symmetric, positive definite: H P H^T + R with R > 0), by Cholesky
    S = L L^T and two triangular solves, row operations on B's rows. Falls back to LU if rounding has made S
    indefinite."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        for i in range(j, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return np.ascontiguousarray(np.linalg.solve(S, B))
                L[j, j] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    X = B.copy()
    for i in range(m):                                        # L Z = B
        for j in range(i):
            _subtract_row(X, i, j, L[i, j])
        _scale_row(X, i, 1.0 / L[i, i])
    for i in range(m - 1, -1, -1):                            # L^T X = Z
        for j in range(i + 1, m):
            _subtract_row(X, i, j, L[j, i])
        _scale_row(X, i, 1.0 / L[i, i])
    return X


@njit(cache=True)
def _subtract_row(X, i, j, a):  # pragma: no cover (compiled)
    """X[i] -= a X[j], in place, by index (a row view per call costs more than the row's arithmetic)."""
    for c in range(X.shape[1]):
        X[i, c] -= a * X[j, c]


@njit(cache=True)
def _scale_row(X, i, d):  # pragma: no cover (compiled)
    for c in range(X.shape[1]):
        X[i, c] *= d


@njit(cache=True)
def _measured(v, j):  # pragma: no cover (compiled)
    """(H v)_j for H of y's row j: the state it reads, plus the bias for the gyro rows."""
    value = v[MEASURED[j]]
    if 3 <= j < 6:
        value += v[BIAS_0 + j - 3]
    return value


@njit(cache=True)
def _accumulate(acc, acc_w, z, gamma, S, forget):  # pragma: no cover (compiled)
    """Eq. (42) with an accumulation window, in place; returns the statistic max_j |z_j|.

    Each channel's normalised innovation gamma_j / sqrt(S_jj) is summed with exponential forgetting (the window
    decays in time, not in samples); divided by the root of the summed squared weights it is N(0, 1) while the
    model fits, and a fault that the LOE random walk has not yet absorbed drives it away from zero. Channels
    not measured now (position, velocity: 100 Hz) only decay."""
    decay = forget * forget
    for j in range(acc.size):
        acc[j] *= forget
        acc_w[j] *= decay
        if j < gamma.size:
            acc[j] += gamma[j] / math.sqrt(S[j, j])
            acc_w[j] += 1.0
        z[j] = acc[j] / math.sqrt(acc_w[j])
    return np.abs(z).max()


@njit(cache=True)
def _dynamics(x, Omega, Omega_dot, c):  # pragma: no cover (compiled)
    """f(x, u) of eq. (43) and the first N_MOVING rows of its Jacobian F (eq. 9); inputs the rotor speeds Omega and
    their rate. The biases, the LOE and d are random walks (eq. 43): their rows of F are zero."""
    f, F = np.zeros(N_X), np.zeros((N_MOVING, N_X))
    k = 1.0 - x[LOE]                                          # effectiveness: eq. (40)'s (1 - l_i) factor
    phi, theta, psi, p, q, r = x[6], x[7], x[8], x[9], x[10], x[11]
    for i in range(3):
        f[i], F[i, 3 + i] = x[3 + i], 1.0
    _translation(f, F, x[VEL], phi, theta, psi, k, Omega, c)
    f[3] += x[19]
    f[4] += x[20]
    F[3, 19] = F[4, 20] = 1.0
    _euler_kinematics(f, F, phi, theta, p, q, r)
    _rotational(f, F, p, q, r, k, Omega, Omega_dot, c)
    return f, F


@njit(cache=True)
def _translation(f, F, v, phi, theta, psi, k, Omega, c):  # pragma: no cover (compiled)
    """Eq. (22)-(24) in NED: m v_dot = m g e3 + R F_b; F_b = thrust and linear body and rotor drag. Writes v_dot
    and its derivatives by v, eta and l into f and F."""
    R = rotation_from_euler(phi, theta, psi)
    mass, c_T, k_d = c[MASS], c[C_T], c[K_D]
    d = c[BODY_DRAG]
    rotor_drag, thrust = 0.0, 0.0
    for j in range(4):
        rotor_drag += k[j] * Omega[j]
        thrust += k[j] * (Omega[j] * Omega[j])
    drag = np.array((-(d[0] + k_d * rotor_drag), -(d[1] + k_d * rotor_drag), -d[2]))
    a_b = np.empty(3)                                         # R^T v, body airspeed (no wind is known)
    for j in range(3):
        a_b[j] = R[0, j] * v[0] + R[1, j] * v[1] + R[2, j] * v[2]
    F_b = drag * a_b
    F_b[2] -= c_T * thrust
    RF = np.empty(3)
    RCRt = np.empty((3, 3))                                   # d(R F_b)/dv = R diag(drag) R^T
    for i in range(3):
        RF[i] = R[i, 0] * F_b[0] + R[i, 1] * F_b[1] + R[i, 2] * F_b[2]
        f[3 + i] = RF[i] / mass
        for j in range(3):
            RCRt[i, j] = R[i, 0] * drag[0] * R[j, 0] + R[i, 1] * drag[1] * R[j, 1] + R[i, 2] * drag[2] * R[j, 2]
            F[3 + i, 3 + j] = RCRt[i, j] / mass
        for j in range(4):                                    # d(R F_b)/dl_j = -R dF_b/dk_j
            F[3 + i, 15 + j] = (R[i, 0] * k_d * a_b[0] * Omega[j] + R[i, 1] * k_d * a_b[1] * Omega[j]
                                + R[i, 2] * c_T * Omega[j] * Omega[j]) / mass
    f[5] += GRAVITY
    # d(R u)/d eta_j = n_j x (R u) with n_phi = R e1, n_theta = Rz e2, n_psi = e3 (ZYX), so the eta
    # columns are n_j x RF + RCR^T (v x n_j) = (RCR^T [v]x - [RF]x) n_j.
    G = -skew_matrix(RF)
    V = skew_matrix(v)
    for i in range(3):
        for j in range(3):
            G[i, j] += RCRt[i, 0] * V[0, j] + RCRt[i, 1] * V[1, j] + RCRt[i, 2] * V[2, j]
    N = ((R[0, 0], -math.sin(psi), 0.0), (R[1, 0], math.cos(psi), 0.0), (R[2, 0], 0.0, 1.0))
    for i in range(3):
        for j in range(3):
            F[3 + i, 6 + j] = (G[i, 0] * N[0][j] + G[i, 1] * N[1][j] + G[i, 2] * N[2][j]) / mass


@njit(cache=True)
def _rotational(f, F, p, q, r, k, Omega, Omega_dot, c):  # pragma: no cover (compiled)
    """Eq. (25)-(27) as Euler's equation J omega_dot = M - omega x J omega; writes omega_dot and its derivatives by
    omega and l into f and F.

    M: rotor thrust and drag moments A (k Omega^2), propeller gyroscopic moment -omega x (0, 0, h),
    the reaction to the propellers' spin-up, linear damping: the simulator's terms (rotors.py).
    """
    J, I_p, s = c[INERTIA], c[I_P], c[SIGNS]
    Jx, Jy, Jz = J
    dx, dy, dz = c[ROTATIONAL_DRAG]
    A, A_over_J = c[MOMENTS], c[MOMENTS_OVER_J]
    h, spin_up = 0.0, 0.0
    M = np.zeros(3)
    for j in range(4):
        h -= I_p * s[j] * Omega[j]                            # propellers' angular momentum along body z
        spin_up += I_p * s[j] * Omega_dot[j]
        Omega2 = Omega[j] * Omega[j]
        for i in range(3):
            M[i] += A[4 * i + j] * (k[j] * Omega2)
            F[9 + i, 15 + j] = A_over_J[4 * i + j] * Omega2   # dM/dl_j = -A_j Omega_j^2
    M[0] += -dx * p - q * h - q * r * (Jz - Jy)
    M[1] += -dy * q + p * h - p * r * (Jx - Jz)
    M[2] += -dz * r + spin_up - p * q * (Jy - Jx)
    for i in range(3):
        f[9 + i] = M[i] / J[i]
    F[9, 9], F[9, 10], F[9, 11] = -dx / Jx, (-h - r * (Jz - Jy)) / Jx, -q * (Jz - Jy) / Jx
    F[10, 9], F[10, 10], F[10, 11] = (h - r * (Jx - Jz)) / Jy, -dy / Jy, -p * (Jx - Jz) / Jy
    F[11, 9], F[11, 10], F[11, 11] = -q * (Jy - Jx) / Jz, -p * (Jy - Jx) / Jz, -dz / Jz


@njit(cache=True)
def _euler_kinematics(f, F, phi, theta, p, q, r):  # pragma: no cover (compiled)
    """eta_dot = W omega (ZYX; singular at theta = +-90 deg); writes it and its derivatives by eta and omega (W)
    into f and F."""
    cf, sf, ct, tt = math.cos(phi), math.sin(phi), math.cos(theta), math.tan(theta)
    a, b = q * sf + r * cf, q * cf - r * sf
    f[6], f[7], f[8] = p + a * tt, b, a / ct
    F[6, 6], F[6, 7] = b * tt, a / (ct * ct)
    F[7, 6] = -a
    F[8, 6], F[8, 7] = b / ct, a * tt / ct
    F[6, 9], F[6, 10], F[6, 11] = 1.0, sf * tt, cf * tt
    F[7, 10], F[7, 11] = cf, -sf
    F[8, 10], F[8, 11] = sf / ct, cf / ct


@njit(cache=True)
def _wrap(angle):  # pragma: no cover (compiled)
    return (angle + math.pi) % (2 * math.pi) - math.pi
