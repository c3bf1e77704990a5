"""Nominal cascaded quadrotor controller: position -> thrust vector -> attitude -> body rates -> rotor speeds.

Fault-unaware: it knows the nominal parameter set (mass, inertia, rotor geometry and coefficients) and reads
only sensor observations. Position and velocity PID give a desired acceleration; the thrust direction and
yaw give a desired attitude, tracked with the geometric attitude error of Lee et al. (2010) as a body-rate
command; a PI rate loop gives angular accelerations, turned into torques with the inertia (plus the
gyroscopic coupling), and the mixer inverts the control-effectiveness model of 000 eq. (8) (with the yaw
row c_Q s_i of 004 eq. 7) for squared rotor speeds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from ..models.constants import GRAVITY
from ..models.geometry import cross3, rotation_matrix
from ..models.quadrotor import QuadrotorParams, rotor_wrench_matrix
from .base import UP


@dataclass
class ControllerGains:
    """Gains and limits of `NominalController`'s loops, outer to inner (module docstring); each field's unit is at
    its line. `gains_for` gives a vehicle's (`VEHICLE_GAINS`); pass your own to `NominalController(..., gains=...)`
    (`dataclasses.replace` changes one). How they were chosen: docs/measurements.md, 'Tuning record:
    agents/quadrotor_control.py'."""

    position: tuple = (1.6, 1.6, 2.0)       # 1/s^2, acceleration per metre of error
    velocity: tuple = (2.4, 2.4, 3.0)       # 1/s
    position_integral: tuple = (0.4, 0.4, 0.8)
    integral_limit: float = 2.0             # m/s^2, anti-windup on the integral's horizontal acceleration
    # m/s^2, the same upward and downward; None: all the rotors give beyond hover, g (T_max / W - 1), so the
    # integral trims out any payload the vehicle can lift (2 m/s^2 left Mueller's 0.5 kg + 0.5 kg 3.9 m low)
    vertical_integral_limit: float | None = None
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


def vertical_integral_limit(params: QuadrotorParams, gains: ControllerGains) -> float:
    """The gains' vertical_integral_limit, or by default the acceleration the rotors give beyond hover at full
    speed, g (4 c_T omega_max^2 / (m g) - 1) (000 eq. 3)."""
    if gains.vertical_integral_limit is not None:
        return gains.vertical_integral_limit
    return 4 * params.thrust_coefficient * params.omega_max ** 2 / params.mass - GRAVITY


def gains_for(params: QuadrotorParams) -> ControllerGains:
    """The default gains with the vehicle's entries of VEHICLE_GAINS applied."""
    return replace(ControllerGains(), **VEHICLE_GAINS.get(params.name, {}))


#: rows of `NominalController._axis_gains`, per axis (x, y, z): the ControllerGains of the same names, the
#: inertia and the rate integral's limit (rad/s^2)
KP, KD, KI, KATT, KRATE, KRATE_I, MAX_RATE, INERTIA, RATE_INTEGRAL_LIMIT = range(9)
#: entries of `NominalController._scalars`
(DT, MASS, INTEGRAL_LIMIT, MAX_HORIZONTAL, GYRO_ALPHA, W2_MIN, W2_MAX, OMEGA_MIN, OMEGA_MAX,
 VERTICAL_INTEGRAL_LIMIT) = range(10)


class NominalController:
    """Cascaded PID with model-based mixer; the `nominal` benchmark policy.

    The step is compiled (`_control_step`, numba): elementwise arithmetic in the order of the numpy version it
    replaced, and the matrix and vector products BLAS's as numpy's, so trajectories keep their bits. The gains
    are read when the controller is built.
    """

    def __init__(self, params: QuadrotorParams, agent_hz: float, gains: ControllerGains | None = None):
        self.params = params
        self.gains = gains or gains_for(params)
        self.dt = 1.0 / agent_hz
        g = self.gains
        allocation = allocation_matrix(params)
        self._mixer_inverse = np.linalg.inv(allocation)
        # Largest torque about each axis with rotors between idle and max: the integral may use a share of it,
        # enough to trim out a partial loss of effectiveness (002 Sec. 5.2) without winding up.
        span = params.omega_max ** 2 - params.omega_min ** 2
        max_torque = 0.5 * np.abs(allocation[1:]).sum(axis=1) * span
        inertia = np.asarray(params.inertia, dtype=float)
        self._axis_gains = np.array([g.position, g.velocity, g.position_integral, g.attitude, g.rate,
                                     g.rate_integral, g.max_rate, inertia,
                                     g.rate_integral_share * max_torque / inertia], dtype=float)
        self._scalars = np.array([self.dt, params.mass, g.integral_limit,
                                  GRAVITY * np.tan(np.deg2rad(g.max_tilt_deg)),
                                  1.0 - np.exp(-2 * np.pi * g.gyro_cutoff_hz * self.dt),
                                  params.omega_min ** 2, params.omega_max ** 2, params.omega_min, params.omega_max,
                                  vertical_integral_limit(params, g)])
        self.reset()

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        self._pos_integral = np.zeros(3)
        self._rate_integral = np.zeros(3)
        self._gyro = None if obs is None else np.array(obs["gyro"], dtype=float)
        self._thrust_axis = UP.copy()

    @property
    def thrust_axis_reference(self) -> np.ndarray:
        """The thrust direction (NED unit vector) of the last step's command; straight up before the first."""
        return self._thrust_axis.copy()

    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:
        if self._gyro is None:
            self._gyro = np.array(obs["gyro"], dtype=float)
        return _control_step(obs["attitude"], obs["position"], obs["velocity"], obs["reference_position"],
                             obs["reference_velocity"], float(obs["reference_yaw"][0]), obs["gyro"],
                             self._pos_integral, self._rate_integral, self._gyro, self._thrust_axis,
                             self._axis_gains, self._scalars, self._mixer_inverse)

    def mix(self, thrust: float, torque) -> np.ndarray:
        """Normalised rotor commands for a collective thrust (N) and body torques (N m) (`_mix`)."""
        return _mix(float(thrust), np.asarray(torque, dtype=float), self._mixer_inverse, self._scalars)


@njit(cache=True)
def _control_step(attitude, position, velocity, reference_position, reference_velocity, yaw, gyro,
                  pos_integral, rate_integral, gyro_filtered, thrust_axis, gains, scalars,
                  mixer_inverse):  # pragma: no cover (compiled)
    """One step of `NominalController.act`: the normalised rotor commands (float32). Updates in place the
    integrals, the filtered gyro and the thrust axis (-z) the command asks for (NED unit vector)."""
    R = rotation_matrix(attitude)
    accel = _acceleration_command(position, velocity, reference_position, reference_velocity, pos_integral,
                                  gains, scalars)
    mass = scalars[MASS]
    thrust_vector = np.array([mass * accel[0], mass * accel[1], mass * (accel[2] - GRAVITY)])  # NED force wanted
    axis = -thrust_vector / math.sqrt(np.dot(thrust_vector, thrust_vector))   # desired body z (down)
    thrust_axis[:] = -axis
    thrust = np.dot(-thrust_vector, R[:, 2].copy())
    rates_cmd = _attitude_command(R, axis, yaw, gains)
    torque = _rate_command(gyro, rates_cmd, rate_integral, gyro_filtered, gains, scalars)
    return _mix(max(thrust, 0.0), torque, mixer_inverse, scalars)


@njit(cache=True)
def _acceleration_command(position, velocity, reference_position, reference_velocity, pos_integral, gains,
                          scalars):  # pragma: no cover (compiled)
    """Desired NED acceleration: position and velocity PID, the integral's acceleration clipped to
    +-integral_limit horizontally and +-vertical_integral_limit vertically (anti-windup, the integral kept
    consistent with the clip), the horizontal part limited to the tilt limit's and at most 0.8 g downward (never
    less than 20% of hover thrust)."""
    dt, max_horizontal = scalars[DT], scalars[MAX_HORIZONTAL]
    accel = np.empty(3)
    for i in range(3):
        limit = scalars[INTEGRAL_LIMIT] if i < 2 else scalars[VERTICAL_INTEGRAL_LIMIT]
        error = reference_position[i] - position[i]
        ki = gains[KI, i]
        integral = min(max(ki * (pos_integral[i] + error * dt), -limit), limit)
        pos_integral[i] = integral / ki if ki > 0 else 0.0
        accel[i] = gains[KP, i] * error + gains[KD, i] * (reference_velocity[i] - velocity[i]) + integral
    horizontal = math.hypot(accel[0], accel[1])
    if horizontal > max_horizontal:
        scale = max_horizontal / horizontal
        accel[0] *= scale
        accel[1] *= scale
    accel[2] = min(accel[2], 0.8 * GRAVITY)
    return accel


@njit(cache=True)
def _attitude_command(R, z_des, yaw, gains):  # pragma: no cover (compiled)
    """Body-rate command from the geometric attitude error e_R = vee(R_d^T R - R^T R_d) / 2 (Lee 2010), R_d
    with body z along `z_des` and heading `yaw`; clipped to +-max_rate."""
    y = np.array(cross3(z_des, (math.cos(yaw), math.sin(yaw), 0.0)))
    y /= math.sqrt(np.dot(y, y))
    x = cross3(y, z_des)
    R_des_T = np.array([[x[0], x[1], x[2]], [y[0], y[1], y[2]], [z_des[0], z_des[1], z_des[2]]])
    E = R_des_T @ R - R.T @ R_des_T.T
    e_R = (0.5 * E[2, 1], 0.5 * E[0, 2], 0.5 * E[1, 0])
    rates = np.empty(3)
    for i in range(3):
        rates[i] = min(max(-gains[KATT, i] * e_R[i], -gains[MAX_RATE, i]), gains[MAX_RATE, i])
    return rates


@njit(cache=True)
def _rate_command(gyro, rates_cmd, rate_integral, gyro_filtered, gains, scalars):  # pragma: no cover (compiled)
    """Body torque (N m): the gyro low-passed (first order), a PI rate loop with its integral clipped to the
    limit, times the inertia, plus the gyroscopic coupling w x I w."""
    alpha = np.empty(3)
    for i in range(3):
        gyro_filtered[i] += scalars[GYRO_ALPHA] * (gyro[i] - gyro_filtered[i])
        error = rates_cmd[i] - gyro_filtered[i]
        limit = gains[RATE_INTEGRAL_LIMIT, i]
        rate_integral[i] = min(max(rate_integral[i] + gains[KRATE_I, i] * error * scalars[DT], -limit), limit)
        alpha[i] = gains[KRATE, i] * error + rate_integral[i]
    inertia = gains[INERTIA]
    gyroscopic = cross3(gyro_filtered, inertia * gyro_filtered)
    return inertia * alpha + np.array(gyroscopic)


@njit(cache=True)
def _mix(thrust, torque, mixer_inverse, scalars):  # pragma: no cover (compiled)
    """Normalised rotor commands (float32) for a collective thrust (N) and body torques (N m): the inverse of the
    control-effectiveness model (module docstring) for squared rotor speeds.

    When the rotors saturate, yaw torque is given up first (it matters least for staying aloft): only the
    share of it that fits between the rotor limits is kept.
    """
    w2_min, w2_max, omega_min, omega_max = scalars[W2_MIN], scalars[W2_MAX], scalars[OMEGA_MIN], scalars[OMEGA_MAX]
    base = mixer_inverse @ np.array([thrust, torque[0], torque[1], 0.0])
    yaw = mixer_inverse[:, 3] * torque[2]
    w2 = base + _largest_fitting_share(base, yaw, w2_min, w2_max) * yaw
    command = np.empty(len(w2), dtype=np.float32)
    for i in range(len(w2)):
        omega = math.sqrt(min(max(w2[i], w2_min), w2_max))
        command[i] = min(max((omega - omega_min) / (omega_max - omega_min), 0.0), 1.0)
    return command


@njit(cache=True)
def _largest_fitting_share(base, extra, low, high):  # pragma: no cover (compiled)
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
