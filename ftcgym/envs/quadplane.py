"""`ftcgym/QuadPlane-v0`: a VSQP-class quad-plane (001) in PyBullet with sensors, wind and faults.

The vehicle (`vsqp.py`): fuselage, a wing that skews from 0 (hover, along the fuselage) to 90 deg (forward
flight), four hover rotors (two on the wing, turning with it), a pusher propeller driven by an electric
motor (003 eq. 1-5, `pusher.py`), aileron, elevator and rudder. Forces and moments: the component model of
001 eq. (6)-(30) with control surfaces, tail and damping, plus the spinning propellers' spin-up reaction and
gyroscopic moment (`quadplane_aero.py`, `rotor_inertia_moment`).

Action: Box (9,) float32, clipped to its bounds (a wrong shape or a non-finite value raises ValueError):
  [0:4] hover-rotor speed commands in [0, 1] (omega = omega_min + u (omega_max - omega_min), rotor order of
        `VsqpParams.hover_rotor_positions`), [4] pusher throttle in [0, 1] (share of the battery voltage, pusher.py),
  [5:8] aileron, elevator, rudder in [-1, 1] (fractions of `surface_limit`), [8] wing skew command in
        [0, 1] (0 to 90 deg; the wing follows at `skew_rate_limit`).

Observation: a Dict of float64 sensor readings (`sensors.QuadPlaneSensors`), NED world / FRD body: gyro (3),
accel (3), attitude (4, x y z w), position (3), velocity (3) (navigation filter), pitot_airspeed (1),
gnss_velocity (3), skew (1) rad, hover_rotor_speed (4) rad/s, pusher_speed (1) rad/s, pusher_current (1) A,
reference_position (3), reference_velocity (3), reference_yaw (1).

Reward per agent step: 1 - 0.5 (1 - cos tilt) - 0.01 min(|p - p_ref|, 50), and -100 on a crash (tilt: the
body z axis from vertical). Terminated on a crash (ground contact faster than 3 m/s or tilted more than 60
deg, or leaving the box |north|, |east| <= 2 km, altitude <= 1 km); truncated after `max_episode_seconds`.
The episode starts at rest on the ground at home, motors stopped, nose into the mean wind (north in calm air).

Wind: `wind={"mean", "turbulence", "airspeed"}` (`models.wind`). Unless `airspeed` says otherwise, the Dryden
filters' reference airspeed follows the vehicle's speed through the mean wind (`"vehicle"`): MIL-F-8785C's
spectra are per metre flown, so a quad-plane cruising at 18 m/s meets its gusts 18 times as fast as at 1 m/s.
`airspeed="mean"` gives the quadrotor's default, the mean wind's speed.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from numba import njit

from ..models.checks import Range
from ..models.compiled import without_dispatch
from ..models.faults import QUADPLANE_KINDS, FaultSchedule, parse_faults, resolve
from ..models.geometry import quat_from_euler
from ..models.pusher import INERTIA, SPIN_DIRECTION, THRUST, TORQUE, PusherMotor, pusher_step
from ..models.pusher import OMEGA as PUSHER_OMEGA
from ..models.quadplane_aero import QuadPlaneAero, aero_loads, rotor_inertia_moment
from ..models.rotors import EFFECTIVENESS, OMEGA, OMEGA_DOT, SPIN, RotorSet, advance_speeds
from ..models.sensors import (
    ACCEL_LIMIT,
    GYRO_LIMIT,
    QuadPlaneSensorConfig,
    QuadPlaneSensors,
    SensorLimits,
    advance_phase,
)
from ..models.vsqp import make_vsqp_params
from ..models.wind import VEHICLE
from .action_space import ActionBox
from .flight_env import PHYSICS_HZ, RENDER_SIZE, FlightEnv, check_action
from .frames import RAW_EXAMPLE, body_state, to_bullet
from .visuals import QuadPlaneLook

#: the sensors (observation keys) a sensor fault may target, with their sizes
SENSOR_SIZES = {"gyro": 3, "accel": 3, "attitude": 4, "position": 3, "velocity": 3, "pitot_airspeed": 1,
                "gnss_velocity": 3, "skew": 1, "hover_rotor_speed": 4, "pusher_speed": 1, "pusher_current": 1}
ACTION_LOW = np.array([0, 0, 0, 0, 0, -1, -1, -1, 0], dtype=np.float32)
ACTION_HIGH = np.ones(9, dtype=np.float32)
ACTION_LAYOUT = "4 hover-rotor commands, pusher throttle, aileron, elevator, rudder, skew command"
CRASH_PENALTY = 100.0
SURFACE_TIME_CONSTANT = 0.03       # s, control-surface servo lag (assumed, hobby-grade digital servo)
#: a motor that lost its propeller spins 30% faster with little inertia, as for the quadrotor (000 Fig. 8)
UNLOADED_SPEED_RATIO, UNLOADED_TIME_CONSTANT = 1.3, 0.02
#: `QuadPlaneEnv._controls`: the hover-rotor speed set-points [0:4] (rad/s), then these (throttle; rad)
THROTTLE, AILERON_CMD, SKEW_CMD = 4, 5, 8
#: `QuadPlaneEnv._motion`: the wing skew and the aileron, elevator, rudder angles (rad)
SKEW, AILERON = 0, 1


class QuadPlaneEnv(FlightEnv):
    """Quad-plane with actuator-level actions; see the module docstring for spaces, reward and termination."""

    controls = "actuators"                 # what the action commands
    TASKS = ("mission", "hover")
    BOUNDS, CEILING = 2000.0, 1000.0   # m
    CRASH_SPEED = 3.0                  # m/s, ground contact faster than this is an impact (a 6.5 kg airframe)
    # The roll mode is stiff: roll damping L_p about -0.28 V N m s (quadplane_aero) on 001 eq. 8.1's
    # Ixx = 2.862e-2 kg m^2 gives a time constant of about 5.7 ms at 18 m/s and 2.9 ms at 35 m/s. The loads act
    # from the last step's state (explicit), which is stable only for steps under twice that: 100 Hz diverged
    # open-loop at 22 m/s; 250 Hz keeps a margin to about 50 m/s.
    PHYSICS_HZ = Range(250.0, PHYSICS_HZ.high)
    WIND_AIRSPEED = VEHICLE   # Dryden V_a = the speed through the mean wind: cruise's gust bandwidth in cruise

    def __init__(self, vehicle: str = "vsqp", vehicle_overrides: dict | None = None, wind: dict | None = None,
                 faults=None, task="mission", max_episode_seconds: float = 240.0, physics_hz: float = 500.0,
                 agent_hz: float = 100.0, sensors: dict | None = None, render_mode: str | None = None,
                 render_size=RENDER_SIZE, info_level: str = "full", observation_format: str = "dict", **unknown):
        self._setup(vehicle, vehicle_overrides, wind, faults, task, max_episode_seconds, physics_hz, agent_hz,
                    render_mode, render_size, unknown, info_level, observation_format)
        self._sensor_config = QuadPlaneSensorConfig.from_overrides(sensors)
        self._surface_alpha = 1.0 - math.exp(-self.dt / SURFACE_TIME_CONSTANT)
        self._controls, self._motion = np.zeros(9), np.zeros(4)
        self._set_observation_space(self._make_observation_space(self.params))
        self._limits = {key: (box.low, box.high) for key, box in self.dict_observation_space.spaces.items()}
        self._build_vehicle()
        self.action_space = ActionBox(ACTION_LOW, ACTION_HIGH, dtype=np.float32)
        self._open_world()

    def _make_params(self, vehicle, overrides):
        return make_vsqp_params(vehicle, overrides)

    def _parse_faults(self, faults):
        return parse_faults(faults, 4, SENSOR_SIZES, QUADPLANE_KINDS)

    def _make_look(self):
        return QuadPlaneLook(self.params)

    def _look_state(self) -> tuple:
        return self.hover_rotors, self.skew

    def _build_vehicle(self) -> None:
        """Hover rotors, pusher, sensors and surface limits of the parameter set `self.params`."""
        p = self.params
        self.hover_rotors = RotorSet(p.hover_rotor_positions(0.0), p.hover_yaw_signs, p.hover_thrust_coefficient,
                                     p.hover_torque_coefficient, p.hover_omega_min, p.hover_omega_max,
                                     p.hover_time_constant, p.hover_max_acceleration, p.propeller_inertia, 0.0,
                                     UNLOADED_SPEED_RATIO, UNLOADED_TIME_CONSTANT)
        self.aero = QuadPlaneAero(p)
        self.pusher = PusherMotor(p)
        # the constants of `physics_loads`, in its order
        self._loads_params = np.array([self.dt, *self.hover_rotors.gains(self.dt), p.skew_rate_limit * self.dt,
                                       self._surface_alpha], dtype=float)
        self._nominal_pusher = {name: getattr(self.pusher, name) for name in ("theta_1", "c_v", "I_0")}
        high = {key: top[0] for key, (_, top) in self._limits.items()}
        limits = SensorLimits(high["position"], high["velocity"], high["hover_rotor_speed"], high["pusher_speed"],
                              high["pusher_current"])
        self.sensors = QuadPlaneSensors(self._sensor_config, p.hover_omega, 1.0 / self.agent_hz, limits)
        self._surface_limit = np.broadcast_to(np.asarray(p.surface_limit, dtype=float), (3,)).copy()
        self._rest_height = 0.5 * float(p.body_size[2])
        # the physics step's compiled call, its argument types fixed here (`models.compiled.without_dispatch`)
        self._bullet_loads = without_dispatch(
            bullet_loads, self.hover_rotors.state, self._controls, self._motion, self.aero.constants,
            self.pusher.state, self.pusher.constants, self._loads_params, RAW_EXAMPLE, (0.0, 0.0, 0.0), np.zeros(4))

    def _make_observation_space(self, params) -> spaces.Dict:
        big, fast = 1e4, self.MAX_SPEED

        def box(low, high, n):
            return spaces.Box(low, high, (n,), np.float64)

        return spaces.Dict({
            "gyro": box(-GYRO_LIMIT, GYRO_LIMIT, 3), "accel": box(-ACCEL_LIMIT, ACCEL_LIMIT, 3),
            "attitude": box(-1.0, 1.0, 4), "position": box(-big, big, 3), "velocity": box(-fast, fast, 3),
            "pitot_airspeed": box(0.0, fast, 1), "gnss_velocity": box(-fast, fast, 3),
            "skew": box(-np.pi, np.pi, 1),
            "hover_rotor_speed": box(0.0, 2.0 * params.hover_omega_max, 4),
            "pusher_speed": box(0.0, 2.0 * params.pusher_omega_max, 1),
            "pusher_current": box(-1e3, 1e3, 1),
            "reference_position": box(-big, big, 3), "reference_velocity": box(-fast, fast, 3),
            "reference_yaw": box(-np.pi, np.pi, 1),
        })

    # ----------------------------------------------------------------------------------------- reset
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; `options` may hold `faults`, `wind`, `vehicle_overrides` for it (`FlightEnv`)."""
        self._begin_episode(seed, options)
        rng = self.np_random
        self._faults = FaultSchedule(resolve(self.fault_specs, rng, 4, list(SENSOR_SIZES)), 4, self._limits)
        position = np.array([0.0, 0.0, -self._rest_height])
        attitude = quat_from_euler(0.0, 0.0, self._start_heading() + float(rng.uniform(-0.02, 0.02)))
        self._start(position, attitude)
        self.hover_rotors.reset(0.0)
        self.pusher.reset(0.0)
        self._controls[:] = 0.0
        self._motion[:] = 0.0
        self._apply_faults()
        self._wind = tuple(self.wind.reset(rng).tolist())
        self.sensors.reset(rng)
        self._at_rest_readings()
        self._air_body = air_velocity(self._R, self._v, self._wind)
        return self._observation(), self._info()

    def _start_heading(self) -> float:
        """Nose into the mean wind, as a pilot places a VTOL for take-off (north in calm air): in quad mode
        the fin weathervanes, and a crosswind on the fin yaws the airframe harder than the rotors can hold."""
        mean = self.wind.mean
        if math.hypot(mean[0], mean[1]) < 0.5:
            return 0.0
        return math.atan2(-mean[1], -mean[0])

    # ----------------------------------------------------------------------------------------- step
    def step(self, action):
        self._set_commands(check_action(action, ACTION_LOW, ACTION_HIGH, ACTION_LAYOUT))
        obs, terminated, truncated = self._advance()
        return obs, self._reward(), terminated, truncated, self._info()

    def _set_commands(self, command: np.ndarray) -> None:
        controls = self._controls
        controls[:4] = self.hover_rotors.command_to_omega(command[:4])
        controls[THROTTLE] = command[4]
        controls[AILERON_CMD:SKEW_CMD] = command[5:8] * self._surface_limit
        controls[SKEW_CMD] = float(command[8]) * 0.5 * np.pi

    def _loads_arguments(self) -> tuple:
        """`bullet_loads`' arguments before the state: hover rotors, controls, wing and surfaces, aerodynamic
        constants, pusher and the constants of the step."""
        return (self.hover_rotors.state, self._controls, self._motion, self.aero.constants, self.pusher.state,
                self.pusher.constants, self._loads_params)

    def _keep_loads(self, loads: tuple) -> None:
        """The body air velocity the last physics step's loads were computed with."""
        self._air_body = loads[2]

    @property
    def skew(self) -> float:
        """The wing's skew angle (rad)."""
        return self._motion.item(SKEW)

    def _apply_faults(self) -> None:
        """Hover-rotor and pusher faults in force from `self.time` on."""
        if self._faults.rotor_state(self.time, self.hover_rotors.effectiveness, self.hover_rotors.loaded):
            self.hover_rotors.sync()
        if self._faults.has_propulsion_faults:      # every physics step: skip the dict when there is nothing to do
            for name, factor in self._faults.propulsion_factors(self.time).items():
                setattr(self.pusher, name, self._nominal_pusher[name] * factor)

    # ----------------------------------------------------------------------------------------- outputs
    def _observe(self) -> dict:
        readings = self.sensors.read(self._p, self._v, self._q, self._w, self._sf,
                                     self.hover_rotors.omega.tolist(), self._air_body[0], self.skew,
                                     self.pusher.omega, self.pusher.current)
        readings["pitot_airspeed"][0] = self._faults.apply_to_pitot(self.time, float(readings["pitot_airspeed"][0]))
        self._faults.apply_to_sensors(self.time, readings)
        return self._with_reference(readings)

    def _reward(self) -> float:
        if self._crashed:
            return -CRASH_PENALTY
        (x, y, z), ref = self._p, self._reference.position.tolist()
        ex, ey, ez = x - ref[0], y - ref[1], z - ref[2]
        return 1.0 - 0.5 * (1.0 - self._Rm[8]) - 0.01 * min(math.sqrt(ex * ex + ey * ey + ez * ez), 50.0)

    def airspeed(self) -> float:
        """True airspeed |v - wind| (m/s)."""
        v, wind = self._v, self._wind
        ax, ay, az = v[0] - wind[0], v[1] - wind[1], v[2] - wind[2]
        return math.sqrt(ax * ax + ay * ay + az * az)

    def angle_of_attack(self) -> float:
        """alpha = atan2(w, u) of the body air velocity (rad)."""
        u, _, w = self._air_body
        return math.atan2(w, u) if abs(u) + abs(w) > 1e-9 else 0.0

    def _truth(self) -> dict:
        """`info["truth"]` (docs/concepts.md, 'The info contract'), fresh arrays."""
        rotors, pusher = self.hover_rotors, self.pusher
        return {
            "position": np.array(self._p), "velocity": np.array(self._v), "attitude": np.array(self._q),
            "body_rates": np.array(self._w), "wind": np.array(self._wind), "airspeed": self.airspeed(),
            "air_velocity_body": np.array(self._air_body), "angle_of_attack": self.angle_of_attack(),
            "mass": self.params.mass, "rotor_effectiveness": rotors.effectiveness.copy(),
            "rotor_speed": rotors.omega.copy(), "skew": self.skew, "surfaces": self._motion[AILERON:].copy(),
            "pusher": {"omega": pusher.omega, "current": pusher.current, "thrust": pusher.thrust,
                       "theta_1": pusher.theta_1, "c_v": pusher.c_v, "I_0": pusher.I_0},
        }


@njit(cache=True)
def bullet_loads(rotors, controls, motion, aero, pusher, pusher_constants, params, raw, wind,
                 angles):  # pragma: no cover (compiled)
    """`physics_loads` on the state as PyBullet gives it (`raw`, `frames.body_state`): the force and torque
    PyBullet takes (`frames.to_bullet`), then the body air velocity (u, v, w)."""
    _, _, R_rows, v, rates = body_state(raw)
    loads = physics_loads(rotors, controls, motion, aero, pusher, pusher_constants, params, R_rows, v, rates, wind,
                          angles)
    force, torque = to_bullet(loads)
    return force, torque, (loads[6], loads[7], loads[8])


@njit(cache=True)
def physics_loads(rotors, controls, motion, aero, pusher, pusher_constants, params, R_rows, v, rates, wind,
                  angles):  # pragma: no cover (compiled)
    """One physics step of the actuators and the loads on the body, in the world frame: (fx, fy, fz, mx, my, mz)
    NED, then the air velocity in the body frame (u, v, w) the loads were computed with.

    In place: the hover-rotor speeds (`advance_speeds` on `rotors`, toward `controls`[:4]) and angles
    (`advance_phase` on `angles`); the wing skew, toward its set-point at the skew rate limit, and the surfaces,
    after their servos' first-order lag (`motion`); the pusher (`pusher_step`, at the throttle, fed the forward
    air speed). The air velocity is R^T (v - wind); the loads are `aero_loads`' (pusher included) plus the
    spinning propellers' moment (`rotor_inertia_moment`), rotated into the world frame by BLAS's products, as
    numpy's. `params`: dt, the gains of `RotorSet.gains`, the skew step
    per physics step, the servos' lag factor. The attitude R comes as its 9 entries row by row (`_Rm`)."""
    R = np.array(R_rows).reshape(3, 3)
    dt = params[0]
    advance_speeds(rotors, controls[:4], dt, params[1], params[2], params[3], params[4])
    advance_phase(angles, rotors[OMEGA], dt)
    _move_wing_and_surfaces(motion, controls, params[5], params[6])
    u, v_air, w = air_velocity(R, v, wind)
    pusher_step(pusher, pusher_constants, controls[THROTTLE], max(u, 0.0), dt)
    p, q, r = rates
    loads = aero_loads(aero, u, v_air, w, p, q, r, motion[SKEW], motion[AILERON], motion[AILERON + 1],
                       motion[AILERON + 2], rotors[OMEGA], rotors[EFFECTIVENESS], pusher[THRUST], pusher[TORQUE])
    skew = motion[SKEW]
    spinning = rotor_inertia_moment(aero, rotors[OMEGA], rotors[OMEGA_DOT], rotors[SPIN], math.sin(skew),
                                    math.cos(skew), p, q, r,
                                    pusher_constants[INERTIA] * pusher_constants[SPIN_DIRECTION] * pusher[PUSHER_OMEGA])
    force, moment = np.empty(3), np.empty(3)
    force[0], force[1], force[2] = loads[0], loads[1], loads[2]
    moment[0], moment[1], moment[2] = loads[3] + spinning[0], loads[4] + spinning[1], loads[5] + spinning[2]
    force_ned, moment_ned = np.dot(R, force), np.dot(R, moment)
    return (force_ned[0], force_ned[1], force_ned[2], moment_ned[0], moment_ned[1], moment_ned[2], u, v_air, w)


@njit(cache=True)
def _move_wing_and_surfaces(motion, controls, skew_step, servo_factor):  # pragma: no cover (compiled)
    """The wing turns toward its set-point by at most `skew_step`; each surface moves `servo_factor` of the way
    to its set-point (the servo's first-order lag over a physics step). In place on `motion`."""
    skew = motion[SKEW]
    motion[SKEW] = skew + min(max(controls[SKEW_CMD] - skew, -skew_step), skew_step)
    for i in range(3):
        angle = motion[AILERON + i]
        motion[AILERON + i] = angle + servo_factor * (controls[AILERON_CMD + i] - angle)


@njit(cache=True)
def air_velocity(R, v, wind):  # pragma: no cover (compiled)
    """R^T (v - wind): the velocity relative to the air in the body frame (3 floats)."""
    dx, dy, dz = v[0] - wind[0], v[1] - wind[1], v[2] - wind[2]
    return (R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz, R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz,
            R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz)
