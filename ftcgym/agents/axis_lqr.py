"""`ScheduledAxisLqr`: the inner loop of `SpinRecoveryController`, primary-axis LQR about the relaxed hover.

Mueller & D'Andrea, ICRA 2014 (001 Part II App. B), with the rotor lag in the state, a gain schedule on the
yaw rate while the spin builds up, and the arrest of the roll/pitch rate the detection delay leaves.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import solve_continuous_are

from ..models.geometry import cross
from ..models.quadrotor import YAW_SIGNS, QuadrotorParams
from .relaxed_hover import body_moment, rotor_roles

if TYPE_CHECKING:
    from .spin_recovery import SpinRecoveryGains


class ScheduledAxisLqr:
    """LQR of the primary axis about the relaxed hover, gain-scheduled on the yaw rate (one failed rotor).

    Mueller & D'Andrea stabilise the relaxed hover with an LQR on the linearised body-frame dynamics of
    (p, q, n_x, n_y). We add the rotor forces' first-order lag to the state (15-33 ms while the body turns at
    20-30 rad/s) and use the two force changes that leave the collective thrust alone (the altitude loop owns
    it): the adjacent pair's differential and the opposite rotor against the pair. The linearisation keeps the
    gyroscopic coupling -Omega x (I Omega + h): after the loss no rotor can push the failed rotor's side up,
    and a roll/pitch rate crossed with the spin (and the propellers' momentum) is the only moment that can.
    While the yaw rate builds up the operating point is the frozen-r spin about the scheduled axis, so gains
    are designed on a grid of yaw rates and interpolated.
    """

    def __init__(self, params: QuadrotorParams, failed_rotor: int, equilibrium: dict, gains: SpinRecoveryGains):
        self.params, self.gains = params, gains
        self.working = np.array([i for i in range(4) if i != failed_rotor])
        (a, b), opposite = rotor_roles(failed_rotor)
        slot = {int(i): k for k, i in enumerate(self.working)}
        self.basis = np.zeros((3, 2))
        self.basis[[slot[a], slot[b]], 0] = (1.0, -1.0)
        self.basis[[slot[a], slot[opposite], slot[b]], 1] = (-0.5, 1.0, -0.5)
        self.basis /= np.linalg.norm(self.basis, axis=0)
        self.pair = self.basis[:, 0] != 0.0
        self.opposite = slot[opposite]
        self.loaded = np.arange(4) != failed_rotor
        self.inertia = np.asarray(params.inertia, dtype=float)
        pos = params.rotor_positions[self.working]
        self.balance_rows = np.vstack([-pos[:, 1], pos[:, 0], np.ones(3)])   # [M_x, M_y, T] per newton
        self.yaw_signs = np.asarray(YAW_SIGNS)[self.working]
        self.n_bar, self.r_bar = equilibrium["n"], equilibrium["yaw_rate"]
        self.f_min = params.thrust_coefficient * params.omega_min ** 2
        self.f_max = params.thrust_coefficient * params.omega_max ** 2
        self.grid = self.r_bar * np.linspace(0.0, 1.3, 14)
        self.gain_grid = np.array([self._design(r, equilibrium["thrust"]) for r in self.grid])

    # -------------------------------------------------------------- operating point
    def target_axis(self, r: float) -> np.ndarray:
        """n_bar leaned from -z by (r / r_bar)^power: without spin there is no gyroscopic stiffness to hold
        a tilted axis with, and the level spin (rho = 0) has the most yaw torque to spin up with."""
        share = min(max(r / self.r_bar, 0.0), 1.0) ** self.gains.schedule_power
        axis = np.array([share * self.n_bar[0], share * self.n_bar[1], self.n_bar[2]])
        return axis / np.linalg.norm(axis)

    def operating_point(self, r: float, thrust: float, rotor_speed=None):
        """Axis, body rates and forces of the frozen-r spin: Omega = (r / n_z) n keeps n steady, and the
        forces hold Omega steady about x and y (the moment balance of App. B eq. 12-13) with sum = thrust."""
        axis = self.target_axis(r)
        rates = r / axis[2] * axis
        h_z = self._propeller_momentum(thrust, rotor_speed)
        momentum = self.inertia * rates + np.array([0.0, 0.0, h_z])
        needed = cross(rates, momentum) - self.params.rotational_drag_moment(rates)
        forces = np.linalg.solve(self.balance_rows, np.array([needed[0], needed[1], thrust]))
        if forces[self.opposite] < self.f_min and self.gains.balance_idle:
            rates, forces = self._idle_balance(rates, thrust, h_z)
        return axis, rates, np.clip(forces, self.f_min, self.f_max)

    def _propeller_momentum(self, thrust, rotor_speed) -> float:
        """h_z = -I_p sum(s_i omega_i) of the working propellers (measured speeds, or equal shares of thrust)."""
        if rotor_speed is None:
            omega = np.full(3, np.sqrt(thrust / 3.0 / self.params.thrust_coefficient))
        else:
            omega = np.asarray(rotor_speed, dtype=float)[self.working]
        return -self.params.propeller_inertia * float(self.yaw_signs @ omega)

    def _idle_balance(self, rates, thrust, h_z):
        """Rates and forces that hold p, q steady with the opposite rotor at idle.

        At idle the opposite rotor still tips the body toward the failed rotor, and no rotor can push back;
        the gyroscopic moment Omega x (I Omega + h) of a roll/pitch rate can. At frozen r the balance is linear
        in (p, q): we take the (p, q) nearest the nominal ones.
        """
        ixx, iyy, izz = self.inertia
        r = rates[2]
        # damping -(D1 + D2 |w|) w as a secant through zero at the nominal rates
        dx, dy = np.asarray(self.params.rotational_drag[:2]) + np.asarray(
            self.params.rotational_drag_quadratic[:2]) * np.abs(rates[:2])
        coupling = np.array([[dx, r * (izz - iyy) + h_z], [-(r * (izz - ixx) + h_z), dy]])  # moment_xy = C (p, q)
        free = np.arange(3) != self.opposite
        A, b = np.zeros((5, 4)), np.zeros(5)
        A[:2, :2], A[:2, 2:] = self.balance_rows[:2, free], -coupling
        b[:2] = coupling @ rates[:2] - self.balance_rows[:2, self.opposite] * self.f_min
        A[2, :2], b[2] = 1.0, thrust - self.f_min
        A[:3], b[:3] = 1e3 * A[:3], 1e3 * b[:3]          # the balance rows exactly, then the least rate change
        A[3, 2] = A[4, 3] = 1.0
        solution = np.linalg.lstsq(A, b, rcond=None)[0]
        forces = np.full(3, self.f_min)
        forces[free] = solution[:2]
        return np.array([rates[0] + solution[2], rates[1] + solution[3], r]), forces

    # -------------------------------------------------------------- design
    def _state_derivative(self, state, command, r) -> np.ndarray:
        """d/dt (p, q, n_x, n_y, f_working) at frozen yaw rate r; forces lag their commands by tau."""
        p, q, nx, ny = state[:4]
        rates = np.array([p, q, r])
        n = np.array([nx, ny, -np.sqrt(max(1.0 - nx * nx - ny * ny, 1e-9))])
        forces = np.zeros(4)
        forces[self.working] = state[4:]
        rates_dot = body_moment(self.params, rates, forces, self.loaded) / self.inertia
        n_dot = np.cross(n, rates)
        return np.concatenate([rates_dot[:2], n_dot[:2], (command - state[4:]) / self.params.motor_time_constant])

    def _design(self, r: float, thrust: float) -> np.ndarray:
        axis, rates, forces = self.operating_point(r, thrust)
        x0 = np.concatenate([rates[:2], axis[:2], forces])
        A, B = _jacobians(lambda x, u: self._state_derivative(x, u, r), x0, forces)
        g = self.gains
        share = min(abs(r / self.r_bar), 1.0)
        axis_weight = g.lqr_axis_weight * (g.lqr_axis_floor + (1.0 - g.lqr_axis_floor) * share ** 2)
        Q = np.diag([g.lqr_rate_weight] * 2 + [axis_weight] * 2 + [g.lqr_force_weight] * 3)
        # The opposite rotor cannot go below idle, where the low-spin operating point has it: its input weighs
        # lqr_opposite_weight times more at r = 0, falling to 1 at r_bar.
        R = np.diag([1.0, g.lqr_opposite_weight ** (1.0 - share)]) * g.lqr_input_weight
        Bv = B @ self.basis
        P = solve_continuous_are(A, Bv, Q, R)
        return np.linalg.solve(R, Bv.T @ P)

    def gain(self, r: float) -> np.ndarray:
        """K at yaw rate r, linear between grid points (held beyond the grid)."""
        s = min(max((r - self.grid[0]) / (self.grid[1] - self.grid[0]), 0.0), len(self.grid) - 1.0)
        k = min(int(s), len(self.grid) - 2)
        w = s - k
        return (1.0 - w) * self.gain_grid[k] + w * self.gain_grid[k + 1]

    # -------------------------------------------------------------- control
    def forces(self, n_body, rates, rotor_speed, thrust):
        """Commanded forces of the working rotors (N) and the target axis at the measured yaw rate."""
        r = float(rates[2])
        axis, rates0, forces0 = self.operating_point(r, thrust, rotor_speed)
        measured = self.params.thrust_coefficient * np.asarray(rotor_speed, dtype=float)[self.working] ** 2
        deviation = np.concatenate([rates[:2] - rates0[:2], n_body[:2] - axis[:2], measured - forces0])
        spinning_up = abs(r) < self.gains.boost_until * abs(self.r_bar)
        arrest = self.gains.arrest_rate
        if spinning_up and arrest is not None and np.hypot(rates[0], rates[1]) > arrest:
            return self.arrest(rates, n_body), axis
        command = forces0 + self.basis @ (-self.gain(r) @ deviation)
        if spinning_up:
            thrust = 3.0 * self.f_max   # spin up as fast as the rotors allow: yaw torque, lift, stiffness all grow
        return self._keep_thrust(command, thrust), axis

    def arrest(self, rates, n_body=None) -> np.ndarray:
        """Spin up flat out and damp the roll/pitch rate left by the detection delay (the upset of Sun et al.,
        "Upset recovery control for quadrotors subjected to a complete rotor failure from large initial
        disturbances", ICRA 2020), toward the rate that rights the thrust axis.

        Rate target: with `arrest_attitude_gain` k > 0 and the commanded axis n_B = R^T n_des given, the
        proportional reduced-attitude law omega_xy = k ((-z) x n_B)_xy = k (n_By, -n_Bx) turns the thrust axis
        toward n_des (the primary-axis error of Sun et al., RA-L 2018, taken about the thrust axis while the
        spin is too slow to hold a tilted primary axis); k = 0 damps the rate to zero. Damping alone freezes
        the tilt the loss left: the spin's gyroscopic stiffness then holds it in the world, and the thrust,
        flat out, pushes the vehicle sideways.
        With `arrest_attitude_fade` f, the target shrinks to zero over the last share f of the boost's spin
        (r from (1 - f) to 1 times boost_until r_bar): handed over with a rate still steering, the LQR let the
        axis nutate 15-35 deg about n_des for ~0.7 s on bebop2.

        After the loss the body tips about the axis along which only the lost rotor could push back, and the
        opposite rotor can only push the wrong way: it is stopped. The adjacent pair's differential acts about
        the perpendicular axis; the gyroscopic coupling (I_zz - I_xx) r + h_z of the spin and the propellers
        turns the rate vector into its reach. Per step the differential gives the angular acceleration nearest
        -arrest_gain * (p, q) (least squares along its one direction), taken from the slower rotor of the pair
        while the faster stays at f_max, so the spin and the propellers' momentum keep building up. A linear
        design about the relaxed hover does not see this phase: from the ~6 rad/s a Bebop 2 has at a 60 ms
        alarm it lets the axis settle far off (docs/measurements.md, 'Tuning record: agents/spin_recovery.py').
        """
        a, b = np.flatnonzero(self.pair)
        per_newton = (self.balance_rows[:2, a] - self.balance_rows[:2, b]) / 2.0 / self.inertia[:2]
        rates = np.asarray(rates, dtype=float)
        rate_target = np.zeros(2)
        if n_body is not None and self.gains.arrest_attitude_gain:
            # body rate that turns the thrust axis -z toward n_des: k (-z) x n_B = k (n_y, -n_x, 0)
            rate_target = self.gains.arrest_attitude_gain * np.array([n_body[1], -n_body[0]])
            fade = self.gains.arrest_attitude_fade
            if fade is not None:
                # toward zero as the spin nears the hand-over to the LQR: it takes over with the rate damped
                share = abs(float(rates[2])) / (self.gains.boost_until * abs(self.r_bar))
                rate_target *= min(max((1.0 - share) / fade, 0.0), 1.0)
        desired = -self.gains.arrest_gain * (rates[:2] - rate_target)
        differential = float(per_newton @ desired) / float(per_newton @ per_newton)
        forces = np.full(3, self.f_min)
        forces[a] = max(self.f_max + min(0.0, differential), self.f_min)
        forces[b] = max(self.f_max - max(0.0, differential), self.f_min)
        return forces

    def _keep_thrust(self, command, thrust) -> np.ndarray:
        """Clip to the rotor limits, then give the adjacent pair (whose common change moves neither roll nor
        pitch) what clipping took from, or added to, the collective thrust, as far as the pair can take it
        without losing its differential."""
        clipped = np.clip(command, self.f_min, self.f_max)
        pair = clipped[self.pair]
        shift = np.clip((thrust - clipped.sum()) / 2.0, self.f_min - pair.min(), self.f_max - pair.max())
        clipped[self.pair] += shift
        return clipped


def _jacobians(f, x0, u0, eps=1e-6):
    """Central-difference Jacobians of f(x, u) at (x0, u0)."""
    A = np.column_stack([(f(x0 + eps * e, u0) - f(x0 - eps * e, u0)) / (2 * eps) for e in np.eye(len(x0))])
    B = np.column_stack([(f(x0, u0 + eps * e) - f(x0, u0 - eps * e)) / (2 * eps) for e in np.eye(len(u0))])
    return A, B
