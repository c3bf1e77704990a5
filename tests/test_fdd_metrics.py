"""Detection metrics against hand-computed numbers (the definitions of docs/concepts.md)."""
import math

import pytest

from ftcgym.fdd import (
    detection_delay,
    false_alarms_per_hour,
    is_false_alarm,
    isolation_accuracy,
    missed_detection_rate,
)


def test_detection_delay_is_alarm_minus_onset():
    assert detection_delay(3.5, 3.2) == pytest.approx(0.3)
    assert detection_delay(3.2, 3.2) == 0.0


@pytest.mark.parametrize("alarm, onset", [(None, 3.0), (2.0, None), (None, None), (2.9, 3.0)])
def test_no_detection_delay_without_a_detection(alarm, onset):
    assert detection_delay(alarm, onset) is None


@pytest.mark.parametrize("alarm, onset, expected", [
    (2.9, 3.0, True),     # before onset
    (1.0, None, True),    # fault-free episode
    (3.0, 3.0, False),    # at onset: a detection
    (None, 3.0, False),
    (None, None, False),
])
def test_false_alarm(alarm, onset, expected):
    assert is_false_alarm(alarm, onset) is expected


def test_false_alarms_per_hour():
    assert false_alarms_per_hour(2, 1800.0) == pytest.approx(4.0)
    assert false_alarms_per_hour(0, 10.0) == 0.0


@pytest.mark.parametrize("count, seconds", [(-1, 10.0), (1, 0.0), (1, -5.0), (1, math.nan)])
def test_false_alarms_per_hour_rejects_bad_input(count, seconds):
    with pytest.raises(ValueError):
        false_alarms_per_hour(count, seconds)


def test_missed_detection_rate_counts_no_alarm_and_early_alarm():
    # detected, never alarmed, alarmed only before onset, detected
    assert missed_detection_rate([3.5, None, 1.0, 6.0], [3.0, 3.0, 2.0, 4.0]) == pytest.approx(0.5)


def test_missed_detection_rate_rejects_fault_free_and_mismatched_input():
    with pytest.raises(ValueError, match="fault onsets"):
        missed_detection_rate([1.0], [None])
    with pytest.raises(ValueError, match="same length"):
        missed_detection_rate([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="empty"):
        missed_detection_rate([], [])
    with pytest.raises(ValueError, match="finite"):
        missed_detection_rate([math.inf], [1.0])


def test_isolation_accuracy_counts_nothing_isolated_as_wrong():
    assert isolation_accuracy([0, 2, None, 3], [0, 1, 2, 3]) == pytest.approx(0.5)


def test_isolation_accuracy_needs_true_targets():
    with pytest.raises(ValueError, match="true_targets"):
        isolation_accuracy([1], [None])
