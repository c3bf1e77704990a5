"""Rotor set of a multirotor: motor dynamics, thrust, drag torque, rotor drag, gyroscopic moments.

One model for every vehicle: positions, spin directions and coefficients come from the parameter set.
Effectiveness k_i (000 eq. 3) and `loaded` (propeller present) are the fault handles.
"""
from __future__ import annotations

import numpy as np


class RotorSet:
    """N rotors with thrust along body -z (FRD), first-order motors with rate limits."""

    def __init__(self, positions, yaw_signs, thrust_coefficient, torque_coefficient, omega_min, omega_max,
                 time_constant, max_acceleration, propeller_inertia, drag_coefficient,
                 unloaded_speed_ratio, unloaded_time_constant):
        self.positions = np.asarray(positions, dtype=float)
        self.yaw_signs = np.asarray(yaw_signs, dtype=float)
        self.c_t, self.c_q = thrust_coefficient, torque_coefficient
        self.omega_min, self.omega_max = omega_min, omega_max
        self.tau, self.tau_unloaded = time_constant, unloaded_time_constant
        self.max_acceleration = max_acceleration
        self.propeller_inertia = propeller_inertia
        self.drag_coefficient = drag_coefficient
        self.unloaded_speed_ratio = unloaded_speed_ratio
        n = len(self.positions)
        self.omega = np.zeros(n)
        self.omega_dot = np.zeros(n)
        self.effectiveness = np.ones(n)
        self.loaded = np.ones(n, dtype=bool)
        self._gain_dt = None
        # Moments of the rotor thrusts T_i (along -z): r_i x (0, 0, -T_i) = (-y_i T_i, x_i T_i, 0), 000 eq. (4).
        self._roll_arm = -self.positions[:, 1]
        self._pitch_arm = self.positions[:, 0]

    @classmethod
    def from_params(cls, params, yaw_signs):
        return cls(params.rotor_positions, yaw_signs, params.thrust_coefficient, params.torque_coefficient,
                   params.omega_min, params.omega_max, params.motor_time_constant,
                   params.max_rotor_acceleration, params.propeller_inertia, params.rotor_drag_coefficient,
                   params.unloaded_speed_ratio, params.unloaded_time_constant)

    def reset(self, omega) -> None:
        self.omega[:] = omega
        self.omega_dot[:] = 0.0
        self.effectiveness[:] = 1.0
        self.loaded[:] = True

    def command_to_omega(self, command: np.ndarray) -> np.ndarray:
        """Normalised commands in [0, 1] -> rotor speed set-points (linear between idle and max)."""
        return self.omega_min + command * (self.omega_max - self.omega_min)

    def step(self, omega_cmd: np.ndarray, dt: float) -> None:
        """Exact first-order lag toward the set-point, then the acceleration limit.

        A motor that lost its propeller (000 Sec. III-A) is unloaded: the ESC drives it faster for the same
        command (`unloaded_speed_ratio`) and it responds faster (`unloaded_time_constant`).
        """
        if dt != self._gain_dt:
            self._gain_dt = dt
            self._gain_loaded = 1.0 - np.exp(-dt / self.tau)
            self._gain_unloaded = 1.0 - np.exp(-dt / self.tau_unloaded)
        if self.loaded.all():
            delta = (omega_cmd - self.omega) * self._gain_loaded
        else:
            target = np.where(self.loaded, omega_cmd, omega_cmd * self.unloaded_speed_ratio)
            delta = (target - self.omega) * np.where(self.loaded, self._gain_loaded, self._gain_unloaded)
        limit = self.max_acceleration * dt
        delta = np.minimum(np.maximum(delta, -limit), limit)
        self.omega_dot = delta / dt
        self.omega = self.omega + delta

    def wrench(self, body_rates: np.ndarray, air_velocity_body: np.ndarray):
        """Force and moment on the body (FRD) from all rotors.

        - thrust c_T k_i omega_i^2 along -z (000 eq. 3) and its moments (000 eq. 4, 8);
        - drag torque c_Q k_i omega_i^2 with the yaw signs of 004 eq. (7) (docs/concepts.md, 'Rotor numbering');
        - rotor drag -k_d k_i omega_i v_inplane, proportional to airspeed times rotor speed (001 Sec. 4.3);
        - gyroscopic moment -Omega x h of the spinning propellers and the reaction to their spin-up.
          Propeller i spins about -s_i z (s_i its yaw sign), so h = -I_p sum(s_i omega_i) z.
        """
        k = self.effectiveness
        w = self.omega
        w2k = k * w * w
        thrust = self.c_t * w2k
        mx = float(self._roll_arm @ thrust)
        my = float(self._pitch_arm @ thrust)
        mz = self.c_q * float(self.yaw_signs @ w2k)
        inertia = self.propeller_inertia * self.loaded
        h_z = -float(inertia * self.yaw_signs @ w)
        mz += float(inertia * self.yaw_signs @ self.omega_dot)  # reaction to propeller spin-up
        p, q, _ = body_rates
        # -Omega x (0, 0, h_z) = (-q h_z, p h_z, 0)
        mx -= q * h_z
        my += p * h_z
        drag_gain = self.drag_coefficient * float(k @ w)
        fx = -drag_gain * air_velocity_body[0]
        fy = -drag_gain * air_velocity_body[1]
        force = np.array((fx, fy, -float(thrust.sum())))
        return force, np.array((mx, my, mz))

    @property
    def total_thrust(self) -> float:
        return self.c_t * float(self.effectiveness @ (self.omega * self.omega))
