"""Flight after the loss of one propeller: give up yaw, spin, and control the primary axis.

`SpinRecoveryController` flies the relaxed hover of Mueller & D'Andrea ("Stability and control of a
quadrocopter despite the complete loss of one, two, or three propellers", ICRA 2014; 001 Part II App. B;
`relaxed_hover.py`). The output is Sun et al.'s reduced attitude ("High-speed flight of quadrotor despite
loss of single rotor", RA-L 2018): the primary axis n_B = R^T n_des, the world direction the vehicle should
spin about, seen in the body; its x and y components are driven to those of the equilibrium axis n_bar.

Per agent step:
1. Outer loop (`_force_command`): position PD + integral on the centre of the small circle the spinning
   vehicle flies -> desired force F = m (a - g) -> n_des = F / |F| (tilt-limited) and the collective
   thrust from the vertical balance T R_33 = -F_z. The PD is a cascade, velocity command k_p / k_d e (capped)
   then a = k_d (v_cmd - v) = k_p e - k_d v, so s^2 + k_d s + k_p: horizontally k_p = 3/s^2, k_d = 3/s
   (poles -1.5 +- 0.87j, damping 0.87), on bebop2 4 and 3.5 (-1.75 +- 0.97j, 0.87); the horizontal command
   is capped at 5 m/s and the tilt of n_des at 20 deg (bebop2 30 deg). n_des then turns at most 60 deg/s
   (`axis_slew_rate_deg`): the spinning vehicle's axis lags a faster swing (the corners of a moving set-point,
   the reversal of a fast return) by more than 10 deg.
   No acceleration feed-forward: the hover and goto set-points are steps, the observation carries no
   reference acceleration.
2. Inner loop (`axis_lqr.ScheduledAxisLqr`): LQR on the linearised body-frame dynamics of (p, q, n_x, n_y) as
   Mueller & D'Andrea, plus the rotor forces' lag, gain-scheduled on the yaw rate while the spin builds
   up. Not the model inversion (NDI) of Sun et al.'s output: it holds the equilibrium, but it cancels the
   gyroscopic coupling that is the only way to hold the failed rotor's side up at low spin
   (docs/measurements.md, 'Tuning record: agents/spin_recovery.py').
3. Forces -> rotor speeds f = c_T omega^2 (App. B eq. 10) -> normalised commands; the failed rotor idles.

Only observations are used (gyro, attitude, position, velocity, rotor_speed, reference_*) and the failed
rotor index given to `engage`. `spin_policies`: `ftc-spin` and `oracle-spin`
wrap it with the nominal controller for the flight before the fault.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..models.constants import GRAVITY
from ..models.geometry import blas_dot, cross3, rotation_matrix
from ..models.quadrotor import QuadrotorParams
from ..models.sensors import GYRO_LIMIT
from .axis_lqr import ScheduledAxisLqr, lqr_forces
from .base import UP
from .relaxed_hover import relaxed_hover_equilibrium

#: Force ratio rho = f_opposite / f_adjacent flown per vehicle; others get `choose_rho`.
DEFAULT_RHO = {"mueller2014": 0.5}   # Mueller & D'Andrea's choice
#: rows of `SpinRecoveryController._outer_gains`, per axis: SpinRecoveryGains position, velocity, position_integral
KP, KD, KI = range(3)
#: entries of `SpinRecoveryController._scalars`
(DT, GYRO_ALPHA, MAX_HORIZONTAL, INTEGRAL_LIMIT, INTEGRAL_ZONE, MAX_HORIZONTAL_SPEED, MASS, THRUST_COEFFICIENT,
 OMEGA_MIN, OMEGA_MAX) = range(10)


@dataclass
class SpinRecoveryGains:
    rho: float | None = None                   # force ratio of the equilibrium; None: DEFAULT_RHO / choose_rho
    # outer loop
    position: tuple = (3.0, 3.0, 4.0)          # 1/s^2, acceleration per metre
    velocity: tuple = (3.0, 3.0, 3.5)          # 1/s
    position_integral: tuple = (0.3, 0.3, 2.0)  # 1/s^3
    integral_limit: float = 2.0                # m/s^2
    integral_zone: float = 0.3                 # m, position error inside which the integral runs
    max_axis_tilt_deg: float = 20.0            # n_des from vertical
    max_horizontal_speed: float = 5.0          # m/s, cap on the velocity command
    axis_slew_rate_deg: float | None = 60.0    # deg/s, fastest turn of the commanded axis n_des; None: no limit
    gyro_cutoff_hz: float = 60.0               # first-order low-pass against motor vibration
    # inner loop (ScheduledAxisLqr)
    schedule_power: float = 2.0                # target axis leans toward n_bar as (r / r_bar)^power
    boost_until: float = 0.5                   # below this share of r_bar the adjacent pair runs flat out
    arrest_rate: float | None = None           # rad/s: above this roll/pitch rate the boost damps it first
    arrest_gain: float = 14.0                  # 1/s, rate-damping gain of the arrest (see axis_lqr.arrest)
    arrest_attitude_gain: float = 0.0          # 1/s, rate per radian of thrust-axis error the arrest steers to
    arrest_attitude_fade: float | None = None  # share of the boost's spin over which that rate target fades out
    lqr_axis_weight: float = 1000.0            # 1/rad^2 on n_x, n_y errors
    lqr_axis_floor: float = 1.0                # share of the axis weight at r = 0, rising as (r / r_bar)^2
    lqr_rate_weight: float = 5.0               # s^2/rad^2 on p, q errors
    lqr_force_weight: float = 0.1              # 1/N^2 on rotor-force errors
    lqr_input_weight: float = 1.0              # 1/N^2 on the two zero-thrust force changes
    lqr_opposite_weight: float = 1.0           # extra weight on the opposite rotor's input at r = 0
    balance_idle: bool = False                 # operating point, opposite rotor at idle (axis_lqr._idle_balance)
    # landing
    landing_speed: float = 0.4                 # m/s, descent of `land()` above 1 m (<= 0.5 m/s)
    touchdown_speed: float = 0.25              # m/s, descent in the last metre
    touchdown_margin: float = 0.15             # m above the resting height where a stop counts as touchdown


#: Per-vehicle departures from the defaults. The Bebop 2 (inertia a third of Mueller's for similar rotor
#: moments) tips fastest: it gets the idle balance, an LQR that leaves the opposite rotor alone while the spin
#: builds up, and little axis weight before gyroscopic stiffness exists. With the stiffer nominal rate loop
#: (`quadrotor_control.VEHICLE_GAINS`) it also boosts to 0.6 r_bar. Chosen on tuning flights; see
#: docs/measurements.md, 'Tuning record: agents/spin_recovery.py'.
VEHICLE_GAINS = {"bebop2": {"balance_idle": True, "lqr_opposite_weight": 1000.0, "lqr_axis_floor": 0.01,
                            "arrest_rate": 1.0, "boost_until": 0.6, "arrest_attitude_gain": 4.0,
                            "arrest_attitude_fade": 0.3, "position": (4.0, 4.0, 6.0), "velocity": (3.5, 3.5, 4.5),
                            "max_axis_tilt_deg": 30.0}}


def gains_for(params: QuadrotorParams) -> SpinRecoveryGains:
    """The default gains with the vehicle's entries of VEHICLE_GAINS applied."""
    return SpinRecoveryGains(**VEHICLE_GAINS.get(params.name, {}))


def choose_rho(params: QuadrotorParams, failed_rotor: int = 3) -> float:
    """Mueller & D'Andrea's 0.5 for their vehicle; else the smallest rho >= 0.5 whose relaxed hover fits the
    rotor limits and keeps the yaw rate 10% inside the gyro's range (the controller must measure the spin)."""
    if params.name in DEFAULT_RHO:
        return DEFAULT_RHO[params.name]
    for rho in np.arange(0.5, 3.0, 0.05):
        try:
            eq = relaxed_hover_equilibrium(params, float(rho), failed_rotor=failed_rotor)
        except ValueError:
            continue
        if abs(eq["yaw_rate"]) < 0.9 * GYRO_LIMIT:
            return float(rho)
    raise ValueError(f"{params.name}: no relaxed hover keeps the yaw rate inside the gyro range")


class SpinRecoveryController:
    """Primary-axis control of a quadrotor that lost one propeller; see the module docstring.

    `engage(failed_rotor, obs)` starts it (the policies call it on the alarm); `land()` turns holding the
    reference into a descent and touchdown. `mode`: "standby" (not engaged), "hold", "land", "landed".
    `thrust_axis_reference` (NED unit vector): where the controller wants the thrust axis -z now (see
    `thrust_axis_reference_for`); `axis_command`: n_des, the world direction it wants to spin about;
    `thrust_command`: the collective thrust (N) of the outer loop's vertical balance (the weight before `act`).
    The gains are read when the controller is built (the inner loop's when it engages a rotor), except
    `axis_slew_rate_deg` and the landing speeds, read at each step. The step's arithmetic is compiled
    (`_axis_demand`, `_inner_step`; numba) in the order of the numpy version it replaced, the products and
    solves BLAS's and LAPACK's as numpy's, so trajectories keep their bits.
    """

    def __init__(self, params: QuadrotorParams, agent_hz: float, gains: SpinRecoveryGains | None = None):
        self.params = params
        self.gains = gains or gains_for(params)
        self.dt = 1.0 / agent_hz
        g = self.gains
        self._outer_gains = np.array([g.position, g.velocity, g.position_integral], dtype=float)
        self._scalars = np.array([self.dt, 1.0 - np.exp(-2 * np.pi * g.gyro_cutoff_hz * self.dt),
                                  GRAVITY * np.tan(np.deg2rad(g.max_axis_tilt_deg)), g.integral_limit,
                                  g.integral_zone, g.max_horizontal_speed, params.mass, params.thrust_coefficient,
                                  params.omega_min, params.omega_max], dtype=float)
        self._equilibria: dict[int, dict] = {}
        self._lqrs: dict[int, ScheduledAxisLqr] = {}
        self.reset()

    # ------------------------------------------------------------------ lifecycle
    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        self.failed_rotor, self.mode = None, "standby"
        self._pos_integral = np.zeros(3)
        self._gyro = None
        self._landing_target = None
        self._stopped_steps = 0
        self.thrust_axis_reference = UP.copy()
        self.axis_command = UP.copy()
        self.thrust_command = self.params.mass * GRAVITY
        self._axis_slewed = None

    def equilibrium(self, failed_rotor: int) -> dict:
        """The relaxed hover flown without `failed_rotor` (cached)."""
        if failed_rotor not in self._equilibria:
            rho = self.gains.rho if self.gains.rho is not None else choose_rho(self.params, failed_rotor)
            self._equilibria[failed_rotor] = relaxed_hover_equilibrium(self.params, rho, failed_rotor=failed_rotor)
        return self._equilibria[failed_rotor]

    def engage(self, failed_rotor: int, obs: dict | None = None) -> None:
        """Start flying without `failed_rotor` (0-based); gains are designed on first use of each rotor."""
        failed_rotor = int(failed_rotor)
        if failed_rotor not in self._lqrs:
            self._lqrs[failed_rotor] = ScheduledAxisLqr(self.params, failed_rotor, self.equilibrium(failed_rotor),
                                                        self.gains)
        self.failed_rotor, self._lqr = failed_rotor, self._lqrs[failed_rotor]
        self.mode = "hold"
        if obs is not None:
            self._gyro = np.asarray(obs["gyro"], dtype=float).copy()

    def land(self) -> None:
        """Descend where the vehicle is (landing_speed, touchdown_speed in the last metre) and stop the
        motors once the ground has stopped it."""
        if self.mode == "standby":
            raise RuntimeError("SpinRecoveryController.land before engage(failed_rotor)")
        if self.mode == "hold":
            self.mode, self._landing_target = "land", None

    # ------------------------------------------------------------------ control
    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:
        if self.mode == "standby":
            raise RuntimeError("SpinRecoveryController.act before engage(failed_rotor)")
        if self.mode == "land" and self._touched_down(obs):
            self.mode = "landed"
        if self.mode == "landed":
            return np.zeros(4, dtype=np.float32)
        R = rotation_matrix(np.asarray(obs["attitude"], dtype=float))
        gyro, rotor_speed = np.asarray(obs["gyro"], dtype=float), np.asarray(obs["rotor_speed"], dtype=float)
        if self._gyro is None:
            self._gyro = gyro.copy()
        target, velocity_ref = self._position_reference(obs)
        axis, thrust = _axis_demand(R, gyro, np.asarray(obs["position"], dtype=float),
                                    np.asarray(obs["velocity"], dtype=float), rotor_speed, target, velocity_ref,
                                    self._gyro, self._pos_integral, self._lqr.working, self._outer_gains,
                                    self._scalars)
        self.axis_command, self.thrust_command = self._slew(axis), thrust
        command, self.thrust_axis_reference = _inner_step(R, self.axis_command, self._gyro, rotor_speed, thrust,
                                                          self._lqr.model, self._scalars)
        return command

    def _slew(self, axis) -> np.ndarray:
        """The commanded axis turned from its last value toward `axis` by at most axis_slew_rate_deg * dt."""
        rate = self.gains.axis_slew_rate_deg
        if rate is None or self._axis_slewed is None:
            self._axis_slewed = axis
            return axis
        step = math.radians(rate) * self.dt
        previous = self._axis_slewed
        # numpy's arccos: on AVX-512 machines numpy has its own kernel, whose bits math.acos does not share
        if float(np.arccos(min(max(blas_dot(previous, axis), -1.0), 1.0))) > step:
            axis = _turn_toward(previous, axis, step)
        self._axis_slewed = axis
        return axis

    def _position_reference(self, obs):
        """The task's reference while holding; while landing, a point sinking below the ground at the
        descent speed, above the spot where `land()` was called."""
        if self.mode != "land":
            return (np.asarray(obs["reference_position"], dtype=float),
                    np.asarray(obs["reference_velocity"], dtype=float))
        if self._landing_target is None:
            self._landing_target = np.asarray(obs["position"], dtype=float).copy()
        altitude = -float(obs["position"][2]) - self._rest_height()
        speed = self.gains.landing_speed if altitude > 1.0 else self.gains.touchdown_speed
        target = self._landing_target
        target[2] = min(max(target[2], float(obs["position"][2]) - 0.5) + speed * self.dt, 0.5)
        return target.copy(), np.array([0.0, 0.0, speed])

    def _touched_down(self, obs) -> bool:
        """Near the ground and no longer sinking for 0.1 s: the ground holds the vehicle."""
        low = -float(obs["position"][2]) < self._rest_height() + self.gains.touchdown_margin
        stopped = float(obs["velocity"][2]) < 0.05
        self._stopped_steps = self._stopped_steps + 1 if (low and stopped) else 0
        return self._stopped_steps * self.dt >= 0.1

    def _rest_height(self) -> float:
        return 0.5 * self.params.body_size[2]


@njit(cache=True)
def thrust_axis_reference_for(R, n_body, n_target):  # pragma: no cover (compiled)
    """Where the thrust axis belongs now: -z of the attitude nearest R whose primary axis is on target.

    That attitude is R Q, Q the smallest rotation taking n_target to n_body (the commanded axis n_des seen in
    the body), so R Q n_target = n_des. Its thrust axis is at most the primary-axis error away from the
    measured one. In the relaxed hover the thrust axis circles n_des at the equilibrium tilt (16 deg for
    mueller2014 at rho = 0.5): compared with n_des itself, that design tilt would count as error.
    """
    axis = np.array(cross3(n_target, n_body))
    s, c = math.sqrt(np.dot(axis, axis)), np.dot(n_target, n_body)
    minus_z = np.array([0.0, 0.0, -1.0])
    if s < 1e-12:
        return R @ minus_z
    k = axis / s
    rotated = (minus_z * c + np.array(cross3(k, minus_z)) * s
               + k * np.dot(k, minus_z) * (1.0 - c))   # Rodrigues
    return R @ rotated


@njit(cache=True)
def _turn_toward(previous, axis, step):  # pragma: no cover (compiled)
    """`previous` (unit vector) turned by the angle `step` toward `axis` (Rodrigues about previous x axis)."""
    k = np.array(cross3(previous, axis))
    k /= math.sqrt(np.dot(k, k))
    return previous * math.cos(step) + np.array(cross3(k, previous)) * math.sin(step)


@njit(cache=True)
def _axis_demand(R, gyro, position, velocity, rotor_speed, target, velocity_ref, gyro_filtered, pos_integral,
                 working, gains, scalars):  # pragma: no cover (compiled)
    """Outer loop (module docstring, step 1): the desired thrust direction n_des (NED unit vector, before the
    slew) and the collective thrust from the vertical balance T R_33 = -F_z. Low-passes the gyro (first order,
    against motor vibration) and updates the position integral, in place."""
    alpha = scalars[GYRO_ALPHA]
    for i in range(3):
        gyro_filtered[i] += alpha * (gyro[i] - gyro_filtered[i])
    centre, centre_velocity = _circle_centre(R, gyro_filtered, position, velocity, rotor_speed[working], scalars)
    force = _force_command(target, velocity_ref, centre, centre_velocity, pos_integral, gains, scalars)
    return force / math.sqrt(np.dot(force, force)), -force[2] / max(R[2, 2], 0.5)


@njit(cache=True)
def _circle_centre(R, rates, position, velocity, omega, scalars):  # pragma: no cover (compiled)
    """Position and velocity of the centre of the small circle the spinning vehicle flies; `omega`: the
    working rotors' speeds.

    The thrust component a_perp normal to the spin axis turns with the body at |Omega|, so the centre of
    mass circles at radius |a_perp| / |Omega|^2 with velocity -Omega_w x a_perp / |Omega|^2 (App. B's
    r_ps). That motion is locked to the spin: fed back, it would return as a constant offset of the
    primary axis in the body (4 deg on mueller2014). The outer loop sees the centre only.
    """
    spin_w = R @ rates
    spin2 = np.dot(spin_w, spin_w)
    weight = min(max((math.sqrt(spin2) - 5.0) / 5.0, 0.0), 1.0)   # no circle to speak of below ~5 rad/s
    if weight == 0.0:
        return position, velocity
    accel = scalars[THRUST_COEFFICIENT] * np.dot(omega, omega) / scalars[MASS] * -R[:, 2]
    accel_perp = accel - spin_w * np.dot(spin_w, accel) / spin2
    return (position + weight * accel_perp / spin2,
            velocity + weight * np.array(cross3(spin_w, accel_perp)) / spin2)


@njit(cache=True)
def _force_command(target, velocity_ref, position, velocity, pos_integral, gains,
                   scalars):  # pragma: no cover (compiled)
    """Desired force (NED, N): position PD + integral, velocity command capped, tilt of n_des limited. The
    integral runs only near the target: the transient after the switch would wind it up (overshoot)."""
    dt, limit, zone = scalars[DT], scalars[INTEGRAL_LIMIT], scalars[INTEGRAL_ZONE]
    velocity_cmd, integral = np.empty(3), np.empty(3)
    for i in range(3):
        error = target[i] - position[i]
        near = 1.0 if abs(error) < zone else 0.0
        integral[i] = min(max(gains[KI, i] * (pos_integral[i] + near * error * dt), -limit), limit)
        pos_integral[i] = integral[i] / gains[KI, i]
        velocity_cmd[i] = velocity_ref[i] + gains[KP, i] / gains[KD, i] * error
    _limit_horizontal(velocity_cmd, scalars[MAX_HORIZONTAL_SPEED])
    accel = gains[KD] * (velocity_cmd - velocity) + integral
    _limit_horizontal(accel, scalars[MAX_HORIZONTAL])
    accel[2] = min(accel[2], 0.7 * GRAVITY)   # never ask for less than 30% of the weight
    mass = scalars[MASS]
    return np.array([mass * accel[0], mass * accel[1], mass * (accel[2] - GRAVITY)])


@njit(cache=True)
def _limit_horizontal(vector, limit):  # pragma: no cover (compiled)
    """Scale the horizontal part of `vector` (in place) down to `limit` at most."""
    horizontal = math.hypot(vector[0], vector[1])
    if horizontal > limit:
        scale = limit / horizontal
        vector[0] *= scale
        vector[1] *= scale


@njit(cache=True)
def _inner_step(R, axis_command, rates, rotor_speed, thrust, model, scalars):  # pragma: no cover (compiled)
    """Inner loop and rotors (module docstring, steps 2-3): the normalised rotor commands (float32; the failed
    rotor idles) and the thrust axis reference (`thrust_axis_reference_for`). The primary axis n_B = R^T n_des."""
    n_body = R.T @ axis_command
    forces, n_target = lqr_forces(model, n_body, rates, rotor_speed, thrust)
    omega_min, omega_max = scalars[OMEGA_MIN], scalars[OMEGA_MAX]
    omega = np.sqrt(forces / scalars[THRUST_COEFFICIENT])    # f = c_T omega^2 (App. B eq. 10)
    command = np.zeros(4, dtype=np.float32)
    for k in range(len(model.working)):
        command[model.working[k]] = min(max((omega[k] - omega_min) / (omega_max - omega_min), 0.0), 1.0)
    return command, thrust_axis_reference_for(R, n_body, n_target)
