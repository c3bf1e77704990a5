"""Offline replay: a detector run over every sample of a recorded flight (`ftcgym replay LOG --detector NAME`).

The same detector object runs online in `DetectorWrapper`; here it reads a `FlightLog` instead of the env.
For a vehicle other than ours (a PX4 ULog) the detector's model is identified from the log's fault-free
part (`identify_effectiveness`), since 000's G belongs to the Bebop 2 and its sign pattern to 000's numbering.
"""
from __future__ import annotations

import contextlib
import json
import sys

import numpy as np
from scipy import signal

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
MAIN_ESTIMATE = {"loe_kalman": "k_hat"}   # detector -> the output that `final_estimate` reports
FILTER_WN, FILTER_ZETA = 50.0, 0.55       # rad/s, 000 Sec. IV-A, as in the detector
#: Below this PWM log rate the roll/pitch gains cannot be identified: the low-pass passes ~8 Hz (50 rad/s),
#: and PWM sampled at 10 Hz (RflyMAD SIL logs) misses the controller's fast corrections, so the fit dilutes
#: them to 1-15% of their value (checked by decimating the ~225 Hz HIL logs to 10 Hz).
MIN_IDENTIFICATION_RATE_HZ = 50.0
#: (G_p, G_q) / G_az = m * arm / I (000 eq. 9) used then: identified on the fault-free part of the RflyMAD
#: HIL logs (PWM at ~225 Hz), where G_p / G_az = 10.4-12.6 and G_q / G_az = 10.1-13.5; the SIL logs fly the
#: same simulated vehicle (same hover PWM, same G_az = 1.7e-5 within 2%).
ROLL_PITCH_PER_HEAVE = 12.0


# ----------------------------------------------------------------------------------------- replay

def replay(log: FlightLog, detector) -> dict:
    """Feed `detector` every sample of `log`; report each rising edge of its alarm and its final estimate.

    Times are seconds from the log's start; targets and estimates are in the log's own actuator order, and each
    alarm's `rotor` is its target as an ftcgym rotor index (None where the order or the target is unknown).
    """
    detector.reset()
    alarms, alarmed = [], False
    to_ftcgym = FTCGYM_INDEX.get(log.actuator_order)
    for time, readings, command in log.samples():
        detector.update(readings, time, command)
        status = detector.status()
        if status["alarm"] and not alarmed:
            target = status.get("isolated")
            rotor = to_ftcgym[target] if to_ftcgym is not None and isinstance(target, int) else None
            alarms.append({"time": time, "target": target, "rotor": rotor})
        alarmed = bool(status["alarm"])
    return {"detector": detector.name, "alarms": alarms, "final_estimate": _main_estimate(detector)}


def _main_estimate(detector) -> list:
    outputs = detector.outputs()
    field = MAIN_ESTIMATE.get(detector.name, next(iter(outputs)))
    return np.asarray(outputs[field], dtype=float).tolist()


# ----------------------------------------------------------------------------------------- detectors

def make_detector(name: str, log: FlightLog, **overrides):
    """The detector `name` set up for `log`; keyword arguments override its constructor's."""
    return _detector_factory(name)(log, **overrides)


def _detector_factory(name: str):
    if name not in REPLAYABLE:
        raise ValueError(f"detector {name!r} cannot replay a log; replay sets up: {', '.join(REPLAYABLE)}")
    return REPLAYABLE[name]


def _loe_kalman(log: FlightLog, **overrides) -> LoeKalmanDetector:
    """000's detector at the log's rate. Our own vehicle: its G (as the online wrapper). Another: B identified."""
    rotors = log.readings["rotor_speed"].shape[1]
    if rotors != SIGNS_000.shape[1]:
        raise LogError(log.source, f"'rotor_speed' has {rotors} columns; loe_kalman models a quadrotor "
                                   f"({SIGNS_000.shape[1]} rotors)")
    settings = {"dt": log.dt}
    if log.actuator_order == FTCGYM_ROTOR_ORDER:
        if "effectiveness_G" in log.metadata:
            settings["G"] = tuple(log.metadata["effectiveness_G"])
    elif "effectiveness_matrix" not in overrides:
        settings["effectiveness_matrix"] = effectiveness_for_detector(log)
    return LoeKalmanDetector(**{**settings, **overrides})


def effectiveness_for_detector(log: FlightLog) -> np.ndarray:
    """000's B for another vehicle, from the fault-free flight of `log`.

    Through the origin: 000's model has no bias (k_i scales rotor i's whole thrust, so B must reproduce the
    thrust itself, not its local slope). With the rotor layout known, only the gains G are left to the data.
    """
    signs = ROTOR_SIGNS.get(log.actuator_order)
    B, _ = identify_effectiveness(log, *fault_free_window(log), signs=signs, bias=False)
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


def fault_free_window(log: FlightLog, after_takeoff: float = 3.0, before_fault: float = 2.0):
    """(start, end) s: from `after_takeoff` s past take-off (ground contact and its transient over) to
    `before_fault` s before the logged fault (the 10 Hz ground truth may trail the onset by up to 0.1 s)."""
    start = takeoff_time(log) + after_takeoff
    end = (log.fault_time if log.fault_time is not None else log.time[-1]) - before_fault
    if end <= start:
        raise LogError(log.source, f"no fault-free flight to identify on (take-off + {after_takeoff} s "
                                   f"= {start:.2f} s, fault - {before_fault} s = {end:.2f} s)")
    return start, end


def takeoff_time(log: FlightLog, climb: float = 1.0) -> float:
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
    """`ftcgym replay LOG --detector NAME [--json] [--rate HZ]` (arguments parsed by ftcgym.cli).

    Exit status 2 and one line on stderr, "ftcgym replay: <file>: <problem>", for a log it cannot replay
    (any LogError) or a detector it cannot set up; other exceptions are bugs and keep their traceback.
    """
    try:
        build = _detector_factory(args.detector)  # a wrong name fails before the log is read
    except ValueError as error:
        return _fail(error)
    try:
        # Library chatter goes to stderr: with --json, stdout carries exactly one JSON object.
        with contextlib.redirect_stdout(sys.stderr):
            log = read_log(args.log, rate_hz=args.rate)
            result = replay(log, build(log))
    except LogError as error:
        return _fail(error)
    print(json.dumps(result) if args.json else format_result(result, log))
    return 0


def _fail(error: Exception) -> int:
    print(f"ftcgym replay: {error}", file=sys.stderr)
    return 2


def format_result(result: dict, log: FlightLog) -> str:
    """A short human table: each alarm with its delay after the logged fault, then the final estimate."""
    lines = [f"{log.source}: {len(log)} samples at {log.rate_hz:.0f} Hz, detector {result['detector']}",
             f"rotors: {log.actuator_order}"]
    if log.fault_time is not None:
        lines.append(f"logged fault: rotor {log.fault_target} at {log.fault_time:.3f} s")
    lines.append(f"{'alarm time [s]':>15}  {'target':>6}  {'ftcgym rotor':>12}  {'after fault [s]':>15}")
    for alarm in result["alarms"]:
        delay = "" if log.fault_time is None else f"{alarm['time'] - log.fault_time:+.3f}"
        lines.append(f"{alarm['time']:15.3f}  {str(alarm['target']):>6}  {str(alarm['rotor']):>12}  {delay:>15}")
    if not result["alarms"]:
        lines.append(f"{'(no alarm)':>15}")
    lines.append("final estimate: " + ", ".join(f"{v:.3f}" for v in result["final_estimate"]))
    return "\n".join(lines)
