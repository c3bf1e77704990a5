"""Fault detection and diagnosis: detectors as plain numpy classes, their wrappers, detection metrics.

Nothing here imports the simulator (`ftcgym.envs`): detectors read readings by key, so they also run on
recorded logs; the plant formulas they need come from `ftcgym.models`.

`wrap_with_detector(name, env, **kwargs)` wraps an env with a detector named as `ftcgym.registry` resolves
names: a built-in one (`DETECTORS`), an installed plug-in (entry-point group `ftcgym.detectors`) or
MODULE:ATTR. The object a name stands for is either a class satisfying the `Detector` protocol, built with
`cls.from_env(env, **kwargs)` when it has that classmethod and `cls(**kwargs)` otherwise, then wrapped in
`DetectorWrapper`; or a factory `f(env, **kwargs)` that returns the wrapped env, as the built-in ones are.
"""
import inspect

import gymnasium as gym

from ftcgym.fdd.base import AlarmLatch, Detector
from ftcgym.fdd.loe_cusum import LoeCusumDetector, loe_cusum_wrapper
from ftcgym.fdd.loe_kalman import LoeKalmanDetector, loe_kalman_wrapper
from ftcgym.fdd.metrics import (
    detection_delay,
    false_alarms_per_hour,
    is_false_alarm,
    isolation_accuracy,
    missed_detection_rate,
)
from ftcgym.fdd.wrapper import DetectorWrapper
from ftcgym.registry import Entry, Registry

DETECTORS = Registry("detector", "ftcgym.detectors", {
    "loe_kalman": Entry("ftcgym.fdd.loe_kalman:loe_kalman_wrapper",
                        "loss-of-effectiveness Kalman estimator and hypothesis test (Strack van Schijndel et al. "
                        "2023)"),
    "loe_cusum": Entry("ftcgym.fdd.loe_cusum:loe_cusum_wrapper",
                       "fast rotor loss: per-rotor CUSUM on the angular-acceleration residual of Strack van "
                       "Schijndel et al. 2023, confirmed by the motor-speed residual (Page 1954)"),
    "aekf": Entry("ftcgym.fdd.aekf:aekf_wrapper",
                  "augmented EKF of rotor loss of effectiveness with an innovation test (Lu, van Kampen and Yu)"),
    "iv_change": Entry("ftcgym.fdd.iv_change:iv_change_wrapper",
                       "payload change by sensor-to-sensor instrumental variables (Ho, Hendeby and Enqvist 2020)"),
    "airdata_ekf": Entry("ftcgym.fdd.airdata_ekf:airdata_ekf_wrapper",
                         "synthetic air-data EKF with pitot, GNSS and pusher-RPM fault detection (Larocque 2023)"),
    "propulsion_bayes": Entry("ftcgym.fdd.propulsion_bayes:propulsion_bayes_wrapper",
                              "propeller icing and motor friction by multiple-model Kalman and Bayes filters "
                              "(Haaland et al.)"),
})


def wrap_with_detector(name: str, env: gym.Env, **kwargs) -> gym.Env:
    """`env` wrapped with the detector `name` (module docstring), built with `kwargs`."""
    target = DETECTORS.load(name)
    if not inspect.isclass(target):
        wrapped = target(env, **kwargs)
        if not isinstance(wrapped, gym.Env):
            raise TypeError(f"detector {name!r}: the factory returned {type(wrapped).__name__}, not the wrapped env")
        return wrapped
    missing = [member for member in ("name", "output_fields", "reset", "update", "outputs", "status")
               if not hasattr(target, member)]
    if missing:
        raise TypeError(f"detector {name!r}: class {target.__name__} lacks {missing} of the Detector protocol "
                        f"(ftcgym.fdd.Detector)")
    detector = target.from_env(env, **kwargs) if hasattr(target, "from_env") else target(**kwargs)
    return DetectorWrapper(env, detector)


def published_detector(env: gym.Env, name: str | None) -> str | None:
    """The key under which `env`'s outermost detector wrapper publishes `info["fdd"]` (its detector's `name`),
    or `name` when the env has none (None stays None)."""
    if name is None:
        return None
    while isinstance(env, gym.Wrapper):
        if isinstance(env, DetectorWrapper):
            return env.detector.name
        env = env.env
    return name


__all__ = [
    "AlarmLatch",
    "DETECTORS",
    "Detector",
    "DetectorWrapper",
    "LoeCusumDetector",
    "LoeKalmanDetector",
    "loe_cusum_wrapper",
    "loe_kalman_wrapper",
    "published_detector",
    "wrap_with_detector",
    "detection_delay",
    "false_alarms_per_hour",
    "is_false_alarm",
    "isolation_accuracy",
    "missed_detection_rate",
]
