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
5. Motor-speed residual (ours; 000 Sec. III-A and Fig. 8 report that a motor that lost its propeller spins up):
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

Steps 1-6 are one compiled function (numba: `_step`, on the detector's state and constants packed in two arrays,
as numba's call cost grows with each argument), with the operations of the plain-Python detector it replaced in
the same order, so every output keeps its bits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..models.constants import GRAVITY
from ..models.quadrotor import QuadrotorParams
from ..settings import updated
from .base import (
    BEYOND_LIMIT,
    AlarmLatch,
    biquad_constants,
    biquad_step,
    check_reading,
    check_time,
    missing_reading,
    vehicle_params,
    within_limit,
)
from .loe_kalman import (
    NO_ALARM,
    NON_FINITE,
    READINGS,
    TABLE_II,
    _sample,
    effectiveness_matrix,
    lowpass_coefficients,
    scaled_G,
)

CUSUM_CEILING = 1e6  # the published statistics are clipped here (they are unbounded after a loss)

#: The detector's state (`LoeCusumDetector._state`): what `outputs` publishes (g, h, e), three flags (1.0 true:
#: the detection is armed, a sample was seen, the baseline is set), the baseline b, the last filtered p and q,
#: the last measured rotor speeds and the low-pass's memory (2 x 7 channels: p, q, a_z, omega_1..4).
CUSUM, SPEED_CUSUM, RESIDUAL, OUTPUTS = slice(0, 4), slice(4, 8), slice(8, 11), slice(0, 11)
ARMED, STARTED, BASELINE_SET, BASELINE, LAST_P, LAST_Q = 11, 12, 13, slice(14, 17), 17, 18
LAST_SPEEDS, LOWPASS_MEMORY, STATE_SIZE = slice(19, 23), slice(23, 37), 37
#: Its constants (`LoeCusumDetector._constants`): B (3 x 4, row-major), theta_i / omega_i^2 (rotor i's shift
#: per squared speed, row i), Sigma^-1's diagonal, the low-pass (`biquad_constants`), then dt, the thrust that arms
#: it, the baseline's and the motor's gains, the threshold on g, the speed test's settings and whether it is on.
B_ROWS, SHIFTS, INVERSE_VARIANCE, LOWPASS = slice(0, 12), slice(12, 24), slice(24, 27), slice(27, 35)
DT, ARMING_THRUST, BASELINE_GAIN, MOTOR_GAIN, THRESHOLD = range(35, 40)
OMEGA_MIN, OMEGA_SPAN, SPEED_SIGMA, SPEED_DRIFT, SPEED_THRESHOLD, SPEED_TEST = range(40, 46)
_NO_COMMAND = np.empty(0)


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
        shifts = -s.fault_fraction * B.T                                  # theta_i / omega_i^2, row i
        lowpass = biquad_constants(*lowpass_coefficients(s.filter_wn, s.filter_zeta, self.dt))
        self._constants = np.concatenate((B.ravel(), shifts.ravel(), 1.0 / sigma ** 2, lowpass, (
            self.dt, s.takeoff_fraction * GRAVITY, 1.0 - math.exp(-self.dt / s.baseline_time_constant),
            1.0 - math.exp(-self.dt / s.motor_time_constant), s.threshold, s.omega_min, s.omega_max - s.omega_min,
            s.speed_sigma, s.speed_drift, s.speed_threshold, bool(s.speed_test))))
        self._state = np.zeros(STATE_SIZE)
        self._alarm = AlarmLatch()
        self.reset()

    def reset(self) -> None:
        self._state[:] = 0.0
        self._alarm.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        """One sample, compiled (`_step`); a reading or command beyond READING_LIMIT (NaN, inf), a non-finite time
        or a missing reading raises ValueError naming it, the state untouched."""
        check_time(time, self.name)
        command = _NO_COMMAND if command is None else np.asarray(command, dtype=np.float64)
        try:
            gyro, accel, rotor_speed = readings["gyro"], readings["accel"], readings["rotor_speed"]
        except KeyError:
            raise missing_reading(readings, READINGS, self.name) from None
        rotor = _step(gyro, accel, rotor_speed, command, self._state, self._constants)
        if rotor >= 0:
            self._alarm.trigger(time, rotor)
        elif rotor == NON_FINITE:
            _reject_non_finite(readings, command)

    @property
    def cusum(self) -> np.ndarray:
        """g, the CUSUM per rotor (a view of the state)."""
        return self._state[CUSUM]

    @property
    def speed_cusum(self) -> np.ndarray:
        """h, the motor-speed CUSUM per rotor (a view of the state)."""
        return self._state[SPEED_CUSUM]

    @property
    def residual(self) -> np.ndarray:
        """e, the residual less its baseline (a view of the state)."""
        return self._state[RESIDUAL]

    @property
    def armed(self) -> bool:
        """Whether the detection has started (000 Sec. V-D)."""
        return bool(self._state[ARMED])

    def outputs(self) -> dict:
        published = self._state[OUTPUTS].copy()                     # one copy, three views of it
        return {"cusum": published[CUSUM], "speed_cusum": published[SPEED_CUSUM], "residual": published[RESIDUAL]}

    def status(self) -> dict:
        alarm, values = self._alarm, self._state[:ARMED + 1].tolist()
        return {"alarm": alarm.alarm, "alarm_time": alarm.alarm_time, "isolated": alarm.isolated,
                "cusum": values[CUSUM], "speed_cusum": values[SPEED_CUSUM], "armed": values[ARMED] == 1.0}


@njit(cache=True)
def _step(gyro, accel, rotor_speed, command, state, constants):  # pragma: no cover (compiled)
    """One sample, in place on `state` (layout at STATE_SIZE): steps 1-6 of the module docstring. `command` is
    empty when unknown. Returns the rotor the alarm isolates, NO_ALARM, or NON_FINITE (state untouched) for a
    reading or command beyond READING_LIMIT (NaN, inf)."""
    sample = _sample(gyro, accel, rotor_speed)
    if sample.size == 0 or not within_limit(command):
        return NON_FINITE
    started = state[STARTED] == 1.0
    _speed_test(sample[3:], command, state, constants, started)
    filtered = biquad_step(constants[LOWPASS], state[LOWPASS_MEMORY].reshape(2, 7), sample, not started)
    p_last, q_last = state[LAST_P], state[LAST_Q]
    state[LAST_P], state[LAST_Q], state[STARTED] = filtered[0], filtered[1], 1.0
    omega2 = np.empty(4)
    for i in range(4):
        omega2[i] = filtered[3 + i] * filtered[3 + i]
    B = constants[B_ROWS].reshape(3, 4)
    if state[ARMED] == 0.0:                                          # take-off gating (000 Sec. V-D)
        state[ARMED] = abs(_dot(B[2], omega2)) >= constants[ARMING_THRUST]
    if not started or state[ARMED] == 0.0:
        return NO_ALARM
    dt = constants[DT]
    z = ((filtered[0] - p_last) / dt, (filtered[1] - q_last) / dt, filtered[2])   # 000 eq. (10), (13)
    _residual(z, omega2, B, state, constants[BASELINE_GAIN])
    _cusum(omega2, state, constants)
    use_speed = constants[SPEED_TEST] == 1.0 and command.size > 0
    return _decision(state, constants[THRESHOLD], constants[SPEED_THRESHOLD], use_speed)


@njit(cache=True)
def _speed_test(speed, command, state, constants, started):  # pragma: no cover (compiled)
    """Step 5: the one-step motor-speed residual and its one-sided CUSUM h from the last measured speeds (once
    `started`), then these speeds become the last."""
    last, h = state[LAST_SPEEDS], state[SPEED_CUSUM]
    omega_min, span, gain = constants[OMEGA_MIN], constants[OMEGA_SPAN], constants[MOTOR_GAIN]
    for i in range(min(command.size, 4) if started else 0):
        predicted = last[i] + gain * (omega_min + command[i] * span - last[i])   # first-order motor lag (ours)
        step = (speed[i] - predicted) / constants[SPEED_SIGMA] - constants[SPEED_DRIFT]
        h[i] = _clip_cusum(h[i] + step)                                           # Page 1954
    for i in range(4):
        last[i] = speed[i]


@njit(cache=True)
def _residual(z, omega2, B, state, gain):  # pragma: no cover (compiled)
    """Step 3: e = r - b for r = z - B omega^2 (000 eq. 12, k = 1), then the baseline b moves toward r; b starts
    at the first r."""
    baseline, e = state[BASELINE], state[RESIDUAL]
    for c in range(3):
        r = z[c] - _dot(B[c], omega2)
        if state[BASELINE_SET] == 0.0:
            baseline[c] = r
        e[c] = r - baseline[c]
        baseline[c] = baseline[c] + gain * (r - baseline[c])
    state[BASELINE_SET] = 1.0


@njit(cache=True)
def _cusum(omega2, state, constants):  # pragma: no cover (compiled)
    """Step 4: g_i = max(0, g_i + theta_i^T Sigma^-1 (e - theta_i / 2)) per rotor (Page 1954; Basseville &
    Nikiforov 1993, ch. 2), theta_i = -nu B_i omega_i^2 (000 eq. 12, k_i = 0)."""
    (e0, e1, e2), (v0, v1, v2) = state[RESIDUAL], constants[INVERSE_VARIANCE]
    shifts, g = constants[SHIFTS].reshape(4, 3), state[CUSUM]
    for i in range(4):
        t0, t1, t2 = shifts[i, 0] * omega2[i], shifts[i, 1] * omega2[i], shifts[i, 2] * omega2[i]
        step = t0 * v0 * (e0 - 0.5 * t0) + t1 * v1 * (e1 - 0.5 * t1) + t2 * v2 * (e2 - 0.5 * t2)  # the LLR
        g[i] = _clip_cusum(g[i] + step)


@njit(cache=True)
def _decision(state, threshold, speed_threshold, use_speed):  # pragma: no cover (compiled)
    """Step 6: of the rotors whose g passes `threshold` (and, with `use_speed`, whose h passes `speed_threshold`)
    the one of the largest g (the first of equals), else NO_ALARM."""
    g, h = state[CUSUM], state[SPEED_CUSUM]
    isolated = NO_ALARM
    for i in range(4):
        if g[i] > threshold and (not use_speed or h[i] > speed_threshold) and (
                isolated == NO_ALARM or g[i] > g[isolated]):
            isolated = i
    return isolated


@njit(cache=True)
def _clip_cusum(value):  # pragma: no cover (compiled)
    """min(max(0, value), CUSUM_CEILING) with Python's max and min."""
    value = value if value > 0.0 else 0.0
    return CUSUM_CEILING if value > CUSUM_CEILING else value


@njit(cache=True)
def _dot(row, values):  # pragma: no cover (compiled)
    """The dot product of two arrays of 4 floats, summed left to right."""
    return row[0] * values[0] + row[1] * values[1] + row[2] * values[2] + row[3] * values[3]


def loe_cusum_wrapper(env, G="vehicle", G_scale: float = 1.0, motor="vehicle", **kwargs):
    """`env` wrapped with a LoeCusumDetector at the env's agent rate.

    G="vehicle" takes 000 eq. (9)'s G from the env's nominal parameter set (as `loe_kalman_wrapper`); numbers
    override it and G_scale multiplies it. motor="vehicle" takes the motor's time constant and command range
    from the same set (settings given as keywords win).
    """
    from .wrapper import DetectorWrapper
    params = vehicle_params(env, "loe_cusum", QuadrotorParams)
    dt = 1.0 / env.get_wrapper_attr("agent_hz")
    if isinstance(G, str) and G == "vehicle":
        G = params.effectiveness_G
    if isinstance(motor, str) and motor == "vehicle":
        motor = {"motor_time_constant": params.motor_time_constant, "omega_min": params.omega_min,
                 "omega_max": params.omega_max}
    return DetectorWrapper(env, LoeCusumDetector(dt, G=scaled_G(G, G_scale, "loe_cusum"),
                                                  **{**(motor or {}), **kwargs}))


def _reject_non_finite(readings: dict, command) -> None:
    """Raise a ValueError naming the first reading (or the command) beyond READING_LIMIT (NaN, inf), as `_step`
    rejects it."""
    for key in READINGS:
        check_reading("loe_cusum", key, readings[key])
    raise ValueError(f"loe_cusum: the command {BEYOND_LIMIT}: {np.asarray(command, dtype=float).tolist()}")
