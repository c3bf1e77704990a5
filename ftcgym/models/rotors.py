"""Rotor set of a multirotor: motor dynamics, thrust, drag torque, rotor drag, gyroscopic moments.

One model for every vehicle: positions, spin directions and coefficients come from the parameter set.
Effectiveness k_i (000 eq. 3) and `loaded` (propeller present) are the fault handles: arrays written in place
(`faults.FaultSchedule.rotor_state`), after which `sync()` brings the physics step's copies up to date.
The rotor speeds live as plain floats (the physics step's form); `omega` and `omega_dot` give them as arrays.
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
        self._omega, self._omega_dot = [0.0] * n, [0.0] * n
        self.effectiveness = np.ones(n)
        self.loaded = np.ones(n, dtype=bool)
        self._gain_dt = None
        # Moments of the rotor thrusts T_i (along -z): r_i x (0, 0, -T_i) = (-y_i T_i, x_i T_i, 0), 000 eq. (4).
        self._roll_arm = -self.positions[:, 1]
        self._pitch_arm = self.positions[:, 0]
        self._roll_arm_list, self._pitch_arm_list = self._roll_arm.tolist(), self._pitch_arm.tolist()
        self._signs_list = self.yaw_signs.tolist()
        self.sync()

    @classmethod
    def from_params(cls, params, yaw_signs):
        return cls(params.rotor_positions, yaw_signs, params.thrust_coefficient, params.torque_coefficient,
                   params.omega_min, params.omega_max, params.motor_time_constant,
                   params.max_rotor_acceleration, params.propeller_inertia, params.rotor_drag_coefficient,
                   params.unloaded_speed_ratio, params.unloaded_time_constant)

    omega = property(lambda self: np.array(self._omega), doc="rotor speeds (rad/s), a fresh array")
    omega_dot = property(lambda self: np.array(self._omega_dot), doc="rotor accelerations (rad/s^2), a fresh array")

    omega_list = property(lambda self: self._omega, doc="rotor speeds (rad/s): the physics step's list (read only)")

    @omega.setter
    def omega(self, value) -> None:
        self._omega = np.broadcast_to(np.asarray(value, dtype=float), (len(self._omega),)).tolist()

    def reset(self, omega) -> None:
        self.omega = omega
        self._omega_dot = [0.0] * len(self._omega)
        self.effectiveness[:] = 1.0
        self.loaded[:] = True
        self.sync()

    def sync(self) -> None:
        """Copy the fault handles `effectiveness` and `loaded` into the physics step's floats (after a write)."""
        self._k, self._loaded_list = self.effectiveness.tolist(), self.loaded.tolist()
        self._all_loaded = all(self._loaded_list)
        # I_p * loaded_i * s_i per rotor (0 for a rotor without its propeller)
        self._spin = (self.propeller_inertia * self.loaded * self.yaw_signs).tolist()

    def command_to_omega(self, command: np.ndarray) -> np.ndarray:
        """Normalised commands in [0, 1] -> rotor speed set-points (linear between idle and max)."""
        return self.omega_min + command * (self.omega_max - self.omega_min)

    def step(self, omega_cmd, dt: float) -> None:
        """Exact first-order lag toward the set-point, then the acceleration limit.

        A motor that lost its propeller (000 Sec. III-A) is unloaded: the ESC drives it faster for the same
        command (`unloaded_speed_ratio`) and it responds faster (`unloaded_time_constant`). `omega` and
        `omega_dot` are updated.
        """
        self.advance(omega_cmd, dt)

    def advance(self, omega_cmd, dt: float):
        """`step` on plain floats (four rotors cost less without numpy); returns (omega, omega_dot) as lists."""
        if dt != self._gain_dt:
            self._gain_dt = dt
            self._gain_loaded = float(1.0 - np.exp(-dt / self.tau))
            self._gain_unloaded = float(1.0 - np.exp(-dt / self.tau_unloaded))
        omega, loaded = self._omega, self._loaded_list
        gain, limit = self._gain_loaded, self.max_acceleration * dt
        if len(omega) == 4 and self._all_loaded:    # the common case, unrolled
            c0, c1, c2, c3 = omega_cmd
            w0, w1, w2, w3 = omega
            d0 = min(max((c0 - w0) * gain, -limit), limit)
            d1 = min(max((c1 - w1) * gain, -limit), limit)
            d2 = min(max((c2 - w2) * gain, -limit), limit)
            d3 = min(max((c3 - w3) * gain, -limit), limit)
            omega_dot = [d0 / dt, d1 / dt, d2 / dt, d3 / dt]
            omega = [w0 + d0, w1 + d1, w2 + d2, w3 + d3]
        else:
            ratio, unloaded_gain = self.unloaded_speed_ratio, self._gain_unloaded
            delta = [min(max((c - w) * gain if on else (c * ratio - w) * unloaded_gain, -limit), limit)
                     for c, w, on in zip(omega_cmd, omega, loaded)]
            omega_dot = [d / dt for d in delta]
            omega = [w + d for w, d in zip(omega, delta)]
        self._omega, self._omega_dot = omega, omega_dot
        return omega, omega_dot

    def wrench(self, body_rates, air_velocity_body):
        """Force and moment on the body (FRD) from all rotors, as arrays (`wrench_floats`)."""
        force, moment = self.wrench_floats(self._omega, self._omega_dot, body_rates, air_velocity_body)
        return np.array(force), np.array(moment)

    def wrench_floats(self, omega, omega_dot, body_rates, air_velocity_body):
        """Force and moment on the body (FRD) from all rotors at speeds `omega` and accelerations `omega_dot`
        (the state `advance` returns), as 3-tuples of floats:

        - thrust c_T k_i omega_i^2 along -z (000 eq. 3) and its moments (000 eq. 4, 8);
        - drag torque c_Q k_i omega_i^2 with the yaw signs of 004 eq. (7) (docs/concepts.md, 'Rotor numbering');
        - rotor drag -k_d k_i omega_i v_inplane, proportional to airspeed times rotor speed (001 Sec. 4.3);
        - gyroscopic moment -Omega x h of the spinning propellers and the reaction to their spin-up.
          Propeller i spins about -s_i z (s_i its yaw sign), so h = -I_p sum(s_i omega_i) z.

        The sums run rotor by rotor in index order, as numpy's dot products of 4-vectors do (same bits).
        """
        k = self._k
        if len(k) == 4:
            return self._wrench4(k, omega, omega_dot, body_rates, air_velocity_body)
        c_t, roll_arm, pitch_arm, signs = self.c_t, self._roll_arm_list, self._pitch_arm_list, self._signs_list
        w2k = [ki * wi * wi for ki, wi in zip(k, omega)]
        thrust = [c_t * x for x in w2k]
        mx = mz = drag = total = h_z = spin_up = 0.0
        my_even = my_odd = 0.0
        for i in range(len(thrust)):
            t = thrust[i]
            mx += roll_arm[i] * t
            if i % 2:
                my_odd += pitch_arm[i] * t
            else:
                my_even += pitch_arm[i] * t
            mz += signs[i] * w2k[i]
            drag += k[i] * omega[i]
            total += t
        # The pitch sum in two interleaved partial sums: the bits of BLAS's dot product over the strided column
        # `positions[:, 0]` that this model used before it went to plain floats (the trajectories stay the same).
        my = my_even + my_odd
        mz *= self.c_q
        # the propellers' angular momentum: I_p (loaded) s_i, dotted with omega and omega_dot
        for i, inertia in enumerate(self._spin):
            h_z += inertia * omega[i]
            spin_up += inertia * omega_dot[i]
        h_z = -h_z
        mz += spin_up                          # reaction to propeller spin-up
        p, q = body_rates[0], body_rates[1]
        # -Omega x (0, 0, h_z) = (-q h_z, p h_z, 0)
        mx -= q * h_z
        my += p * h_z
        drag_gain = self.drag_coefficient * drag
        return (-drag_gain * air_velocity_body[0], -drag_gain * air_velocity_body[1], -total), (mx, my, mz)

    def _wrench4(self, k, omega, omega_dot, body_rates, air):
        """`wrench_floats` of four rotors, unrolled (the same operations in the same order)."""
        k0, k1, k2, k3 = k
        w0, w1, w2, w3 = omega
        a0, a1, a2, a3 = k0 * w0 * w0, k1 * w1 * w1, k2 * w2 * w2, k3 * w3 * w3
        c_t = self.c_t
        t0, t1, t2, t3 = c_t * a0, c_t * a1, c_t * a2, c_t * a3
        r0, r1, r2, r3 = self._roll_arm_list
        x0, x1, x2, x3 = self._pitch_arm_list
        s0, s1, s2, s3 = self._signs_list
        i0, i1, i2, i3 = self._spin
        e0, e1, e2, e3 = omega_dot
        h_z = -(i0 * w0 + i1 * w1 + i2 * w2 + i3 * w3)
        mx = r0 * t0 + r1 * t1 + r2 * t2 + r3 * t3 - body_rates[1] * h_z
        my = (x0 * t0 + x2 * t2) + (x1 * t1 + x3 * t3) + body_rates[0] * h_z   # pairs: see `wrench_floats`
        mz = (s0 * a0 + s1 * a1 + s2 * a2 + s3 * a3) * self.c_q + (i0 * e0 + i1 * e1 + i2 * e2 + i3 * e3)
        drag_gain = self.drag_coefficient * (k0 * w0 + k1 * w1 + k2 * w2 + k3 * w3)
        return (-drag_gain * air[0], -drag_gain * air[1], -(t0 + t1 + t2 + t3)), (mx, my, mz)

    @property
    def total_thrust(self) -> float:
        return self.c_t * float(self.effectiveness @ (self.omega * self.omega))
