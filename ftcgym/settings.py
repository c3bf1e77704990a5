"""Settings as data: a detector's or controller's parameters are a frozen dataclass with documented fields, and
keyword arguments (from Python, a sweep config or `--detector-kwargs` JSON) update it field by field."""
from __future__ import annotations

import dataclasses


def updated(settings, overrides: dict | None, where: str):
    """`settings` (a dataclass instance) with `overrides` applied. A field holding a dataclass or a NamedTuple
    takes a dict of its fields or a list in field order. An unknown field is a ValueError naming it and the
    accepted ones."""
    if not overrides:
        return settings
    fields = [f.name for f in dataclasses.fields(settings)]
    unknown = sorted(set(overrides) - set(fields), key=str)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; accepted: {fields}")
    return dataclasses.replace(settings, **{name: _converted(getattr(settings, name), value, f"{where}.{name}")
                                            for name, value in overrides.items()})


def _converted(current, value, where: str):
    """`value` in the type of the field's current value when that is a dataclass or a NamedTuple."""
    if dataclasses.is_dataclass(current) and isinstance(value, dict):
        return updated(current, value, where)
    if hasattr(current, "_fields") and isinstance(value, (dict, list, tuple)) and not isinstance(value, type(current)):
        names = current._fields
        if isinstance(value, dict):
            unknown = sorted(set(value) - set(names), key=str)
            if unknown:
                raise ValueError(f"{where}: unknown field(s) {unknown}; accepted: {list(names)}")
            return current._replace(**value)
        if len(value) != len(names):
            raise ValueError(f"{where}: expected {len(names)} values {list(names)}, got {list(value)!r}")
        return type(current)(*value)
    return value
