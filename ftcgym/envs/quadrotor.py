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

from ..models.faults import FaultSchedule, parse_faults, resolve
from ..models.geometry import quat_from_euler
from ..models.quadrotor import YAW_SIGNS, make_params, rotational_drag_moment
from ..models.rotors import RotorSet
from ..models.sensors import ACCEL_LIMIT, GYRO_LIMIT, QuadrotorSensors, SensorConfig, SensorLimits
from .flight_env import RENDER_SIZE, FlightEnv, check_action
from .visuals import QuadrotorLook

#: the sensors (observation keys) a sensor fault may target, with their sizes
SENSOR_SIZES = {"gyro": 3, "accel": 3, "attitude": 4, "position": 3, "velocity": 3, "rotor_speed": 4}
BOUNDS = 100.0                    # m, half-width and ceiling of the flight box
ROTOR_LOW, ROTOR_HIGH = np.zeros(4), np.ones(4)
CRASH_PENALTY = 100.0


class QuadrotorEnv(FlightEnv):
    """Quadrotor with motor-level actions; see the module docstring for spaces, reward and termination."""

    controls = "rotors"                 # what the action commands
    TASKS = ("hover", "goto", "square")
    BOUNDS = CEILING = BOUNDS

    def __init__(self, vehicle: str = "bebop2", vehicle_overrides: dict | None = None, wind: dict | None = None,
                 faults=None, task="hover", max_episode_seconds: float = 30.0, physics_hz: float = 500.0,
                 agent_hz: float = 500.0, sensors: dict | None = None, render_mode: str | None = None,
                 render_size=RENDER_SIZE, **unknown):
        self._setup(vehicle, vehicle_overrides, wind, faults, task, max_episode_seconds, physics_hz, agent_hz,
                    render_mode, render_size, unknown)
        self._sensor_config = SensorConfig.from_overrides(sensors)
        self.observation_space = self._make_observation_space(self.params)
        self._limits = {key: (box.low, box.high) for key, box in self.observation_space.spaces.items()}
        self._build_vehicle()
        self.action_space = spaces.Box(0.0, 1.0, (4,), np.float32)
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
        self._body_drag = np.asarray(self.params.body_drag, dtype=float)
        self._rot_drag = (np.asarray(self.params.rotational_drag, dtype=float),   # cached for the physics loop
                          np.asarray(self.params.rotational_drag_quadratic, dtype=float))

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
        self._omega_cmd = np.full(4, self.params.hover_omega)
        self._wind = self.wind.reset(rng)
        self.sensors.reset(rng)
        self._at_rest_readings()
        obs = self._observe()
        return obs, self._info()

    # ----------------------------------------------------------------------------------------- step
    def step(self, action):
        command = check_action(action, ROTOR_LOW, ROTOR_HIGH, "normalised rotor commands")
        self._omega_cmd = self.rotors.command_to_omega(command)
        obs, terminated, truncated = self._advance()
        reward = self._reward(command)
        return obs, reward, terminated, truncated, self._info()

    def _physics_step(self) -> None:
        dt, rotors = self.dt, self.rotors
        rotors.step(self._omega_cmd, dt)
        self._wind = self.wind.step()
        R = self._R
        air_body = R.T @ (self._vel - self._wind)
        force, moment = rotors.wrench(self._rates, air_body)
        force -= self._body_drag * air_body
        moment += rotational_drag_moment(*self._rot_drag, self._rates)
        self.sensors.advance_rotor_phase(rotors.omega, dt)
        self._integrate(R, force, moment)

    def _apply_faults(self) -> None:
        """Set the rotor and mass faults in force from `self.time` on (so info at t shows what acts next)."""
        self._faults.rotor_state(self.time, self.rotors.effectiveness, self.rotors.loaded)
        if self._has_payload:
            self._update_mass(self.time)

    def _update_mass(self, t: float) -> None:
        mass = self.params.mass + self._faults.added_mass(t)
        if mass != self._mass:
            self._mass = mass
            self.world.set_mass(mass)

    # ----------------------------------------------------------------------------------------- outputs
    def _observe(self) -> dict:
        readings = self.sensors.read(self._pos, self._vel, self._quat, self._rates, self._specific_force,
                                     self.rotors.omega)
        self._faults.apply_to_sensors(self.time, readings)
        return self._with_reference(readings)

    def _reward(self, command: np.ndarray) -> float:
        if self._crashed:
            return -CRASH_PENALTY
        e = self._pos - self._reference.position
        error = math.sqrt(e @ e)
        return float(1.0 - 0.5 * min(error, 4.0) - 0.5 * (1.0 - self._R[2, 2]) - 0.05 * float(command @ command) / 4)

    def _info(self) -> dict:
        """A fresh info dict (docs/concepts.md, 'The info contract')."""
        rotors = self.rotors
        airspeed_vec = self._vel - self._wind
        return {
            "time": self.time,
            "fault": self._faults.current(self.time),
            "faults": self._faults.as_dicts(),
            "truth": {
                "position": self._pos.copy(),
                "velocity": self._vel.copy(),
                "attitude": self._quat.copy(),
                "body_rates": self._rates.copy(),
                "wind": self._wind.copy(),
                "airspeed": float(np.sqrt(airspeed_vec @ airspeed_vec)),
                "mass": self._mass,
                "rotor_effectiveness": rotors.effectiveness.copy(),
                "rotor_speed": rotors.omega.copy(),
            },
            **self._outcome(),
        }
