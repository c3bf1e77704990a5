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

from dataclasses import dataclass

import numpy as np

from ..models.constants import GRAVITY
from ..models.geometry import cross, rotation_matrix
from ..models.quadrotor import QuadrotorParams
from ..models.sensors import GYRO_LIMIT
from .axis_lqr import ScheduledAxisLqr
from .base import UP
from .relaxed_hover import relaxed_hover_equilibrium

#: Force ratio rho = f_opposite / f_adjacent flown per vehicle; others get `choose_rho`.
DEFAULT_RHO = {"mueller2014": 0.5}   # Mueller & D'Andrea's choice


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
    arrest_gain: float = 14.0                  # 1/s, rate-damping gain of the arrest (see ScheduledAxisLqr.arrest)
    arrest_attitude_gain: float = 0.0          # 1/s, rate per radian of thrust-axis error the arrest steers to
    arrest_attitude_fade: float | None = None  # share of the boost's spin over which that rate target fades out
    lqr_axis_weight: float = 1000.0            # 1/rad^2 on n_x, n_y errors
    lqr_axis_floor: float = 1.0                # share of the axis weight at r = 0, rising as (r / r_bar)^2
    lqr_rate_weight: float = 5.0               # s^2/rad^2 on p, q errors
    lqr_force_weight: float = 0.1              # 1/N^2 on rotor-force errors
    lqr_input_weight: float = 1.0              # 1/N^2 on the two zero-thrust force changes
    lqr_opposite_weight: float = 1.0           # extra weight on the opposite rotor's input at r = 0
    balance_idle: bool = False                 # operating point with the opposite rotor at idle (see _idle_balance)
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
    `thrust_axis_reference_for`); `axis_command`: n_des, the world direction it wants to spin about.
    """

    def __init__(self, params: QuadrotorParams, agent_hz: float, gains: SpinRecoveryGains | None = None):
        self.params = params
        self.gains = gains or gains_for(params)
        self.dt = 1.0 / agent_hz
        g = self.gains
        self._kp, self._kd, self._ki = (np.asarray(x, dtype=float)
                                        for x in (g.position, g.velocity, g.position_integral))
        self._gyro_alpha = 1.0 - np.exp(-2 * np.pi * g.gyro_cutoff_hz * self.dt)
        self._max_horizontal = GRAVITY * np.tan(np.deg2rad(g.max_axis_tilt_deg))
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
        R = rotation_matrix(obs["attitude"])
        rates = self._filtered_rates(obs["gyro"])
        position, velocity = self._circle_centre(obs, R, rates)
        force = self._force_command(obs, position, velocity)
        self.axis_command = self._slew(force / np.linalg.norm(force))
        thrust = -force[2] / max(R[2, 2], 0.5)
        n_body = R.T @ self.axis_command
        forces, n_target = self._lqr.forces(n_body, rates, obs["rotor_speed"], thrust)
        self.thrust_axis_reference = thrust_axis_reference_for(R, n_body, n_target)
        return self._commands(forces)

    def _slew(self, axis) -> np.ndarray:
        """The commanded axis turned from its last value toward `axis` by at most axis_slew_rate_deg * dt."""
        rate = self.gains.axis_slew_rate_deg
        if rate is None or self._axis_slewed is None:
            self._axis_slewed = axis
            return axis
        step = np.deg2rad(rate) * self.dt
        previous = self._axis_slewed
        angle = float(np.arccos(np.clip(previous @ axis, -1.0, 1.0)))
        if angle > step:
            k = cross(previous, axis)
            k /= np.linalg.norm(k)
            axis = previous * np.cos(step) + cross(k, previous) * np.sin(step)
        self._axis_slewed = axis
        return axis

    def _filtered_rates(self, gyro) -> np.ndarray:
        gyro = np.asarray(gyro, dtype=float)
        if self._gyro is None:
            self._gyro = gyro.copy()
        self._gyro += self._gyro_alpha * (gyro - self._gyro)
        return self._gyro

    def _circle_centre(self, obs, R, rates):
        """Position and velocity of the centre of the small circle the spinning vehicle flies.

        The thrust component a_perp normal to the spin axis turns with the body at |Omega|, so the centre of
        mass circles at radius |a_perp| / |Omega|^2 with velocity -Omega_w x a_perp / |Omega|^2 (App. B's
        r_ps). That motion is locked to the spin: fed back, it would return as a constant offset of the
        primary axis in the body (4 deg on mueller2014). The outer loop sees the centre only.
        """
        position, velocity = np.asarray(obs["position"], float), np.asarray(obs["velocity"], float)
        spin_w = R @ rates
        spin2 = float(spin_w @ spin_w)
        weight = min(max((np.sqrt(spin2) - 5.0) / 5.0, 0.0), 1.0)   # no circle to speak of below ~5 rad/s
        if weight == 0.0:
            return position, velocity
        omega = np.asarray(obs["rotor_speed"], float)[self._lqr.working]
        accel = self.params.thrust_coefficient * float(omega @ omega) / self.params.mass * -R[:, 2]
        accel_perp = accel - spin_w * float(spin_w @ accel) / spin2
        return (position + weight * accel_perp / spin2,
                velocity + weight * cross(spin_w, accel_perp) / spin2)

    def _force_command(self, obs, position, velocity) -> np.ndarray:
        """Desired force (NED, N): position PD + integral, velocity command capped, tilt of n_des limited."""
        target, velocity_ref = self._position_reference(obs)
        error = target - position
        limit = self.gains.integral_limit
        # Integrate only near the target: the transient after the switch would wind it up (overshoot).
        near = np.abs(error) < self.gains.integral_zone
        integral = np.clip(self._ki * (self._pos_integral + near * error * self.dt), -limit, limit)
        self._pos_integral = integral / self._ki
        velocity_cmd = velocity_ref + self._kp / self._kd * error
        horizontal = np.hypot(velocity_cmd[0], velocity_cmd[1])
        if horizontal > self.gains.max_horizontal_speed:
            velocity_cmd[:2] *= self.gains.max_horizontal_speed / horizontal
        accel = self._kd * (velocity_cmd - velocity) + integral
        horizontal = np.hypot(accel[0], accel[1])
        if horizontal > self._max_horizontal:
            accel[:2] *= self._max_horizontal / horizontal
        accel[2] = min(accel[2], 0.7 * GRAVITY)   # never ask for less than 30% of the weight
        return self.params.mass * (accel - np.array([0.0, 0.0, GRAVITY]))

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

    def _commands(self, forces) -> np.ndarray:
        p = self.params
        omega = np.sqrt(forces / p.thrust_coefficient)
        command = np.zeros(4)
        command[self._lqr.working] = (omega - p.omega_min) / (p.omega_max - p.omega_min)
        return np.clip(command, 0.0, 1.0).astype(np.float32)


def thrust_axis_reference_for(R, n_body, n_target) -> np.ndarray:
    """Where the thrust axis belongs now: -z of the attitude nearest R whose primary axis is on target.

    That attitude is R Q, Q the smallest rotation taking n_target to n_body (the commanded axis n_des seen in
    the body), so R Q n_target = n_des. Its thrust axis is at most the primary-axis error away from the
    measured one. In the relaxed hover the thrust axis circles n_des at the equilibrium tilt (16 deg for
    mueller2014 at rho = 0.5): compared with n_des itself, that design tilt would count as error.
    """
    axis = cross(n_target, n_body)
    s, c = float(np.linalg.norm(axis)), float(n_target @ n_body)
    minus_z = np.array([0.0, 0.0, -1.0])
    if s < 1e-12:
        return R @ minus_z
    k = axis / s
    rotated = minus_z * c + cross(k, minus_z) * s + k * float(k @ minus_z) * (1.0 - c)   # Rodrigues
    return R @ rotated
