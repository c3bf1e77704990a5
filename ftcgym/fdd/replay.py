"""Offline replay: a detector run over every sample of a recorded flight (`ftcgym replay LOG --detector NAME`).

The same detector object runs online in `DetectorWrapper`; here it reads a `FlightLog` instead of the env.
For a vehicle other than ours (a PX4 ULog) the detector's model is identified from the log itself
(`identify_effectiveness`), since 000's G belongs to the Bebop 2 and its sign pattern to 000's numbering. The
identification window is fixed from the log's flight alone (`identification_window`: take-off, a settling time,
then the first stretch of steady flight), never from the logged fault, which real use does not know.
"""
from __future__ import annotations

import contextlib
import json
import math
import sys

import numpy as np
from scipy import signal

from ..models.constants import GRAVITY
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
MAIN_ESTIMATE = {"loe_kalman": "k_hat"}   # detector -> the output `estimate_at_alarm`, `final_estimate` report
FILTER_WN, FILTER_ZETA = 50.0, 0.55       # rad/s, 000 Sec. IV-A, as in the detector
#: Below this motor-command rate the roll/pitch gains cannot be identified: the low-pass passes ~8 Hz (50 rad/s),
#: and commands sampled at 10-20 Hz (RflyMAD SIL logs) miss the controller's fast corrections, so the fit dilutes
#: them to 1-15% of their value (checked by decimating the ~225 Hz HIL logs to 10 Hz).
MIN_IDENTIFICATION_RATE_HZ = 50.0
#: (G_p, G_q) / G_az = m * arm / I (000 eq. 9) used then: identified on the fault-free part of the RflyMAD
#: HIL logs (PWM at ~225 Hz), where G_p / G_az = 10.4-12.6 and G_q / G_az = 10.1-13.5; the SIL logs fly the
#: same simulated vehicle (same hover PWM, same G_az = 1.7e-5 within 2%).
ROLL_PITCH_PER_HEAVE = 12.0


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
        if status["alarm"] and not alarmed:
            target = status.get("isolated")
            rotor = to_ftcgym[target] if to_ftcgym is not None and isinstance(target, int) else None
            alarms.append({"time": time, "target": target, "rotor": rotor})
            if at_alarm is None:
                at_alarm = _main_estimate(detector)
        alarmed = bool(status["alarm"])
    logged = None if log.fault_time is None else {"time": log.fault_time, "target": log.fault_target}
    return {"detector": detector.name, "identification": identification, "alarms": alarms,
            "estimate_at_alarm": at_alarm, "final_estimate": _main_estimate(detector), "logged_fault": logged}


def _main_estimate(detector) -> list:
    outputs = detector.outputs()
    field = MAIN_ESTIMATE.get(detector.name, next(iter(outputs)))
    return np.asarray(outputs[field], dtype=float).tolist()


# ----------------------------------------------------------------------------------------- detectors

def make_detector(name: str, log: FlightLog, identify=None, **overrides):
    """The detector `name` set up for `log`; keyword arguments override its constructor's.

    `identify` (start, end) s: the window its model is identified on, instead of `identification_window`'s.
    """
    return _detector_factory(name)(log, identify=identify, **overrides)


#: detectors that cannot replay a log yet -> why, in one line
CANNOT_REPLAY = {
    "aekf": "its model needs the vehicle's mass, inertia, arm and rotor constants, which a flight log does not "
            "carry and replay does not identify yet",
}


def _detector_factory(name: str):
    if name not in REPLAYABLE:
        why = f": {CANNOT_REPLAY[name]}" if name in CANNOT_REPLAY else ""
        raise ValueError(f"detector {name!r} cannot replay a log{why}; replay sets up: {', '.join(REPLAYABLE)}")
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


#: the detectors replay can set up for a log (their model identified from it), by name
REPLAYABLE = {"loe_kalman": _loe_kalman}


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
    """`ftcgym replay LOG --detector NAME [--json] [--rate HZ] [--identify START:END]` (parsed by ftcgym.cli).

    Exit status 2 and one line on stderr, "ftcgym replay: <file>: <problem>", for a log it cannot replay
    (any LogError, an identification window included) or a detector it cannot set up; other exceptions are bugs
    and keep their traceback.
    """
    try:
        build = _detector_factory(args.detector)  # a wrong name fails before the log is read
    except ValueError as error:
        return _fail(error)
    identify = getattr(args, "identify", None)
    try:
        # Library chatter goes to stderr: with --json, stdout carries exactly one JSON object.
        with contextlib.redirect_stdout(sys.stderr):
            log = read_log(args.log, rate_hz=args.rate)
            result = replay(log, build(log, identify=identify), identification(log, identify))
    except LogError as error:
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
