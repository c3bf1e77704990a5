"""Propeller icing and electric-propulsion faults: the multiple-model Kalman/Bayes FDI of 003 Sec. III.

Haaland, Wenz, Gryte, Hann, Johansen, "Detection and Isolation of Propeller Icing and Electric Propulsion
System Faults in Fixed-Wing UAVs" (003). Readings: pusher speed omega (rad/s), pusher current I_e (A)
and airspeed V_a (m/s, the pitot). Fault states x = [theta_1, c_v, I_0] (Sec. II-B): 1 icing, 2 viscous
friction, 3 static friction (zero-load current).

Per sample (`update`):
1. Decimate: readings are averaged over blocks of 1 / fdi_hz s (003 Sec. IV-B suggests averaging). Over a
   block, eq. (1) integrates exactly to
       k_e mean(I_e) - Theta (omega_end - omega_start) / T = mean(C) x,  C = [Q_a*(omega, V), omega, k_e]
   (eq. 9-11 with the erratum of docs/references.md: y = k_e I_e - Theta omega_dot). Departure: eq. (10) drops
   Theta omega_dot; our pusher is run by an airspeed loop, not a speed governor, and in light turbulence
   omega swings by +-70-80 rad/s within 3 s of cruise (Theta omega_dot up to ~0.1 N m, far above a 10%
   friction fault, ~0.001 N m), so the term is kept, from the speeds at the block's boundaries, each estimated from the
   samples around it (`_BlockAverager`): one noisy sample per boundary put ~5e-4 N m on Theta omega_dot.
2. Calibration (departure): the detector's model errs by `coefficient_error` on C_Q, k_e, Theta,
   c_v* and I_0*. A 10% error in k_e alone shifts y by more than the static-friction fault, so a detector
   fed the erroneous x* would alarm at once. Like a vehicle identified in healthy flight, it therefore
   re-fits theta_1*, I_0* and Theta (instrumental variables; c_v* kept) over a healthy stretch of early cruise, at
   the cruise airspeed and at the perturbed one that isolation later uses (it requests the same step).
   R is the variance of the calibration residual.
3. Detection (Sec. III-C, Fig. 3): KF^(i), i = 1..3, one scalar random-walk Kalman filter per mode (eq.
   15-24), each started at x*; the static fault-free model Y^(0) (eq. 25); three Bayes filters BF^(i)
   comparing Y^(0) with KF^(i) (eq. 29-30, S = s_detect R for both: Sec. III-B), each restarted from the
   prior Pi^h_1 = [2/3, 1/3] (eq. 32) every detection window L_D; at the end of a window
   H_D = H_1 or H_2 or H_3 (argmax of each). H_D raises the alarm (latched, `alarm_time`).
4. Isolation (Sec. III-D, Fig. 4), with departures (003 samples KF^(i) on the airspeed step and tests on the
   return, which here confuses the friction modes):
   (a) after the alarm it waits for the fault to develop (Sec. III-E: not before the KFs have stabilized):
   every KF's mean over the last `develop_window` s has moved by < `develop_ratio` of its distance from x*
   since the window before, or `max_develop` s have passed. An icing alarm comes 15-30 s into a 50 s ramp,
   and static models sampled on the ramp pick the wrong mode. (b) Step 1 and 3: +`perturbation` m/s
   (`airspeed_request`) for `level_seconds`, then the cruise airspeed for `level_seconds`; every valid
   sample from the last develop window on, the steps included (eq. 1 in integral form holds there too), is
   the isolation record. (c) Step 2: the static models Y^(0..3) (eq. 25-28), Y^(i) with x_ks^(i) in mode i,
   are least-squares fits to the whole record, each together with a correction (d theta_1*, d I_0*) of the
   healthy reference x* that must also fit the calibration record without a fault. A 10% viscous fault is
   ~8e-4 N m (0.04 A); what tells it from a static one is how it changes between the two airspeeds,
   ~2e-4 N m, as large as the error of a reference fitted on ~50 s, so the reference is re-tested with
   each hypothesis instead of trusted. (d) Step 4: the Bayes filter of eq. (29)-(31) runs over the
   innovations of both records from the uniform prior Pi^f_1 (eq. 33); if the winner's probability is below
   `p_confident` it steps again with the record kept (at most `max_cycles` steps), else, or after the
   last step, H_I = argmax. H_I > 0 sets `isolated` to the mode name; H_I = 0 (a false detection,
   Sec. III-A) returns to detection (the alarm stays latched). The margins between the friction modes stay
   thin, and the airspeed reading's noise sets the floor: with the 001 scenarios' pitot (0.3 m/s noise, 0.05 s
   lag) the torque samples scatter about twice as much as with the true airspeed. The qp-propulsion scenarios
   therefore fly 003 Sec. IV-B's sensor model (`scenarios.PROPULSION_003_SENSORS`). With the 001 pitot the
   detector raises occasional late false alarms in fault-free flights, a cause not yet understood. The
   measurements behind these choices: docs/measurements.md, 'Tuning record: fdd/propulsion_bayes.py'.

The detector only runs while the pusher drives wing-borne flight (airspeed >= `min_airspeed` and current
>= `min_current`, held for `settle` s) below 98% of the ESC's speed limit (there the speed is clipped and
eq. (1) fails: at +4 m/s, 22 m/s in the circuit, 6% of the samples were); other samples are skipped, so
windows count active time.

Airspeed perturbation path: the detector only publishes `airspeed_request` (an offset to the cruise
airspeed setpoint, m/s; output field `airspeed_request`). `propulsion_bayes_wrapper` hands it after every
step to `QuadPlaneAutopilotEnv.request_airspeed_offset`, which the autopilot adds to its cruise airspeed
target; on a recorded log or another env the request is only published.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models.checks import Range
from ..models.pusher import TWO_PI, pusher_aero_torque
from ..models.vsqp import VsqpParams
from ..settings import accepts, updated
from . import kalman
from .base import BEYOND_LIMIT, READING_LIMIT, AlarmLatch, check_time, missing_reading, model_with_error, vehicle_params
from .wrapper import DetectorWrapper

MODES = ("no_fault", "propeller_icing", "viscous_friction", "static_friction")   # 003 Sec. II-B, m = 0..3
HEALTH_PRIOR = (2.0 / 3.0, 1.0 / 3.0)           # 003 eq. (32): first row of Pi^h
FAULT_PRIOR = (0.25, 0.25, 0.25, 0.25)          # 003 eq. (33): first row of Pi^f
#: parameters of the vehicle set the detector's model takes (each erring by coefficient_error)
ERROR_COEFFICIENTS = ("pusher_torque_coefficients", "pusher_motor_constant", "pusher_inertia",
                      "pusher_viscous_friction", "pusher_zero_load_current")
PHASES = ("waiting", "calibrating", "detecting", "isolating", "isolated")


class PropulsionModel:
    """The detector's copy of 003 eq. (1)-(5): the plant's pusher formulas (`ftcgym.models.pusher`) on the
    parameter set with ERROR_COEFFICIENTS scaled by 1 + coefficient_error (error_seed None) or 1 +-
    coefficient_error with seeded random signs (`model_with_error`). rho and D are exact (atmosphere,
    geometry)."""

    def __init__(self, params, coefficient_error: float = 0.10, error_seed: int | None = None):
        self.scale, self.params = model_with_error(params, ERROR_COEFFICIENTS, coefficient_error, error_seed)
        p = self.params
        self.rho, self.D, self.cq = float(p.air_density), float(p.pusher_diameter), p.pusher_torque_coefficients
        self.k_e, self.Theta = p.pusher_motor_constant, p.pusher_inertia
        self.x_star = np.array([1.0, p.pusher_viscous_friction, p.pusher_zero_load_current])

    def nominal_torque(self, omega, V):
        """Q_a* of 003 eq. (2)-(4) (theta_1 = 1), expanded in n = omega / 2 pi so it is finite at omega = 0."""
        return pusher_aero_torque(self.params, omega, V)

    def regressors(self, omega, V) -> np.ndarray:
        """C = [Q_a*, omega, k_e] of 003 eq. (9)/(11), one row per sample."""
        omega = np.asarray(omega, dtype=float)
        return np.stack([self.nominal_torque(omega, V), omega, np.full_like(omega, self.k_e)], axis=-1)


class ScalarKalmanFilter:
    """KF^(i) of 003 eq. (15)-(24) for one fault mode (delta_i = 1): random walk x, y = C x + offset."""

    def __init__(self, x0: float, P0: float, Q: float):
        self.x, self.P, self.Q = float(x0), float(P0), float(Q)

    def step(self, y: float, C: float, offset: float, R: float) -> tuple[float, float]:
        """One prediction + update; returns the innovation and its covariance (nu, S)."""
        P = kalman.predict(np.array([[self.P]]), self.Q)   # eq. (17)-(18): x_k|k-1 = x_k-1
        nu = y - (C * self.x + offset)                  # eq. (19)-(20), offset = the other modes at x* (eq. 16)
        # eq. (21)-(24): S, the gain W, x and P (Joseph form)
        x, P, S, _ = kalman.update(np.array([self.x]), P, np.array([nu]), np.array([[C]]), np.array([[R]]))
        self.x, self.P = float(x[0]), float(P[0, 0])
        return nu, float(S[0, 0])


class BayesFilter:
    """003 eq. (29): p(H_i | z_0:k) ~ N(nu_i; 0, S_i) p(H_i | z_0:k-1), over a window of L samples from the
    prior (a row of a Markov matrix). Kept as log-probabilities: the likelihood products underflow."""

    def __init__(self, prior, window: int):
        self.log_prior = np.log(np.asarray(prior, dtype=float))
        self.window = int(window)
        self.reset()

    def reset(self) -> None:
        self.log_p = self.log_prior.copy()
        self.count = 0

    @property
    def probabilities(self) -> np.ndarray:
        p = np.exp(self.log_p - self.log_p.max())
        return p / p.sum()

    def update(self, nu, S) -> int | None:
        """One sample of innovations nu (one per hypothesis) with variances S; at the end of the window the
        hypothesis of highest probability (and the filter restarts from its prior), else None."""
        nu, S = np.asarray(nu, dtype=float), np.broadcast_to(np.asarray(S, dtype=float), np.shape(nu))
        self.log_p = self.log_p - 0.5 * (nu * nu / S + np.log(TWO_PI * S))    # eq. (30) likelihoods
        self.log_p -= self.log_p.max() + math.log(np.exp(self.log_p - self.log_p.max()).sum())  # eq. (29) denominator
        self.count += 1
        if self.count < self.window:
            return None
        winner = int(np.argmax(self.log_p))
        self.reset()
        return winner


class _BlockAverager:
    """Averages the samples of each block of n readings; over a block, eq. (1) integrates exactly, with omega_dot
    from the speeds at the block's boundaries. A single speed sample carries 003 Sec. IV-B's noise (covariance
    0.5, 0.7 rad/s), which put ~5e-4 N m on each 0.5 s sample of Theta omega_dot: more than the ~2e-4 N m by
    which a viscous fault differs from a static one between the two airspeeds. So each boundary speed is
    estimated from the 2m + 1 samples centred on it, about the speed the model predicts: with `rate` the model's
    omega_dot per sample (eq. 1) and W(t) its running integral, omega - W only carries the model's error (the
    fault, slow) and the noise, so its centred mean plus W at the boundary estimates the speed there; a plain
    mean would smear the fast swings the current drives (measured: docs/measurements.md, 'Tuning record:
    fdd/propulsion_bayes.py'). A block is returned m
    samples after its end boundary. Also returns an instrument for omega_dot: the same estimate from the m
    samples just before each centred window, whose noise is independent of theirs (the calibration's
    instrumental-variable fit of Theta needs it)."""

    def __init__(self, n: int, m: int = 10, dt: float = 0.01):
        if not 1 <= m < n // 2:
            raise ValueError(f"omega smoothing: need 1 <= {m} samples each side < half the block ({n} samples)")
        self.n, self.m, self.dt = n, m, float(dt)
        self.reset()

    def reset(self) -> None:
        self.rows, self.before = [], None   # rows since 2m samples before the last boundary; its (speed, instrument)
        self.integral = 0.0                 # W: the model's omega_dot integrated over the samples, rad/s

    def _boundary(self, b: int) -> tuple[float, float]:
        """(centred estimate, instrument) of the speed at row index b."""
        m = self.m
        rows = np.array(self.rows[b - 2 * m:b + m + 1])
        detrended, w_b = rows[:, 0] - rows[:, 3], rows[2 * m, 3]
        return float(np.mean(detrended[m:])) + w_b, float(np.mean(detrended[:m])) + w_b

    def add(self, omega: float, current: float, airspeed: float, rate: float = 0.0):
        """One sample and the model's omega_dot for it (rad/s^2). When a block completes: its rows (omega, V,
        I_e), omega's change over it and the instrument's; else None."""
        self.integral += rate * self.dt
        self.rows.append((omega, airspeed, current, self.integral))
        m = self.m
        if self.before is None:                   # warm-up: the first boundary, at row 2m
            if len(self.rows) == 3 * m + 1:
                self.before = self._boundary(2 * m)
            return None
        end = 2 * m + self.n                      # this block is rows 2m+1 .. end
        if len(self.rows) < end + m + 1:
            return None
        after = self._boundary(end)
        block = np.array(self.rows[2 * m + 1:end + 1])[:, :3]
        diff, instrument = after[0] - self.before[0], after[1] - self.before[1]
        self.rows, self.before = self.rows[end - 2 * m:], after
        return block, diff, instrument


@dataclass(frozen=True)
class PropulsionBayesSettings:
    """The parameters of `PropulsionBayesDetector`; each keyword of `PropulsionBayesDetector(..., **overrides)`
    updates one."""

    fdi_hz: float = 2.0                        # Hz, rate of the FDI samples (block averages of the readings)
    coefficient_error: float = 0.10            # the model's error on ERROR_COEFFICIENTS (`PropulsionModel`)
    error_seed: int | None = None              # None: every coefficient 1 + error; else seeded signs
    process_noise: tuple = (5e-4, 5e-4, 5e-4)  # N m per sqrt(s), per mode: Q^(i) = (q_i / mean C^(i))^2 / fdi_hz
    s_detect: float = 1.0                      # Bayes-filter innovation variance in detection, in units of R
    s_isolate: float = 1.0                     # the same in isolation (the sensitivity, 003 Sec. III-E)
    # s, L_D of the detection Bayes filters (003 Sec. III-C); 003's simulations used 100 s (Sec. III-E): 20 s is
    # a departure, and the delays and false alarms of docs/results.md are measured with it
    detection_window: float = 20.0
    perturbation: float = 4.0                  # m/s, the cruise-airspeed step asked for (003 Sec. III-D)
    settle: float = 12.0                       # s after each calibration airspeed change and after the gate opens
    calibration_seconds: float = 15.0          # s of data at each calibration airspeed
    level_seconds: float = 25.0                # s at each airspeed of an isolation step
    develop_window: float = 10.0               # s: a fault counts as developed when the KF means over this ...
    develop_ratio: float = 0.15                # ... moved less than this share of their distance from x* ...
    max_develop: float = 30.0                  # ... or after this many s
    # isolation posterior that stops stepping
    p_confident: float = field(default=0.95, metadata=accepts(Range(0.0, 1.0, open_low=True, open_high=True)))
    max_cycles: int = 2                        # most isolation steps
    min_airspeed: float = 12.0                 # m/s: below it the detector idles (not wing-borne)
    min_current: float = 3.0                   # A: below it the detector idles (pusher not driven)
    airspeed_key: str = "pitot_airspeed"       # the airspeed reading
    omega_smoothing: float = 0.1               # s either side of a block boundary averaged for its speed

class PropulsionBayesDetector:
    """003 Sec. III: detects and isolates propeller icing, viscous and static friction. See the module
    docstring for the pipeline and the departures.

    Readings: pusher_speed (rad/s), pusher_current (A), airspeed (`airspeed_key`, default pitot_airspeed).
    Parameters: params (the vehicle set, read by attribute), sample_hz (rate of `update`) and the settings
    (`PropulsionBayesSettings`, each field also a keyword).
    """

    name = "propulsion_bayes"
    output_fields = {"p_fault_detect": (0.0, 1.0, (3,)), "p_isolate": (0.0, 1.0, (4,)),
                     "estimate": (-1e3, 1e3, (3,)), "airspeed_request": (-20.0, 20.0, (1,)),
                     "phase": (0.0, len(PHASES) - 1.0, (1,))}

    def __init__(self, params, sample_hz: float, settings: PropulsionBayesSettings | None = None, **overrides):
        s = self.settings = updated(settings or PropulsionBayesSettings(), overrides, "propulsion_bayes")
        if not (math.isfinite(sample_hz) and 0.0 < s.fdi_hz <= sample_hz):
            raise ValueError(f"sample_hz {sample_hz!r} and fdi_hz {s.fdi_hz!r}: need 0 < fdi_hz <= sample_hz")
        for key in ("s_detect", "s_isolate", "detection_window", "calibration_seconds", "level_seconds",
                    "develop_window", "omega_smoothing"):
            value = getattr(s, key)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{key}: must be a positive number, got {value!r}")
        self.model = PropulsionModel(params, s.coefficient_error, s.error_seed)
        self.block = max(1, int(round(sample_hz / s.fdi_hz)))
        self.dt = self.block / float(sample_hz)                   # s per FDI sample
        self.q = np.asarray(s.process_noise, dtype=float)
        self.s_detect, self.s_isolate = float(s.s_detect), float(s.s_isolate)
        self.L_detect = self._samples(s.detection_window)
        self.perturbation, self.settle = float(s.perturbation), float(s.settle)
        self.n_calibration, self.n_develop = self._samples(s.calibration_seconds), self._samples(s.develop_window)
        self.level_seconds, self.develop_ratio = float(s.level_seconds), float(s.develop_ratio)
        self.max_develop = float(s.max_develop)
        self.p_confident, self.max_cycles = float(s.p_confident), int(s.max_cycles)
        self.min_airspeed, self.min_current = float(s.min_airspeed), float(s.min_current)
        self.airspeed_key = s.airspeed_key
        self.max_speed = 0.98 * float(params.pusher_omega_max)
        self._rate_alpha = 1.0 - math.exp(-1.0 / (sample_hz * 0.5))     # 0.5 s low-pass of the airspeed
        self._averager = _BlockAverager(self.block, max(1, int(round(s.omega_smoothing * sample_hz))), 1.0 / sample_hz)
        self._latch = AlarmLatch()
        self.reset()

    def _samples(self, seconds: float) -> int:
        return max(1, int(round(seconds / self.dt)))

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        self.phase, self.step_name = "waiting", "settle"
        self._latch.reset()
        self._averager.reset()
        self._rate_airspeed = None
        self.x_star = self.model.x_star.copy()
        self.R = None
        self.filters = None
        self.detect_filters = [BayesFilter(HEALTH_PRIOR, self.L_detect) for _ in range(3)]
        self.isolate_filter = BayesFilter(FAULT_PRIOR, 1)
        self.airspeed_request = 0.0
        self.isolated, self.hypothesis, self.detections = None, None, 0
        self._gate_since, self._step_start, self._time = None, None, 0.0
        self.Theta = self.model.Theta
        self._calibration, self._omega_sum, self._level_count = [], 0.0, 0   # rows, sum of omega, level samples
        self._history, self._static, self._record, self._cycles, self._reference = [], None, [], 0, None
        self._published = self._status = None            # what outputs() and status() return, when built

    def _enter(self, phase: str, step: str, time: float) -> None:
        self.phase, self.step_name, self._step_start = phase, step, time

    # ------------------------------------------------------------------ input
    def update(self, readings: dict, time: float, command=None) -> None:
        check_time(time, self.name)
        keys = ("pusher_speed", "pusher_current", self.airspeed_key)
        values = []
        for key in keys:
            if key not in readings:
                raise missing_reading(readings, keys, self.name)
            value = float(np.asarray(readings[key], dtype=float).reshape(-1)[0])
            if not abs(value) <= READING_LIMIT:
                raise ValueError(f"propulsion_bayes: reading {key!r} {BEYOND_LIMIT} at t = {time}: {value!r}")
            values.append(value)
        omega, current, airspeed = values
        self._time = float(time)
        if airspeed < self.min_airspeed or current < self.min_current or omega > self.max_speed:
            # not wing-borne under power, or at the ESC's speed limit, where eq. (1) no longer holds
            self._gate_since = None
            self._averager.reset()
            self._rate_airspeed = None
            return
        if self._gate_since is None:
            self._gate_since = self._time
        if self._time - self._gate_since < self.settle - 1e-9 and self.phase == "waiting":
            return
        # eq. (1): the model's omega_dot for _BlockAverager, on the airspeed low-passed over 0.5 s; the pitot's
        # per-sample noise (0.3 m/s on the 001 pitot) in it raises late false alarms (docs/measurements.md)
        m = self.model
        previous = airspeed if self._rate_airspeed is None else self._rate_airspeed
        self._rate_airspeed = previous + self._rate_alpha * (airspeed - previous)
        theta_1, c_v, i_0 = self.x_star                               # C x* of eq. (11), without building C
        load = float(m.nominal_torque(omega, self._rate_airspeed)) * theta_1 + omega * c_v + m.k_e * i_0
        rate = (m.k_e * current - load) / self.Theta
        block = self._averager.add(omega, current, airspeed, rate)
        if block is not None:
            self._fdi_sample(*block)
            self._published = self._status = None        # outputs and status change only here

    def _fdi_sample(self, block: np.ndarray, omega_diff: float, instrument: float) -> None:
        """One FDI sample from a block of (omega, V, I_e) rows: y and C of eq. (9)-(11) in integral form."""
        m = self.model
        motor_torque, omega_dot = m.k_e * float(np.mean(block[:, 2])), omega_diff / self.dt
        C = m.regressors(block[:, 0], block[:, 1]).mean(axis=0)
        if self.phase == "waiting":
            self._enter("calibrating", "base", self._time)
        if self.phase == "calibrating":
            self._calibrate(motor_torque, (omega_dot, instrument / self.dt), C)
            return
        y = motor_torque - self.Theta * omega_dot                     # eq. (9), sign per the erratum
        {"detecting": self._detect, "isolating": self._isolate, "isolated": self._track}[self.phase](y, C)

    # ------------------------------------------------------------------ calibration (departure, see docstring)
    def _calibrate(self, motor_torque: float, omega_dot: tuple, C: np.ndarray) -> None:
        """Collects [Q_a*, k_e, omega_dot] -> k_e I_e - c_v* omega at both airspeeds, then fits theta_1*, I_0*
        and Theta (the detector's Theta errs too, and in turbulence Theta omega_dot is the largest term of the
        residual) by instrumental variables: omega_dot from noisy speeds would bias a least-squares Theta
        toward 0. c_v* is kept: its term is small and nearly a combination of the others here, so a fit leaves
        it poorly determined. The samples of the airspeed changes are fitted as well (eq. 1 in integral form
        holds there too): the fit is the healthy reference the isolation tests against, and the level samples
        alone leave it tilted between the two airspeeds like a viscous fault (docs/measurements.md, 'Tuning
        record: fdd/propulsion_bayes.py')."""
        level = self.step_name in ("base", "high")
        self._calibration.append(([C[0], C[2], omega_dot[0]], [C[0], C[2], omega_dot[1]],
                                  motor_torque - C[1] * self.x_star[1], level))
        self._omega_sum += C[1]
        if level:
            self._level_count += 1
            if self._level_count >= self.n_calibration * (1 if self.step_name == "base" else 2):
                self.airspeed_request = self.perturbation if self.step_name == "base" else 0.0
                self._enter("calibrating", "up" if self.step_name == "base" else "down", self._time)
        elif self._time - self._step_start >= self.settle - 1e-9:
            if self.step_name == "up":
                self._enter("calibrating", "high", self._time)
            else:
                self._finish_calibration()

    def _finish_calibration(self) -> None:
        rows, instruments, targets, level = (np.array(column) for column in zip(*self._calibration))
        theta, i_0, inertia = np.linalg.solve(instruments.T @ rows, instruments.T @ targets)
        self._omega_mean = self._omega_sum / len(rows)
        self.x_star, self.Theta = np.array([theta, self.x_star[1], i_0]), float(inertia)
        residual = targets - rows @ np.array([theta, i_0, inertia])
        # R from the samples at the two airspeeds (the steps' large omega_dot would inflate it)
        self.R = float(np.var(residual[level]))
        self._reference = (rows[:, :2], residual)        # [Q_a*, k_e] and the healthy residual, for isolation
        # Q^(i): a random walk of `process_noise` N m per sqrt(s) in the torque each mode explains (Sec. III-E:
        # commensurate with the fault), so every KF^(i) settles in a few seconds after the airspeed step.
        C_mean = np.abs(np.array([rows[:, 0].mean(), self._omega_mean, rows[:, 1].mean()]))
        Q = (self.q / C_mean) ** 2 * self.dt                          # per FDI sample
        P0 = Q * 100.0 / self.dt                                      # 100 s of random walk
        self.filters = [ScalarKalmanFilter(self.x_star[i], P0[i], Q[i]) for i in range(3)]
        for bf in self.detect_filters:
            bf.reset()
        self._enter("detecting", "window", self._time)

    # ------------------------------------------------------------------ detection (Sec. III-C)
    def _kalman(self, y: float, C: np.ndarray) -> np.ndarray:
        """Runs KF^(1..3); returns [nu_0 (static Y^(0), eq. 25), nu_1, nu_2, nu_3]."""
        nu = [y - float(C @ self.x_star)]
        for i, kf in enumerate(self.filters):
            offset = float(C @ self.x_star) - C[i] * self.x_star[i]     # eq. (16): the other modes at x*
            nu.append(kf.step(y, C[i], offset, self.R)[0])
        self._history.append([kf.x for kf in self.filters])
        del self._history[:-2 * self.n_develop]
        return np.array(nu)

    def _detect(self, y: float, C: np.ndarray) -> None:
        nu = self._kalman(y, C)
        S = self.s_detect * self.R                                     # Sec. III-B: S = R for every model
        votes = [bf.update([nu[0], nu[i + 1]], S) for i, bf in enumerate(self.detect_filters)]
        if any(v == 1 for v in votes):                                 # H_D = H_1 or H_2 or H_3 (Fig. 3)
            self.detections += 1
            self._latch.trigger(self._time)
            self._record, self._cycles = [], 0
            self._enter("isolating", "develop", self._time)            # then Sec. III-D step 1

    # ------------------------------------------------------------------ isolation (Sec. III-D)
    def _isolate(self, y: float, C: np.ndarray) -> None:
        nu = self._kalman(y, C)
        if self.step_name == "develop":
            self._develop(nu[0], C)
            return
        self._record.append((nu[0], C))                                # every valid sample, steps included
        if self._time - self._step_start < self.level_seconds - 1e-9:
            return
        if self.step_name == "up":                                     # step 3: back to the cruise airspeed
            self.airspeed_request = 0.0
            self._enter("isolating", "down", self._time)
            return
        self._cycles += 1
        winner, p = self._isolation_test()
        if p[winner] < self.p_confident and self._cycles < self.max_cycles:
            self.airspeed_request = self.perturbation                  # not confident: one more step
            self._enter("isolating", "up", self._time)
            return
        self.hypothesis = winner
        if winner == 0:                                                # a false detection: back to detection
            for bf in self.detect_filters:
                bf.reset()
            self._enter("detecting", "window", self._time)
        else:
            self.isolated = MODES[winner]
            self._latch.isolated = self.isolated if self._latch.isolated is None else self._latch.isolated
            self._enter("isolated", "done", self._time)

    def _develop(self, nu_0: float, C: np.ndarray) -> None:
        """Waits until the fault has developed (Sec. III-E: isolation should not start before the KFs have
        stabilized): the mean of every KF estimate over the last `develop_window` s has moved by less than
        `develop_ratio` of its distance from x* since the window before (or `max_develop` s have passed).
        Then the last window's samples open the isolation record and the airspeed step is asked for (step 1)."""
        self._record.append((nu_0, C))
        n = self.n_develop
        del self._record[:-n]
        history = np.array(self._history[-2 * n:])
        elapsed = self._time - self._step_start
        if len(history) < 2 * n and elapsed < self.max_develop - 1e-9:
            return
        stable = False
        if len(history) == 2 * n:
            last, before = history[-n:].mean(axis=0), history[:-n].mean(axis=0)
            stable = bool(np.all(np.abs(last - before) <= self.develop_ratio * np.abs(last - self.x_star)))
        if stable or elapsed >= self.max_develop - 1e-9:
            self.airspeed_request = self.perturbation
            self._enter("isolating", "up", self._time)

    def _isolation_test(self) -> tuple[int, np.ndarray]:
        """Steps 2 and 4 on the isolation record (departures, see the module docstring): the static models
        Y^(0..3) (eq. 25-28), Y^(i) with x_ks^(i) in mode i, are fitted by least squares to the record together
        with a correction (d theta_1*, d I_0*) of the healthy reference x*, which also has to fit the
        calibration record without a fault; then the Bayes filter of eq. (29)-(31) runs from Pi^f_1 (eq. 33)
        over their innovations on both records."""
        A_ref, e_ref = self._reference
        nu_0 = np.array([row[0] for row in self._record])
        C = np.array([row[1] for row in self._record])
        target = np.concatenate([e_ref, nu_0])
        innovations, static = [], self.x_star.copy()
        for mode in range(4):                                          # 0: no fault, the reference alone
            fault = np.zeros(len(target)) if mode == 0 else np.concatenate([np.zeros(len(e_ref)), C[:, mode - 1]])
            A = np.column_stack([np.vstack([A_ref, C[:, [0, 2]]]), fault])[:, :3 if mode else 2]
            solution = np.linalg.lstsq(A, target, rcond=None)[0]
            innovations.append(target - A @ solution)
            if mode:
                static[mode - 1] = self.x_star[mode - 1] + solution[2]   # x_ks^(i)
        self._static = static
        self.isolate_filter = BayesFilter(FAULT_PRIOR, len(target) + 1)  # one window: both records
        for row in np.column_stack(innovations):
            self.isolate_filter.update(row, self.s_isolate * self.R)
        p = self.isolate_filter.probabilities
        return int(np.argmax(p)), p

    def _track(self, y: float, C: np.ndarray) -> None:
        self._kalman(y, C)

    # ------------------------------------------------------------------ output
    def outputs(self) -> dict:
        """The published estimates. They change only at an FDI sample: built once after each, then one copy per
        call (five views of it)."""
        if self._published is None:
            estimate = [kf.x for kf in self.filters] if self.filters else list(self.x_star)
            self._published = np.concatenate((
                np.array([bf.probabilities[1] for bf in self.detect_filters]), self.isolate_filter.probabilities,
                np.clip(estimate, -1e3, 1e3), (self.airspeed_request, float(PHASES.index(self.phase)))))
        published = self._published.copy()
        return {"p_fault_detect": published[0:3], "p_isolate": published[3:7], "estimate": published[7:10],
                "airspeed_request": published[10:11], "phase": published[11:12]}

    def status(self) -> dict:
        """The status. It changes only at an FDI sample: built once after each, then a new dict per call (its
        x_star list is built anew after each change and never changed in place)."""
        if self._status is None:
            self._status = {**self._latch.status(), "phase": self.phase, "step": self.step_name,
                            "hypothesis": None if self.hypothesis is None else MODES[self.hypothesis],
                            "detections": self.detections, "x_star": self.x_star.tolist(), "R": self.R,
                            "airspeed_request": self.airspeed_request}
        return dict(self._status)


class PropulsionBayesWrapper(DetectorWrapper):
    """DetectorWrapper that also hands the detector's airspeed request to the env's
    `request_airspeed_offset` (QuadPlaneAutopilot-v0: the autopilot's cruise setpoint; 003 Sec. III-D, Fig. 2)
    after every observation. Envs without that method only see the request in the observation."""

    def observation(self, observation: dict) -> dict:
        out = super().observation(observation)
        request = getattr(self.env.unwrapped, "request_airspeed_offset", None)
        if request is not None:
            request(self.detector.airspeed_request)
        return out


def propulsion_bayes_wrapper(env, params="vehicle", **kwargs):
    """`env` (QuadPlaneAutopilot-v0, or QuadPlane-v0) wrapped with a PropulsionBayesDetector at the env's agent
    rate; params="vehicle" reads the env's parameter set (the detector then errs by `coefficient_error`)."""
    vehicle = vehicle_params(env, "propulsion_bayes", VsqpParams)
    if isinstance(params, str) and params == "vehicle":
        params = vehicle
    return PropulsionBayesWrapper(env, PropulsionBayesDetector(params, env.get_wrapper_attr("agent_hz"), **kwargs))
