"""`ftcgym/Quadrotor-v0`: a PyBullet quadrotor with sensors, wind and faults (Gymnasium API).

Action: Box(0, 1, (4,)) normalised rotor-speed commands, omega_cmd = omega_min + u (omega_max - omega_min),
rotors r1..r4 of 000 Fig. 2 (index 0 is r1). Out-of-range commands are clipped to [0, 1]; a wrong shape,
NaN or infinite command raises ValueError (nothing non-finite reaches the physics).

Observation: a Dict of sensor readings (see `sensors.py`), all float64, NED world / FRD body:
  gyro (3) rad/s, accel (3) m/s^2 specific force, attitude (4) quaternion x y z w (truth + small random
  rotation, i.e. an onboard estimator's error without its dynamics), position (3) m and velocity (3) m/s
  (sample-and-hold at `sensors["position_hz"]`), rotor_speed (4) rad/s from the ESCs,
  reference_position (3), reference_velocity (3), reference_yaw (1): the task's set-point now.

Reward per agent step (suited to recovery training; a spinning vehicle is not penalised for yaw):
  r = 1 - 0.5 min(|p - p_ref|, 4) - 0.5 (1 - cos tilt) - 0.05 mean(u^2),  and -100 on a crash,
where tilt is the angle of the thrust axis (body -z) from vertical.

Episode end: terminated on a crash (ground contact faster than 2 m/s or tilted more than 60 deg, or leaving
the box |north|, |east| <= 100 m, altitude <= 100 m); truncated after `max_episode_seconds`.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from numba import njit

from ..models.compiled import without_dispatch
from ..models.faults import FaultSchedule, parse_faults, resolve
from ..models.geometry import quat_from_euler
from ..models.quadrotor import YAW_SIGNS, make_params
from ..models.rotors import OMEGA, RotorSet, advance_speeds, rotor_loads
from ..models.sensors import (
    ACCEL_LIMIT,
    GYRO_LIMIT,
    READINGS,
    QuadrotorSensors,
    SensorConfig,
    SensorLimits,
    advance_phase,
    reading_slices,
)
from .action_space import ActionBox
from .flight_env import RENDER_SIZE, FlightEnv, check_command
from .frames import RAW_EXAMPLE, body_state, to_bullet
from .visuals import QuadrotorLook

#: the sensors (observation keys) a sensor fault may target, with their sizes
SENSOR_SIZES = {"gyro": 3, "accel": 3, "attitude": 4, "position": 3, "velocity": 3, "rotor_speed": 4}
BOUNDS = 100.0                    # m, half-width and ceiling of the flight box
CRASH_PENALTY = 100.0
#: the observation's keys in order, with their sizes: the sensors' readings, then the task's set-point
OBSERVATION = (*READINGS, ("reference_position", 3), ("reference_velocity", 3), ("reference_yaw", 1))
_OBSERVATION_SLICES = reading_slices(OBSERVATION)


class QuadrotorEnv(FlightEnv):
    """Quadrotor with motor-level actions; see the module docstring for spaces, reward and termination."""

    controls = "rotors"                 # what the action commands
    TASKS = ("hover", "goto", "square")
    BOUNDS = CEILING = BOUNDS

    def __init__(self, vehicle: str = "bebop2", vehicle_overrides: dict | None = None, wind: dict | None = None,
                 faults=None, task="hover", max_episode_seconds: float = 30.0, physics_hz: float = 500.0,
                 agent_hz: float = 500.0, sensors: dict | None = None, render_mode: str | None = None,
                 render_size=RENDER_SIZE, info_level: str = "full", observation_format: str = "dict", **unknown):
        self._setup(vehicle, vehicle_overrides, wind, faults, task, max_episode_seconds, physics_hz, agent_hz,
                    render_mode, render_size, unknown, info_level, observation_format)
        self._sensor_config = SensorConfig.from_overrides(sensors)
        self._set_observation_space(self._make_observation_space(self.params))
        # "flat": the sample's indices in the flat observation's (sorted key) order (`_observation`)
        slices = {key: (start, stop) for key, start, stop in _OBSERVATION_SLICES}
        self._flat_order = None if observation_format == "dict" else np.concatenate(
            [np.arange(*slices[key]) for key in self._observation_keys])
        self._limits = {key: (box.low, box.high) for key, box in self.dict_observation_space.spaces.items()}
        self._build_vehicle()
        self.action_space = ActionBox(0.0, 1.0, (4,), np.float32)
        self._open_world()

    def _make_params(self, vehicle, overrides):
        return make_params(vehicle, overrides)

    def _parse_faults(self, faults):
        return parse_faults(faults, 4, SENSOR_SIZES)

    def _make_look(self):
        return QuadrotorLook(self.params)

    def _look_state(self) -> tuple:
        return self.rotors, 0.0

    def _build_vehicle(self) -> None:
        """Rotors, sensors and drag of the parameter set `self.params`."""
        self.rotors = RotorSet.from_params(self.params, YAW_SIGNS)
        high = {key: top[0] for key, (_, top) in self._limits.items()}
        limits = SensorLimits(high["position"], high["velocity"], high["rotor_speed"])
        self.sensors = QuadrotorSensors(self._sensor_config, 4, self.params.hover_omega, 1.0 / self.agent_hz, limits)
        p, rotors = self.params, self.rotors
        self._omega_low, self._omega_span = float(p.omega_min), float(p.omega_max - p.omega_min)
        # the constants of `physics_loads`, in its order
        self._loads_params = np.array([rotors.c_t, rotors.c_q, rotors.drag_coefficient, self.dt,
                                       *rotors.gains(self.dt), *p.body_drag,
                                       *np.ravel(np.column_stack([p.rotational_drag, p.rotational_drag_quadratic]))],
                                      dtype=float)
        # the physics step's compiled call, its argument types fixed here (omega_cmd and the rotor angles: four
        # float64 each; the wind: three floats)
        self._bullet_loads = without_dispatch(bullet_loads, rotors.state, rotors.geometry, np.zeros(4),
                                              self._loads_params, RAW_EXAMPLE, (0.0, 0.0, 0.0), np.zeros(4))

    # ----------------------------------------------------------------------------------------- spaces
    def _make_observation_space(self, params) -> spaces.Dict:
        far, fast = 2.0 * BOUNDS, self.MAX_SPEED  # the crash box bounds position; speed is bounded physically
        omega_top = params.omega_max * params.unloaded_speed_ratio * 1.5

        def box(low, high, n):
            return spaces.Box(low, high, (n,), np.float64)
        return spaces.Dict({
            "gyro": box(-GYRO_LIMIT, GYRO_LIMIT, 3),
            "accel": box(-ACCEL_LIMIT, ACCEL_LIMIT, 3),
            "attitude": box(-1.0, 1.0, 4),
            "position": box(-far, far, 3),
            "velocity": box(-fast, fast, 3),
            "rotor_speed": box(0.0, omega_top, 4),
            "reference_position": box(-far, far, 3),
            "reference_velocity": box(-fast, fast, 3),
            "reference_yaw": box(-np.pi, np.pi, 1),
        })

    # ----------------------------------------------------------------------------------------- reset
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; `options` may hold `faults`, `wind`, `vehicle_overrides` for it (`FlightEnv`)."""
        self._begin_episode(seed, options)
        rng = self.np_random
        self._faults = FaultSchedule(resolve(self.fault_specs, rng, 4, list(SENSOR_SIZES)), 4, self._limits)
        self._has_payload = any(s.kind == "payload" for s in self._faults.specs)
        self._mass = self.params.mass
        ref = self.task.reference(0.0)
        position = ref.position + rng.uniform(-0.05, 0.05, 3)
        roll, pitch, dyaw = rng.uniform(-np.deg2rad(2), np.deg2rad(2), 3)
        attitude = quat_from_euler(roll, pitch, ref.yaw + dyaw)
        self._start(position, attitude)
        self.rotors.reset(self.params.hover_omega)
        self._apply_faults()
        self._omega_cmd = np.full(4, float(self.params.hover_omega))
        self._wind = tuple(self.wind.reset(rng).tolist())
        self.sensors.reset(rng)
        self._at_rest_readings()
        return self._observation(), self._info()

    # ----------------------------------------------------------------------------------------- step
    def step(self, action):
        low, span, omega_cmd = self._omega_low, self._omega_span, self._omega_cmd
        # The common case, a float array of four finite commands, in one compiled call; anything else through
        # `check_command`, which raises on what is wrong (a non-finite command leaves `omega_cmd` untouched).
        effort = (rotor_command(action, low, span, omega_cmd)
                  if type(action) is np.ndarray and action.dtype in _FLOAT_DTYPES and action.shape == (4,)
                  else math.nan)
        if effort != effort:
            command = check_command(action, 4, 0.0, 1.0, "normalised rotor commands")
            effort = rotor_command(np.array(command, dtype=np.float64), low, span, omega_cmd)
        obs, terminated, truncated = self._advance()
        reward = self._reward(effort)
        return obs, reward, terminated, truncated, self._info()

    def _loads_arguments(self) -> tuple:
        """`bullet_loads`' arguments before the state: the rotors, the speed commands and the constants."""
        rotors = self.rotors
        return rotors.state, rotors.geometry, self._omega_cmd, self._loads_params

    def _apply_faults(self) -> None:
        """Set the rotor and mass faults in force from `self.time` on (so info at t shows what acts next)."""
        if self._faults.rotor_state(self.time, self.rotors.effectiveness, self.rotors.loaded):
            self.rotors.sync()
        if self._has_payload:
            self._update_mass(self.time)

    def _update_mass(self, t: float) -> None:
        mass = self.params.mass + self._faults.added_mass(t)
        if mass != self._mass:
            self._mass = mass
            self.world.set_mass(mass)

    # ----------------------------------------------------------------------------------------- outputs
    def _observe(self) -> dict:
        """The readings and the set-point as views of one fresh array (one allocation per step)."""
        flat = self._sample()
        readings = {key: flat[start:stop] for key, start, stop in _OBSERVATION_SLICES}
        faults = self._faults
        return faults.apply_to_sensors(self.time, readings) if faults.acts_on_sensors else readings

    def _observation(self):
        """At observation_format "flat" with no sensor fault scheduled, the sample put in the flat layout by one
        indexing (`_flat_order`): the values `_format(_observe())` concatenates, without the dict of views."""
        if self._flat_order is None or self._faults.acts_on_sensors:
            return super()._observation()
        return self._sample()[self._flat_order]

    def _sample(self) -> np.ndarray:
        """The sensors' readings and the task's set-point now, in `OBSERVATION`'s layout."""
        ref = self._reference = self.task.reference(self.time)
        return self.sensors.sample(self._p, self._v, self._q, self._w, self._sf, self.rotors.omega, ref.as_array)

    def _reward(self, effort: float) -> float:
        """The module docstring's reward; `effort` is the sum of the squared (clipped) commands."""
        if self._crashed:
            return -CRASH_PENALTY
        (x, y, z), ref = self._p, self._reference.position.tolist()
        ex, ey, ez = x - ref[0], y - ref[1], z - ref[2]
        error = math.sqrt(ex * ex + ey * ey + ez * ez)
        return 1.0 - 0.5 * min(error, 4.0) - 0.5 * (1.0 - self._Rm[8]) - 0.05 * effort / 4

    def _truth(self) -> dict:
        """`info["truth"]` (docs/concepts.md, 'The info contract'), fresh arrays."""
        rotors, wind, v = self.rotors, self._wind, self._v
        ax, ay, az = v[0] - wind[0], v[1] - wind[1], v[2] - wind[2]
        return {
            "position": np.array(self._p),
            "velocity": np.array(v),
            "attitude": np.array(self._q),
            "body_rates": np.array(self._w),
            "wind": np.array(wind),
            "airspeed": math.sqrt(ax * ax + ay * ay + az * az),
            "mass": self._mass,
            "rotor_effectiveness": rotors.effectiveness.copy(),
            "rotor_speed": rotors.omega.copy(),
        }


#: the action dtypes `rotor_command` takes directly (others go through `check_command` first)
_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


@njit(cache=True)
def rotor_command(command, low, span, omega_cmd):  # pragma: no cover (compiled)
    """The rotor-speed commands omega_cmd = low + clip(u, 0, 1) span, in place (`RotorSet.command_to_omega`), and
    the effort sum of u^2 over the clipped commands; NaN, with `omega_cmd` untouched, if a command is not
    finite. Per command the operations of the Python step it replaced, in the same order (same bits)."""
    for i in range(4):
        if not math.isfinite(command[i]):
            return math.nan
    effort = 0.0
    for i in range(4):
        u = min(max(float(command[i]), 0.0), 1.0)
        omega_cmd[i] = low + u * span
        effort += u * u
    return effort


@njit(cache=True)
def bullet_loads(rotors, geometry, command, params, raw, wind, angles):  # pragma: no cover (compiled)
    """`physics_loads` on the state as PyBullet gives it (`raw`, `frames.body_state`), returned as the force and
    torque PyBullet takes (`frames.to_bullet`)."""
    _, _, R_rows, v, rates = body_state(raw)
    return to_bullet(physics_loads(rotors, geometry, command, params, R_rows, v, rates, wind, angles))


@njit(cache=True)
def physics_loads(rotors, geometry, command, params, R_rows, v, rates, wind, angles):  # pragma: no cover (compiled)
    """One physics step's rotor speeds and angles (`advance_speeds`, in place on `rotors`; `advance_phase`, in
    place on `angles`) and the loads they and the airframe put on the body, in the world frame:
    (fx, fy, fz, mx, my, mz) NED.

    The air velocity in the body frame is R^T (v - wind); the body drag is -D v_air per axis and the
    rotational drag -(D1 + D2 |w|) w (`models.quadrotor`); `params` holds c_T, c_Q, k_d, dt, the gains of
    `RotorSet.gains`, D and (D1, D2) per axis. The attitude R comes as its 9 entries row by row (`_Rm`: a
    tuple passes to compiled code for less than a copy into an array costs); the rotations into the world frame
    are BLAS's, as numpy's."""
    R = np.array(R_rows).reshape(3, 3)
    c_t, c_q, k_d, dt = params[0], params[1], params[2], params[3]
    advance_speeds(rotors, command, dt, params[4], params[5], params[6], params[7])
    advance_phase(angles, rotors[OMEGA], dt)
    dx, dy, dz = v[0] - wind[0], v[1] - wind[1], v[2] - wind[2]
    ax = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
    ay = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
    az = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
    p, q, r = rates
    fx, fy, fz, mx, my, mz = rotor_loads(rotors, geometry, c_t, c_q, k_d, p, q, ax, ay)
    force, moment = np.empty(3), np.empty(3)
    force[0], force[1], force[2] = fx - params[8] * ax, fy - params[9] * ay, fz - params[10] * az
    moment[0] = mx + -(params[11] + params[12] * abs(p)) * p
    moment[1] = my + -(params[13] + params[14] * abs(q)) * q
    moment[2] = mz + -(params[15] + params[16] * abs(r)) * r
    force_ned, moment_ned = np.dot(R, force), np.dot(R, moment)
    return force_ned[0], force_ned[1], force_ned[2], moment_ned[0], moment_ned[1], moment_ned[2]
