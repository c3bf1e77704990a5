"""Rotor set of a multirotor: motor dynamics, thrust, drag torque, rotor drag, gyroscopic moments.

One model for every vehicle: positions, spin directions and coefficients come from the parameter set.
Effectiveness k_i (000 eq. 3) and `loaded` (propeller present) are the fault handles: arrays written in place
(`faults.FaultSchedule.rotor_state`), after which `sync()` brings the physics step's copies up to date.

The per-step arithmetic is compiled (numba: `advance_speeds`, `rotor_loads`), so a physics step can run it
without the interpreter; it keeps the operations and their order of the plain-Python model it replaced, so
trajectories keep their bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: rows of `RotorSet.state`: speeds (rad/s), accelerations (rad/s^2), effectiveness, propeller present (1/0),
#: I_p * present * yaw sign (the propeller's spin inertia about -z)
OMEGA, OMEGA_DOT, EFFECTIVENESS, LOADED, SPIN = range(5)
#: rows of `RotorSet.geometry`: thrust moment arms about x (-y_i) and y (x_i), yaw signs
ROLL_ARM, PITCH_ARM, SIGNS = range(3)


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
        self.state = np.zeros((5, n))
        self._rows = tuple(self.state)
        self.effectiveness[:] = 1.0
        self.loaded = np.ones(n, dtype=bool)
        self._gain_dt = None
        # Moments of the rotor thrusts T_i (along -z): r_i x (0, 0, -T_i) = (-y_i T_i, x_i T_i, 0), 000 eq. (4).
        self.geometry = np.array([-self.positions[:, 1], self.positions[:, 0], self.yaw_signs])
        self.sync()

    @classmethod
    def from_params(cls, params, yaw_signs):
        return cls(params.rotor_positions, yaw_signs, params.thrust_coefficient, params.torque_coefficient,
                   params.omega_min, params.omega_max, params.motor_time_constant,
                   params.max_rotor_acceleration, params.propeller_inertia, params.rotor_drag_coefficient,
                   params.unloaded_speed_ratio, params.unloaded_time_constant)

    # Rows of `state`, the same view objects every time (writes go to the state the compiled step reads).
    omega = property(lambda self: self._rows[OMEGA], doc="rotor speeds (rad/s)")
    omega_dot = property(lambda self: self._rows[OMEGA_DOT], doc="rotor accelerations (rad/s^2)")
    effectiveness = property(lambda self: self._rows[EFFECTIVENESS], doc="loss-of-effectiveness factors k_i")

    @omega.setter
    def omega(self, value) -> None:
        self.state[OMEGA] = value

    def reset(self, omega) -> None:
        self.omega[:] = omega
        self.omega_dot[:] = 0.0
        self.effectiveness[:] = 1.0
        self.loaded[:] = True
        self.sync()

    def sync(self) -> None:
        """Copy the fault handle `loaded` into `state` (after a write; `effectiveness` is a row of it)."""
        self.state[LOADED] = self.loaded
        self.state[SPIN] = self.propeller_inertia * self.loaded * self.yaw_signs

    def gains(self, dt: float) -> tuple:
        """(loaded gain, unloaded gain, acceleration limit, unloaded speed ratio) of `advance_speeds` for dt."""
        if dt != self._gain_dt:
            self._gain_dt = dt
            self._gains = (float(1.0 - np.exp(-dt / self.tau)), float(1.0 - np.exp(-dt / self.tau_unloaded)),
                           self.max_acceleration * dt, float(self.unloaded_speed_ratio))
        return self._gains

    def command_to_omega(self, command: np.ndarray) -> np.ndarray:
        """Normalised commands in [0, 1] -> rotor speed set-points (linear between idle and max)."""
        return self.omega_min + command * (self.omega_max - self.omega_min)

    def wrench(self, body_rates, air_velocity_body):
        """Force and moment on the body (FRD) from all rotors, as arrays (`rotor_loads`)."""
        loads = rotor_loads(self.state, self.geometry, self.c_t, self.c_q, self.drag_coefficient,
                            float(body_rates[0]), float(body_rates[1]), float(air_velocity_body[0]),
                            float(air_velocity_body[1]))
        return np.array(loads[:3]), np.array(loads[3:])

    @property
    def total_thrust(self) -> float:
        return self.c_t * float(self.effectiveness @ (self.omega * self.omega))


@njit(cache=True)
def advance_speeds(state, command, dt, gain, unloaded_gain, limit, ratio):  # pragma: no cover (compiled)
    """Exact first-order lag of each motor toward its set-point, then the acceleration limit (`limit` rad/s
    per step), in place on `state`'s OMEGA and OMEGA_DOT rows.

    A motor that lost its propeller (000 Sec. III-A) is unloaded: the ESC drives it faster for the same command
    (`ratio`, `unloaded_speed_ratio`) and it responds faster (`unloaded_gain`, from `unloaded_time_constant`).
    """
    for i in range(state.shape[1]):
        w = state[OMEGA, i]
        if state[LOADED, i] != 0.0:
            delta = (command[i] - w) * gain
        else:
            delta = (command[i] * ratio - w) * unloaded_gain
        delta = min(max(delta, -limit), limit)
        state[OMEGA_DOT, i] = delta / dt
        state[OMEGA, i] = w + delta


@njit(cache=True)
def rotor_loads(state, geometry, c_t, c_q, drag_coefficient, p, q, air_x, air_y):  # pragma: no cover (compiled)
    """Force and moment on the body (FRD) from all rotors of `state`, (fx, fy, fz, mx, my, mz):

    - thrust c_T k_i omega_i^2 along -z (000 eq. 3) and its moments (000 eq. 4, 8);
    - drag torque c_Q k_i omega_i^2 with the yaw signs of 004 eq. (7) (docs/concepts.md, 'Rotor numbering');
    - rotor drag -k_d k_i omega_i v_inplane, proportional to airspeed times rotor speed (001 Sec. 4.3);
    - gyroscopic moment -Omega x h of the spinning propellers and the reaction to their spin-up.
      Propeller i spins about -s_i z (s_i its yaw sign), so h = -I_p sum(s_i omega_i) z.

    The sums run rotor by rotor in index order, as numpy's dot products of 4-vectors do; the pitch sum runs
    in two interleaved partial sums, the bits of BLAS's dot product over the strided column `positions[:, 0]`
    that this model used first (the trajectories stay the same).
    """
    mx = my_even = my_odd = mz = drag = total = h_z = spin_up = 0.0
    for i in range(state.shape[1]):
        w, k = state[OMEGA, i], state[EFFECTIVENESS, i]
        w2k = k * w * w
        thrust = c_t * w2k
        mx += geometry[ROLL_ARM, i] * thrust
        if i % 2:
            my_odd += geometry[PITCH_ARM, i] * thrust
        else:
            my_even += geometry[PITCH_ARM, i] * thrust
        mz += geometry[SIGNS, i] * w2k
        drag += k * w
        total += thrust
        h_z += state[SPIN, i] * w
        spin_up += state[SPIN, i] * state[OMEGA_DOT, i]
    h_z = -h_z
    drag_gain = drag_coefficient * drag
    # -Omega x (0, 0, h_z) = (-q h_z, p h_z, 0); the reaction to the propellers' spin-up about z
    return (-drag_gain * air_x, -drag_gain * air_y, -total,
            mx - q * h_z, (my_even + my_odd) + p * h_z, mz * c_q + spin_up)
