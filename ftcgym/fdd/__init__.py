"""Fault detection and diagnosis: detectors as plain numpy classes, their wrappers, detection metrics.

Nothing here imports the simulator (DESIGN.md): detectors and metrics also run on recorded logs.
"""
from ftcgym.fdd.metrics import (
    detection_delay,
    false_alarms_per_hour,
    is_false_alarm,
    isolation_accuracy,
    missed_detection_rate,
)

__all__ = [
    "detection_delay",
    "false_alarms_per_hour",
    "is_false_alarm",
    "isolation_accuracy",
    "missed_detection_rate",
]
