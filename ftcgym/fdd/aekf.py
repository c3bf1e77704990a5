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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.constants import GRAVITY
from ..models.geometry import euler_from_quat, rotation_from_euler, skew_matrix
from ..models.quadrotor import YAW_SIGNS, rotor_wrench_matrix
from ..settings import updated
from . import kalman
from .base import AlarmLatch
from .wrapper import DetectorWrapper

N_X = 21
POS, VEL, ETA, OMEGA, BIAS, LOE, DIST = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                                         slice(15, 19), slice(19, 21))
PSI = 8


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

    model_error: float = 0.0           # the detector's c_T is (1 + model_error) times the nominal one
    loe_walk: float = 0.05             # 1/sqrt(s), sigma of the LOE random walk w' (eq. 43)
    window: float = 0.5                # s, time constant of the innovation accumulation window (eq. 42)
    threshold: float = 3.0             # T_0 of eq. (42), standard deviations of the accumulated innovation
    isolation_threshold: float = 0.1   # LOE estimate above which a rotor may be isolated
    warmup: float = 1.0                # s after the first sample without alarms
    q_sigma: dict | None = None        # overrides of Q_SIGMA entries
    r_sigma: dict | None = None        # overrides of R_SIGMA entries

class AugmentedEkfDetector:
    """002's augmented EKF (see the module docstring), fed one sample at a time; plain numpy.

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
        self._I = np.eye(N_X)
        self.reset()

    @classmethod
    def from_params(cls, params, dt: float, **kwargs) -> AugmentedEkfDetector:
        """A detector for a `QuadrotorParams`-like object (attributes read by name)."""
        return cls(QuadrotorModel.from_params(params), dt, **kwargs)

    def _use_model(self, m: QuadrotorModel, model_error: float) -> None:
        """Constants of f(x, u), with c_T scaled by (1 + model_error)."""
        r = np.asarray(m.rotor_positions, dtype=float)
        self.c_T = m.thrust_coefficient * (1.0 + model_error)
        self.J = np.asarray(m.inertia, dtype=float)
        self.s = np.asarray(m.yaw_signs, dtype=float)
        # Moment per unit effective Omega^2 (000 eq. 4; yaw row 004 eq. 7): columns are rotors.
        self.A = rotor_wrench_matrix(r, self.c_T, m.torque_coefficient, self.s)[1:]
        self.I_p, self.k_d = m.propeller_inertia, m.rotor_drag_coefficient
        self.mass, self.d_body = m.mass, tuple(m.body_drag)
        self.J_tuple, self.d_rot_tuple = tuple(m.inertia), tuple(m.rotational_drag)
        self._A_over_J = -self.A / self.J[:, None]
        self._gravity = np.array((0.0, 0.0, GRAVITY))
        self._zeros9 = np.zeros(9)
        self._F0 = np.zeros((N_X, N_X))
        self._F0[POS, VEL] = np.eye(3)
        self._F0[VEL, DIST] = np.eye(3)[:, :2]

    # ------------------------------------------------------------------------------------ protocol
    def reset(self) -> None:
        self.x = np.zeros(N_X)
        self.P = self._P0.copy()
        self._latch = AlarmLatch()
        self._start = None
        self._Omega = None
        self._held = None
        self._acc = np.zeros(12)       # accumulated normalised innovation per channel (eq. 42)
        self._acc_w = np.ones(12)      # sum of squared window weights: var of _acc if the model fits
        self.z = np.zeros(12)
        self.statistic = 0.0

    def update(self, readings: dict, time: float, command: np.ndarray | None = None) -> None:
        """One sample: predict from the previous one (eq. 6-12), correct with this one (eq. 13-18)."""
        z = _finite(readings, self.KEYS, command)
        if not math.isfinite(time):
            raise ValueError(f"time: must be finite, got {time!r}")
        Omega = z["rotor_speed"]
        held = z["position"].tobytes() + z["velocity"].tobytes()
        if self._start is None:
            self._initialise(z, time)
        else:
            self.predict(Omega)
            fresh = held != self._held                       # sample-and-hold: a new sample, or the old one
            self.correct(_measurement(z, fresh))
            self._detect(time)
        self._Omega, self._held = Omega, held

    def outputs(self) -> dict:
        return {"loe": self.x[LOE].copy(), "loe_std": np.sqrt(np.diag(self.P)[LOE]),
                "innovation": np.array([self.statistic])}

    def status(self) -> dict:
        return {**self._latch.status(), "loe": self.x[LOE].tolist()}

    # ------------------------------------------------------------------------------------ filter
    def _initialise(self, z: dict, time: float) -> None:
        """x(0|0) from the first sample (002 assumes all states measured, eq. 28-36); no faults."""
        self._start = float(time)
        self.x[POS], self.x[VEL] = z["position"], z["velocity"]
        self.x[ETA] = euler_from_quat(z["attitude"])
        self.x[OMEGA] = z["gyro"]

    def predict(self, Omega: np.ndarray) -> None:
        """Eq. (6)-(12): x(k+1|k) by a second-order Taylor step, P(k+1|k) = Phi P Phi^T + Q_d."""
        dt = self.dt
        f, F = self.dynamics(self.x, Omega, (Omega - self._Omega) / dt)   # F at x(k|k), eq. (9)
        Fdt = F * dt
        self.x = self.x + dt * f + (0.5 * dt) * Fdt.dot(f)   # eq. (6)
        self.x[PSI] = _wrap(self.x[PSI])
        Phi = self._I + Fdt + 0.5 * Fdt.dot(Fdt)             # eq. (8), to second order
        self.P = kalman.predict(self.P, self.Q, Phi)         # eq. (7)

    def correct(self, y: np.ndarray) -> None:
        """Eq. (13)-(18) for y = H x + v: [eta, gyro] or [eta, gyro, p, v] (H constant, so eq. 15 is exact)."""
        m = y.size
        H, R = self.H_full[:m], self.R_full[:m, :m]
        gamma = y - H.dot(self.x)                            # eq. (17)
        gamma[2] = _wrap(gamma[2])                           # yaw innovation across +-pi
        # eq. (13)-(16), and eq. (18): the Joseph form
        self.x, self.P, S, _ = kalman.update(self.x, self.P, gamma, H, R)
        self.x[PSI] = _wrap(self.x[PSI])
        self.gamma, self.S = gamma, S

    def dynamics(self, x: np.ndarray, Omega: np.ndarray, Omega_dot: np.ndarray):
        """f(x, u) of eq. (43) and its Jacobian F (eq. 9); inputs the rotor speeds Omega and their rate."""
        Omega2 = Omega * Omega
        k = 1.0 - x[LOE]                                      # effectiveness: eq. (40)'s (1 - l_i) factor
        phi, theta, psi, p, q, r = x[6:12].tolist()
        v_dot, dv_dv, dv_deta, dv_dl = self._translation(x[VEL], phi, theta, psi, k, Omega, Omega2)
        eta_dot, deta_deta, W = _euler_kinematics(phi, theta, p, q, r)
        w_dot, dw_dw = self._rotational(p, q, r, k * Omega2, Omega, Omega_dot)
        v_dot[:2] += x[DIST]
        f = np.concatenate((x[VEL], v_dot, eta_dot, w_dot, self._zeros9))  # biases, LOE: eq. (43) random walks
        F = self._F0.copy()                                   # dp_dot/dv = I
        F[VEL, VEL], F[VEL, ETA], F[VEL, LOE] = dv_dv, dv_deta, dv_dl
        F[ETA, ETA], F[ETA, OMEGA] = deta_deta, W
        F[OMEGA, OMEGA] = dw_dw
        F[OMEGA, LOE] = self._A_over_J * Omega2              # dM/dl_i = -A_i Omega_i^2
        return f, F

    def _translation(self, v, phi, theta, psi, k, Omega, Omega2):
        """Eq. (22)-(24) in NED: m v_dot = m g e3 + R F_b; F_b = thrust and linear body and rotor drag.

        Plain floats and whole blocks: numpy's per-call cost, not arithmetic, dominates at this size.
        """
        mass = self.mass
        R = rotation_from_euler(phi, theta, psi)
        a_b = v.dot(R)                                        # R^T v, body airspeed (no wind is known)
        rotor_drag = self.k_d * float(k.dot(Omega))
        c = -np.array((self.d_body[0] + rotor_drag, self.d_body[1] + rotor_drag, self.d_body[2]))
        F_b = c * a_b
        F_b[2] -= self.c_T * float(k.dot(Omega2))
        RF = R.dot(F_b)
        RCRt = (R * c).dot(R.T)
        # d(R u)/d eta_j = n_j x (R u) with n_phi = R e1, n_theta = Rz e2, n_psi = e3 (ZYX), so the eta
        # columns are n_j x RF + RCR^T (v x n_j) = (RCR^T [v]x - [RF]x) n_j.
        N = np.array(((R[0, 0], -math.sin(psi), 0.0), (R[1, 0], math.cos(psi), 0.0), (R[2, 0], 0.0, 1.0)))
        dv_deta = (RCRt.dot(skew_matrix(v)) - skew_matrix(RF)).dot(N) / mass
        dFb_dl = np.array((self.k_d * a_b[0] * Omega, self.k_d * a_b[1] * Omega, self.c_T * Omega2))
        return RF / mass + self._gravity, RCRt / mass, dv_deta, R.dot(dFb_dl) / mass

    def _rotational(self, p, q, r, kOmega2, Omega, Omega_dot):
        """Eq. (25)-(27) as Euler's equation J omega_dot = M - omega x J omega, and d(omega_dot)/d omega.

        M: rotor thrust and drag moments A (k Omega^2), propeller gyroscopic moment -omega x (0, 0, h),
        the reaction to the propellers' spin-up, linear damping: the simulator's terms (rotors.py).
        """
        Jx, Jy, Jz = self.J_tuple
        dx, dy, dz = self.d_rot_tuple
        h = -self.I_p * float(self.s.dot(Omega))              # propellers' angular momentum along body z
        M = self.A.dot(kOmega2)
        M[0] += -dx * p - q * h - q * r * (Jz - Jy)
        M[1] += -dy * q + p * h - p * r * (Jx - Jz)
        M[2] += -dz * r + self.I_p * float(self.s.dot(Omega_dot)) - p * q * (Jy - Jx)
        dw_dw = np.array(((-dx / Jx, (-h - r * (Jz - Jy)) / Jx, -q * (Jz - Jy) / Jx),
                          ((h - r * (Jx - Jz)) / Jy, -dy / Jy, -p * (Jx - Jz) / Jy),
                          (-q * (Jy - Jx) / Jz, -p * (Jy - Jx) / Jz, -dz / Jz)))
        return M / self.J, dw_dw

    # ------------------------------------------------------------------------------------ detection
    def _detect(self, time: float) -> None:
        """Eq. (41)-(42) with an accumulation window: alarm when a channel's windowed innovation >= T_0 sigma.

        Each channel's normalised innovation gamma_j / sqrt(S_jj) is summed with exponential forgetting;
        divided by the root of the summed squared weights it is N(0, 1) while the model fits, and a fault
        that the LOE random walk has not yet absorbed drives it away from zero.
        """
        m = self.gamma.size                                    # channels measured now (position: 100 Hz)
        lam = self._forget                                     # the window decays in time, not in samples
        self._acc *= lam
        self._acc[:m] += self.gamma / np.sqrt(self.S.diagonal())
        self._acc_w *= lam * lam
        self._acc_w[:m] += 1.0
        self.z = self._acc / np.sqrt(self._acc_w)
        self.statistic = float(np.abs(self.z).max())
        if self.statistic >= self.threshold and time - self._start >= self.warmup:
            self._latch.trigger(time, self._isolate())
        elif self._latch.alarm and self._latch.isolated is None:
            self._latch.isolated = self._isolate()             # the first isolation after the alarm is kept

    def _isolate(self) -> int | None:
        loe = self.x[LOE]
        i = int(np.argmax(loe))
        return i if loe[i] > self.isolation_threshold else None


def aekf_wrapper(env, **kwargs) -> DetectorWrapper:
    """`env` wrapped with an `AugmentedEkfDetector` built from its nominal parameters and agent rate."""
    base = env.unwrapped
    return DetectorWrapper(env, AugmentedEkfDetector.from_params(base.params, 1.0 / base.agent_hz, **kwargs))


# ---------------------------------------------------------------------------------------- helpers
def _finite(readings: dict, keys, command) -> dict:
    """The readings as float arrays; a missing or non-finite one raises ValueError naming its key."""
    missing = [key for key in keys if key not in readings]
    if missing:
        raise ValueError(f"readings: missing {missing} (the aekf detector needs {list(keys)})")
    z = {key: np.asarray(readings[key], dtype=np.float64) for key in keys}
    # one check (a sum is finite only if every term is); the key is looked for only on failure
    if not math.isfinite(sum(np.concatenate(list(z.values())).tolist())):
        bad = next((key for key in keys if not np.isfinite(z[key]).all()), None)
        if bad is not None:                                   # else only the sum overflowed
            raise ValueError(f"readings[{bad!r}]: must be finite (no NaN or inf), got {z[bad].tolist()}")
    if (command is not None and not math.isfinite(sum(np.asarray(command, dtype=np.float64).ravel().tolist()))
            and not np.isfinite(np.asarray(command, dtype=np.float64)).all()):
        raise ValueError(f"command: must be finite (no NaN or inf), got {np.asarray(command).tolist()}")
    return z


def _override(defaults: dict, overrides: dict | None, name: str) -> dict:
    unknown = set(overrides or {}) - set(defaults)
    if unknown:
        raise ValueError(f"{name}: unknown key(s) {sorted(unknown)}; accepted: {sorted(defaults)}")
    return {**defaults, **(overrides or {})}


def _blocks(pos, vel, eta, omega, bias, loe, dist) -> np.ndarray:
    """A per-state vector from one value per block of x."""
    return np.repeat([pos, vel, eta, omega, bias, loe, dist], [3, 3, 3, 3, 3, 4, 2]).astype(float)


def _measurement(z: dict, fresh: bool) -> np.ndarray:
    parts = [euler_from_quat(z["attitude"]), z["gyro"]]
    if fresh:
        parts += [z["position"], z["velocity"]]
    return np.concatenate(parts)




def _euler_kinematics(phi: float, theta: float, p: float, q: float, r: float):
    """eta_dot = W omega, d(eta_dot)/d eta and W (ZYX; singular at theta = +-90 deg)."""
    cf, sf, ct, tt = math.cos(phi), math.sin(phi), math.cos(theta), math.tan(theta)
    a, b = q * sf + r * cf, q * cf - r * sf
    eta_dot = np.array([p + a * tt, b, a / ct])
    d_eta = np.array([[b * tt, a / (ct * ct), 0.0],
                      [-a, 0.0, 0.0],
                      [b / ct, a * tt / ct, 0.0]])
    W = np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])
    return eta_dot, d_eta, W



def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi
