"""Benchmark metrics: per-episode numbers from a recorded trajectory, and their per-scenario summary.

Pure numpy functions of arrays, testable without the simulator. Definitions are those of docs/concepts.md
('Benchmark metrics'); the field lists below are its `results.json` contract.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ftcgym.criteria import (  # noqa: F401
    AIRSPEED_TOLERANCE,
    ALTITUDE_TOLERANCE,
    ENVELOPE_PITCH,
    ENVELOPE_ROLL,
    RECOVERY_HOLD,
    THRUST_AXIS_TOLERANCE,
)
from ftcgym.fdd.metrics import false_alarms_per_hour, isolation_accuracy, missed_detection_rate

EPISODE_FIELDS = (
    "scenario", "policy", "seed", "fault_kind", "fault_target", "fault_onset", "alarm_time",
    "detection_delay", "isolated_target", "isolation_correct", "false_alarm", "recovery_time",
    "recovered", "crashed", "altitude_loss", "position_rmse", "airspeed_error_rmse", "flight_time",
)
#: position-return fields of a quadrotor fault episode, appended to each episode row; null without a fault and on
#: the quad-plane
RETURN_FIELDS = ("return_time_0_5m", "return_time_0_2m", "max_position_error", "final_position_error")
#: quad-plane mission fields, appended to each episode row; null for the quadrotor
QUADPLANE_FIELDS = ("mission_complete", "time_quad_mode", "time_transition", "time_forward_flight",
                    "cruise_airspeed_rmse", "max_attitude_deg", "upset_attitude_deg", "upset_altitude_loss")
EPISODE_FIELDS = EPISODE_FIELDS + RETURN_FIELDS + QUADPLANE_FIELDS
SUMMARY_FIELDS = (
    "scenario", "policy", "episodes", "detection_delay_median", "detection_delay_p95",
    "missed_detection_rate", "false_alarms_per_hour", "isolation_accuracy",
    "recovery_latency_median", "recovery_latency_p95", "success_rate", "crash_rate",
    "return_time_0_5m_median", "return_time_0_2m_median", "max_position_error_median",
    "final_position_error_median", "altitude_loss_median",
)
#: radii (m) of the position-return bands, by field
RETURN_BANDS = {"return_time_0_5m": 0.5, "return_time_0_2m": 0.2}
#: the final position error is the RMS over this many seconds at the end of the episode
FINAL_WINDOW = 2.0

UP = np.array([0.0, 0.0, -1.0])       # NED: the thrust axis of a level vehicle


def thrust_axis(attitude: np.ndarray) -> np.ndarray:
    """Thrust directions (N, 3) in NED of FRD->NED quaternions (N, 4) x, y, z, w: body -z."""
    return Rotation.from_quat(attitude).apply(-np.eye(3)[2])


def thrust_axis_error(attitude: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Angle (rad, (N,)) between each thrust axis and its reference direction (N, 3)."""
    reference = reference / np.linalg.norm(reference, axis=-1, keepdims=True)
    cosine = np.sum(thrust_axis(attitude) * reference, axis=-1)
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def hover_recovered(altitude, altitude_reference, axis_error) -> np.ndarray:
    """Per-sample rotor-loss recovery condition (docs/concepts.md, 'Benchmark metrics'): altitude and thrust axis
    on target."""
    altitude_ok = np.abs(np.asarray(altitude) - np.asarray(altitude_reference)) <= ALTITUDE_TOLERANCE
    return altitude_ok & (np.asarray(axis_error) <= THRUST_AXIS_TOLERANCE)


def recovery_time(time, recovered, onset: float, hold: float = RECOVERY_HOLD) -> float | None:
    """Start of the first window after `onset` in which `recovered` holds for `hold` s (docs/concepts.md,
    'Benchmark metrics').

    A stretch of recovered samples lasts until the next unrecovered sample, or until the last
    sample if the episode ends recovered. None when no stretch lasts `hold` s.
    """
    time, recovered = np.asarray(time, dtype=float), np.asarray(recovered, dtype=bool)
    after = time >= onset
    time, recovered = time[after], recovered[after]
    # Rising and falling edges of the recovered stretches; `stops` is one past each stretch.
    edges = np.flatnonzero(np.diff(np.concatenate(([0], recovered.astype(int), [0]))))
    starts, stops = edges[::2], edges[1::2]
    if starts.size == 0:
        return None
    ends = time[np.minimum(stops, len(time) - 1)]
    long_enough = np.flatnonzero(ends - time[starts] >= hold - 1e-9)
    return float(time[starts[long_enough[0]]]) if long_enough.size else None


# Flight phases by wing skew, as 001 Table 5 splits them: quad mode below 30 deg, transition 30-80 deg,
# forward flight above 80 deg.
TRANSITION_SKEW = (np.radians(30.0), np.radians(80.0))


def roll_pitch(attitude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (rad, (N,)) of FRD->NED quaternions (N, 4) x, y, z, w (ZYX Euler angles)."""
    yaw_pitch_roll = Rotation.from_quat(attitude).as_euler("ZYX")
    return yaw_pitch_roll[:, 2], yaw_pitch_roll[:, 1]


def airspeed_recovered(airspeed_used, airspeed, attitude) -> np.ndarray:
    """Per-sample airspeed-fault recovery condition (docs/concepts.md, 'Benchmark metrics')."""
    roll, pitch = roll_pitch(attitude)
    close = np.abs(np.asarray(airspeed_used) - np.asarray(airspeed)) <= AIRSPEED_TOLERANCE
    return close & (np.abs(roll) <= ENVELOPE_ROLL) & (np.abs(pitch) <= ENVELOPE_PITCH)


def flight_phase_times(time, skew, airborne) -> dict:
    """Seconds spent airborne in quad mode, transition and forward flight (skew thresholds above)."""
    time, skew, airborne = np.asarray(time, float), np.asarray(skew, float), np.asarray(airborne, bool)
    dt = np.diff(time, append=time[-1]) * airborne
    low, high = TRANSITION_SKEW
    return {"time_quad_mode": float(dt[skew < low].sum()),
            "time_transition": float(dt[(skew >= low) & (skew <= high)].sum()),
            "time_forward_flight": float(dt[skew > high].sum())}


def rms(values) -> float | None:
    values = np.asarray(values, float)
    return float(np.sqrt(np.mean(values ** 2))) if values.size else None


#: what a detector must name to isolate a fault whose `target` is not its channel (a pitot blockage's target
#: is its mode, "zero" or "stuck"; the detector names the sensor)
ISOLATION_TARGETS = {"pitot_blockage": "pitot"}
# propulsion_bayes names the mode
ISOLATION_TARGETS.update({kind: kind for kind in ("propeller_icing", "viscous_friction", "static_friction")})
ISOLATION_TARGETS.update({"gnss": "gnss", "pusher_rpm_sensor": "pusher_rpm"})   # airdata_ekf innovation detectors


def isolation_target(kind, target):
    """The value a detector's `isolated` must equal for the fault (kind, target)."""
    return ISOLATION_TARGETS.get(kind, target)


def altitude_loss(time, altitude, onset: float) -> float | None:
    """Altitude at onset minus the lowest altitude after it, at least 0; None if onset is past the end."""
    time, altitude = np.asarray(time, dtype=float), np.asarray(altitude, dtype=float)
    after = altitude[time >= onset]
    if after.size == 0:
        return None
    return max(0.0, float(after[0] - after.min()))


#: How long after a fault's onset the upset fields look (s): a recovery flown on a wrong reading shows within it
UPSET_WINDOW = 10.0


def upset(time, altitude, roll, pitch, onset: float, window: float = UPSET_WINDOW) -> tuple[float, float] | None:
    """(largest |roll| or |pitch|, deg; altitude at onset minus the lowest, m, at least 0) over the `window` s
    after onset; None if onset is past the end."""
    time = np.asarray(time, dtype=float)
    inside = (time >= onset) & (time <= onset + window)
    if not inside.any():
        return None
    attitude = np.degrees(np.maximum(np.abs(np.asarray(roll)[inside]), np.abs(np.asarray(pitch)[inside])))
    return float(attitude.max()), altitude_loss(time[inside], np.asarray(altitude, dtype=float)[inside], onset)


def position_rmse(position, reference_position) -> float:
    """Root mean square of the distance between position and reference position (both (N, 3))."""
    error = np.asarray(position) - np.asarray(reference_position)
    return float(np.sqrt(np.mean(np.sum(error**2, axis=-1))))


def position_error(position, reference_position) -> np.ndarray:
    """Distance (m, (N,)) between each position and its reference position (both (N, 3))."""
    return np.linalg.norm(np.asarray(position, dtype=float) - np.asarray(reference_position, dtype=float), axis=-1)


def return_time(time, error, onset: float, radius: float, crashed: bool = False) -> float | None:
    """Seconds from `onset` to the first sample from which `error` stays within `radius` until the last sample
    (docs/concepts.md, 'Benchmark metrics'): the last entry into the band. 0 if it never leaves the band after
    onset; None if the last sample is outside it, the episode crashed or no sample is at or after onset."""
    time, error = np.asarray(time, dtype=float), np.asarray(error, dtype=float)
    after = time >= onset
    time, error = time[after], error[after]
    if crashed or time.size == 0 or not error[-1] <= radius:
        return None
    outside = np.flatnonzero(~(error <= radius))
    entry = time[outside[-1] + 1] if outside.size else time[0]
    return float(entry - onset)


def max_position_error(time, error, onset: float) -> float | None:
    """The largest position error (m) at or after `onset`; None if no sample is."""
    after = np.asarray(error, dtype=float)[np.asarray(time, dtype=float) >= onset]
    return float(after.max()) if after.size else None


def final_position_error(time, error, window: float = FINAL_WINDOW) -> float | None:
    """RMS of the position error (m) over the last `window` s of the episode (the samples at or after the last
    time minus `window`)."""
    time, error = np.asarray(time, dtype=float), np.asarray(error, dtype=float)
    if time.size == 0:
        return None
    return rms(error[time >= time[-1] - window - 1e-9])


def return_fields(time, position, reference_position, onset: float, crashed: bool) -> dict:
    """RETURN_FIELDS of a fault episode from its per-step true and reference positions."""
    error = position_error(position, reference_position)
    fields = {name: return_time(time, error, onset, radius, crashed) for name, radius in RETURN_BANDS.items()}
    fields["max_position_error"] = max_position_error(time, error, onset)
    fields["final_position_error"] = final_position_error(time, error)
    return fields


def summarize(episodes: list[dict]) -> list[dict]:
    """One row of SUMMARY_FIELDS per (scenario, policy), in order of first appearance."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for episode in episodes:
        groups.setdefault((episode["scenario"], episode["policy"]), []).append(episode)
    return [_summary_row(scenario, policy, rows) for (scenario, policy), rows in groups.items()]


def _summary_row(scenario: str, policy: str, rows: list[dict]) -> dict:
    faulty = [row for row in rows if row["fault_onset"] is not None]
    monitored = [row for row in rows if row["false_alarm"] is not None]  # a detector was scored
    delays = [row["detection_delay"] for row in rows if row["detection_delay"] is not None]
    latencies = [row["recovery_time"] - row["fault_onset"] for row in faulty if row["recovered"]]
    return {
        "scenario": scenario,
        "policy": policy,
        "episodes": len(rows),
        "detection_delay_median": _percentile(delays, 50),
        "detection_delay_p95": _percentile(delays, 95),
        "missed_detection_rate": _missed_rate([row for row in faulty if row["false_alarm"] is not None]),
        "false_alarms_per_hour": _false_alarm_rate(monitored),
        "isolation_accuracy": _isolation_accuracy(rows),
        "recovery_latency_median": _percentile(latencies, 50),
        "recovery_latency_p95": _percentile(latencies, 95),
        "success_rate": float(np.mean([_succeeded(row) for row in rows])) if rows else None,
        "crash_rate": float(np.mean([bool(row["crashed"]) for row in rows])) if rows else None,
        **_return_medians(rows),
    }


def _return_medians(rows: list[dict]) -> dict:
    """Medians of the position-return fields over the episodes that scored them (a `max_position_error`): an
    episode that never returned counts as +inf in its return-time median, and a median that is inf is None."""
    scored = [row for row in rows if row.get("max_position_error") is not None]
    medians = {f"{name}_median": _median_or_none([row[name] if row[name] is not None else np.inf
                                                 for row in scored]) for name in RETURN_BANDS}
    for name in ("max_position_error", "final_position_error", "altitude_loss"):
        medians[f"{name}_median"] = _median_or_none([row[name] for row in rows if row.get(name) is not None])
    return medians


def _median_or_none(values: list[float]) -> float | None:
    """The median (the mean of the middle two of an even count, as the linear percentile), None of nothing or
    where it is inf."""
    if not values:
        return None
    median = float(np.median(np.asarray(values, dtype=float)))
    return median if np.isfinite(median) else None


def _percentile(values: list[float], q: float) -> float | None:
    """The q-th percentile (linear interpolation, numpy's default), or None of nothing."""
    return float(np.percentile(values, q)) if values else None


def _missed_rate(rows: list[dict]) -> float | None:
    if not rows:
        return None
    return missed_detection_rate([row["alarm_time"] for row in rows], [row["fault_onset"] for row in rows])


def _false_alarm_rate(rows: list[dict]) -> float | None:
    """False alarms per hour of fault-free flight: the time before onset, or the whole episode."""
    exposure = sum(row["fault_onset"] if row["fault_onset"] is not None else row["flight_time"]
                   for row in rows)
    if not rows or exposure <= 0:
        return None
    return false_alarms_per_hour(sum(bool(row["false_alarm"]) for row in rows), exposure)


def _isolation_accuracy(rows: list[dict]) -> float | None:
    """Over the detected faults that have a target to isolate (a rotor, a sensor)."""
    targets = [isolation_target(row["fault_kind"], row["fault_target"]) for row in rows]
    detected = [(row, target) for row, target in zip(rows, targets)
                if row["detection_delay"] is not None and target is not None]
    if not detected:
        return None
    return isolation_accuracy([row["isolated_target"] for row, _ in detected], [target for _, target in detected])


def _succeeded(row: dict) -> bool:
    """Success (docs/concepts.md, 'Benchmark metrics'): recovered after a fault; in a fault-free episode,
    ended without a crash."""
    if row["fault_onset"] is not None:
        return bool(row["recovered"])
    return not row["crashed"]
