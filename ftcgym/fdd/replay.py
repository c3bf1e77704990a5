"""Offline replay: a detector run over every sample of a recorded flight (`ftcgym replay LOG --detector NAME`).

The same detector object runs online in `DetectorWrapper`; here it reads a `FlightLog` instead of the env.
For a vehicle other than ours (a PX4 ULog) the detector's model is identified from the log itself
(`identify_effectiveness`), since 000's G belongs to the Bebop 2 and its sign pattern to 000's numbering. The
identification window is fixed from the log's flight alone (`identification_window`: take-off, a settling time,
then the first stretch of steady flight), never from the logged fault, which real use does not know.
"""
from __future__ import annotations

import contextlib
import dataclasses
import difflib
import json
import math
import sys

import numpy as np
from scipy import signal

from ..models.constants import GRAVITY
from ..models.quadrotor import VEHICLES, YAW_SIGNS, make_params
from .aekf import AugmentedEkfDetector, QuadrotorModel
from .loe_kalman import SIGNS_000, LoeKalmanDetector, lowpass_coefficients
from .logs import FTCGYM_INDEX, FTCGYM_ROTOR_ORDER, PX4_QUAD_X_ORDER, FlightLog, LogError, read_log

#: Sign of each rotor's thrust in [p_dot, q_dot, a_z] (000 eq. 8-9 with the rotor positions of each layout):
#: a rotor at y < 0 rolls right (+p), at x > 0 pitches up (+q), and every rotor pushes a_z negative.
ROTOR_SIGNS = {
    FTCGYM_ROTOR_ORDER: SIGNS_000,
    PX4_QUAD_X_ORDER: np.array([[-1.0, 1.0, 1.0, -1.0],     # front-right, rear-left, front-left, rear-right
                                [1.0, -1.0, 1.0, -1.0],
                                [-1.0, -1.0, -1.0, -1.0]]),
}
#: detector -> the output `estimate_at_alarm` and `final_estimate` report
MAIN_ESTIMATE = {"loe_kalman": "k_hat", "aekf": "loe"}
FILTER_WN, FILTER_ZETA = 50.0, 0.55       # rad/s, 000 Sec. IV-A, as in the detector
#: Below this motor-command rate the roll/pitch gains cannot be identified: the low-pass passes ~8 Hz (50 rad/s),
#: and commands sampled at 10-20 Hz (RflyMAD SIL logs) miss the controller's fast corrections, so the fit dilutes
#: them to 1-15% of their value (checked by decimating the ~225 Hz HIL logs to 10 Hz).
MIN_IDENTIFICATION_RATE_HZ = 50.0
#: (G_p, G_q) / G_az = m * arm / I (000 eq. 9) used then: identified on the fault-free part of the RflyMAD
#: HIL logs (PWM at ~225 Hz), where G_p / G_az = 10.4-12.6 and G_q / G_az = 10.1-13.5; the SIL logs fly the
#: same simulated vehicle (same hover PWM, same G_az = 1.7e-5 within 2%).
ROLL_PITCH_PER_HEAVE = 12.0

#: `aekf`'s position and velocity noise on a log whose model is identified (a PX4 log): the logged values are the
#: autopilot's estimates fused from GNSS, not the env's sensors (0.01 m, 0.02 m/s), so PX4's default GNSS noise
#: (EKF2_GPS_P_NOISE 0.5 m, EKF2_GPS_V_NOISE 0.3 m/s) stands in for their error
IDENTIFIED_NAVIGATION_SIGMA = {"position": 0.5, "velocity": 0.3}

#: The automatic identification window (`identification_window`): set from what each means, not fitted to any log
#: (no values were searched; docs/howto/replay.md shows the RflyMAD results do not move with the window):
TAKEOFF_CLIMB = 1.0        # m above the first logged altitude: in the air (`takeoff_time`)
SETTLE_TIME = 3.0          # s after take-off: ground effect and the take-off transient over
IDENTIFICATION_SECONDS = 5.0   # s of steady flight fitted: 1250 samples at 250 Hz for one gain per axis
STEADY_RATE = math.radians(20.0)   # rad/s, largest |p|, |q|, |r| in steady flight
STEADY_SPECIFIC_FORCE = 0.2        # largest |a_z + g| / g in steady flight (unaccelerated: a_z = -g)


# ----------------------------------------------------------------------------------------- replay

def replay(log: FlightLog, detector, identification: dict | None = None) -> dict:
    """Feed `detector` every sample of `log`; report each rising edge of its alarm and its estimates.

    Times are seconds from the log's start; targets and estimates are in the log's own actuator order, and each
    alarm's `rotor` is its target as an ftcgym rotor index (None where the order or the target is unknown).
    An alarm's target is the first the detector isolates while that alarm is raised, at `isolated_time` (its
    `time` for a detector that isolates as it alarms; None if it never isolates).
    `estimate_at_alarm` is the main estimate at the first alarm (None without one); `final_estimate` the one
    after the log's last sample: after any crash the log ends with, where it no longer describes the rotors.
    `identification` (from `identification`) is reported as given; `logged_fault` is the log's ground truth,
    which the replay never reads (it is there to compare the alarms with).
    """
    detector.reset()
    alarms, alarmed, at_alarm = [], False, None
    to_ftcgym = FTCGYM_INDEX.get(log.actuator_order)
    for time, readings, command in log.samples():
        detector.update(readings, time, command)
        status = detector.status()
        target = status.get("isolated")
        if status["alarm"] and not alarmed:
            alarms.append({"time": time, "target": None, "rotor": None, "isolated_time": None})
            if at_alarm is None:
                at_alarm = _main_estimate(detector)
        if status["alarm"] and target is not None and alarms[-1]["target"] is None:
            rotor = to_ftcgym[target] if to_ftcgym is not None and isinstance(target, int) else None
            alarms[-1].update(target=target, rotor=rotor, isolated_time=time)
        alarmed = bool(status["alarm"])
    logged = None if log.fault_time is None else {"time": log.fault_time, "target": log.fault_target}
    return {"detector": detector.name, "identification": identification, "alarms": alarms,
            "estimate_at_alarm": at_alarm, "final_estimate": _main_estimate(detector), "logged_fault": logged}


def _main_estimate(detector) -> list:
    outputs = detector.outputs()
    field = MAIN_ESTIMATE.get(detector.name, next(iter(outputs)))
    return np.asarray(outputs[field], dtype=float).tolist()


# ----------------------------------------------------------------------------------------- detectors

def make_detector(name: str, log: FlightLog, identify=None, vehicle: str | None = None, **overrides):
    """The detector `name` set up for `log`; keyword arguments override its constructor's.

    `identify` (start, end) s: the window its model is identified on, instead of `identification_window`'s.
    `vehicle`: a built-in vehicle name (`ftcgym.models.quadrotor.VEHICLES`) whose shape `aekf` takes
    (`aekf_model`); only `aekf` reads it.
    """
    build = _detector_factory(name)
    if vehicle is not None and name not in READS_VEHICLE:
        raise ValueError(f"vehicle {vehicle!r}: only {', '.join(READS_VEHICLE)} reads a vehicle; {name} identifies "
                         f"its model from the log (leave --vehicle out)")
    extra = {"vehicle": vehicle} if name in READS_VEHICLE else {}
    return build(log, identify=identify, **extra, **overrides)


#: registered detectors that cannot replay a log -> why, in one line (every name of `ftcgym.fdd.DETECTORS` is
#: in REPLAYABLE or here; a test holds it)
CANNOT_REPLAY = {
    "loe_cusum": "its motor-speed confirmation needs measured rotor speeds, which a PX4 log does not carry (replay "
                 "makes them from the PWM), and its thrust test alone, set for the simulator's residuals, alarms in "
                 "the take-off; an ftcgym recording carries them, but replay sets it up for neither (wrap the env "
                 "with it instead)",
    "iv_change": "it needs the position, velocity and yaw references the vehicle was flown to (its instruments "
                 "are made from them), which replay does not read from a log",
    "airdata_ekf": "it needs a quad-plane's pitot airspeed, pusher speed and current and GNSS velocity, which a "
                   "quadrotor log does not carry",
    "propulsion_bayes": "it needs a pusher motor's measured speed and current and the airspeed, which a quadrotor "
                        "log does not carry",
}


def _detector_factory(name: str):
    if name in CANNOT_REPLAY:
        raise ValueError(f"detector {name!r} cannot replay a log: {CANNOT_REPLAY[name]}; replay sets up: "
                         f"{', '.join(REPLAYABLE)}")
    if name not in REPLAYABLE:
        close = difflib.get_close_matches(str(name), list(REPLAYABLE), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"detector: unknown name {name!r}{hint}; replay sets up: {', '.join(REPLAYABLE)}")
    return REPLAYABLE[name]


def _loe_kalman(log: FlightLog, identify=None, **overrides) -> LoeKalmanDetector:
    """000's detector at the log's rate. Our own vehicle: its G (as the online wrapper). Another: B identified."""
    rotors = log.readings["rotor_speed"].shape[1]
    if rotors != SIGNS_000.shape[1]:
        raise LogError(log.source, f"'rotor_speed' has {rotors} columns; loe_kalman models a quadrotor "
                                   f"({SIGNS_000.shape[1]} rotors)")
    settings = {"dt": log.dt}
    plan = identification(log, identify)
    if plan is None:
        if "effectiveness_G" in log.metadata:
            settings["G"] = tuple(log.metadata["effectiveness_G"])
    elif "effectiveness_matrix" not in overrides:
        settings["effectiveness_matrix"] = effectiveness_for_detector(log, (plan["start"], plan["end"]))
    return LoeKalmanDetector(**{**settings, **overrides})


def identification(log: FlightLog, identify=None) -> dict | None:
    """{"start", "end", "rule"} of the window the detector's model is identified on, or None where it is not
    identified (an ftcgym recording, whose vehicle's G is known, unless `identify` (start, end) is given).

    Raises LogError for a window outside the log, or where `identification_window` finds none.
    """
    if identify is not None:
        start, end = (float(t) for t in identify)
        if not (math.isfinite(start) and math.isfinite(end) and start < end):
            raise LogError(log.source, f"identification window {start:g}:{end:g} s: expected START < END, finite")
        if start < log.time[0] or end > log.time[-1]:
            raise LogError(log.source, f"identification window {start:g}:{end:g} s is outside the log "
                                       f"({log.time[0]:.2f}-{log.time[-1]:.2f} s)")
        return {"start": start, "end": end, "rule": "given (--identify)"}
    if log.actuator_order == FTCGYM_ROTOR_ORDER:
        return None
    start, end = identification_window(log)
    return {"start": start, "end": end, "rule": IDENTIFICATION_RULE}


def effectiveness_for_detector(log: FlightLog, window=None) -> np.ndarray:
    """000's B for another vehicle, from the flight of `log` in `window` (default `identification_window`).

    Through the origin: 000's model has no bias (k_i scales rotor i's whole thrust, so B must reproduce the
    thrust itself, not its local slope). With the rotor layout known, only the gains G are left to the data.
    """
    signs = ROTOR_SIGNS.get(log.actuator_order)
    start, end = identification_window(log) if window is None else window
    B, _ = identify_effectiveness(log, start, end, signs=signs, bias=False)
    if signs is not None and log.metadata.get("actuator_rate_hz", np.inf) < MIN_IDENTIFICATION_RATE_HZ:
        heave_gain = abs(B[2, 0])
        B[:2] = signs[:2] * ROLL_PITCH_PER_HEAVE * heave_gain
    return B


def _aekf(log: FlightLog, identify=None, vehicle: str | None = None, **overrides):
    """002's augmented EKF at the log's rate on `aekf_model`. Its model has no ground contact, so on a log whose
    model is identified (a PX4 log, from the ground up) it is fed from the take-off on (`StartingAt`); an ftcgym
    recording is fed from its start."""
    plan = identification(log, identify)
    window = None if plan is None else (plan["start"], plan["end"])
    if window is not None:
        overrides = {"r_sigma": IDENTIFIED_NAVIGATION_SIGMA, **overrides}
    detector = AugmentedEkfDetector(aekf_model(log, window, vehicle), log.dt, **overrides)
    return StartingAt(detector, log.time[0] if window is None else takeoff_time(log))


def aekf_model(log: FlightLog, window=None, vehicle: str | None = None) -> QuadrotorModel:
    """The vehicle model `aekf` runs on for `log`, in the log's actuator order.

    - An ftcgym recording (no `window`): the vehicle it was flown with (`vehicle`, else its metadata's), whose
      rotor speeds the recording holds.
    - Otherwise B is identified on `window` (`effectiveness_for_detector`). A log's rotor speeds are made from
      the PWM (`logs.read_ulog`), so the thrust coefficient is the one that carries the weight at those speeds:
      c_T = m G_az (000 eq. 9). With `vehicle`, its mass, inertia, arm, drag and propeller inertia are kept and
      c_T, c_Q rescaled together. Without, everything comes from B: the EKF without drag sees only c_T / m,
      c_T b / I_x and c_T h / I_y (002 eq. 22-27 with 000 eq. 4), so m = 1 kg and b = h = 1 m fix the scale,
      I_x = c_T b / G_p, I_y = c_T h / G_q, I_z = I_x + I_y (a flat vehicle), and c_Q = 0: B has no yaw row,
      so the yaw moment is left to the process noise.
    Raises LogError for an unknown vehicle, or a recording with none.
    """
    if window is None:
        name = vehicle or log.metadata.get("vehicle")
        if name is None:
            raise LogError(log.source, f"no vehicle for aekf's model (the recording names none); give one with "
                                       f"--vehicle NAME (accepted: {', '.join(sorted(VEHICLES))})")
        return QuadrotorModel.from_params(_vehicle(log, name))
    heave, roll, pitch = _effectiveness_gains(log, window)
    order = FTCGYM_INDEX.get(log.actuator_order, (0, 1, 2, 3))
    if vehicle is None:
        positions = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]])
        inertia = (heave / roll, heave / pitch, heave / roll + heave / pitch)
        return QuadrotorModel(mass=1.0, inertia=inertia, rotor_positions=tuple(map(tuple, positions[list(order)])),
                              thrust_coefficient=heave, torque_coefficient=0.0,
                              yaw_signs=tuple(YAW_SIGNS[i] for i in order))
    params = _vehicle(log, vehicle)
    model = QuadrotorModel.from_params(params)
    scale = params.mass * heave / params.thrust_coefficient
    return dataclasses.replace(model, thrust_coefficient=model.thrust_coefficient * scale,
                               torque_coefficient=model.torque_coefficient * scale,
                               rotor_positions=tuple(model.rotor_positions[i] for i in order),
                               yaw_signs=tuple(model.yaw_signs[i] for i in order))


def _effectiveness_gains(log: FlightLog, window) -> tuple:
    """(G_az, G_p, G_q) of 000 eq. (9), magnitudes of the B identified on `window`."""
    B = np.abs(effectiveness_for_detector(log, window))
    return float(B[2].mean()), float(B[0].mean()), float(B[1].mean())


def _vehicle(log: FlightLog, name: str):
    try:
        return make_params(name)
    except ValueError:
        raise LogError(log.source, f"vehicle: unknown name {name!r}; accepted: {', '.join(sorted(VEHICLES))}") from None


class StartingAt:
    """A detector fed only from `start` (s) on: before it, the samples are skipped (reset state is kept)."""

    def __init__(self, detector, start: float):
        self.detector, self.start = detector, float(start)
        self.name, self.output_fields = detector.name, detector.output_fields

    def reset(self) -> None:
        self.detector.reset()

    def update(self, readings: dict, time: float, command=None) -> None:
        if time >= self.start:
            self.detector.update(readings, time, command)

    def outputs(self) -> dict:
        return self.detector.outputs()

    def status(self) -> dict:
        return self.detector.status()


#: the detectors replay can set up for a log (their model identified from it), by name
REPLAYABLE = {"loe_kalman": _loe_kalman, "aekf": _aekf}
READS_VEHICLE = ("aekf",)


# ----------------------------------------------------------------------------------------- identification

def identify_effectiveness(log: FlightLog, t_start: float, t_end: float, signs=None, bias: bool = True):
    """Least-squares B (3, 4) and bias (3,) of [p_dot, q_dot, a_z] = B omega^2 + bias on [t_start, t_end].

    The signals go through the detector's own filtering (000 Sec. IV-A: 2nd-order low-pass wn = 50 rad/s,
    zeta = 0.55 on p, q, a_z and omega; p_dot, q_dot by backward difference, eq. 10), so B fits what the
    detector will see. `signs` (3, 4): fit only one gain per row, B = diag(G) signs (000 eq. 9 with the
    vehicle's geometry): hover excites the rotors together, which leaves a full B ill-conditioned.
    `bias=False` fits through the origin (bias returned as zeros). Use a fault-free window only.
    """
    targets, omega2 = _filtered_signals(log)
    window = (log.time[1:] >= t_start) & (log.time[1:] <= t_end)
    if window.sum() < 10:
        raise LogError(log.source, f"too few samples to identify the effectiveness from ({window.sum()} in "
                                   f"[{t_start:.2f}, {t_end:.2f}] s; at least 10 needed)")
    targets, omega2 = targets[window], omega2[window]
    if signs is None:
        return _least_squares(omega2, targets, bias)
    signs = np.asarray(signs, dtype=float)
    gains, offsets = zip(*(_least_squares((omega2 @ row)[:, None], targets[:, [i]], bias)
                           for i, row in enumerate(signs)))
    return np.ravel(gains)[:, None] * signs, np.ravel(offsets)


def _least_squares(regressors: np.ndarray, targets: np.ndarray, bias: bool):
    """Columns of `targets` = coefficients @ regressors (+ bias): returns (coefficients (m, n), bias (m,))."""
    design = np.column_stack([regressors, np.ones(len(regressors))]) if bias else regressors
    solution, *_ = np.linalg.lstsq(design, targets, rcond=None)
    n = regressors.shape[1]
    return solution[:n].T, (solution[n] if bias else np.zeros(targets.shape[1]))


def _filtered_signals(log: FlightLog):
    """[p_dot, q_dot, a_z] (N-1, 3) and omega^2 (N-1, 4), filtered and differentiated as the detector does."""
    b, a = lowpass_coefficients(FILTER_WN, FILTER_ZETA, log.dt)

    def lowpass(x):  # started at steady state, as the detector's filter
        return signal.lfilter(b, a, x, axis=0, zi=signal.lfilter_zi(b, a)[:, None] * x[0])[0]

    rates = lowpass(log.readings["gyro"][:, :2])
    a_z = lowpass(log.readings["accel"][:, 2:3])
    omega = lowpass(log.readings["rotor_speed"])
    rate_derivatives = np.diff(rates, axis=0) / log.dt                # eq. (10)
    return np.column_stack([rate_derivatives, a_z[1:]]), omega[1:] ** 2


IDENTIFICATION_RULE = (f"first {IDENTIFICATION_SECONDS:g} s of steady flight (|p|, |q|, |r| <= "
                       f"{math.degrees(STEADY_RATE):.0f} deg/s, |a_z + g| <= {STEADY_SPECIFIC_FORCE:g} g) from "
                       f"{SETTLE_TIME:g} s after take-off ({TAKEOFF_CLIMB:g} m above the first altitude)")


def identification_window(log: FlightLog, settle: float = SETTLE_TIME, seconds: float = IDENTIFICATION_SECONDS,
                          max_rate: float = STEADY_RATE, max_specific_force: float = STEADY_SPECIFIC_FORCE):
    """(start, end) s: the first `seconds` of steady flight from `settle` s after take-off; read from the flight
    alone, never from the logged fault (which real use does not know).

    The rule, as an operator would identify a model before trusting a detector with it:
    - take-off: the first time 1 m above the first logged altitude (`takeoff_time`; the log's start where no
      position is logged), then `settle` s for ground effect and the take-off transient to die out;
    - steady flight, every sample: |p|, |q|, |r| <= `max_rate` (20 deg/s) and |a_z + g| <= `max_specific_force`
      g (0.2). 000's model (eq. 8-9) has no drag, gyroscopic or ground-effect terms and its gains are hover
      values; it fits flight near the unaccelerated state (a_z = -g, slow rotation), and the identification
      uses only such flight. Climb at constant speed passes (it is unaccelerated);
    - the first window found, of `seconds` (5 s): as early as the flight allows, so that it ends before a
      later fault, and long enough for one gain per axis (1250 samples at 250 Hz).
    None of these constants was tuned (chosen before any replay result; see docs/howto/replay.md for how the
    RflyMAD results change with the window). A fault inside the window, which nothing in the log can rule out,
    corrupts the model: `--identify` then gives a window by hand.

    Raises LogError where the vehicle never climbs or the flight never holds `seconds` of steady flight.
    """
    first = takeoff_time(log) + settle
    steady = ((np.abs(log.readings["gyro"]) <= max_rate).all(axis=1)
              & (np.abs(log.readings["accel"][:, 2] + GRAVITY) <= max_specific_force * GRAVITY)
              & (log.time >= first))
    n = max(int(round(seconds / log.dt)), 1)
    unsteady_so_far = np.concatenate(([0], np.cumsum(~steady)))
    runs = np.flatnonzero(unsteady_so_far[n:] == unsteady_so_far[:-n]) if len(steady) >= n else np.array([], int)
    if runs.size == 0:
        raise LogError(log.source, f"the flight never settles: no {seconds:g} s of steady flight (|p|, |q|, |r| <= "
                                   f"{math.degrees(max_rate):.0f} deg/s, |a_z + g| <= {max_specific_force:g} g) "
                                   f"from {first:.2f} s ({settle:g} s after take-off) to identify the effectiveness "
                                   f"on; give one with --identify START:END")
    i = int(runs[0])
    return float(log.time[i]), float(log.time[i + n - 1])


def takeoff_time(log: FlightLog, climb: float = TAKEOFF_CLIMB) -> float:
    """First time 1 m (`climb`) above the first logged altitude (NED: z decreases); the log's start if
    no position is logged."""
    if "position" not in log.readings:
        return float(log.time[0])
    z = log.readings["position"][:, 2]
    above = np.flatnonzero(z <= z[0] - climb)
    if above.size == 0:
        raise LogError(log.source, f"the vehicle never climbs {climb} m: no flight to identify on")
    return float(log.time[above[0]])


# ----------------------------------------------------------------------------------------- command line

def main(args) -> int:
    """`ftcgym replay LOG --detector NAME [--json] [--rate HZ] [--identify START:END] [--vehicle NAME]` (parsed
    by ftcgym.cli).

    Exit status 2 and one line on stderr, "ftcgym replay: <file>: <problem>", for a log it cannot replay
    (any LogError, an identification window included) or a detector it cannot set up (a ValueError: an unknown
    or unreplayable detector, a vehicle it does not read); other exceptions are bugs and keep their traceback.
    """
    try:
        _detector_factory(args.detector)  # a wrong name fails before the log is read
    except ValueError as error:
        return _fail(error)
    identify, vehicle = getattr(args, "identify", None), getattr(args, "vehicle", None)
    try:
        # Library chatter goes to stderr: with --json, stdout carries exactly one JSON object.
        with contextlib.redirect_stdout(sys.stderr):
            log = read_log(args.log, rate_hz=args.rate)
            detector = make_detector(args.detector, log, identify, vehicle)
            result = replay(log, detector, identification(log, identify))
    except ValueError as error:     # LogError included
        return _fail(error)
    print(json.dumps(result) if args.json else format_result(result, log))
    return 0


def _fail(error: Exception) -> int:
    print(f"ftcgym replay: {error}", file=sys.stderr)
    return 2


def format_result(result: dict, log: FlightLog) -> str:
    """A short human table: the identification window, each alarm with its delay after the logged fault, then
    the estimates at the first alarm and at the log's end."""
    lines = [f"{log.source}: {len(log)} samples at {log.rate_hz:.0f} Hz, detector {result['detector']}",
             f"rotors: {log.actuator_order}"]
    plan = result.get("identification")
    if plan is not None:
        lines.append(f"identified on: {plan['start']:.3f}-{plan['end']:.3f} s, {plan['rule']}")
    if log.fault_time is not None:
        lines.append(f"logged fault: rotor {log.fault_target} at {log.fault_time:.3f} s")
    lines.append(f"{'alarm time [s]':>15}  {'target':>6}  {'ftcgym rotor':>12}  {'after fault [s]':>15}")
    for alarm in result["alarms"]:
        delay = "" if log.fault_time is None else f"{alarm['time'] - log.fault_time:+.3f}"
        lines.append(f"{alarm['time']:15.3f}  {str(alarm['target']):>6}  {str(alarm['rotor']):>12}  {delay:>15}")
    if not result["alarms"]:
        lines.append(f"{'(no alarm)':>15}")
    if result.get("estimate_at_alarm") is not None:
        lines.append("estimate at first alarm: " + ", ".join(f"{v:.3f}" for v in result["estimate_at_alarm"]))
    final = ", ".join(f"{v:.3f}" for v in result["final_estimate"])
    lines.append(f"final estimate (log end, after any crash): {final}")
    return "\n".join(lines)
