"""Detection metrics on alarm and onset times: plain numpy, so they also score a recorded log.

Definitions follow docs/concepts.md ('Benchmark metrics'): detection delay = alarm time - fault onset; a false
alarm is an alarm before onset or in a fault-free episode. Times are seconds of simulated time; an
onset of None means a fault-free episode and an alarm time of None means the detector never alarmed.
Each episode contributes its first alarm only.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

SECONDS_PER_HOUR = 3600.0


def _time(name: str, value) -> float | None:
    """`value` as a float, or None; rejects NaN and infinities, which would poison every mean."""
    if value is None:
        return None
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite time in seconds or None, got {value}")
    return value


def _same_length(**sequences: Sequence) -> int:
    lengths = {name: len(values) for name, values in sequences.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"sequences must have the same length, got {lengths}")
    n = next(iter(lengths.values()))
    if n == 0:
        raise ValueError(f"{' and '.join(lengths)} are empty: the rate of nothing is undefined")
    return n


def detection_delay(alarm_time, onset) -> float | None:
    """Seconds from fault onset to the alarm (docs/concepts.md, 'Benchmark metrics': alarm time - fault onset).

    None when there is no fault, no alarm, or the alarm came before onset: that alarm is a false
    alarm (`is_false_alarm`), not a detection of this fault.
    """
    alarm_time, onset = _time("alarm_time", alarm_time), _time("onset", onset)
    if alarm_time is None or onset is None or alarm_time < onset:
        return None
    return alarm_time - onset


def is_false_alarm(alarm_time, onset) -> bool:
    """True for an alarm before the fault onset, or any alarm in a fault-free episode (onset None)."""
    alarm_time, onset = _time("alarm_time", alarm_time), _time("onset", onset)
    if alarm_time is None:
        return False
    return onset is None or alarm_time < onset


def false_alarms_per_hour(n_false_alarms: int, flight_seconds: float) -> float:
    """False alarms per hour of fault-free flight (`flight_seconds` of exposure, > 0)."""
    if n_false_alarms < 0:
        raise ValueError(f"n_false_alarms must be >= 0, got {n_false_alarms}")
    flight_seconds = _time("flight_seconds", flight_seconds)
    if flight_seconds is None or flight_seconds <= 0:
        raise ValueError(f"flight_seconds must be > 0, got {flight_seconds}")
    return n_false_alarms * SECONDS_PER_HOUR / flight_seconds


def missed_detection_rate(alarm_times: Sequence, onsets: Sequence) -> float:
    """Fraction of fault episodes whose alarm never came at or after the onset.

    One alarm time (or None) and one onset per fault episode; an alarm raised before the onset is a
    false alarm and leaves the fault missed.
    """
    _same_length(alarm_times=alarm_times, onsets=onsets)
    if any(onset is None for onset in onsets):
        raise ValueError("onsets must all be fault onsets: a fault-free episode has no fault to miss")
    missed = [detection_delay(alarm, onset) is None for alarm, onset in zip(alarm_times, onsets)]
    return float(np.mean(missed))


def isolation_accuracy(isolated: Sequence, true_targets: Sequence) -> float:
    """Fraction of episodes whose isolated target (e.g. rotor index) equals the true one.

    An episode whose detector isolated nothing (None) counts as wrong.
    """
    _same_length(isolated=isolated, true_targets=true_targets)
    if any(target is None for target in true_targets):
        raise ValueError("true_targets must all be set: isolation only applies to faults with a target")
    correct = [guess is not None and guess == target for guess, target in zip(isolated, true_targets)]
    return float(np.mean(correct))
