"""`AugmentedEkfDetector` ("aekf"): actuator loss-of-effectiveness estimation with an augmented EKF.

Lu, van Kampen, Yu, *Actuator Fault Detection and Diagnosis for Quadrotors* (seeds/002): the rigid-body
model (eq. 19-27) is augmented with the loss of effectiveness l_i of each rotor as a random-walk state
(eq. 43-44), estimated by an EKF (eq. 6-18, Joseph-form covariance eq. 18) from position, velocity and
attitude measurements (eq. 28-36); a threshold on the accumulated innovation raises the alarm (eq. 41-42).

Adaptations of the paper to ftcgym (each also noted where it happens):
- Frames: NED / FRD (DESIGN.md), so eq. (24) reads m dv_z/dt = -U cos(phi) cos(theta) + m g; the full
  rotation R(phi, theta, psi) (ZYX) replaces eq. (22)-(24)'s expanded products.
- Attitude: ZYX Euler angles eta = (phi, theta, psi), as 002 (eq. 34-36 then stay linear, H is a selection
  matrix and the Joseph update is exact). A quadrotor that does not crash stays far from the pitch
  singularity (the env ends a flight beyond 60 deg of tilt); the yaw innovation is wrapped to (-pi, pi].
- Rotational dynamics: 002 eq. (25)-(27) (J eta_ddot = tau) become Euler's equation in body rates
  J omega_dot = M - omega x J omega, with the rotor moments of 000 eq. (4) (X frame), the drag-torque yaw
  moment (004 eq. 7 signs), propeller gyroscopic and spin-up torques and rotational damping.
- Inputs: 002's inputs are PWM commands through a first-order actuator (eq. 37-40). Our ESCs report the
  rotor speeds Omega_i (obs["rotor_speed"]), i.e. the output of that actuator lag, so they are the inputs:
  thrust T_i = c_T k_i Omega_i^2 and drag torque c_Q k_i Omega_i^2 with effectiveness k_i = 1 - l_i, the
  product eq. (40) puts on the actuator input. Over one step the mean of the previous and current Omega_i^2
  is used; the spin-up torque uses their difference (the momentum change, so ESC noise does not accumulate).
- Gyro: a measurement of the body rates plus a constant bias (3 random-walk states), not an input. The
  rotor moments act on the body rates, so the rates must be states for the individual l_i to be
  observable (as inputs, the gyro would leave only the collective thrust to identify one of four LOEs).
- Measurements: 002 measures p, v, eta (eq. 28-36); we add the gyro. Position and velocity are
  sample-and-hold (100 Hz): they update the filter only when their value changes, so one noisy sample is
  not counted five times.
- Discretisation: Phi = I + F dt + (F dt)^2 / 2 (eq. 8 to second order), Q_d = Q dt (eq. 10, first term),
  state propagation by the second-order Taylor step of eq. (6).
- Detection: eq. (41) as printed, H x - H x_hat, uses the unknown true state; we use the innovation
  gamma = y - H x_hat (eq. 17), normalised per channel by sqrt(S_jj). Eq. (42)'s accumulation window is an
  exponential window per channel; the statistic is the mean over channels of the squared, normalised
  accumulated innovation (chi-square / m, about 1 when the model fits). Isolation: the rotor whose LOE
  estimate is largest above `isolation_threshold`.
- LOE estimates are not clipped to [0, 1]: clipping would bias them (002 values their unbiasedness).

The state x = [p (3, NED m), v (3, NED m/s), eta (3, rad), omega (3, FRD rad/s), b_g (3, rad/s), l (4)].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import AlarmLatch
from .wrapper import DetectorWrapper

GRAVITY = 9.81
N_X = 19
POS, VEL, ETA, OMEGA, BIAS, LOE = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                                   slice(15, 19))
DEFAULT_YAW_SIGNS = (1.0, -1.0, 1.0, -1.0)  # DESIGN.md / 004 eq. (7)


@dataclass(frozen=True)
class QuadrotorModel:
    """The detector's knowledge of the vehicle: nominal numbers only (SI, body FRD, rotors r1..r4)."""

    mass: float
    inertia: tuple                      # (Ixx, Iyy, Izz)
    rotor_positions: tuple              # 4 x (x, y, z) in body FRD
    thrust_coefficient: float           # c_T: T_i = c_T k_i Omega_i^2
    torque_coefficient: float           # c_Q: drag torque c_Q k_i Omega_i^2
    yaw_signs: tuple = DEFAULT_YAW_SIGNS
    propeller_inertia: float = 0.0      # gyroscopic and spin-up torques
    rotor_drag_coefficient: float = 0.0  # in-plane rotor drag k_d k_i Omega_i v
    body_drag: tuple = (0.0, 0.0, 0.0)   # N s/m, linear, FRD
    rotational_drag: tuple = (0.0, 0.0, 0.0)  # N m s, linear

    @classmethod
    def from_params(cls, params) -> "QuadrotorModel":
        """Read a `QuadrotorParams`-like object by attribute name (no simulator import)."""
        return cls(
            mass=float(params.mass), inertia=tuple(map(float, params.inertia)),
            rotor_positions=tuple(map(tuple, np.asarray(params.rotor_positions, dtype=float))),
            thrust_coefficient=float(params.thrust_coefficient),
            torque_coefficient=float(params.torque_coefficient),
            yaw_signs=tuple(getattr(params, "yaw_signs", DEFAULT_YAW_SIGNS)),
            propeller_inertia=float(getattr(params, "propeller_inertia", 0.0)),
            rotor_drag_coefficient=float(getattr(params, "rotor_drag_coefficient", 0.0)),
            body_drag=tuple(map(float, getattr(params, "body_drag", (0.0, 0.0, 0.0)))),
            rotational_drag=tuple(map(float, getattr(params, "rotational_drag", (0.0, 0.0, 0.0)))))


class AugmentedEkfDetector:
    """002's augmented EKF: 15 rigid-body/gyro-bias states plus 4 random-walk LOE states; see the module doc.

    dt:                  the update interval (s) the model is discretised at (the env's 1 / agent_hz)
    model_error:         the detector's c_T is (1 + model_error) times the nominal one (robustness studies)
    loe_walk:            sigma of the LOE random walk w' of eq. (43), 1/sqrt(s): larger tracks faster, noisier
    window:              time constant (s) of the innovation accumulation window (eq. 42)
    threshold:           T_0 of eq. (42) on the accumulated statistic (about 1 when fault-free)
    isolation_threshold: LOE estimate above which a rotor may be isolated
    warmup:              s after the first sample during which no alarm is raised (the filter converges)
    """

    name = "aekf"
    output_fields = {
        "loe": (-np.inf, np.inf, (4,)),
        "loe_std": (0.0, np.inf, (4,)),
        "innovation": (0.0, np.inf, (1,)),
    }
    # Continuous process noise densities (Q, per second) and measurement noise sigmas (R): tuned on the
    # env's default sensors (sensors.py) with seeds 1-3, see tests/test_aekf.py.
    Q_SIGMA = {"pos": 1e-3, "vel": 0.03, "eta": 1e-3, "omega": 1.5, "bias": 1e-3}
    R_SIGMA = {"position": 0.01, "velocity": 0.02, "attitude": np.deg2rad(0.2), "gyro": 0.05}
    P0_SIGMA = {"pos": 0.01, "vel": 0.02, "eta": np.deg2rad(0.5), "omega": 0.05, "bias": 0.01, "loe": 0.05}
    KEYS = ("position", "velocity", "attitude", "gyro", "rotor_speed")

    def __init__(self, model: QuadrotorModel, dt: float, *, model_error: float = 0.0, loe_walk: float = 0.05,
                 window: float = 0.5, threshold: float = 4.0, isolation_threshold: float = 0.1,
                 warmup: float = 1.0):
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.model, self.dt = model, float(dt)
        self.threshold, self.isolation_threshold, self.warmup = threshold, isolation_threshold, warmup
        self._forget = math.exp(-self.dt / window)
        self._set_model(model, model_error)
        q = self.Q_SIGMA
        q_c = np.concatenate([np.full(3, q["pos"]), np.full(3, q["vel"]), np.full(3, q["eta"]),
                              np.full(3, q["omega"]), np.full(3, q["bias"]), np.full(4, loe_walk)]) ** 2
        self.Q = np.diag(q_c * self.dt)  # eq. (10), first term: Q_d = G Q G^T dt with G = I
        p0 = self.P0_SIGMA
        self._P0 = np.diag(np.concatenate([np.full(3, p0["pos"]), np.full(3, p0["vel"]), np.full(3, p0["eta"]),
                                           np.full(3, p0["omega"]), np.full(3, p0["bias"]),
                                           np.full(4, p0["loe"])]) ** 2)
        r = self.R_SIGMA
        r_all = np.concatenate([np.full(3, r["attitude"]), np.full(3, r["gyro"]),
                                np.full(3, r["position"]), np.full(3, r["velocity"])]) ** 2
        # Eq. (28)-(36) plus the gyro: attitude and gyro every step; position and velocity when fresh.
        self.H_full = np.zeros((12, N_X))
        self.H_full[0:3, ETA] = np.eye(3)
        self.H_full[3:6, OMEGA] = np.eye(3)
        self.H_full[3:6, BIAS] = np.eye(3)
        self.H_full[6:9, POS] = np.eye(3)
        self.H_full[9:12, VEL] = np.eye(3)
        self.R_full, self._r = np.diag(r_all), r_all
        self._I = np.eye(N_X)
        self.reset()

    @classmethod
    def from_params(cls, params, dt: float, **kwargs) -> "AugmentedEkfDetector":
        """A detector for a `QuadrotorParams`-like object (attributes read by name)."""
        return cls(QuadrotorModel.from_params(params), dt, **kwargs)

    def _set_model(self, m: QuadrotorModel, model_error: float) -> None:
        r = np.asarray(m.rotor_positions, dtype=float)
        self.c_T = m.thrust_coefficient * (1.0 + model_error)
        self.J = np.asarray(m.inertia, dtype=float)
        self.s = np.asarray(m.yaw_signs, dtype=float)
        # Moment per unit effective Omega^2 (000 eq. 4; yaw row 004 eq. 7): columns are rotors.
        self.A = np.vstack([-self.c_T * r[:, 1], self.c_T * r[:, 0], m.torque_coefficient * self.s])
        self.I_p, self.k_d = m.propeller_inertia, m.rotor_drag_coefficient
        self.mass, self.d_body = m.mass, tuple(m.body_drag)
        self.J_tuple, self.d_rot_tuple = tuple(m.inertia), tuple(m.rotational_drag)
        self._A_over_J = -self.A / self.J[:, None]
        self._gravity = np.array((0.0, 0.0, GRAVITY))
        self._zeros7 = np.zeros(7)
        self._F0 = np.zeros((N_X, N_X))
        self._F0[POS, VEL] = np.eye(3)

    # ------------------------------------------------------------------------------------ protocol
    def reset(self) -> None:
        self.x = np.zeros(N_X)
        self.P = self._P0.copy()
        self._latch = AlarmLatch()
        self._start = None
        self._Omega = None
        self._held = None
        self._acc = np.zeros(12)       # accumulated normalised innovation per channel (eq. 42)
        self._acc_w = np.ones(12)      # sum of squared window weights: var of _acc when the model fits
        self.z = np.zeros(12)
        self.statistic = 0.0

    def update(self, readings: dict, time: float, command: np.ndarray | None = None) -> None:
        """One sample: predict from the previous one (eq. 6-12), correct with this one (eq. 13-18)."""
        z = _finite(readings, self.KEYS, command)
        Omega = z["rotor_speed"]
        held = z["position"].tobytes() + z["velocity"].tobytes()
        if self._start is None:
            self._initialise(z, time)
        else:
            self.predict(Omega)
            fresh = held != self._held                         # sample-and-hold: a new sample, or the old one
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
        self.x[ETA] = _euler(z["attitude"])
        self.x[OMEGA] = z["gyro"]

    def predict(self, Omega: np.ndarray) -> None:
        """Eq. (6)-(12): state by a second-order Taylor step, P by Phi P Phi^T + Q_d."""
        dt = self.dt
        Omega_prev = self._Omega if self._Omega is not None else Omega
        f, F = self.dynamics(self.x, Omega, (Omega - Omega_prev) / dt)
        Fdt = F * dt
        self.x = self.x + dt * f + (0.5 * dt) * (Fdt @ f)     # eq. (6), second order
        self.x[8] = _wrap(self.x[8])
        Phi = self._I + Fdt + 0.5 * (Fdt @ Fdt)          # eq. (8), second order
        self.P = Phi @ self.P @ Phi.T + self.Q               # eq. (7)

    def correct(self, y: np.ndarray) -> None:
        """Eq. (13)-(18) with the linear measurement y = H x + v: attitude, gyro [, position, velocity]."""
        m = y.size
        H, R = self.H_full[:m], self.R_full[:m, :m]
        gamma = y - H @ self.x                                # eq. (17)
        gamma[2] = _wrap(gamma[2])                            # yaw innovation across +-pi
        PHt = self.P @ H.T
        S = H @ PHt + R                                       # eq. (14), V in the paper
        S_inv = np.linalg.inv(S)
        K = PHt @ S_inv                                       # eq. (13)
        self.x = self.x + K @ gamma                           # eq. (16)
        self.x[8] = _wrap(self.x[8])
        A = self._I - K @ H
        self.P = A @ self.P @ A.T + (K * self._r[:m]) @ K.T   # eq. (18), Joseph form (R diagonal)
        self.gamma, self.S = gamma, S

    def dynamics(self, x: np.ndarray, Omega: np.ndarray, Omega_dot: np.ndarray):
        """f(x, u) of eq. (43) and its Jacobian F (eq. 9), NED / FRD; inputs the rotor speeds and their rate.

        Scalars are plain floats and blocks are built whole: numpy's per-call cost dominates at this size.
        """
        Omega2 = Omega * Omega
        v = x[VEL]
        phi, theta, psi, p, q, r = x[6:12].tolist()
        k = 1.0 - x[LOE]                                       # effectiveness, eq. (40): (1 - l_i) input
        kOmega2 = k * Omega2
        m, J = self.mass, self.J
        # Translation, eq. (19)-(24) in NED: p_dot = v; m v_dot = m g e3 + R F_b.
        R = _rotation(phi, theta, psi)
        a_b = v @ R                                            # R^T v: body airspeed (no wind known)
        rotor_drag = self.k_d * float(k @ Omega)
        c = -np.array((self.d_body[0] + rotor_drag, self.d_body[1] + rotor_drag, self.d_body[2]))
        F_b = c * a_b
        F_b[2] -= self.c_T * float(kOmega2.sum())
        RF = R @ F_b
        RCRt = (R * c) @ R.T
        # d(R u)/d eta_j = n_j x (R u) with n_phi = R e1, n_theta = Rz e2, n_psi = e3 (ZYX), so the eta
        # columns are n_j x RF + RCR^T (v x n_j) = (RCR^T [v]x - [RF]x) n_j.
        N = np.array(((R[0, 0], -math.sin(psi), 0.0), (R[1, 0], math.cos(psi), 0.0), (R[2, 0], 0.0, 1.0)))
        dv_deta = (RCRt @ _skew(v) - _skew(RF)) @ N / m
        dFb_dl = np.vstack((self.k_d * a_b[0] * Omega, self.k_d * a_b[1] * Omega, self.c_T * Omega2))
        # Attitude kinematics eta_dot = W(eta) omega (ZYX Euler rates).
        eta_dot, deta_deta, W = _euler_kinematics(phi, theta, p, q, r)
        # Rotation, eq. (25)-(27) as Euler's equation: J omega_dot = M - omega x J omega.
        Jx, Jy, Jz = self.J_tuple
        dx, dy, dz = self.d_rot_tuple
        h = -self.I_p * float(self.s @ Omega)                  # propeller angular momentum along body z
        M = self.A @ kOmega2
        M[0] += -dx * p - q * h - q * r * (Jz - Jy)            # gyroscopic -Omega x (0, 0, h); -omega x J omega
        M[1] += -dy * q + p * h - p * r * (Jx - Jz)
        M[2] += -dz * r + self.I_p * float(self.s @ Omega_dot) - p * q * (Jy - Jx)  # spin-up reaction
        dw_dw = np.array(((-dx / Jx, (-h - r * (Jz - Jy)) / Jx, -q * (Jz - Jy) / Jx),
                          ((h - r * (Jx - Jz)) / Jy, -dy / Jy, -p * (Jx - Jz) / Jy),
                          (-q * (Jy - Jx) / Jz, -p * (Jy - Jx) / Jz, -dz / Jz)))
        f = np.concatenate((v, RF / m + self._gravity, eta_dot, M / J, self._zeros7))
        F = self._F0.copy()                                    # p_dot = v; biases and LOE: zero drift
        F[VEL, VEL] = RCRt / m
        F[VEL, ETA] = dv_deta
        F[VEL, LOE] = R @ dFb_dl / m
        F[ETA, ETA] = deta_deta
        F[ETA, OMEGA] = W
        F[OMEGA, OMEGA] = dw_dw
        F[OMEGA, LOE] = self._A_over_J * Omega2               # dM/dl_i = -A_i Omega_i^2
        return f, F

    # ------------------------------------------------------------------------------------ detection
    def _detect(self, time: float) -> None:
        """Eq. (41)-(42) with an accumulation window: alarm when a channel's windowed innovation >= T_0 sigma.

        Each channel's normalised innovation gamma_j / sqrt(S_jj) is summed with exponential forgetting;
        divided by the root of the summed squared weights it is N(0, 1) while the model fits, and a fault
        that the LOE random walk has not yet absorbed drives it away from zero.
        """
        m = self.gamma.size
        lam = self._forget
        self._acc[:m] = lam * self._acc[:m] + self.gamma / np.sqrt(np.diag(self.S))
        self._acc_w[:m] = lam * lam * self._acc_w[:m] + 1.0
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
    if not np.isfinite(np.concatenate(list(z.values()))).all():    # one check; find the key only on failure
        bad = next(key for key in keys if not np.isfinite(z[key]).all())
        raise ValueError(f"readings[{bad!r}]: must be finite (no NaN or inf), got {z[bad].tolist()}")
    if command is not None and not np.isfinite(np.asarray(command, dtype=np.float64)).all():
        raise ValueError(f"command: must be finite (no NaN or inf), got {np.asarray(command).tolist()}")
    return z


def _measurement(z: dict, fresh: bool) -> np.ndarray:
    parts = [_euler(z["attitude"]), z["gyro"]]
    if fresh:
        parts += [z["position"], z["velocity"]]
    return np.concatenate(parts)


def _euler(q) -> np.ndarray:
    """ZYX Euler angles (phi, theta, psi) of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
                     math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0)),
                     math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))])


def _rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body (FRD) -> world (NED) rotation Rz(psi) Ry(theta) Rx(phi)."""
    cf, sf, ct, st, cp, sp = (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
                              math.cos(psi), math.sin(psi))
    return np.array([[ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
                     [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
                     [-st, sf * ct, cf * ct]])


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


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi
