"""Fast rotor-loss detection: a CUSUM per rotor on the angular-acceleration residual of 000's effectiveness model,
confirmed by the motor-speed residual.

`loe_kalman` (000 = Strack van Schijndel, Sun, de Visser, ICUAS 2023) estimates the effectiveness factors k with
a Kalman filter behind an 8 Hz low-pass and alarms on P(k_i < k_thres); its delay (median 44 ms on `bebop2`) is
mostly that filter's lag and the time the estimate takes to fall. This detector tests the hypothesis "rotor i
lost its thrust" directly, on the same measurement model:

1. The second-order low-pass of 000 Sec. IV-A, H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2) by the bilinear
   transform, with a wider band (`filter_wn`), on p, q, a_z and the rotor speeds.
2. p_dot, q_dot by backward difference of the filtered rates (000 eq. 10); z = [p_dot, q_dot, a_z].
3. The residual of the healthy model (all k = 1): r = z - B omega_f^2, B = diag(G) S (000 eq. 8, 9, 12), less a
   slow baseline b (first-order, `baseline_time_constant`) that absorbs the model's steady errors: e = r - b.
4. A total loss of rotor i shifts e by theta_i = -nu B_i omega_i^2 (000 eq. 12 with k_i = 0; nu =
   `fault_fraction`). Per rotor, Page's CUSUM of the log-likelihood ratio of a change in the mean of a Gaussian
   vector from 0 to theta_i, with diagonal covariance Sigma = diag(`residual_sigma`^2) (Page 1954; Basseville &
   Nikiforov 1993, ch. 2: the CUSUM g_k = max(0, g_k-1 + s_k) with s_k the log-likelihood ratio of sample k,
   which for a known change in a Gaussian mean is s_k = theta^T Sigma^-1 (e_k - theta / 2)):
       g_i,k = max(0, g_i,k-1 + theta_i^T Sigma^-1 (e_k - theta_i / 2))
5. Motor-speed residual (000 Sec. III-A and Fig. 8: a motor that lost its propeller is unloaded and spins up):
   the ESC's speed one sample ahead of the last measured one under the first-order motor lag toward the command,
   w_hat_k = w_k-1 + (1 - exp(-dt / tau)) (c_k - w_k-1), c = omega_min + u (omega_max - omega_min); the
   residual m_i = w_i,k - w_hat_i,k rises when rotor i is unloaded. A one-sided CUSUM of m_i / `speed_sigma`
   with drift `speed_drift` (Page 1954) gives h_i.
6. Decision: the first rotor whose g_i passes `threshold` while its h_i passes `speed_threshold` (or, with
   `speed_test` off or no command known, g_i alone) raises the alarm and is isolated.

`residual_sigma`, `filter_wn`, `fault_fraction`, `threshold` and `speed_*` were set by hand to the order of the
residuals' spread and checked on tuning flights only (base seed 1000 of `quad-rotor-loss-hover`,
`quad-rotor-loss-maneuver` and `quad-no-fault-long`, replayed offline); the thresholds are empirical (the filtered
residual is not white). The figures on held-out seeds are in docs/detectors/loe-cusum.md. Detection starts, as
000 Sec. V-D, once the rotors carry `takeoff_fraction` of the weight.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.constants import GRAVITY
from ..settings import updated
from .base import AlarmLatch, Biquad
from .loe_kalman import TABLE_II, effectiveness_matrix, lowpass_coefficients

CUSUM_CEILING = 1e6  # the published statistics are clipped here (they are unbounded after a loss)


@dataclass(frozen=True)
class LoeCusumSettings:
    """The parameters of `LoeCusumDetector`; each `LoeCusumDetector(..., **overrides)` keyword updates one."""

    G: tuple = TABLE_II["G"]              # (G_p, G_q, G_az) of 000 eq. (9); the wrapper takes the vehicle's
    effectiveness_matrix: tuple | None = None  # a (3, 4) B replacing diag(G) S, as in loe_kalman
    filter_wn: float = 200.0              # rad/s, the low-pass's natural frequency (000 Sec. IV-A: 50)
    filter_zeta: float = 0.55             # its damping (000 Sec. IV-A)
    baseline_time_constant: float = 1.0   # s, the slow baseline b of the residual
    residual_sigma: tuple = (4.0, 4.0, 0.5)   # (rad/s^2, rad/s^2, m/s^2), Sigma's diagonal
    fault_fraction: float = 1.0           # nu: the share of rotor i's thrust the CUSUM's alternative loses (total)
    threshold: float = 50.0               # the alarm threshold on g_i (log-likelihood ratio)
    speed_test: bool = True               # confirm by the motor-speed residual (needs the command)
    motor_time_constant: float = 1.0 / 30.0   # s, tau of the healthy motor (the wrapper takes the vehicle's)
    omega_min: float = 0.0                # rad/s, speed at command 0 (the wrapper takes the vehicle's)
    omega_max: float = 1200.0             # rad/s, speed at command 1 (the wrapper takes the vehicle's)
    speed_sigma: float = 2.0              # rad/s, the one-step speed residual's scale
    speed_drift: float = 2.0              # the speed CUSUM's drift, in speed_sigma
    speed_threshold: float = 5.0          # the speed CUSUM's threshold, in speed_sigma
    takeoff_fraction: float = 0.5         # detection starts once the rotors carry this share of the weight


class LoeCusumDetector:
    """Rotor-loss detector (module docstring). Readings (numpy arrays): `gyro` (rad/s, FRD), `accel` (m/s^2),
    `rotor_speed` (rad/s); `command` (normalised rotor commands in [0, 1]) for the motor-speed test.

    Parameters: dt (sample time) and the settings (`LoeCusumSettings`; each field also a keyword).
    """

    name = "loe_cusum"
    output_fields = {"cusum": (0.0, CUSUM_CEILING, (4,)), "speed_cusum": (0.0, CUSUM_CEILING, (4,)),
                     "residual": (-np.inf, np.inf, (3,))}

    def __init__(self, dt: float, settings: LoeCusumSettings | None = None, **overrides):
        s = self.settings = updated(settings or LoeCusumSettings(), overrides, "loe_cusum")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.dt = float(dt)
        B = effectiveness_matrix(s)
        sigma = np.asarray(s.residual_sigma, dtype=float)
        if sigma.shape != (3,) or not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise ValueError(f"residual_sigma: must be 3 finite numbers > 0, got {s.residual_sigma!r}")
        for field in ("filter_wn", "filter_zeta", "baseline_time_constant", "fault_fraction", "threshold",
                      "motor_time_constant", "speed_sigma", "speed_threshold"):
            value = getattr(s, field)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{field}: must be a finite number > 0, got {value!r}")
        self.B = B
        self._rows = B.tolist()
        self._shift_columns = [[-s.fault_fraction * b for b in column] for column in B.T.tolist()]  # theta_i/omega_i^2
        self._inverse_variance = (1.0 / sigma ** 2).tolist()
        self._baseline_gain = 1.0 - math.exp(-self.dt / s.baseline_time_constant)
        self._motor_gain = 1.0 - math.exp(-self.dt / s.motor_time_constant)
        self._coefficients = lowpass_coefficients(s.filter_wn, s.filter_zeta, self.dt)
        self._alarm = AlarmLatch()
        self.reset()

    def reset(self) -> None:
        self.cusum = [0.0] * 4
        self.speed_cusum = [0.0] * 4
        self.residual = [0.0] * 3
        self._baseline = None
        self._filter = Biquad(*self._coefficients)
        self._previous_rates = None
        self._previous_speed = None
        self.armed = False
        self._alarm.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        gyro, accel, speed = readings["gyro"].tolist(), readings["accel"].tolist(), readings["rotor_speed"].tolist()
        sample = [gyro[0], gyro[1], accel[2], *speed]
        command = None if command is None else np.asarray(command, dtype=float).tolist()
        if not math.isfinite(sum(sample)) or (command is not None and not math.isfinite(sum(command))):
            _reject_non_finite(readings, command)
        s = self.settings
        self._speed_test(speed, command)
        filtered = self._filter(sample)
        previous, self._previous_rates = self._previous_rates, filtered
        omega2 = [w * w for w in filtered[3:]]
        B = self._rows
        if not self.armed:
            self.armed = abs(_dot(B[2], omega2)) >= s.takeoff_fraction * GRAVITY
        if previous is None or not self.armed:
            return
        z = ((filtered[0] - previous[0]) / self.dt, (filtered[1] - previous[1]) / self.dt, filtered[2])
        r = [zc - _dot(row, omega2) for zc, row in zip(z, B)]                   # 000 eq. (12), k = 1
        if self._baseline is None:
            self._baseline = r
        e = self.residual = [rc - bc for rc, bc in zip(r, self._baseline)]
        gain = self._baseline_gain
        self._baseline = [bc + gain * (rc - bc) for rc, bc in zip(r, self._baseline)]
        (e0, e1, e2), (v0, v1, v2) = e, self._inverse_variance
        for i, ((c0, c1, c2), w) in enumerate(zip(self._shift_columns, omega2)):
            t0, t1, t2 = c0 * w, c1 * w, c2 * w                                   # theta_i, 000 eq. (12), k_i = 0
            step = t0 * v0 * (e0 - 0.5 * t0) + t1 * v1 * (e1 - 0.5 * t1) + t2 * v2 * (e2 - 0.5 * t2)  # LLR, B & N
            self.cusum[i] = min(max(0.0, self.cusum[i] + step), CUSUM_CEILING)    # Page 1954
        use_speed = s.speed_test and command is not None
        candidates = [i for i in range(4) if self.cusum[i] > s.threshold
                      and (not use_speed or self.speed_cusum[i] > s.speed_threshold)]
        if candidates:
            self._alarm.trigger(time, max(candidates, key=lambda i: self.cusum[i]))

    def _speed_test(self, speed: list, command: list | None) -> None:
        """Step 5 of the module docstring: the one-step motor-speed residual and its one-sided CUSUM."""
        previous, self._previous_speed = self._previous_speed, speed
        if command is None or previous is None:
            return
        s = self.settings
        span, gain = s.omega_max - s.omega_min, self._motor_gain
        for i, (w, w_last, u) in enumerate(zip(speed, previous, command)):
            predicted = w_last + gain * (s.omega_min + u * span - w_last)   # first-order lag (000 Sec. III-A)
            step = (w - predicted) / s.speed_sigma - s.speed_drift
            self.speed_cusum[i] = min(max(0.0, self.speed_cusum[i] + step), CUSUM_CEILING)

    def outputs(self) -> dict:
        return {"cusum": np.array(self.cusum), "speed_cusum": np.array(self.speed_cusum),
                "residual": np.array(self.residual)}

    def status(self) -> dict:
        return {**self._alarm.status(), "cusum": list(self.cusum), "speed_cusum": list(self.speed_cusum),
                "armed": self.armed}


def loe_cusum_wrapper(env, G="vehicle", G_scale: float = 1.0, motor="vehicle", **kwargs):
    """`env` wrapped with a LoeCusumDetector at the env's agent rate.

    G="vehicle" takes 000 eq. (9)'s G from the env's nominal parameter set (as `loe_kalman_wrapper`); numbers
    override it and G_scale multiplies it. motor="vehicle" takes the motor's time constant and command range
    from the same set (settings given as keywords win).
    """
    from .wrapper import DetectorWrapper
    dt = 1.0 / env.get_wrapper_attr("agent_hz")
    params = None
    if isinstance(G, str) and G == "vehicle":
        params = env.get_wrapper_attr("params")
        G = params.effectiveness_G
    if isinstance(motor, str) and motor == "vehicle":
        params = params or env.get_wrapper_attr("params")
        motor = {"motor_time_constant": params.motor_time_constant, "omega_min": params.omega_min,
                 "omega_max": params.omega_max}
    return DetectorWrapper(env, LoeCusumDetector(dt, G=tuple(np.asarray(G) * G_scale), **{**(motor or {}), **kwargs}))


def _dot(row: list, values: list) -> float:
    """The dot product of two lists of 4 floats, summed left to right."""
    return row[0] * values[0] + row[1] * values[1] + row[2] * values[2] + row[3] * values[3]


def _reject_non_finite(readings: dict, command) -> None:
    """Raise a ValueError naming the first reading (or the command) with a NaN or infinity."""
    for key in ("gyro", "accel", "rotor_speed"):
        value = np.asarray(readings[key], dtype=float)
        if not np.all(np.isfinite(value)):
            raise ValueError(f"loe_cusum: reading {key!r} is not finite: {value.tolist()}")
    raise ValueError(f"loe_cusum: the command is not finite: {np.asarray(command, dtype=float).tolist()}")
