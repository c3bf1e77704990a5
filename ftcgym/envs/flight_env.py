"""What the quadrotor and the quad-plane envs share: rates and arguments, the PyBullet world, the physics
step's integration and IMU specific force, crash detection, rendering."""
from __future__ import annotations

import math
import os
import socket
import sys
import warnings

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..models.checks import POSITIVE, Range, no_unknown, number, real_array
from ..models.compiled import without_dispatch
from ..models.constants import GRAVITY
from ..models.quadrotor import SCALE_LIMIT
from ..models.tasks import make_task
from ..models.wind import MEAN, DrydenWind
from .frames import RAW_EXAMPLE, body_state, step_state
from .world import PyBulletWorld

RENDER_SIZE = (480, 360)     # pixels, width x height of an rgb_array frame
MAX_RENDER_SIDE = 4096


class FaultAfterEndWarning(UserWarning):
    """A fault's onset is at or after the episode's end: it may never act."""


class StepAfterEndWarning(UserWarning):
    """`step` after the episode ended (terminated or truncated) without a `reset`: the simulation goes on, and a
    crashed vehicle earns the crash penalty again at every step."""


PHYSICS_HZ = Range(50.0, 20_000.0)   # Hz: coarser steps miss the motor lag, finer ones add cost, not accuracy


class FlightEnv(gym.Env):
    """Base class. Subclasses set the class constants, call `_setup` first in `__init__`, and implement
    `_make_params(vehicle, overrides)`, `_parse_faults(faults)`, `_build_vehicle()` (the parts made from
    `self.params`; it sets `_bullet_loads`, `_run_physics`'s compiled call), `_loads_arguments()`, `_observe()`,
    `_truth()` (`info["truth"]`) and `_apply_faults()` (the faults in force from `self.time` on); `reset` starts with
    `_begin_episode(seed, options)`.

    `reset(options=...)` takes `faults`, `wind` and `vehicle_overrides` for one episode (RESET_OPTIONS): each
    is validated as the `gym.make` keyword of the same name and stands in for it until the next reset; a reset
    without options flies the make-time configuration again.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 30}
    RESET_OPTIONS = ("faults", "wind", "vehicle_overrides")
    TASKS = ("hover", "goto", "square", "mission")    # the tasks a vehicle flies (`tasks.TASKS` names)
    BOUNDS = 100.0        # m, half-width of the flight box
    PHYSICS_HZ = PHYSICS_HZ   # the physics rates the vehicle's model stays stable and accurate at
    CEILING = 100.0       # m
    MAX_SPEED = 100.0     # m/s, observation bound on velocities
    CRASH_SPEED = 2.0     # m/s, ground contact faster than this is an impact
    CRASH_TILT = np.deg2rad(60.0)   # rad, ground contact more tilted than this is a crash
    WIND_AIRSPEED = MEAN  # the Dryden filters' V_a when `wind` names none (models.wind): the mean wind's speed

    def _setup(self, vehicle, vehicle_overrides, wind, faults, task, max_episode_seconds, physics_hz, agent_hz,
               render_mode, render_size=RENDER_SIZE, unknown: dict | None = None, info_level: str = "full",
               observation_format: str = "dict") -> None:
        """Validate the shared keyword arguments and build the task, wind and faults (`_open_world` follows,
        once the subclass has validated the rest, so a failed make holds no PyBullet client)."""
        self.world, self._ended, self._warned_after_end = None, False, False
        no_unknown(unknown or {}, KEYWORDS, "gym.make keyword")
        self.vehicle = vehicle
        self.params = self._configured_params = self._make_params(vehicle, vehicle_overrides)
        self.physics_hz, self.agent_hz = check_rates(physics_hz, agent_hz, self.PHYSICS_HZ)
        self.substeps = int(round(self.physics_hz / self.agent_hz))
        self.dt = 1.0 / self.physics_hz
        self._step_state = without_dispatch(step_state, RAW_EXAMPLE, RAW_EXAMPLE, self.dt, GRAVITY)
        self.max_episode_seconds = number(max_episode_seconds, "max_episode_seconds", POSITIVE)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode: {render_mode!r}; accepted: None, {self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.render_size = check_render_size(render_size)
        if info_level not in INFO_LEVELS:
            raise ValueError(f"info_level: {info_level!r}; accepted: {list(INFO_LEVELS)}")
        self.info_level = info_level
        if observation_format not in OBSERVATION_FORMATS:
            raise ValueError(f"observation_format: {observation_format!r}; accepted: {list(OBSERVATION_FORMATS)}")
        self.observation_format = observation_format
        # gymnasium's RecordVideo films one frame per step at render_fps: the agent rate makes it real time
        self.metadata = {**self.metadata, "render_fps": _whole(self.agent_hz)}
        self.task = self._check_task(make_task(task))
        self.wind = self._configured_wind = DrydenWind.from_config(wind, self.dt, self.WIND_AIRSPEED)
        self.fault_specs = self._configured_faults = self._parse_faults(faults)
        self._check_faults(self.params, self.fault_specs)

    def _set_observation_space(self, space) -> None:
        """The Dict of readings (`dict_observation_space`), and `observation_space`: that Dict, or at
        observation_format "flat" one Box of its entries end to end in its (sorted) key order, as
        `gymnasium.spaces.flatten` lays them out (`gymnasium.spaces.unflatten` gives the Dict back)."""
        self.dict_observation_space = space
        self._observation_keys = tuple(space.spaces)
        self.observation_space = space if self.observation_format == "dict" else spaces.flatten_space(space)

    def _observation(self):
        """The observation now, in `observation_format`."""
        return self._format(self._observe())

    def _format(self, readings: dict):
        """An observation in `observation_format`."""
        if self.observation_format == "dict":
            return readings
        return np.concatenate([readings[key] for key in self._observation_keys])

    def _open_world(self) -> None:
        """Connect the PyBullet client (the last step of `__init__`). A window needs a display: without one
        PyBullet ends the process, so that is checked first and raised as an exception."""
        if self.render_mode == "human":
            check_display()
        self.world = PyBulletWorld(self.physics_hz, self.params.mass, self.params.inertia, self.params.body_size,
                                   gui=self.render_mode == "human")
        self._size_body()

    def _check_task(self, task):
        """A task this vehicle flies, whose set-points lie inside the flight box and the observation bounds."""
        if task.name not in self.TASKS:
            raise ValueError(f"task: {type(self).__name__} does not fly {task.name!r}; accepted: {list(self.TASKS)}")
        extent = task.extent()
        limits = {"horizontal": self.BOUNDS, "altitude": self.CEILING, "speed": self.MAX_SPEED}
        for key, value in extent.items():
            if not value <= limits[key]:
                raise ValueError(f"task: its {key} reaches {value:g}, beyond this env's limit {limits[key]:g} "
                                 f"({type(task).__name__}; the flight box is |north|, |east| <= {self.BOUNDS:g} m, "
                                 f"altitude <= {self.CEILING:g} m)")
        return task

    def _check_faults(self, params, specs) -> None:
        """The payloads (a drop is negative) must keep the mass above zero and within SCALE_LIMIT times the
        vehicle's at every time. A fault that may begin
        at or after the episode's end is legal (a run cut short on purpose) but warned about: it would not act."""
        for index, spec in enumerate(specs):
            latest = max(spec.time) if isinstance(spec.time, tuple) else spec.time
            if latest >= self.max_episode_seconds:
                warnings.warn(f"faults[{index}].time: {spec.time!r} s is not before the episode's end "
                              f"(max_episode_seconds = {self.max_episode_seconds:g}); the fault may not act",
                              FaultAfterEndWarning, stacklevel=4)
        payloads = [s.magnitude for s in specs if s.kind == "payload"]
        lightest = params.mass + sum(min(m, 0.0) for m in payloads)
        heaviest = params.mass + sum(max(m, 0.0) for m in payloads)
        if lightest <= 0.0 or heaviest > SCALE_LIMIT * params.mass:
            raise ValueError(f"faults: the payloads take the mass to {lightest if lightest <= 0.0 else heaviest:g} kg "
                             f"(vehicle {params.mass:g} kg); accepted: payloads that keep the mass above 0 and at most "
                             f"{SCALE_LIMIT:g} times the vehicle's")

    def _begin_episode(self, seed, options) -> None:
        """`gym.Env.reset`'s seeding, then this episode's parameters, wind and faults (class docstring)."""
        self._check_open("reset")
        super().reset(seed=seed)
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset options: expected a dict with keys {list(self.RESET_OPTIONS)}, got {options!r}")
        options = dict(options or {})
        no_unknown(options, self.RESET_OPTIONS, "reset options key")
        try:   # all checked before any is installed: a refused reset leaves the env as it was
            params = (self._make_params(self.vehicle, options["vehicle_overrides"]) if "vehicle_overrides" in options
                      else self._configured_params)
            wind = (DrydenWind.from_config(options["wind"], self.dt, self.WIND_AIRSPEED) if "wind" in options
                    else self._configured_wind)
            fault_specs = self._parse_faults(options["faults"]) if "faults" in options else self._configured_faults
            self._check_faults(params, fault_specs)
        except ValueError as error:
            raise ValueError(f"reset options: {error}") from None
        if params is not self.params:
            self._check_space_bounds(params)
        self.wind, self.fault_specs = wind, fault_specs
        if params is not self.params:
            self.params = params
            self._build_vehicle()
            self._size_body()

    def _size_body(self) -> None:
        """The rigid body and the ground-contact check of `self.params` (the world builds the body at reset)."""
        look = self._make_look() if self.render_mode is not None else None   # visuals only where drawn
        self.world.set_body(self.params.mass, self.params.inertia, self.params.body_size, look)
        # Below this altitude the body may touch the ground: 1.5 x half its diagonal (contacts are queried only here).
        self._ground_check_altitude = 0.75 * float(np.linalg.norm(self.params.body_size))

    def _check_space_bounds(self, params) -> None:
        """Per-episode vehicle overrides must keep the observations inside the space fixed at `gym.make`."""
        space = self._make_observation_space(params)
        for key, box in space.spaces.items():
            fixed = self.dict_observation_space[key]
            if np.any(box.high > fixed.high) or np.any(box.low < fixed.low):
                raise ValueError(f"reset options: vehicle_overrides widen the bounds of observation {key!r} beyond "
                                 f"the space fixed at gym.make; pass these overrides to gym.make instead")

    def _start(self, position, attitude) -> None:
        """Place the body at rest and reset the clock (reset's first step)."""
        self.time, self._physics_steps = 0.0, 0
        self._ended = self._warned_after_end = False   # `step` after the end warns once per episode
        self._faults_steady_until = -math.inf     # the faults are applied at the first physics step
        self.world.reset(position, attitude, np.zeros(3), np.zeros(3))
        self._crashed, self._termination = False, None

    def _advance(self):
        """Run the physics substeps of one agent step; (observation, terminated, truncated)."""
        self._check_open("step")
        if self._ended:
            self._warn_after_end()
        self._run_physics(self.substeps)
        self._set_state()
        obs = self._observation()
        self._check_crash()
        terminated = self._crashed
        truncated = not terminated and self.time >= self.max_episode_seconds - 1e-9
        self._ended = terminated or truncated
        if self.render_mode == "human":
            self.render()
        return obs, terminated, truncated

    def _warn_after_end(self) -> None:
        """`StepAfterEndWarning`, once per episode (off the step's hot path)."""
        if not self._warned_after_end:
            self._warned_after_end = True
            warnings.warn("step() after the episode ended (terminated or truncated): call reset() first; the "
                          "simulation goes on, a crash's penalty repeats", StepAfterEndWarning, stacklevel=4)

    def _run_physics(self, steps: int) -> None:
        """`steps` physics steps: per step the wind, the vehicle's compiled loads on the state as PyBullet gives it
        (`_bullet_loads(*_loads_arguments(), state, wind, rotor angles)`: force and torque in PyBullet's world
        frame, then what the vehicle keeps of them, `_keep_loads`), PyBullet's step, then the faults of the new
        time (`_apply_faults`) where they change.

        The state stays in PyBullet's form here (`_raw`, `PyBulletWorld.read_raw`), and the loop's objects in
        local names: this loop is most of the step at 240 Hz physics and 30 Hz control. `_set_state` converts
        the state once per agent step."""
        loads, arguments, angles = self._bullet_loads, self._loads_arguments(), self.sensors.rotor_angles
        world, wind, rate = self.world, self.wind, self.physics_hz
        raw, count, steady_until = self._raw, self._physics_steps, self._faults_steady_until
        if wind.follows_vehicle:           # the turbulence's V_a: the vehicle's speed through the mean wind
            wind.follow(self._v, steps)
        for _ in range(steps):
            air = wind.advance()
            out = loads(*arguments, raw, air, angles)
            raw_before, raw = raw, world.advance(out[0], out[1], raw[0])
            count += 1
            time = count / rate            # counted, so it never drifts
            if time >= steady_until:       # else the faults act as at the last step (`FaultSchedule.steady_until`)
                self._physics_steps, self.time = count, time      # what `_apply_faults` reads
                self._apply_faults()
                steady_until = self._faults.steady_until(time)
        self._physics_steps, self.time = count, time
        self._raw, self._raw_before, self._wind = raw, raw_before, air
        self._faults_steady_until = steady_until
        self._keep_loads(out)

    def _keep_loads(self, loads: tuple) -> None:
        """What the vehicle keeps of the last physics step's compiled loads (nothing by default)."""

    def _set_state(self) -> None:
        """The state after the last physics step in NED / FRD as plain floats: `_p`, `_v`, `_q`, `_Rm`
        (row-major), `_w` (body rates), `_vb` (the velocity before that step) and `_sf`, the IMU's specific force
        over it (`frames.step_state`); `_pos`, `_vel`, ... give them as arrays."""
        (self._p, self._q, self._Rm, self._v, self._w, self._vb,
         self._sf) = self._step_state(self._raw, self._raw_before, self.dt, GRAVITY)

    def _read_state(self) -> None:
        """Read the body's state from the world (`_raw`) and set it in NED / FRD as `_set_state` does."""
        self._raw = self.world.read_raw()
        self._p, self._q, self._Rm, self._v, self._w = body_state(self._raw)

    def _at_rest_readings(self) -> None:
        """Velocity history and specific force of a body at rest (reset's last step)."""
        self._read_state()
        self._raw_before, self._vb = self._raw, self._v
        R, g = self._Rm, -GRAVITY
        self._sf = (R[0] * -0.0 + R[3] * -0.0 + R[6] * g, R[1] * -0.0 + R[4] * -0.0 + R[7] * g,
                    R[2] * -0.0 + R[5] * -0.0 + R[8] * g)

    # The state as fresh arrays, for the code that works per agent step (observations, info, rendering).
    _pos = property(lambda self: np.array(self._p))
    _vel = property(lambda self: np.array(self._v))
    _quat = property(lambda self: np.array(self._q))
    _rates = property(lambda self: np.array(self._w))
    _R = property(lambda self: np.array(self._Rm).reshape(3, 3))
    _specific_force = property(lambda self: np.array(self._sf))
    _v_before = property(lambda self: np.array(self._vb))

    def _check_crash(self) -> None:
        """Crashed: out of the flight box, or touching the ground too fast or too tilted."""
        x, y, z = self._p
        altitude = -z
        if abs(x) > self.BOUNDS or abs(y) > self.BOUNDS or altitude > self.CEILING:
            self._crashed, self._termination = True, "out_of_bounds"
        elif altitude < self._ground_check_altitude and self.world.touching_ground():
            a, v = self._vb, self._v
            impact = math.sqrt(max(a[0] * a[0] + a[1] * a[1] + a[2] * a[2], v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
            if impact > self.CRASH_SPEED or self._tilt() > self.CRASH_TILT:
                self._crashed, self._termination = True, "ground_impact"

    def _tilt(self) -> float:
        """Angle between the body -z axis and up (scalar math: numpy's clip and arccos of one float cost ~4 us)."""
        return math.acos(min(max(self._Rm[8], -1.0), 1.0))

    def _with_reference(self, readings: dict) -> dict:
        """The readings plus the task's set-point now (observation keys reference_*)."""
        ref = self._reference = self.task.reference(self.time)
        readings["reference_position"] = ref.position.copy()
        readings["reference_velocity"] = ref.velocity.copy()
        readings["reference_yaw"] = np.array([ref.yaw])
        return readings

    def _info(self) -> dict:
        """A fresh info dict (docs/concepts.md, 'The info contract'); `truth` (`_truth`) only at info_level "full",
        empty at "none"."""
        if self.info_level == "none":
            return {}
        info = {"time": self.time, "fault": self._faults.current(self.time), "faults": self._faults.as_dicts()}
        if self.info_level == "full":
            info["truth"] = self._truth()
        info.update(self._outcome())
        return info

    def _outcome(self) -> dict:
        """The `info` entries every env reports after `truth`: the task's reference and the crash state."""
        ref = self._reference
        return {"reference": {"position": ref.position.copy(), "velocity": ref.velocity.copy(), "yaw": ref.yaw},
                "crashed": self._crashed, "termination": self._termination}

    def render(self):
        """`rgb_array`: the chase camera's frame (`render_size`), the vehicle drawn with its rotors coloured by
        state (`envs.visuals`); `human`: the GUI's look brought up to date (`step` calls this)."""
        if self.render_mode is None:
            return None
        self._check_open("render")
        self.world.show(*self._look_state())   # rotor colours and wing skew change only when a frame is drawn
        if self.render_mode == "rgb_array":
            return self.world.camera_image(self._p, *self.render_size)
        return None

    def _make_look(self):
        """The vehicle's `envs.visuals` look for `self.params` (subclasses)."""
        return None

    def _look_state(self) -> tuple:
        """(rotors, skew) that `PyBulletWorld.show` draws (subclasses)."""
        return None, 0.0

    def close(self):
        if getattr(self, "world", None) is not None:
            self.world.close()
            self.world = None

    def _check_open(self, call: str) -> None:
        if self.world is None:
            raise RuntimeError(f"{call}: this env is closed (its PyBullet client is released); make a new one")


def check_action(action, low, high, what: str) -> np.ndarray:
    """`action` as float64 clipped to [low, high]; a wrong type or shape or a non-finite value raises ValueError."""
    if type(action) is np.ndarray and action.dtype.kind == "f" and action.shape == low.shape:
        a = action.astype(np.float64)       # the common case: a float array of the right shape
    else:
        a = real_array(action, "action", f"real numbers, {what}")
    if a.shape != np.shape(low):
        raise ValueError(f"action: expected shape {np.shape(low)}: {what}; got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"action: must be finite (no NaN or inf), got {a.tolist()}")
    return np.minimum(np.maximum(a, low), high)


def check_command(action, size: int, low: float, high: float, what: str) -> list:
    """`check_action` for `size` commands sharing the bounds [low, high], as a list of floats (the physics
    step's form): the same values, without numpy on the common path (a float array of the right shape)."""
    if type(action) is np.ndarray and action.dtype.kind == "f" and action.shape == (size,):
        values = action.tolist()
        if math.isfinite(sum(values)):     # else the full check below names what is wrong
            return [min(max(v, low), high) for v in values]
    return check_action(action, np.full(size, low), np.full(size, high), what).tolist()


#: the keyword arguments of the simulator envs (`gym.make`)
KEYWORDS = ("vehicle", "vehicle_overrides", "wind", "faults", "task", "max_episode_seconds", "physics_hz", "agent_hz",
            "sensors", "render_mode", "render_size", "info_level", "observation_format")
#: `info_level`: "full" (the info contract, docs/concepts.md), "minimal" (no `truth`: for training loops that
#: never read it; the benchmark and the training tasks, whose rewards read the truth, keep "full") or "none"
#: (an empty dict: the cheapest for vector envs, which merge every key of every env's info at every step)
INFO_LEVELS = ("full", "minimal", "none")
#: `observation_format`: "dict" (the readings by name: what the policies and detectors of ftcgym read) or
#: "flat" (one float64 array, `FlightEnv._set_observation_space`: for learning code and vector envs)
OBSERVATION_FORMATS = ("dict", "flat")
def check_render_size(size) -> tuple[int, int]:
    """(width, height) in pixels: two whole numbers in [16, MAX_RENDER_SIDE]."""
    try:
        width, height = size
        ok = all(float(v).is_integer() and 16 <= v <= MAX_RENDER_SIDE for v in (width, height))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"render_size: expected (width, height), whole numbers of pixels in [16, "
                         f"{MAX_RENDER_SIDE}], got {size!r}")
    return int(width), int(height)


def _whole(rate: float):
    """A rate as an int when it is a whole number (gymnasium's render_fps is an int by convention)."""
    return int(rate) if float(rate).is_integer() else float(rate)


MAX_SUBSTEPS = 1000           # physics steps per agent step


def check_rates(physics_hz, agent_hz, accepted: Range = PHYSICS_HZ) -> tuple[float, float]:
    """The physics and agent rates: physics_hz within `accepted` (the env's own range), and physics_hz / agent_hz a
    whole number of substeps."""
    physics_hz = number(physics_hz, "physics_hz", accepted)
    agent_hz = number(agent_hz, "agent_hz", POSITIVE)
    ratio = physics_hz / agent_hz
    if abs(ratio - round(ratio)) > 1e-9 or not 1 <= round(ratio) <= MAX_SUBSTEPS:
        raise ValueError(f"agent_hz: physics_hz / agent_hz must be a whole number in [1, {MAX_SUBSTEPS}], "
                         f"got {physics_hz:g}/{agent_hz:g}")
    return physics_hz, agent_hz


def check_display() -> None:
    """Raise RuntimeError unless an X display answers (PyBullet's GUI exits the process without one)."""
    if not sys.platform.startswith("linux"):
        return
    display = os.environ.get("DISPLAY", "")
    host, _, number_part = display.rpartition(":")
    digits = number_part.split(".")[0]
    if not digits.isdigit():
        raise RuntimeError(f"render_mode='human': no display (DISPLAY={display!r}); use render_mode='rgb_array', "
                           f"or run under a display server such as `xvfb-run`")
    address = (("unix", f"/tmp/.X11-unix/X{digits}") if host in ("", "unix")
               else ("tcp", (host, 6000 + int(digits))))
    family = socket.AF_UNIX if address[0] == "unix" else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.settimeout(2.0)
        try:
            probe.connect(address[1])
        except OSError as error:
            raise RuntimeError(f"render_mode='human': the display {display!r} does not answer ({error}); use "
                               f"render_mode='rgb_array', or run under a display server such as `xvfb-run`") from None
