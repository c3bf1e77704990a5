"""Tasks: the reference a vehicle should follow (position, velocity, yaw in NED) and where it starts.

- hover: hold a set-point (default 5 m above the origin, yaw 0).
- goto: start at a set-point (as hover), which steps after `step_time` by (`step_north`, `step_east`,
  `step_altitude`) m (default (1, 1, 0) m, right after the start) and is held there: a set-point step, zero
  reference velocity.
- square: 004 Sec. 5.1: from hover, an 8 m x 8 m square at constant altitude (8 m) flown at `speed`
  along the path, plus 004's sinusoidal speed excitation
  v = 0.5 sin(2.51t)cos(3.14t) + 0.5 sin(3.14t)cos(4.19t) + 0.5 sin(4.19t)cos(6.28t),
  optionally turning the heading by 90 deg at each corner (004's second scenario).
- mission (quad-plane): take off at home, hover, transition along the take-off heading (into the
  mean wind; north in calm air), fly `laps` of a circle of `circuit_radius` m through home (centre to the
  right of that heading: clockwise seen from above) at `cruise_airspeed`, back-transition, return to home
  and land. The phases are the autopilot's (`agents.quadplane_autopilot`); the task's own reference is
  home at the mission altitude.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np

from .checks import FINITE, NON_NEGATIVE, POSITIVE, Range, no_unknown, number

# 004 Sec. 5.1 excitation as sums of sines: sin(a t) cos(b t) = (sin((a+b)t) + sin((a-b)t)) / 2.
_EXCITATION_PAIRS = ((2.51, 3.14), (3.14, 4.19), (4.19, 6.28))
_EXCITATION_FREQS = np.array([f for a, b in _EXCITATION_PAIRS for f in (a + b, a - b)])
EXCITATION_PEAK = 0.25 * len(_EXCITATION_FREQS)   # m/s, bound of |excitation_speed|
_sum = np.add.reduce    # np.sum's reduction, without its Python-level dispatch (a microsecond a call)


def excitation_speed(t: float) -> float:
    """004 Sec. 5.1 speed excitation at time t (m/s)."""
    return _excitation(t)[1]


def excitation_distance(t: float) -> float:
    """Integral of `excitation_speed` from 0 to t (m), in closed form."""
    return _excitation(t)[0]


def _excitation(t: float) -> tuple[float, float]:
    """(`excitation_distance`, `excitation_speed`) at t, both from one product of the frequencies and time."""
    angles = _EXCITATION_FREQS * t
    return (float(0.25 * _sum((1.0 - np.cos(angles)) / _EXCITATION_FREQS)), float(0.25 * _sum(np.sin(angles))))


@dataclass(frozen=True)
class Reference:
    position: np.ndarray   # NED m
    velocity: np.ndarray   # NED m/s
    yaw: float             # rad

    @cached_property
    def as_array(self) -> np.ndarray:
        """(position, velocity, yaw) end to end, 7 floats: the observation's reference_* entries (computed once
        per set-point; a task at rest hands out the same set-point at every step)."""
        return np.array([*self.position.tolist(), *self.velocity.tolist(), self.yaw])


def _fixed(north: float, east: float, altitude: float, yaw: float) -> Reference:
    """A set-point at rest, its arrays read-only (a task hands out the same one at every step)."""
    position, velocity = np.array([north, east, -altitude]), np.zeros(3)
    position.flags.writeable = velocity.flags.writeable = False
    return Reference(position, velocity, yaw)


@dataclass(frozen=True)
class HoverTask:
    """Hold `altitude` m above (north, east)."""

    name = "hover"
    altitude: float = 5.0
    north: float = 0.0
    east: float = 0.0
    yaw: float = 0.0

    def reference(self, t: float) -> Reference:
        return self._set_point

    @cached_property
    def _set_point(self) -> Reference:
        return _fixed(self.north, self.east, self.altitude, self.yaw)

    def extent(self) -> dict:
        """The farthest set-point from home (|north| or |east|), the highest altitude and the fastest speed."""
        return {"horizontal": max(abs(self.north), abs(self.east)), "altitude": self.altitude, "speed": 0.0}


@dataclass(frozen=True)
class GotoTask:
    """Start at and hold `altitude` m above (north, east) up to `step_time` s; after it, hold the point
    (`step_north`, `step_east`, `step_altitude`) m away (north, east, up). The env starts the vehicle at the
    set-point of t = 0, the start point even with `step_time` 0 (the default: the step comes right after the
    start, as in the anchor run of Chen et al. 2025)."""

    name = "goto"
    altitude: float = 5.0
    north: float = 0.0
    east: float = 0.0
    yaw: float = 0.0
    step_north: float = 1.0
    step_east: float = 1.0
    step_altitude: float = 0.0
    step_time: float = 0.0

    def __post_init__(self):
        if not self.altitude + self.step_altitude > 0.0:
            raise ValueError(f"task['step_altitude']: the set-point after the step must be above the ground "
                             f"(altitude + step_altitude > 0), got {self.altitude:g} + {self.step_altitude:g}")

    def reference(self, t: float) -> Reference:
        return self._set_points[t > self.step_time]

    @cached_property
    def _set_points(self) -> tuple[Reference, Reference]:
        """(before, after) the step."""
        return (_fixed(self.north, self.east, self.altitude, self.yaw),
                _fixed(self.north + self.step_north, self.east + self.step_east, self.altitude + self.step_altitude,
                       self.yaw))

    def extent(self) -> dict:
        """As `HoverTask.extent`, over both set-points; a step's reference speed is 0."""
        return {"horizontal": max(abs(self.north), abs(self.east), abs(self.north + self.step_north),
                                  abs(self.east + self.step_east)),
                "altitude": max(self.altitude, self.altitude + self.step_altitude), "speed": 0.0}


#: per leg of the square: its direction (north, east) and its first corner in sides (north, east)
_LEG_DIRECTIONS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))
_LEG_CORNERS = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))


@dataclass(frozen=True)
class SquareTask:
    """004 Sec. 5.1 square path after `hold` s of hover at its first corner."""

    name = "square"
    side: float = 8.0
    altitude: float = 8.0
    speed: float = 1.0
    hold: float = 2.0
    excitation: bool = True
    heading_changes: bool = False

    def _distance(self, t: float):
        tau = max(t - self.hold, 0.0)
        s = self.speed * tau
        v = self.speed if t > self.hold else 0.0
        if self.excitation and t > self.hold:
            distance, speed = _excitation(tau)
            s += distance
            v += speed
        return max(s, 0.0), v

    def reference(self, t: float) -> Reference:
        """The point `_distance(t)` m along the square from its first corner, north, east, south, west (clockwise
        seen from above), moving at the path speed along its leg. Scalar arithmetic: this runs at every agent
        step, where numpy's 2-vectors cost more than the sums."""
        s, v = self._distance(t)
        leg, along = divmod(s, self.side)
        leg = int(leg) % 4
        north_step, east_step = _LEG_DIRECTIONS[leg]
        corner_north, corner_east = _LEG_CORNERS[leg]
        north = corner_north * self.side + along * north_step
        east = corner_east * self.side + along * east_step
        yaw = (leg * np.pi / 2) if self.heading_changes else 0.0
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
        return Reference(np.array([north, east, -self.altitude]), np.array([v * north_step, v * east_step, 0.0]), yaw)

    def extent(self) -> dict:
        """As `HoverTask.extent`; the excitation adds at most 1.5 m/s (the sum of its amplitudes)."""
        return {"horizontal": self.side, "altitude": self.altitude,
                "speed": self.speed + (EXCITATION_PEAK if self.excitation else 0.0)}


@dataclass(frozen=True)
class MissionTask:
    """The quad-plane mission (see the module docstring); distances m, speeds m/s, NED."""

    name = "mission"
    altitude: float = 30.0
    cruise_airspeed: float = 18.0
    circuit_radius: float = 150.0
    laps: float = 1.0
    climb_rate: float = 2.0
    descent_rate: float = 1.0
    hover_time: float = 3.0       # s held at altitude before the transition and after the return

    def circuit_centre(self, heading: float) -> np.ndarray:
        """North, east of the circle's centre for a transition along `heading` (rad): to its right."""
        return self.circuit_radius * np.array([-np.sin(heading), np.cos(heading)])

    def reference(self, t: float) -> Reference:
        return self._home

    @cached_property
    def _home(self) -> Reference:
        return _fixed(0.0, 0.0, self.altitude, 0.0)

    def extent(self) -> dict:
        """As `HoverTask.extent`: the circle through home spans two radii from it."""
        return {"horizontal": 2.0 * self.circuit_radius, "altitude": self.altitude,
                "speed": max(self.cruise_airspeed, self.climb_rate, self.descent_rate)}


TASKS = {"hover": HoverTask, "goto": GotoTask, "square": SquareTask, "mission": MissionTask}


def make_task(task) -> HoverTask | GotoTask | SquareTask | MissionTask:
    """A task from its name or a dict `{"name": ..., field: value}`; bad input raises ValueError."""
    if isinstance(task, tuple(TASKS.values())):
        return task
    options = {}
    if isinstance(task, dict):
        options = dict(task)
        task = options.pop("name", None)
    if not isinstance(task, str) or task not in TASKS:
        raise ValueError(f"task: unknown task {task!r}; accepted: {sorted(TASKS)} (or a dict with 'name')")
    cls = TASKS[task]
    accepted = {f.name for f in fields(cls)}
    no_unknown(options, accepted, f"task option of {task!r}")
    for key, value in options.items():
        if isinstance(getattr(cls, key, None), bool):
            if not isinstance(value, bool):
                raise ValueError(f"task[{key!r}]: expected True or False, got {value!r}")
        else:
            options[key] = number(value, f"task[{key!r}]", _TASK_RANGES.get(key, FINITE))
    return cls(**options)


#: accepted values of the task options (others: any finite number)
_TASK_RANGES = {
    **{key: POSITIVE for key in ("altitude", "side", "speed", "cruise_airspeed", "circuit_radius", "laps",
                                 "climb_rate", "descent_rate")},
    "hold": NON_NEGATIVE, "hover_time": NON_NEGATIVE, "step_time": NON_NEGATIVE, "yaw": Range(-np.pi, np.pi),
}
