"""Settings as data: a detector's or controller's parameters are a frozen dataclass with documented fields, and
keyword arguments (from Python, a sweep config or `--detector-kwargs` JSON) update it field by field.

An override is checked against the field's default: a number for a number (an integer for an integer; finite unless
the default is infinite; inside the field's `accepts` range when it declares one), true or false for a flag, text
for text, as many numbers as the default has for a tuple of numbers (any number of them where the field says
`any_length`). None is taken where the field's annotation admits it (`float | None`); a field whose default is
None takes what the detector itself checks."""
from __future__ import annotations

import dataclasses
import math

import numpy as np


def accepts(accepted, **metadata) -> dict:
    """Field metadata: the range a numeric setting (or each number of a tuple) must lie in, a
    `ftcgym.models.checks.Range` (given, not imported: settings and models are both the bottom floor)."""
    return {"accepts": accepted, **metadata}


def updated(settings, overrides: dict | None, where: str):
    """`settings` (a dataclass instance) with `overrides` applied and checked (module docstring). A field holding
    a dataclass or a NamedTuple takes a dict of its fields or a list in field order. An unknown field, or a value
    the field does not take, is a ValueError naming it and what is accepted."""
    if not overrides:
        return settings
    fields = {f.name: f for f in dataclasses.fields(settings)}
    unknown = sorted(set(overrides) - set(fields), key=str)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; accepted: {list(fields)}")
    return dataclasses.replace(settings, **{
        name: None if value is None and _optional(fields[name]) else
        _converted(_kind_of(getattr(settings, name), fields[name]), value, f"{where}.{name}", fields[name].metadata)
        for name, value in overrides.items()})


def _optional(field: dataclasses.Field) -> bool:
    """Whether the field's annotation admits None (`float | None`)."""
    return "None" in str(field.type)


def _kind_of(current, field: dataclasses.Field):
    """What an override is checked against: the current value, or for a number that is None by default
    (`float | None`, `int | None`) a number of that kind."""
    if current is None:
        annotation = str(field.type).replace(" ", "")
        return {"float|None": 0.0, "int|None": 0}.get(annotation)
    return current


def _converted(current, value, where: str, metadata=None):
    """`value` checked against, and in the type of, the field's current value."""
    metadata = metadata or {}
    if dataclasses.is_dataclass(current) and isinstance(value, dict):
        return updated(current, value, where)
    if hasattr(current, "_fields") and isinstance(value, (dict, list, tuple)) and not isinstance(value, type(current)):
        names = current._fields
        if isinstance(value, dict):
            unknown = sorted(set(value) - set(names), key=str)
            if unknown:
                raise ValueError(f"{where}: unknown field(s) {unknown}; accepted: {list(names)}")
            value = current._replace(**value)
        elif len(value) != len(names):
            raise ValueError(f"{where}: expected {len(names)} values {list(names)}, got {list(value)!r}")
        return type(current)(*(_converted(getattr(current, name), item, f"{where}.{name}")
                               for name, item in zip(names, value)))
    if isinstance(current, bool):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{where}: expected true or false, got {value!r}")
        return bool(value)
    if isinstance(current, (int, float)):
        return _number(current, value, where, metadata.get("accepts"))
    if isinstance(current, str):
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected text such as {current!r}, got {value!r}")
        return value
    if isinstance(current, tuple) and current and all(isinstance(c, (int, float)) for c in current):
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__"):
            raise ValueError(f"{where}: expected {len(current)} numbers like {list(current)}, got {value!r}")
        if len(value) != len(current) and not metadata.get("any_length"):
            raise ValueError(f"{where}: expected {len(current)} numbers like {list(current)}, got {len(value)}: "
                             f"{list(value)!r}")
        if len(value) == 0:
            raise ValueError(f"{where}: expected at least one number, got {value!r}")
        return tuple(_number(current[min(i, len(current) - 1)], item, f"{where}[{i}]", metadata.get("accepts"))
                     for i, item in enumerate(value))
    return value


def _number(current, value, where: str, accepted):
    """`value` as the kind of number `current` is: real, not NaN, finite unless `current` is infinite, in
    `accepted`."""
    within = f" {accepted}" if accepted else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{where}: expected a number{within}, got {type(value).__name__} {value!r}")
    value = float(value)
    if math.isnan(value) or (math.isinf(value) and math.isfinite(current)):
        raise ValueError(f"{where}: must be finite (no NaN or inf), got {value!r}")
    if accepted is not None and not accepted.holds(np.asarray(value)):
        raise ValueError(f"{where}: must be {accepted}, got {value!r}")
    if isinstance(current, int) and not isinstance(current, bool):
        if value != int(value):
            raise ValueError(f"{where}: expected an integer{within}, got {value!r}")
        return int(value)
    return value
