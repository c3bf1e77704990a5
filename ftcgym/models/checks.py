"""Checks of what a user passes (make keywords, reset options, parameter overrides, fault specs, sensor and
wind settings): types, finiteness, ranges and shapes.

Every failure is a ValueError whose message names the field, the value given and what is accepted, raised
at `gym.make` or `reset`, never later in the physics. The ranges of the parameter sets live beside them
(`quadrotor.QUADROTOR_RANGES`, `vsqp.VSQP_RANGES`).
"""
from __future__ import annotations

import difflib
import functools
import inspect
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Range:
    """An interval of accepted values; `open_low` / `open_high` exclude the end."""

    low: float = -math.inf
    high: float = math.inf
    open_low: bool = False
    open_high: bool = False

    def holds(self, values: np.ndarray) -> bool:
        above = values > self.low if self.open_low else values >= self.low
        below = values < self.high if self.open_high else values <= self.high
        return bool(np.all(above & below))

    def __str__(self) -> str:
        if self.high == math.inf:
            return "any finite number" if self.low == -math.inf else f"{'>' if self.open_low else '>='} {self.low:g}"
        left, right = "(" if self.open_low else "[", ")" if self.open_high else "]"
        return f"in {left}{self.low:g}, {self.high:g}{right}"


FINITE = Range()
POSITIVE = Range(0.0, open_low=True)
NON_NEGATIVE = Range(0.0)
FRACTION = Range(0.0, 1.0)


def no_unknown(given, accepted, what: str) -> None:
    """ValueError if `given` (names) holds any not in `accepted`, with the closest accepted name and the list."""
    unknown = sorted(set(given) - set(accepted), key=str)
    if unknown:
        close = difflib.get_close_matches(str(unknown[0]), [str(name) for name in accepted], n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"{what}: unknown {unknown}{hint}; accepted: {sorted(accepted, key=str)}")


def keywords_checked(init):
    """An env's `__init__` whose misspelt keyword is a ValueError naming the closest accepted one (as
    `gym.make keyword: unknown [...]`), not Python's TypeError."""
    accepted = [name for name in inspect.signature(init).parameters if name != "self"]

    @functools.wraps(init)
    def checked(self, **kwargs):
        no_unknown(kwargs, accepted, "gym.make keyword")
        init(self, **kwargs)
    return checked


def number(value, field: str, accepted: Range = FINITE) -> float:
    """`value` as a float: a real number (not a bool, string or complex), finite and in `accepted`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{field}: expected a number {accepted}, got {type(value).__name__} {value!r}")
    return float(numbers(value, field, (), accepted))


def whole_number(value, field: str, low: int = 1) -> int:
    """`value` as an int >= `low`: a whole number (an int, or a float without a fraction), not a bool."""
    value_ = number(value, field, Range(low))
    if value_ != int(value_):
        raise ValueError(f"{field}: expected a whole number >= {low}, got {value!r}")
    return int(value_)


def numbers(value, field: str, shape: tuple | None = None, accepted: Range = FINITE) -> np.ndarray:
    """`value` as a float64 array of `shape` (any shape if None): real numbers, finite and in `accepted`."""
    arr = real_array(value, field, f"{_what(shape)} {accepted}")
    if arr.size == 0 and shape is None:
        raise ValueError(f"{field}: expected {_what(shape)} {accepted}, got {value!r}")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{field}: expected {_what(shape)}, got shape {arr.shape} ({value!r})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{field}: must be finite (no NaN or inf), got {value!r}")
    if not accepted.holds(arr):
        raise ValueError(f"{field}: must be {accepted}, got {value!r}")
    return arr


def real_array(value, field: str, what: str) -> np.ndarray:
    """`value` as a float64 array of any shape; anything but real numbers (strings, bools, complex numbers, None,
    ragged nesting) raises ValueError naming `field` and `what` it should be."""
    try:
        arr = np.asarray(value)
    except ValueError:                       # ragged nesting
        arr = np.asarray(None)
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{field}: expected {what}, got {value!r}")
    return arr.astype(np.float64)


def _what(shape) -> str:
    if shape is None:
        return "a number or a list of numbers"
    return "a number" if shape == () else f"{'x'.join(map(str, shape))} numbers"
