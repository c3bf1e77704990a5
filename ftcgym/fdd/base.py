"""What every detector is: a plain numpy object fed one sample at a time.

Detectors never import the simulator: they read a dict of sensor readings by key (the env's observation,
or a row of a recorded log) and a time stamp, so the same object runs online in a wrapper and offline in
`ftcgym replay`.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import numpy as np
from numba import njit
from scipy import signal

from ..models.quadrotor import QuadrotorParams
from ..models.vsqp import VsqpParams

#: The largest magnitude a detector takes in a reading or a command (SI units: rad/s, m/s^2, m, m/s, A, rad); a
#: flight's sensors read far less. Beyond it a detector's products overflow, and its state stayed NaN for the rest
#: of the flight without an alarm (loe_kalman's covariance at a rotor speed of 1e20 rad/s). NaN and inf are beyond
#: it, so `abs(v) <= READING_LIMIT` is the one check on a reading. Time stamps (a log's may be large) and settings
#: are only required to be finite.
READING_LIMIT = 1e6
#: how a detector's ValueError describes a reading (or command) that fails that check
BEYOND_LIMIT = f"is not finite or beyond +-{READING_LIMIT:g}"


def beyond_limit(value) -> bool:
    """Whether a reading (a float or an array-like of floats) has a value that fails `abs(v) <= READING_LIMIT`."""
    return not np.all(np.abs(value) <= READING_LIMIT)


def check_reading(detector: str, key: str, value, time: float | None = None) -> None:
    """The ValueError for a reading `key` that fails `abs(v) <= READING_LIMIT`, naming the detector (and the
    time, if given); nothing for one that passes."""
    if beyond_limit(value):
        when = "" if time is None else f" at t = {time}"
        raise ValueError(f"{detector}: reading {key!r} {BEYOND_LIMIT}{when}: "
                         f"{np.asarray(value, dtype=float).tolist()}")


@njit(cache=True)
def within_limit(a):  # pragma: no cover (compiled)
    """Whether every value of the array `a` passes `abs(v) <= READING_LIMIT` (`beyond_limit`'s negation)."""
    within = True
    for v in a.flat:
        within &= abs(v) <= READING_LIMIT
    return within


def check_time(time, detector: str) -> None:
    """ValueError unless `time` (s, a detector's sample time) is a finite number: an alarm time of NaN would
    pass every comparison silently."""
    if not math.isfinite(time):
        raise ValueError(f"{detector}: time must be a finite number of seconds, got {time!r}")


def missing_reading(readings, keys, detector: str) -> ValueError:
    """The error for readings that lack some of `keys` (a KeyError of the dict would not say which detector)."""
    missing = [key for key in keys if key not in readings]
    return ValueError(f"{detector}: readings: missing {missing}; it reads {list(keys)}")


def vehicle_params(env, detector: str, kind: type):
    """The nominal parameter set of `env`'s vehicle, which must be a `kind` (`QuadrotorParams` or `VsqpParams`):
    a detector built on one vehicle's model does not run on the other, and says so (ValueError)."""
    params = env.get_wrapper_attr("params")
    if not isinstance(params, kind):
        raise ValueError(f"detector {detector!r}: runs on {_VEHICLES[kind]}, not on {type(env.unwrapped).__name__} "
                         f"(parameter set {getattr(params, 'name', '?')!r})")
    return params


_VEHICLES = {QuadrotorParams: "the quadrotor (Quadrotor-v0)",
             VsqpParams: "the quad-plane (QuadPlane-v0, QuadPlaneAutopilot-v0)"}


#: the reading types the detectors' compiled steps take as they come (numba converts or rejects their dtypes);
#: anything else is converted in Python first: `ARRAY_TYPES.issuperset(map(type, readings))`
ARRAY_TYPES = frozenset({np.ndarray})


@runtime_checkable
class Detector(Protocol):
    """A fault detector.

    name:           key under which the wrapper publishes it (`fdd/<name>/<field>`, `info["fdd"][name]`)
    output_fields:  field -> (low, high, shape) of each array `outputs()` returns (the wrapper's spaces)
    reset():        forget everything (a new flight)
    update(readings, time, command=None): one sample; `command` is the last action sent, if known
    outputs():      field -> float64 array, the estimates added to the observation
    status():       {"alarm": bool, "alarm_time": float | None, "isolated": int | None, ...}
    """

    name: str
    output_fields: dict

    def reset(self) -> None: ...

    def update(self, readings: dict, time: float, command: np.ndarray | None = None) -> None: ...

    def outputs(self) -> dict: ...

    def status(self) -> dict: ...


class Biquad:
    """A second-order IIR filter (b, a) run one sample at a time, direct form II transposed, on a scalar or a 1-D
    array of channels; it starts at steady state on its first sample (no start-up transient).

    Per sample: y = b0 x + z0; z0 <- b1 x - a1 y + z1; z1 <- b2 x - a2 y. A scalar runs on Python floats; an array
    in one compiled loop over its channels (`_biquad_channels`, returning a new array); compiled detectors call
    `biquad_step` on `biquad_constants`. Each is the same operations in the same order, so the outputs are
    bit-identical."""

    def __init__(self, b, a):
        a = np.asarray(a, dtype=float)
        self.b, self.a = np.asarray(b, dtype=float) / a[0], a / a[0]
        self._b_float, self._a_float = tuple(self.b.tolist()), tuple(self.a.tolist())
        self.z = None

    def reset(self) -> None:
        self.z = None

    def __call__(self, x):
        if self.z is None:
            self.z = np.multiply.outer(signal.lfilter_zi(self.b, self.a), x)
            if self.z.ndim == 1:                                   # on a float: the state as two floats
                self.z = tuple(self.z.tolist())
        if isinstance(self.z, tuple):
            (b0, b1, b2), (_, a1, a2), (z0, z1) = self._b_float, self._a_float, self.z
            y = b0 * x + z0
            self.z = (b1 * x - a1 * y + z1, b2 * x - a2 * y)
            return y
        return _biquad_channels(self.b, self.a, self.z, x)


@njit(cache=True)
def _biquad_channels(b, a, z, x):  # pragma: no cover (compiled)
    """`Biquad` on the 1-D array of channels x: the outputs as a new array, the state z (2, channels) in place."""
    y = np.empty(x.size)
    for i in range(x.size):
        y[i] = b[0] * x[i] + z[0, i]
        z[0, i] = b[1] * x[i] - a[1] * y[i] + z[1, i]
        z[1, i] = b[2] * x[i] - a[2] * y[i]
    return y


def biquad_constants(b, a) -> np.ndarray:
    """`Biquad(b, a)` for `biquad_step`, one array of 8: b and a (each normalised by a0), then zi =
    scipy.signal.lfilter_zi(b, a), the memory per unit input at steady state."""
    lowpass = Biquad(b, a)
    return np.concatenate((lowpass.b, lowpass.a, signal.lfilter_zi(lowpass.b, lowpass.a)))


@njit(cache=True)
def biquad_step(constants, z, x, first):  # pragma: no cover (compiled)
    """`Biquad` on the channels x from compiled code: the outputs as a new array, the memory z (2, channels) in
    place; on the `first` sample z starts at steady state, zi x, as `Biquad` does."""
    if first:
        for i in range(x.size):              # a loop: numba compiles the array expression zi x ten times slower
            z[0, i] = constants[6] * x[i]
            z[1, i] = constants[7] * x[i]
    return _biquad_channels(constants[:3], constants[3:6], z, x)


@njit(cache=True)
def biquad_scalar(constants, memory, at, x, first):  # pragma: no cover (compiled)
    """`Biquad` on one float from compiled code (`biquad_constants`): the output; its memory memory[at],
    memory[at + 1] in place, started at steady state, zi x, on the `first` sample."""
    if first:
        memory[at], memory[at + 1] = constants[6] * x, constants[7] * x
    y = constants[0] * x + memory[at]
    memory[at] = constants[1] * x - constants[4] * y + memory[at + 1]
    memory[at + 1] = constants[2] * x - constants[5] * y
    return y


class AlarmLatch:
    """The first alarm of a flight: when it came and what it isolated (later alarms do not move it)."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.alarm, self.alarm_time, self.isolated = False, None, None

    def trigger(self, time: float, isolated=None) -> None:
        if not self.alarm:
            self.alarm, self.alarm_time, self.isolated = True, float(time), isolated

    def status(self) -> dict:
        return {"alarm": self.alarm, "alarm_time": self.alarm_time, "isolated": self.isolated}


def model_with_error(params, names, coefficient_error: float = 0.10, error_seed: int | None = None):
    """The detector's copy of a parameter set: `params` with the coefficients `names` multiplied by
    1 + coefficient_error (error_seed None) or by 1 +- coefficient_error with a seeded random sign, since a
    detector must not know the plant exactly. The detector then evaluates the plant's own formulas
    (`ftcgym.models`) on this copy. Returns (scale, params_with_error); scale is keyed by name."""
    if not (np.isfinite(coefficient_error) and -1.0 < coefficient_error < 1.0):
        raise ValueError(f"coefficient_error: must be in (-1, 1), got {coefficient_error!r}")
    rng = None if error_seed is None else np.random.default_rng(error_seed)
    scale = {name: 1.0 + coefficient_error * (1.0 if rng is None else float(rng.choice((-1.0, 1.0))))
             for name in names}
    scaled = {name: _scaled(getattr(params, name), scale[name]) for name in names}
    return scale, dataclasses.replace(params, **scaled)


def _scaled(value, factor: float):
    """A scalar or a tuple of coefficients times `factor`, as plain floats."""
    if np.ndim(value):
        return tuple(float(v) * factor for v in value)
    return float(value) * factor
