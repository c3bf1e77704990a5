"""Nominal cascaded quadrotor controller: position -> thrust vector -> attitude -> body rates -> rotor speeds.

Fault-unaware: it knows the nominal parameter set (mass, inertia, rotor geometry and coefficients) and reads
only sensor observations. Position and velocity PID give a desired acceleration; the thrust direction and
yaw give a desired attitude, tracked with the geometric attitude error of Lee et al. (2010) as a body-rate
command; a PI rate loop gives angular accelerations, turned into torques with the inertia (plus the
gyroscopic coupling), and the mixer inverts the control-effectiveness model of 000 eq. (8) (with the yaw
row c_Q s_i of 004 eq. 7) for squared rotor speeds.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..models.constants import GRAVITY
from ..models.geometry import cross, rotation_matrix
from ..models.quadrotor import QuadrotorParams, rotor_wrench_matrix
from .base import UP


@dataclass
class ControllerGains:
    position: tuple = (1.6, 1.6, 2.0)       # 1/s^2, acceleration per metre of error
    velocity: tuple = (2.4, 2.4, 3.0)       # 1/s
    position_integral: tuple = (0.4, 0.4, 0.8)
    integral_limit: float = 2.0             # m/s^2, anti-windup on the integral's acceleration
    attitude: tuple = (7.0, 7.0, 2.5)       # 1/s, rate command per rad of attitude error
    rate: tuple = (18.0, 18.0, 8.0)         # 1/s, angular acceleration per rad/s of rate error
    rate_integral: tuple = (60.0, 60.0, 10.0)  # 1/s^2, integral of rate error -> angular acceleration
    rate_integral_share: float = 0.4         # integral authority as a share of the maximum control torque
    max_tilt_deg: float = 35.0
    max_rate: tuple = (6.0, 6.0, 3.0)       # rad/s
    gyro_cutoff_hz: float = 60.0            # first-order low-pass on the gyro against motor vibration


#: Per-vehicle departures from the defaults. The Bebop 2 gets a stiffer roll/pitch rate loop: after a
#: propeller loss the opposite rotor, still at hover thrust, tips it at ~90 rad/s^2 about the diagonal no
#: other rotor can act on. In the detector's ~60 ms the default rate gain of 18/s slows that rotor too little
#: and leaves a tumble that the spin recovery stops only near 85 deg of tilt. 60/s puts the loop's crossover
#: at ~37 rad/s, phase margin ~30 deg with the Bebop 2's 33 ms motor lag (Sun et al.'s model); hover and
#: square tracking are unchanged. Chosen on tuning flights; see docs/measurements.md, 'Tuning record:
#: agents/quadrotor_control.py'.
VEHICLE_GAINS = {"bebop2": {"rate": (60.0, 60.0, 8.0)}}


def gains_for(params: QuadrotorParams) -> ControllerGains:
    """The default gains with the vehicle's entries of VEHICLE_GAINS applied."""
    return replace(ControllerGains(), **VEHICLE_GAINS.get(params.name, {}))


class NominalController:
    """Cascaded PID with model-based mixer; the `nominal` benchmark policy."""

    def __init__(self, params: QuadrotorParams, agent_hz: float, gains: ControllerGains | None = None):
        self.params = params
        self.gains = gains or gains_for(params)
        self.dt = 1.0 / agent_hz
        g = self.gains
        self._kp, self._kd, self._ki = (np.asarray(x, dtype=float)
                                        for x in (g.position, g.velocity, g.position_integral))
        self._katt, self._krate, self._krate_i = (np.asarray(x, dtype=float)
                                                  for x in (g.attitude, g.rate, g.rate_integral))
        self._max_rate = np.asarray(g.max_rate, dtype=float)
        self._max_horizontal = GRAVITY * np.tan(np.deg2rad(g.max_tilt_deg))
        self._inertia = np.asarray(params.inertia, dtype=float)
        self._gyro_alpha = 1.0 - np.exp(-2 * np.pi * g.gyro_cutoff_hz * self.dt)
        allocation = allocation_matrix(params)
        self._mixer_inverse = np.linalg.inv(allocation)
        # Largest torque about each axis with rotors between idle and max: the integral may use a share of it,
        # enough to trim out a partial loss of effectiveness (002 Sec. 5.2) without winding up.
        span = params.omega_max ** 2 - params.omega_min ** 2
        max_torque = 0.5 * np.abs(allocation[1:]).sum(axis=1) * span
        self._alpha_integral_limit = g.rate_integral_share * max_torque / self._inertia
        self._w2_min, self._w2_max = params.omega_min ** 2, params.omega_max ** 2
        self.thrust_axis_reference = UP.copy()
        self.reset()

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        self._pos_integral = np.zeros(3)
        self._rate_integral = np.zeros(3)
        self._gyro = None if obs is None else np.asarray(obs["gyro"], dtype=float).copy()
        self.thrust_axis_reference = UP.copy()

    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:
        R = rotation_matrix(obs["attitude"])
        accel = self._acceleration_command(obs)
        thrust_vector = self.params.mass * (accel - np.array([0.0, 0.0, GRAVITY]))  # NED force wanted
        axis = -thrust_vector / np.linalg.norm(thrust_vector)                       # desired body z (down)
        self.thrust_axis_reference = -axis
        thrust = float(-thrust_vector @ R[:, 2])
        rates_cmd = self._attitude_command(R, axis, float(obs["reference_yaw"][0]))
        torque = self._rate_command(obs["gyro"], rates_cmd)
        return self.mix(max(thrust, 0.0), torque)

    def _acceleration_command(self, obs) -> np.ndarray:
        error = obs["reference_position"] - obs["position"]
        self._pos_integral += error * self.dt
        integral = np.clip(self._ki * self._pos_integral, -self.gains.integral_limit, self.gains.integral_limit)
        self._pos_integral = np.where(self._ki > 0, integral / np.where(self._ki > 0, self._ki, 1.0), 0.0)
        accel = self._kp * error + self._kd * (obs["reference_velocity"] - obs["velocity"]) + integral
        horizontal = np.hypot(accel[0], accel[1])
        if horizontal > self._max_horizontal:
            accel[:2] *= self._max_horizontal / horizontal
        accel[2] = min(accel[2], 0.8 * GRAVITY)  # never command less than 20% of hover thrust
        return accel

    def _attitude_command(self, R, z_des, yaw) -> np.ndarray:
        """Body-rate command from the geometric attitude error e_R = vee(R_d^T R - R^T R_d) / 2 (Lee 2010)."""
        x_c = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        y_des = cross(z_des, x_c)
        y_des /= np.linalg.norm(y_des)
        R_des = np.array((cross(y_des, z_des), y_des, z_des)).T
        E = R_des.T @ R - R.T @ R_des
        e_R = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        return np.minimum(np.maximum(-self._katt * e_R, -self._max_rate), self._max_rate)

    def _rate_command(self, gyro, rates_cmd) -> np.ndarray:
        if self._gyro is None:
            self._gyro = np.asarray(gyro, dtype=float).copy()
        self._gyro += self._gyro_alpha * (gyro - self._gyro)
        error = rates_cmd - self._gyro
        limit = self._alpha_integral_limit
        integral = self._rate_integral + self._krate_i * error * self.dt
        self._rate_integral = np.minimum(np.maximum(integral, -limit), limit)
        alpha = self._krate * error + self._rate_integral
        inertia, w = self._inertia, self._gyro
        return inertia * alpha + cross(w, inertia * w)

    def mix(self, thrust: float, torque) -> np.ndarray:
        """Normalised rotor commands for a collective thrust (N) and body torques (N m).

        When the rotors saturate, yaw torque is given up first (it matters least for staying aloft): only the
        share of it that fits between the rotor limits is kept.
        """
        base = self._mixer_inverse @ np.array([thrust, torque[0], torque[1], 0.0])
        yaw = self._mixer_inverse[:, 3] * torque[2]
        w2 = base + _largest_fitting_share(base, yaw, self._w2_min, self._w2_max) * yaw
        omega = np.sqrt(np.clip(w2, self._w2_min, self._w2_max))
        p = self.params
        return np.clip((omega - p.omega_min) / (p.omega_max - p.omega_min), 0.0, 1.0).astype(np.float32)


def _largest_fitting_share(base: np.ndarray, extra: np.ndarray, low: float, high: float) -> float:
    """The largest s in [0, 1] with low <= base + s extra <= high for every rotor that base leaves in range."""
    share = 1.0
    for b, e in zip(base, extra):
        if e > 0 and b < high:
            share = min(share, (high - b) / e)
        elif e < 0 and b > low:
            share = min(share, (low - b) / e)
    return max(share, 0.0)


def allocation_matrix(params: QuadrotorParams) -> np.ndarray:
    """[T, tau_x, tau_y, tau_z] = A omega^2 for nominal rotors (000 eq. 8; yaw row 004 eq. 7)."""
    return rotor_wrench_matrix(params.rotor_positions, params.thrust_coefficient, params.torque_coefficient)
