"""`DetectorWrapper`: runs a detector on every observation and publishes what it finds.

Like a Gymnasium `ObservationWrapper`, it adds keys to the observation (`fdd/<name>/<field>`) and declares
them in `observation_space`; it also adds `info["fdd"][<name>]` (alarm, alarm_time, isolated, estimates).
It reads the observation by key and `info["time"]` only, never simulator internals.

The detector's `name` must be a non-empty string without "/", used by no other detector wrapper of the env; its
`outputs()` are checked against `output_fields` (keys, shapes, finite values) and its `status()` for the keys the
benchmark scores on the observation `reset()` returns, naming the detector and the field; not at every step
(their cost).

Per step it returns a fresh observation dict (the env's arrays, not copied, plus the detector's outputs) and
the env's own `info` (envs return a fresh one per step) with `info["fdd"]` replaced by a new dict that keeps
the entries of inner detector wrappers.
"""
from __future__ import annotations

import contextlib

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .base import Detector


class DetectorWrapper(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Feed `detector` each observation; add its outputs to the observation and its status to `info`."""

    def __init__(self, env: gym.Env, detector: Detector):
        gym.utils.RecordConstructorArgs.__init__(self, detector=detector)  # lets env.spec describe the wrapper
        super().__init__(env)
        if not isinstance(env.observation_space, spaces.Dict):
            raise ValueError("DetectorWrapper: the env's observation_space must be a Dict of sensor readings "
                             "(observation_format='dict', the default)")
        if getattr(env.unwrapped, "info_level", "full") == "none":
            raise ValueError("DetectorWrapper: the detector reads info['time'], which info_level='none' leaves out; "
                             "make the env with info_level 'minimal' or 'full' (the default)")
        _check_name(detector, env)
        _check_same_vehicle(detector, env)
        self.detector = detector
        self.prefix = f"fdd/{detector.name}/"
        extra = {self.prefix + field: spaces.Box(low, high, shape, np.float64)
                 for field, (low, high, shape) in detector.output_fields.items()}
        clash = set(extra) & set(env.observation_space.spaces)
        if clash:
            raise ValueError(f"DetectorWrapper: keys {sorted(clash)} already in the observation (detector twice?)")
        self.observation_space = spaces.Dict({**env.observation_space.spaces, **extra})
        self._command = None
        self._time = 0.0
        self._first_of_episode = True

    def reset(self, *, seed=None, options=None):
        self.detector.reset()
        self._command = None
        self._first_of_episode = True
        obs, info = self.env.reset(seed=seed, options=options)
        return self._publish(obs, info)

    def step(self, action):
        self._command = np.asarray(action, dtype=np.float64)
        obs, reward, terminated, truncated, info = self.env.step(action)
        obs, info = self._publish(obs, info)
        return obs, reward, terminated, truncated, info

    def _publish(self, obs, info):
        self._time = float(info["time"])
        obs = self.observation(obs)
        status = self.detector.status()
        if self._first_of_episode:             # the observation reset() returns: once per episode
            self._first_of_episode = False
            _check_outputs(self.detector, self.detector.outputs())
            _check_status(self.detector.name, status)
        info["fdd"] = {**info.get("fdd", {}), self.detector.name: status}
        return obs, info

    def observation(self, observation: dict) -> dict:
        self.detector.update(observation, self._time, self._command)
        prefix = self.prefix
        return {**observation, **{prefix + field: value for field, value in self.detector.outputs().items()}}


def _check_name(detector, env) -> None:
    """The name keys the observation (`fdd/<name>/<field>`) and `info["fdd"]`: a string, and one wrapper's."""
    name = getattr(detector, "name", None)
    if not isinstance(name, str) or not name or "/" in name:
        raise ValueError(f"DetectorWrapper: the detector's name must be a non-empty string without '/' (it keys "
                         f"info['fdd'] and the observation's fdd/<name>/ fields), got {name!r}")
    inner = env
    while isinstance(inner, gym.Wrapper):
        if isinstance(inner, DetectorWrapper) and inner.detector.name == name:
            raise ValueError(f"DetectorWrapper: the env already has a detector named {name!r}; a second would "
                             f"overwrite its info['fdd'][{name!r}]: give one of them another name")
        inner = inner.env


def _check_status(name: str, status) -> None:
    """`status()` holds the keys the benchmark scores (`alarm`, `alarm_time`, `isolated`), and `isolated` is None, a
    rotor index or a name, so that a `[2]` or an array is not scored as a wrong isolation without a word."""
    if not isinstance(status, dict) or not {"alarm", "alarm_time", "isolated"} <= set(status):
        got = sorted(status) if isinstance(status, dict) else type(status).__name__
        raise ValueError(f"detector {name!r}: status() gave {got}; it must hold 'alarm', 'alarm_time' and 'isolated'")
    isolated = status["isolated"]
    if not (isolated is None or isinstance(isolated, str)
            or isinstance(isolated, (int, np.integer)) and not isinstance(isolated, (bool, np.bool_))):
        raise ValueError(f"detector {name!r}: status()['isolated'] is {isolated!r}; accepted: None, a rotor index "
                         f"(int) or a name (str)")


def _check_outputs(detector, outputs) -> None:
    """`outputs()` against `output_fields`: the same fields, each of its declared shape, finite."""
    declared = detector.output_fields
    if not isinstance(outputs, dict) or set(outputs) != set(declared):
        got = sorted(outputs) if isinstance(outputs, dict) else type(outputs).__name__
        raise ValueError(f"detector {detector.name!r}: outputs() gave fields {got}; its output_fields declare "
                         f"{sorted(declared)}")
    for field, (_, _, shape) in declared.items():
        value = np.asarray(outputs[field])
        if value.shape != tuple(shape):
            raise ValueError(f"detector {detector.name!r}: outputs()[{field!r}] has shape {value.shape}; its "
                             f"output_fields declare {tuple(shape)}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"detector {detector.name!r}: outputs()[{field!r}] is not finite ({value!r}); an "
                             f"observation must hold numbers")


def _check_same_vehicle(detector, env) -> None:
    """A detector object moved to another env must find the vehicle set and agent rate it was made for: its model
    (G, the mass, the rates) came from them, and on another vehicle it would run on the wrong one without a word.
    The first wrapper records them on the detector (`_made_for`); a detector that takes no attribute is not
    checked."""
    try:
        flown = (env.get_wrapper_attr("params").name, float(env.get_wrapper_attr("agent_hz")))
    except AttributeError:           # not an ftcgym env: nothing to compare
        return
    made_for = getattr(detector, "_made_for", None)
    if made_for is not None and made_for != flown:
        raise ValueError(f"DetectorWrapper: detector {detector.name!r} was made for {made_for[0]} at "
                         f"{made_for[1]:g} Hz; this env flies {flown[0]} at {flown[1]:g} Hz. Make one for it: "
                         f"wrap_with_detector({detector.name!r}, env)")
    with contextlib.suppress(AttributeError):
        detector._made_for = flown

