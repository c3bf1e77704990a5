"""Fault specifications, their validation and their effects over time.

A fault is attached to a channel (a rotor, a sensor, the vehicle's mass), has an onset and ground truth,
in the spirit of safe-control-gym's disturbances. Faults are given to the env as dicts or `FaultSpec`s,
or sampled from the env's seeded RNG with "random:<kind>".

Kinds (quadrotor):
- rotor_loss: propeller ejection (000 Sec. III-A): thrust and drag torque of rotor `target` vanish, its ESC
  still reports a speed and the unloaded motor spins up. magnitude is 1 (total).
- loe: loss of effectiveness of rotor(s) `target` (int or list): a step to `magnitude` (fraction lost), or,
  with `rate` (1/s), a ramp rate*(t - time) capped at `magnitude` (002 Sec. 5.2: 0.1/s capped at 0.5).
- payload: the mass changes by `magnitude` kg linearly over `duration` s (004 Sec. 5.1: +0.5 kg over 2 s).
- sensor_bias / sensor_stuck / sensor_dropout: sensor `target` (an observation key) reads value + magnitude,
  holds its value at onset, or reads zero; for `duration` s or for good.
Kinds (quad-plane; rotor_loss and loe act on its hover rotors):
- pitot_blockage: the pitot reads zero (target "zero", the default) or holds its value ("stuck") from onset;
  with `rate` (m/s^2) it is incipient: the reading drifts down at that rate, floored at zero (001 Sec. 7.2.2:
  2.5 m/s^2).
- gnss, pusher_rpm_sensor: the GNSS velocity / the pusher speed sensor reads zero (001 Sec. 7.3.1, 7.3.2).
- skew_sensor: the skew angle reading holds its value at onset, or with `magnitude` (rad) is biased.
- propeller_icing, viscous_friction, static_friction: the pusher's theta_1, c_v or I_0 (003 eq. 1, 5) grow by
  the factor `magnitude` (default 1.1) along a sigmoid lasting `duration` s (default 50; 003 Sec. IV-A).
Rotor targets are 0-based indices (0 is 000's r1). "random" as a target draws uniformly; a time given as
[lo, hi] draws uniformly from that interval.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .checks import FINITE, POSITIVE, Range, no_unknown, number, numbers

ROTOR_KINDS = ("rotor_loss", "loe")
SENSOR_KINDS = ("sensor_bias", "sensor_stuck", "sensor_dropout")
KINDS = ROTOR_KINDS + ("payload",) + SENSOR_KINDS
#: quad-plane sensor faults with a fixed channel: kind -> (generic sensor fault, observation key)
NAMED_SENSOR_FAULTS = {"gnss": ("sensor_dropout", "gnss_velocity"),
                       "pusher_rpm_sensor": ("sensor_dropout", "pusher_speed"),
                       "skew_sensor": ("sensor_stuck", "skew")}
PITOT_MODES = ("zero", "stuck")
PROPULSION_KINDS = {"propeller_icing": "theta_1", "viscous_friction": "c_v", "static_friction": "I_0"}
QUADPLANE_KINDS = (ROTOR_KINDS + SENSOR_KINDS + ("pitot_blockage",) + tuple(NAMED_SENSOR_FAULTS)
                   + tuple(PROPULSION_KINDS))
RANDOM_ONSET_WINDOW = (2.0, 5.0)  # s, onset window of "random:<kind>" (docs/concepts.md, 'Faults')
_DEFAULT_MAGNITUDE = {"rotor_loss": 1.0, "loe": 0.5, "payload": 0.5, "sensor_bias": 0.1,
                      "sensor_stuck": None, "sensor_dropout": None, "pitot_blockage": None, "gnss": None,
                      "pusher_rpm_sensor": None, "skew_sensor": None,
                      **{kind: 1.1 for kind in PROPULSION_KINDS}}   # 003 Sec. IV-A: x1.1
PROPULSION_RISE_TIME = 50.0   # s, 003 Sec. IV-A
_FIELDS = ("kind", "target", "time", "magnitude", "rate", "duration")
_MAGNITUDE_RANGES = {"loe": Range(0.0, 1.0, open_low=True),        # the fraction of effectiveness lost
                     **{kind: POSITIVE for kind in PROPULSION_KINDS}}   # the parameter's growth factor


@dataclass(frozen=True)
class FaultSpec:
    """One fault. `target` and `time` may be "random" / [lo, hi] until resolved by the env's RNG."""

    kind: str
    target: object = None
    time: object = 0.0
    magnitude: float | None = None
    rate: float | None = None       # 1/s, loe ramp rate; None for a step
    duration: float | None = None   # s, payload ramp length / sensor fault length (None: permanent)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        if isinstance(d["target"], tuple):
            d["target"] = list(d["target"])
        return d


def parse_faults(faults, n_rotors: int, sensors: Mapping[str, int], kinds: Sequence[str] = KINDS) -> list[FaultSpec]:
    """Validate the env's `faults` kwarg into a list of (possibly unresolved) FaultSpecs. `sensors` maps each
    observation key a sensor fault may target to its size; `kinds` are the fault kinds the vehicle accepts
    (KINDS for the quadrotor, QUADPLANE_KINDS for the quad-plane)."""
    if faults is None:
        return []
    if isinstance(faults, (str, dict, FaultSpec)):
        faults = [faults]
    if not isinstance(faults, (list, tuple)):
        raise ValueError(f"faults: expected a list of fault dicts, a FaultSpec or 'random:<kind>', got {faults!r}")
    return [_parse_one(f, i, n_rotors, sensors, tuple(kinds)) for i, f in enumerate(faults)]


def _parse_one(spec, index: int, n_rotors: int, sensors, kinds) -> FaultSpec:
    where = f"faults[{index}]"
    if isinstance(spec, str):
        prefix, _, kind = spec.partition(":")
        if prefix != "random" or kind not in kinds:
            raise ValueError(f"{where}: string specs must be 'random:<kind>' with kind in {list(kinds)}, got {spec!r}")
        target = "random" if kind in ROTOR_KINDS + SENSOR_KINDS else None
        spec = {"kind": kind, "target": target, "time": list(RANDOM_ONSET_WINDOW)}
    if isinstance(spec, FaultSpec):
        spec = spec.to_dict()
    if not isinstance(spec, dict):
        raise ValueError(f"{where}: expected a dict with keys {list(_FIELDS)}, got {type(spec).__name__}")
    no_unknown(spec, _FIELDS, f"{where} key")
    spec = {key: value for key, value in spec.items() if value is not None}   # None: the field's default
    kind = spec.get("kind")
    if not isinstance(kind, str) or kind not in kinds:
        raise ValueError(f"{where}.kind: {kind!r} is not a fault kind of this vehicle; accepted: {list(kinds)}")
    duration = spec.get("duration", PROPULSION_RISE_TIME if kind in PROPULSION_KINDS else None)
    target = _check_target(kind, spec.get("target"), f"{where}.target", n_rotors, sensors)
    size = sensors.get(target, 1) if kind == "sensor_bias" and target != "random" else 1
    return FaultSpec(
        kind=kind,
        target=target,
        time=_check_time(spec.get("time", 0.0), f"{where}.time"),
        magnitude=_check_magnitude(kind, spec.get("magnitude", _DEFAULT_MAGNITUDE[kind]), f"{where}.magnitude",
                                   size),
        rate=_check_positive(spec.get("rate"), f"{where}.rate", kind in ("loe", "pitot_blockage")),
        duration=_check_positive(duration, f"{where}.duration",
                                 kind not in ROTOR_KINDS + ("pitot_blockage",)),
    )


def _check_target(kind, target, where, n_rotors, sensors):
    if kind in ROTOR_KINDS:
        if isinstance(target, str) and target == "random":
            return target
        targets = target if isinstance(target, (list, tuple)) and kind == "loe" else [target]
        ok = all(isinstance(t, (int, np.integer)) and not isinstance(t, bool) and 0 <= t < n_rotors for t in targets)
        if not ok or not targets or len(set(targets)) < len(targets):
            accepted = (f"a rotor index 0..{n_rotors - 1}, 'random'"
                        + (" or a list of distinct indices" if kind == "loe" else ""))
            raise ValueError(f"{where}: {target!r} is not accepted for {kind}; accepted: {accepted}")
        return tuple(int(t) for t in targets) if kind == "loe" else int(target)
    if kind in SENSOR_KINDS:
        if not isinstance(target, str) or target not in (*sensors, "random"):
            raise ValueError(f"{where}: {target!r} is not a sensor; accepted: {[*sensors, 'random']}")
        return target
    if kind == "pitot_blockage":
        if target not in (None,) + PITOT_MODES:
            raise ValueError(f"{where}: {target!r} is not a pitot blockage mode; accepted: {list(PITOT_MODES)}")
        return target or "zero"
    if target is not None:
        raise ValueError(f"{where}: {kind} faults take no target (got {target!r})")
    return None


def _check_time(time, where):
    if isinstance(time, (list, tuple)):
        if len(time) != 2 or not all(_finite(t) for t in time) or not 0 <= time[0] <= time[1]:
            raise ValueError(f"{where}: an interval must be [lo, hi] with 0 <= lo <= hi, got {time!r}")
        return (float(time[0]), float(time[1]))
    if not _finite(time) or time < 0:
        raise ValueError(f"{where}: must be a finite time >= 0 s or an interval [lo, hi], got {time!r}")
    return float(time)


def _check_magnitude(kind, magnitude, where, size: int):
    """The magnitude a kind accepts: none for the kinds without one (skew_sensor: optional), a number or one
    per element of the channel for sensor_bias, exactly 1 for rotor_loss."""
    if magnitude is None:                      # only for the kinds without a default magnitude (_parse_one)
        return None
    if _DEFAULT_MAGNITUDE[kind] is None and kind != "skew_sensor":
        raise ValueError(f"{where}: {kind} takes no magnitude; leave it out (got {magnitude!r})")
    if kind == "sensor_bias" and np.ndim(magnitude) > 0:
        return tuple(numbers(magnitude, where, (size,)).tolist())
    value = number(magnitude, where, _MAGNITUDE_RANGES.get(kind, FINITE))
    if kind == "rotor_loss" and value != 1.0:
        raise ValueError(f"{where}: rotor_loss is a total loss, so its magnitude is 1 (leave it out); "
                         f"for a partial loss use kind 'loe'; got {magnitude!r}")
    return value


def _check_positive(value, where, allowed):
    if value is None:
        return None
    if not allowed:
        raise ValueError(f"{where}: not used by this fault kind; leave it out")
    return number(value, where, POSITIVE)


def _finite(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and bool(np.isfinite(x))


def resolve(specs: list[FaultSpec], rng: np.random.Generator, n_rotors: int,
            sensors: Sequence[str] = ()) -> list[FaultSpec]:
    """Draw every random target (a rotor, or one of `sensors` for a sensor fault) and onset from the env's RNG."""
    out = []
    for s in specs:
        target, time = s.target, s.time
        if target == "random" and s.kind in SENSOR_KINDS:
            target = sensors[int(rng.integers(len(sensors)))]
        elif target == "random":
            target = int(rng.integers(n_rotors))
            if s.kind == "loe":
                target = (target,)
        if isinstance(time, tuple):
            time = float(rng.uniform(*time))
        out.append(dataclasses.replace(s, target=target, time=time))
    return out


class FaultSchedule:
    """The resolved faults of one episode and what they do at time t."""

    def __init__(self, specs: list[FaultSpec], n_rotors: int, limits: Mapping[str, tuple] | None = None):
        """`limits` maps an observation key to its (low, high) bounds: a biased reading saturates there."""
        self.specs = sorted(specs, key=lambda s: s.time)
        self._limits = dict(limits or {})
        self.n_rotors = n_rotors
        self._rotor = [s for s in self.specs if s.kind in ROTOR_KINDS]
        self._payload = [s for s in self.specs if s.kind == "payload"]
        self._sensor = [_as_sensor_fault(s) for s in self.specs if s.kind in SENSOR_KINDS + tuple(NAMED_SENSOR_FAULTS)]
        self._pitot = [s for s in self.specs if s.kind == "pitot_blockage"]
        self._propulsion = [s for s in self.specs if s.kind in PROPULSION_KINDS]
        self.has_propulsion_faults = bool(self._propulsion)
        self.acts_on_sensors = bool(self._sensor)     # else `apply_to_sensors` leaves every reading as it is
        self._stuck: dict[int, np.ndarray] = {}
        self._dicts = [s.to_dict() for s in self.specs]
        ends = [s.time + s.duration for s in self.specs if _ends(s)]
        self._changes = sorted({s.time for s in self.specs} | set(ends))   # times at which info["fault"] changes
        self._current_start, self._current_until = np.inf, -np.inf  # the cached info["fault"] holds in between
        self._rotor_arrays, self._rotor_from, self._rotor_until = (None, None), np.inf, -np.inf   # `rotor_state`

    def rotor_state(self, t: float, effectiveness: np.ndarray, loaded: np.ndarray) -> bool:
        """Write the effectiveness and propeller presence at time t into the given arrays; True if it wrote.

        Called every physics step, so the arrays are written only when the state may have changed: the
        rotor faults are constant between onsets once no loss-of-effectiveness ramp is rising (the arrays
        last written hold their values until the next onset)."""
        if (self._rotor_arrays[0] is effectiveness and self._rotor_arrays[1] is loaded
                and self._rotor_from <= t < self._rotor_until):
            return False
        effectiveness[:] = 1.0
        loaded[:] = True
        rising = False
        for s in self._rotor:
            if t < s.time:
                continue
            if s.kind == "rotor_loss":
                effectiveness[s.target] = 0.0
                loaded[s.target] = False
            else:
                lost = s.magnitude if s.rate is None else min(s.rate * (t - s.time), s.magnitude)
                rising = rising or lost < s.magnitude
                for i in s.target:
                    effectiveness[i] *= 1.0 - lost
        self._rotor_arrays = (effectiveness, loaded)
        self._rotor_from = t
        self._rotor_until = t if rising else min((s.time for s in self._rotor if s.time > t), default=np.inf)
        return True

    def steady_until(self, t: float) -> float:
        """The time until which the rotor, payload and propulsion faults act as they do at t: the next onset, or
        t itself while a loss-of-effectiveness ramp rises, a payload is being added or a propulsion fault acts
        (its factors change at every step). The physics loop applies the faults again only from then on."""
        until = math.inf
        for s in self._rotor + self._payload + self._propulsion:
            if t < s.time:
                until = min(until, s.time)
            elif (s.kind in PROPULSION_KINDS
                  or (s.kind == "payload" and s.duration and t < s.time + s.duration)
                  or (s.kind in ROTOR_KINDS and s.rate is not None and s.rate * (t - s.time) < s.magnitude)):
                return t
        return until

    def added_mass(self, t: float) -> float:
        total = 0.0
        for s in self._payload:
            if t >= s.time:
                ramp = 1.0 if not s.duration else min((t - s.time) / s.duration, 1.0)
                total += s.magnitude * ramp
        return total

    def apply_to_sensors(self, t: float, readings: dict) -> dict:
        """Corrupt the sensor readings in place per the active sensor faults."""
        for i, s in enumerate(self._sensor):
            if t < s.time or (s.duration is not None and t >= s.time + s.duration):
                continue
            value = readings[s.target]
            if s.kind == "sensor_bias":
                low, high = self._limits.get(s.target, (-np.inf, np.inf))
                readings[s.target] = np.minimum(np.maximum(value + np.asarray(s.magnitude), low), high)
            elif s.kind == "sensor_dropout":
                readings[s.target] = np.zeros_like(value)
            else:
                readings[s.target] = self._stuck.setdefault(i, value.copy()).copy()
        return readings

    def apply_to_pitot(self, t: float, reading: float) -> float:
        """The pitot airspeed read at t under the pitot blockages in force."""
        for i, s in enumerate(self._pitot):
            if t < s.time:
                continue
            if s.rate is not None:      # incipient: an offset growing at `rate` (the reading never goes negative)
                reading = max(reading - s.rate * (t - s.time), 0.0)
            elif s.target == "zero":
                reading = 0.0
            else:
                reading = self._stuck.setdefault(("pitot", i), reading)
        return reading

    def propulsion_factors(self, t: float) -> dict:
        """Factors on the pusher's theta_1, c_v and I_0 at t: 1 + (magnitude - 1) * a sigmoid rising over
        `duration` s from onset (003 Sec. IV-A, Fig. 6: 10% over 50 s)."""
        factors = {name: 1.0 for name in PROPULSION_KINDS.values()}
        for s in self._propulsion:
            if t >= s.time:
                x = (t - s.time) / s.duration            # 0..1 over the rise
                rise = 1.0 / (1.0 + math.exp(-12.0 * (x - 0.5)))   # ~0.0025 at onset, ~0.9975 at the end
                factors[PROPULSION_KINDS[s.kind]] *= 1.0 + (s.magnitude - 1.0) * rise
        return factors

    def current(self, t: float) -> dict:
        """info["fault"]: the latest fault acting at t (active); else the latest that has ended (inactive, with
        its onset); else the next scheduled one (inactive, onset None); a fresh dict."""
        if not self._current_start <= t < self._current_until:
            index = bisect.bisect_right(self._changes, t)
            self._current_start = self._changes[index - 1] if index else -np.inf
            self._current_until = self._changes[index] if index < len(self._changes) else np.inf
            self._current = self._describe(t)
        return dict(self._current)

    def _describe(self, t: float) -> dict:
        started = [s for s in self.specs if s.time <= t]
        acting = [s for s in started if not _ended(s, t)]
        if started:
            s = (acting or started)[-1]
            return {"active": bool(acting), "kind": s.kind, "target": _public(s.target), "onset_time": s.time,
                    "magnitude": _public(s.magnitude)}
        if self.specs:
            s = self.specs[0]
            return {"active": False, "kind": s.kind, "target": _public(s.target), "onset_time": None,
                    "magnitude": _public(s.magnitude)}
        return {"active": False, "kind": None, "target": None, "onset_time": None, "magnitude": None}

    def as_dicts(self) -> list[dict]:
        """info["faults"]: the resolved schedule (fresh dicts)."""
        return [dict(d) for d in self._dicts]


def _ends(spec: FaultSpec) -> bool:
    """A sensor fault with a duration ends (a payload's duration is its ramp: it stays)."""
    return spec.duration is not None and spec.kind in SENSOR_KINDS + tuple(NAMED_SENSOR_FAULTS)


def _ended(spec: FaultSpec, t: float) -> bool:
    return _ends(spec) and t >= spec.time + spec.duration


def _as_sensor_fault(spec: FaultSpec) -> FaultSpec:
    """A named quad-plane sensor fault as the generic sensor fault on its channel (skew_sensor with a
    magnitude is a bias, without one it sticks)."""
    if spec.kind not in NAMED_SENSOR_FAULTS:
        return spec
    kind, target = NAMED_SENSOR_FAULTS[spec.kind]
    if spec.kind == "skew_sensor" and spec.magnitude is not None:
        kind = "sensor_bias"
    return dataclasses.replace(spec, kind=kind, target=target)


def _public(value):
    """A JSON-friendly value (a single-rotor tuple reads as its index)."""
    if isinstance(value, tuple):
        return value[0] if len(value) == 1 else list(value)
    return value
