"""Fault detection and diagnosis: detectors as plain numpy classes, their wrappers, detection metrics.

Nothing here imports the simulator (DESIGN.md): detectors and metrics also run on recorded logs.
"""
from importlib import import_module

from ftcgym.fdd.base import AlarmLatch, Detector
from ftcgym.fdd.loe_kalman import LoeKalmanDetector, loe_kalman_wrapper
from ftcgym.fdd.wrapper import DetectorWrapper
from ftcgym.fdd.metrics import (
    detection_delay,
    false_alarms_per_hour,
    is_false_alarm,
    isolation_accuracy,
    missed_detection_rate,
)

#: detector name -> "module:factory", factory(env, **kwargs) -> env wrapped with that detector
DETECTORS = {
    "loe_kalman": "ftcgym.fdd.loe_kalman:loe_kalman_wrapper",
    "aekf": "ftcgym.fdd.aekf:aekf_wrapper",
    "iv_change": "ftcgym.fdd.iv_change:iv_change_wrapper",
    "airdata_ekf": "ftcgym.fdd.airdata_ekf:airdata_ekf_wrapper",
    "propulsion_bayes": "ftcgym.fdd.propulsion_bayes:propulsion_bayes_wrapper",
}


def wrap_with_detector(name: str, env, **kwargs):
    """`env` wrapped with the named detector (a DetectorWrapper) built for that env."""
    if name not in DETECTORS:
        raise ValueError(f"detector: unknown name {name!r}; accepted: {sorted(DETECTORS)}")
    module, factory = DETECTORS[name].split(":")
    return getattr(import_module(module), factory)(env, **kwargs)


__all__ = [
    "AlarmLatch",
    "DETECTORS",
    "Detector",
    "DetectorWrapper",
    "LoeKalmanDetector",
    "loe_kalman_wrapper",
    "wrap_with_detector",
    "detection_delay",
    "false_alarms_per_hour",
    "is_false_alarm",
    "isolation_accuracy",
    "missed_detection_rate",
]
