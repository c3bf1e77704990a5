"""Sensor models: what a flight controller reads, never the truth.

- IMU (000 Sec. IV-A, Fig. 5): gyro and accelerometer sampled at the agent rate with white noise, a
  per-episode constant bias, motor vibration at each rotor's frequency (amplitude ~ omega^2, as from
  propeller imbalance) and saturation at +-2000 deg/s (MPU-6050, 000 Fig. 5) and +-16 g.
- ESC rotor speeds with white noise (000 Table I lists them as uncontaminated; a little noise is kept).
- Attitude: truth perturbed by a small random rotation (an onboard estimator's error; no estimator
  dynamics are simulated, so faults reach it only through the truth). Documented in the env docstring.
- Position and velocity (motion capture / GNSS-like): sample-and-hold at `position_hz` with white noise.
Noise is drawn in blocks from the env's generator (one draw per block, not per step) for speed, and one sample
of every reading is computed by one compiled call (`_sample`, numba) with the operations of the plain-Python
model it replaced, so the readings keep their bits.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .checks import Range, no_unknown, number
from .compiled import without_dispatch
from .constants import GRAVITY

GYRO_LIMIT = np.deg2rad(2000.0)   # rad/s, MPU-6050 full scale (000 Fig. 5)
ACCEL_LIMIT = 16.0 * GRAVITY        # m/s^2, +-16 g full scale
_BLOCK = 512
_TWO_PI = 2 * np.pi
_GYRO_LIMIT, _ACCEL_LIMIT = float(GYRO_LIMIT), float(ACCEL_LIMIT)
# Accepted sensor settings: noise levels and time constants may be 0 (an ideal sensor), rates may not; the
# upper ends only keep the arithmetic finite (no real sensor comes near them).
_LEVEL, _RATE = Range(0.0, 1e6), Range(1e-3, 1e6)


#: the readings of `QuadrotorSensors.read`, in order, with their sizes
READINGS = (("gyro", 3), ("accel", 3), ("attitude", 4), ("position", 3), ("velocity", 3), ("rotor_speed", 4))
_N_READINGS = sum(size for _, size in READINGS)
_NO_TAIL = np.empty(0)


@dataclass(frozen=True)
class SensorConfig:
    """Noise levels (1-sigma per sample) and rates; override with the env's `sensors` kwarg."""

    gyro_noise: float = 0.005           # rad/s; MPU-6050 density 0.005 deg/s/sqrt(Hz) plus airframe noise
    accel_noise: float = 0.05           # m/s^2; MPU-6050 400 ug/sqrt(Hz) over its 184 Hz low-pass: 0.053
    gyro_bias: float = 0.005            # rad/s, per-episode constant bias sigma
    accel_bias: float = 0.05            # m/s^2
    gyro_vibration: float = 0.03        # rad/s amplitude per rotor at hover speed
    accel_vibration: float = 0.8        # m/s^2 amplitude per rotor at hover speed
    rotor_speed_noise: float = 1.0      # rad/s
    attitude_noise: float = np.deg2rad(0.2)  # rad, per axis
    position_noise: float = 0.01        # m (indoor motion capture as in 000's flights)
    velocity_noise: float = 0.02        # m/s
    position_hz: float = 100.0          # Hz, sample-and-hold rate of position and velocity

    @classmethod
    def from_overrides(cls, overrides: dict | None) -> SensorConfig:
        if not overrides:
            return cls()
        if not isinstance(overrides, dict):
            raise ValueError(f"sensors: expected a dict of field -> value, got {overrides!r}")
        names = {f.name for f in dataclasses.fields(cls)}
        no_unknown(overrides, names, "sensors field")
        return cls(**{k: number(v, f"sensors[{k!r}]", _RATE if k.endswith("_hz") else _LEVEL)
                      for k, v in overrides.items()})


@dataclass(frozen=True)
class SensorLimits:
    """Full-scale ranges (symmetric, +-): a reading saturates there, at the observation space's bounds."""

    position: float = np.inf        # m
    velocity: float = np.inf        # m/s (also the pitot's and the GNSS velocity's)
    rotor_speed: float = np.inf     # rad/s
    pusher_speed: float = np.inf    # rad/s
    pusher_current: float = np.inf  # A


class QuadrotorSensors:
    """IMU, ESC, attitude and position/velocity sensors of a quadrotor (four rotors)."""

    #: columns of one noise row: gyro 3, accel 3, attitude 3, position 3, velocity 3, rotor speeds n
    def __init__(self, config: SensorConfig, n_rotors: int, hover_omega: float, dt: float,
                 limits: SensorLimits | None = None):
        if n_rotors != 4:
            raise ValueError(f"QuadrotorSensors: four rotors, got {n_rotors}")
        self.config = config
        self.limits = limits or SensorLimits()
        self.n_rotors = n_rotors
        self.dt = dt
        self._omega_ref2 = hover_omega ** 2
        self._hold_steps = max(1, int(round(1.0 / (config.position_hz * dt))))
        c = config
        self._scales = np.concatenate([
            np.full(3, c.gyro_noise), np.full(3, c.accel_noise), np.full(3, c.attitude_noise / 2),
            np.full(3, c.position_noise), np.full(3, c.velocity_noise), np.full(n_rotors, c.rotor_speed_noise)])
        lim = self.limits
        self._limits = np.array([_GYRO_LIMIT, _ACCEL_LIMIT, lim.position, lim.velocity, lim.rotor_speed])
        self._sample = None              # `_sample` compiled for this instance's argument types (first `reset`)

    def reset(self, rng: np.random.Generator) -> None:
        c = self.config
        self._rng = rng
        self.gyro_bias = rng.normal(0.0, c.gyro_bias, 3) if c.gyro_bias else np.zeros(3)
        self.accel_bias = rng.normal(0.0, c.accel_bias, 3) if c.accel_bias else np.zeros(3)
        # Each rotor shakes the airframe along its own direction (fixed per episode).
        dirs = rng.normal(size=(self.n_rotors, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        self._gyro_vib_dirs = dirs * c.gyro_vibration
        self._accel_vib_dirs = dirs[:, [1, 2, 0]] * c.accel_vibration
        self._biases = np.concatenate([self.gyro_bias, self.accel_bias])
        self._phase = rng.uniform(0.0, 2 * np.pi, self.n_rotors)    # rotor angles, advanced every physics step
        self._noise = np.empty((0, self._scales.size))
        self._row = 0
        self._count = 0
        self._held = np.zeros(6)         # position and velocity, sampled and held
        if self._sample is None:         # every episode's arrays are made alike: their types are the first's
            three = (0.0, 0.0, 0.0)
            self._sample = without_dispatch(
                _sample, np.zeros(self._scales.size), self._phase, np.zeros(4), self._omega_ref2,
                self._gyro_vib_dirs, self._accel_vib_dirs, self._biases, self._limits, self._held, True, three, three,
                (0.0, 0.0, 0.0, 1.0), three, three, _NO_TAIL)

    rotor_angles = property(lambda self: self._phase, doc="the rotors' angles (rad), in place (`advance_phase`)")

    def read(self, position, velocity, quat, body_rates, specific_force, omega) -> dict:
        """One sample of every sensor, from the true state (NED / FRD; arrays or sequences of floats): a dict of
        fresh arrays (views of one array made per sample), keys and sizes as `READINGS`."""
        flat = self.sample(_floats(position), _floats(velocity), _floats(quat), _floats(body_rates),
                           _floats(specific_force), np.asarray(omega, dtype=float))
        return {key: flat[start:stop] for key, start, stop in _READING_SLICES}

    def sample(self, position: tuple, velocity: tuple, quat: tuple, body_rates: tuple, specific_force: tuple,
               omega: np.ndarray, tail: np.ndarray = _NO_TAIL) -> np.ndarray:
        """`read` as one fresh array, the readings of `READINGS` one after the other, then the caller's own
        entries `tail` (the physics step's form: the state as tuples of floats, `omega` a float array)."""
        row = self._row
        if row == len(self._noise):      # the next block of noise (one draw from the generator per block)
            self._noise = self._rng.standard_normal((_BLOCK, self._scales.size)) * self._scales
            row = 0
        self._row = row + 1
        count = self._count
        self._count = count + 1
        return self._sample(self._noise[row], self._phase, omega, self._omega_ref2, self._gyro_vib_dirs,
                       self._accel_vib_dirs, self._biases, self._limits, self._held, count % self._hold_steps == 0,
                       position, velocity, quat, body_rates, specific_force, tail)


def _floats(values) -> tuple:
    """A state vector as the tuple of floats `_sample` is compiled for."""
    return values if type(values) is tuple else tuple(float(v) for v in values)


@njit(cache=True)
def advance_phase(phase, omega, dt):  # pragma: no cover (compiled)
    """Rotor angles, in place: (phase + omega dt) mod 2 pi (every physics step, so vibration is not aliased by
    substeps)."""
    for i in range(phase.size):
        phase[i] = (phase[i] + omega[i] * dt) % _TWO_PI


@njit(cache=True)
def _sample(n, phase, omega, ref2, gyro_vib, accel_vib, biases, limits, held, hold, position, velocity, quat,
            rates, specific_force, tail):  # pragma: no cover (compiled)
    """One sample of every reading of `QuadrotorSensors` (module docstring) with the noise row `n`: a fresh array
    of the `READINGS` then the entries of `tail`; `held` (position, velocity) is sampled anew when `hold`."""
    g, a, p_top, v_top, w_top = limits[0], limits[1], limits[2], limits[3], limits[4]
    # vibration amplitude of each rotor ~ (omega_i / omega_hover)^2, at its angle
    v0 = (omega[0] * omega[0] / ref2) * math.sin(phase[0])
    v1 = (omega[1] * omega[1] / ref2) * math.sin(phase[1])
    v2 = (omega[2] * omega[2] / ref2) * math.sin(phase[2])
    v3 = (omega[3] * omega[3] / ref2) * math.sin(phase[3])
    out = np.empty(_N_READINGS + tail.size)
    for i in range(3):
        # vib @ dirs: the pairings are those of BLAS's kernels for these layouts (gyro directions row-major,
        # accel directions column-major), so the readings keep their bits from the numpy version.
        gv = (v0 * gyro_vib[0, i] + v1 * gyro_vib[1, i]) + (v2 * gyro_vib[2, i] + v3 * gyro_vib[3, i])
        av = (v0 * accel_vib[0, i] + v2 * accel_vib[2, i]) + (v1 * accel_vib[1, i] + v3 * accel_vib[3, i])
        out[i] = min(max(rates[i] + biases[i] + n[i] + gv, -g), g)
        out[3 + i] = min(max(specific_force[i] + biases[3 + i] + n[3 + i] + av, -a), a)
        if hold:
            held[i] = min(max(position[i] + n[9 + i], -p_top), p_top)
            held[3 + i] = min(max(velocity[i] + n[12 + i], -v_top), v_top)
    out[6], out[7], out[8], out[9] = _perturb_floats(quat, n[6], n[7], n[8])
    out[10:16] = held
    for i in range(4):
        out[16 + i] = min(max(omega[i] + n[15 + i], 0.0), w_top)
    out[_N_READINGS:] = tail
    return out




def reading_slices(readings) -> tuple:
    """(key, start, stop) of each (key, size) of `readings` laid end to end in one array."""
    ends = np.cumsum([size for _, size in readings]).tolist()
    return tuple((key, stop - size, stop) for (key, size), stop in zip(readings, ends))


_READING_SLICES = reading_slices(READINGS)


def _saturate(x: np.ndarray, limit: float) -> np.ndarray:
    return np.minimum(np.maximum(x, -limit), limit)


@njit(cache=True)
def _perturb_floats(q, a, b, c):
    """q (x) [a, b, c, 1], normalised: the quaternion q rotated by a small body-frame rotation of half-angles
    (a, b, c) (compiled, for `_sample`)."""
    x, y, z, w = q
    out = (w * a + x + y * c - z * b,
           w * b - x * c + y + z * a,
           w * c + x * b - y * a + z,
           w - x * a - y * b - z * c)
    norm = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3])
    return out[0] / norm, out[1] / norm, out[2] / norm, out[3] / norm


@dataclass(frozen=True)
class QuadPlaneSensorConfig(SensorConfig):
    """The quadrotor's sensors with outdoor navigation rates, plus the quad-plane's own."""

    position_noise: float = 0.3           # m, navigation-filter position (GNSS-aided), assumed
    velocity_noise: float = 0.05          # m/s, navigation-filter velocity, assumed
    position_hz: float = 50.0             # Hz, navigation-filter output rate, assumed
    gyro_vibration: float = 0.01          # rad/s, larger airframe, assumed
    accel_vibration: float = 0.3          # m/s^2, assumed
    rotor_speed_noise: float = 2.0        # rad/s, ESC telemetry of the hover motors, assumed
    pitot_noise: float = 0.3              # m/s, differential-pressure airspeed (MS4525-class at cruise), assumed
    pitot_time_constant: float = 0.05     # s, pneumatic lag of the pitot line, assumed
    gnss_velocity_noise: float = 0.0064   # m/s, 001 Table 1: sigma_Vx^2 = sigma_Vy^2 = 4.1e-5 (m/s)^2
    gnss_vertical_velocity_noise: float = 0.0118   # m/s, 001 Table 1: sigma_Vz^2 = 1.4e-4 (m/s)^2
    gnss_hz: float = 10.0                 # Hz, GNSS velocity rate (u-blox class receiver), assumed
    skew_noise: float = 0.002             # rad, wing-angle encoder, assumed
    pusher_speed_noise: float = 0.71      # rad/s, 003 Sec. IV-B: omega noise covariance 5e-1
    pusher_current_noise: float = 0.0032  # A, 003 Sec. IV-B: I_e noise covariance 1e-5


class QuadPlaneSensors:
    """Quad-plane sensors: the quadrotor set (IMU, attitude, navigation position and velocity, hover-rotor ESCs)
    plus pitot airspeed (noise and first-order lag), GNSS velocity (sample-and-hold), skew angle and the
    pusher's speed and current."""

    def __init__(self, config: QuadPlaneSensorConfig, hover_omega: float, agent_dt: float,
                 limits: SensorLimits | None = None):
        self.config = config
        self.limits = limits = limits or SensorLimits()
        self.base = QuadrotorSensors(config, 4, hover_omega, agent_dt, limits)
        self._pitot_alpha = 1.0 - np.exp(-agent_dt / config.pitot_time_constant) if config.pitot_time_constant else 1.0
        self._gnss_steps = max(1, int(round(1.0 / (config.gnss_hz * agent_dt))))
        c = config
        self._scales = np.array([c.pitot_noise, c.gnss_velocity_noise, c.gnss_velocity_noise,
                                 c.gnss_vertical_velocity_noise, c.skew_noise, c.pusher_speed_noise,
                                 c.pusher_current_noise])

    def reset(self, rng: np.random.Generator, airspeed: float = 0.0) -> None:
        self.base.reset(rng)
        self._rng = rng
        self._pitot = airspeed
        self._gnss = None
        self._count = 0

    rotor_angles = property(lambda self: self.base.rotor_angles, doc="the hover rotors' angles (rad), in place")

    def read(self, position, velocity, quat, body_rates, specific_force, hover_omega, airspeed_x: float,
             skew: float, pusher_omega: float, pusher_current: float) -> dict:
        """One sample of every sensor. `airspeed_x` is the air velocity along the pitot (body x), m/s."""
        common = self.base.read(position, velocity, quat, body_rates, specific_force, hover_omega)
        n = self._rng.standard_normal(7) * self._scales
        self._pitot += self._pitot_alpha * (max(airspeed_x, 0.0) - self._pitot)   # a pitot reads forward flow only
        if self._count % self._gnss_steps == 0:
            self._gnss = _saturate(np.asarray(velocity) + n[1:4], self.limits.velocity)
        self._count += 1
        lim = self.limits
        return {
            "gyro": common["gyro"], "accel": common["accel"], "attitude": common["attitude"],
            "position": common["position"], "velocity": common["velocity"],
            "pitot_airspeed": np.array([min(max(self._pitot + n[0], 0.0), lim.velocity)]),
            "gnss_velocity": self._gnss.copy(),
            "skew": np.array([min(max(skew + n[4], -np.pi), np.pi)]),
            "hover_rotor_speed": common["rotor_speed"],
            "pusher_speed": np.array([min(max(pusher_omega + n[5], 0.0), lim.pusher_speed)]),
            "pusher_current": np.array([min(max(pusher_current + n[6], -lim.pusher_current), lim.pusher_current)]),
        }
