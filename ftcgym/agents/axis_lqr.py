"""`ScheduledAxisLqr`: the inner loop of `SpinRecoveryController`, primary-axis LQR about the relaxed hover.

Mueller & D'Andrea, ICRA 2014 (001 Part II App. B), with the rotor lag in the state, a gain schedule on the
yaw rate while the spin builds up, and the arrest of the roll/pitch rate the detection delay leaves.

The per-step arithmetic is compiled (numba: `lqr_forces` and the functions it calls, on an `AxisLqrModel`);
it keeps the operations and their order of the numpy version it replaced, the products and solves BLAS's
and LAPACK's as numpy's, so trajectories keep their bits. The design (`ScheduledAxisLqr`) runs once per
failed rotor, in Python.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit
from scipy.linalg import solve_continuous_are

from ..models.geometry import cross, cross3
from ..models.quadrotor import YAW_SIGNS, QuadrotorParams, rotational_drag_moment
from .relaxed_hover import body_moment, rotor_roles

if TYPE_CHECKING:
    from .spin_recovery import SpinRecoveryGains


class AxisLqrModel(NamedTuple):
    """What the compiled steps read of a `ScheduledAxisLqr` (its attributes of the same names) and of the
    vehicle and the gains: arrays and floats only."""

    working: np.ndarray            # indices of the working rotors
    pair: np.ndarray               # (3,) bool: the adjacent pair among the working rotors
    opposite: int                  # slot of the opposite rotor among the working rotors
    basis: np.ndarray              # (3, 2) force changes that leave the collective alone
    balance_rows: np.ndarray       # (3, 3) [M_x, M_y, T] per newton of each working rotor
    yaw_signs: np.ndarray          # (3,) of the working rotors
    inertia: np.ndarray
    drag_linear: np.ndarray        # rotational damping D1, D2 (`QuadrotorParams.rotational_drag_moment`)
    drag_quadratic: np.ndarray
    n_bar: np.ndarray
    r_bar: float
    thrust_coefficient: float
    propeller_inertia: float
    f_min: float
    f_max: float
    grid: np.ndarray               # yaw rates of the gain schedule
    gain_grid: np.ndarray          # (len(grid), 2, 7) LQR gains
    schedule_power: float
    boost_until: float
    arrest_rate: float             # inf: no arrest
    arrest_gain: float
    arrest_attitude_gain: float
    fades: bool                    # whether arrest_attitude_fade is set
    arrest_attitude_fade: float
    balance_idle: bool


class ScheduledAxisLqr:
    """LQR of the primary axis about the relaxed hover, gain-scheduled on the yaw rate (one failed rotor).

    Mueller & D'Andrea stabilise the relaxed hover with an LQR on the linearised body-frame dynamics of
    (p, q, n_x, n_y). We add the rotor forces' first-order lag to the state (15-33 ms while the body turns at
    20-30 rad/s) and use the two force changes that leave the collective thrust alone (the altitude loop owns
    it): the adjacent pair's differential and the opposite rotor against the pair. The linearisation keeps the
    gyroscopic coupling -Omega x (I Omega + h): after the loss no rotor can push the failed rotor's side up,
    and a roll/pitch rate crossed with the spin (and the propellers' momentum) is the only moment that can.
    While the yaw rate builds up the operating point is the frozen-r spin about the scheduled axis, so gains
    are designed on a grid of yaw rates and interpolated. `model` is what `lqr_forces` flies with.
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
        self.model = AxisLqrModel(
            self.working, self.pair, self.opposite, self.basis, self.balance_rows, self.yaw_signs, self.inertia,
            np.asarray(params.rotational_drag, dtype=float), np.asarray(params.rotational_drag_quadratic, dtype=float),
            np.asarray(self.n_bar, dtype=float), float(self.r_bar), params.thrust_coefficient,
            params.propeller_inertia, self.f_min, self.f_max, self.grid, np.zeros((0, 2, 7)),
            float(gains.schedule_power), float(gains.boost_until),
            math.inf if gains.arrest_rate is None else float(gains.arrest_rate), float(gains.arrest_gain),
            float(gains.arrest_attitude_gain), gains.arrest_attitude_fade is not None,
            float(gains.arrest_attitude_fade or 0.0), bool(gains.balance_idle))
        self.gain_grid = np.array([self._design(r, equilibrium["thrust"]) for r in self.grid])
        self.model = self.model._replace(gain_grid=self.gain_grid)

    # -------------------------------------------------------------- design
    def _state_derivative(self, state, command, r) -> np.ndarray:
        """d/dt (p, q, n_x, n_y, f_working) at frozen yaw rate r; forces lag their commands by tau."""
        p, q, nx, ny = state[:4]
        rates = np.array([p, q, r])
        n = np.array([nx, ny, -np.sqrt(max(1.0 - nx * nx - ny * ny, 1e-9))])
        forces = np.zeros(4)
        forces[self.working] = state[4:]
        rates_dot = body_moment(self.params, rates, forces, self.loaded) / self.inertia
        n_dot = cross(n, rates)
        return np.concatenate([rates_dot[:2], n_dot[:2], (command - state[4:]) / self.params.motor_time_constant])

    def _design(self, r: float, thrust: float) -> np.ndarray:
        axis, rates, forces = operating_point(self.model, r, thrust, None)
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


def _jacobians(f, x0, u0, eps=1e-6):
    """Central-difference Jacobians of f(x, u) at (x0, u0)."""
    A = np.column_stack([(f(x0 + eps * e, u0) - f(x0 - eps * e, u0)) / (2 * eps) for e in np.eye(len(x0))])
    B = np.column_stack([(f(x0, u0 + eps * e) - f(x0, u0 - eps * e)) / (2 * eps) for e in np.eye(len(u0))])
    return A, B


# ------------------------------------------------------------------ compiled steps
@njit(cache=True)
def target_axis(model, r):  # pragma: no cover (compiled)
    """n_bar leaned from -z by (r / r_bar)^power: without spin there is no gyroscopic stiffness to hold
    a tilted axis with, and the level spin (rho = 0) has the most yaw torque to spin up with."""
    share = min(max(r / model.r_bar, 0.0), 1.0) ** model.schedule_power
    axis = np.array([share * model.n_bar[0], share * model.n_bar[1], model.n_bar[2]])
    return axis / math.sqrt(np.dot(axis, axis))


@njit(cache=True)
def operating_point(model, r, thrust, rotor_speed):  # pragma: no cover (compiled)
    """Axis, body rates and forces of the frozen-r spin: Omega = (r / n_z) n keeps n steady, and the
    forces hold Omega steady about x and y (the moment balance of App. B eq. 12-13) with sum = thrust.
    `rotor_speed` (4,) measured, or None: equal shares of the thrust (`_propeller_momentum`)."""
    axis = target_axis(model, r)
    rates = r / axis[2] * axis
    h_z = _propeller_momentum(model, thrust, rotor_speed)
    momentum = model.inertia * rates + np.array([0.0, 0.0, h_z])
    needed = (np.array(cross3(rates, momentum))
              - rotational_drag_moment(model.drag_linear, model.drag_quadratic, rates))
    forces = np.linalg.solve(model.balance_rows, np.array([needed[0], needed[1], thrust]))
    if forces[model.opposite] < model.f_min and model.balance_idle:
        rates, forces = _idle_balance(model, rates, thrust, h_z)
    return axis, rates, np.minimum(np.maximum(forces, model.f_min), model.f_max)


@njit(cache=True)
def _propeller_momentum(model, thrust, rotor_speed):  # pragma: no cover (compiled)
    """h_z = -I_p sum(s_i omega_i) of the working propellers (measured speeds, or equal shares of thrust)."""
    if rotor_speed is None:
        omega = np.full(3, math.sqrt(thrust / 3.0 / model.thrust_coefficient))
    else:
        omega = rotor_speed[model.working]
    return -model.propeller_inertia * np.dot(model.yaw_signs, omega)


@njit(cache=True)
def _idle_balance(model, rates, thrust, h_z):  # pragma: no cover (compiled)
    """Rates and forces that hold p, q steady with the opposite rotor at idle.

    At idle the opposite rotor still tips the body toward the failed rotor, and no rotor can push back;
    the gyroscopic moment Omega x (I Omega + h) of a roll/pitch rate can. At frozen r the balance is linear
    in (p, q): we take the (p, q) nearest the nominal ones (least squares at numpy's default cut-off,
    machine epsilon times the larger dimension).
    """
    ixx, iyy, izz = model.inertia[0], model.inertia[1], model.inertia[2]
    r, opposite, f_min = rates[2], model.opposite, model.f_min
    # damping -(D1 + D2 |w|) w as a secant through zero at the nominal rates
    dx = model.drag_linear[0] + model.drag_quadratic[0] * abs(rates[0])
    dy = model.drag_linear[1] + model.drag_quadratic[1] * abs(rates[1])
    coupling = np.array([[dx, r * (izz - iyy) + h_z], [-(r * (izz - ixx) + h_z), dy]])  # moment_xy = C (p, q)
    free = np.array([i for i in range(3) if i != opposite])
    A, b = np.zeros((5, 4)), np.zeros(5)
    for row in range(2):
        A[row, 0], A[row, 1] = model.balance_rows[row, free[0]], model.balance_rows[row, free[1]]
        A[row, 2], A[row, 3] = -coupling[row, 0], -coupling[row, 1]
    b[:2] = coupling @ rates[:2] - model.balance_rows[:2, opposite] * f_min
    A[2, :2], b[2] = 1.0, thrust - f_min
    A[:3], b[:3] = 1e3 * A[:3], 1e3 * b[:3]          # the balance rows exactly, then the least rate change
    A[3, 2] = A[4, 3] = 1.0
    solution = np.linalg.lstsq(A, b, rcond=np.finfo(np.float64).eps * 5)[0]
    forces = np.full(3, f_min)
    forces[free] = solution[:2]
    return np.array([rates[0] + solution[2], rates[1] + solution[3], r]), forces


@njit(cache=True)
def gain(model, r):  # pragma: no cover (compiled)
    """K at yaw rate r, linear between grid points (held beyond the grid)."""
    grid = model.grid
    s = min(max((r - grid[0]) / (grid[1] - grid[0]), 0.0), len(grid) - 1.0)
    k = min(int(s), len(grid) - 2)
    w = s - k
    return (1.0 - w) * model.gain_grid[k] + w * model.gain_grid[k + 1]


@njit(cache=True)
def lqr_forces(model, n_body, rates, rotor_speed, thrust):  # pragma: no cover (compiled)
    """Commanded forces of the working rotors (N) and the target axis at the measured yaw rate."""
    r = rates[2]
    axis, rates0, forces0 = operating_point(model, r, thrust, rotor_speed)
    omega = rotor_speed[model.working]
    measured = model.thrust_coefficient * (omega * omega)
    deviation = np.concatenate((rates[:2] - rates0[:2], n_body[:2] - axis[:2], measured - forces0))
    spinning_up = abs(r) < model.boost_until * abs(model.r_bar)
    if spinning_up and math.hypot(rates[0], rates[1]) > model.arrest_rate:
        return arrest(model, rates, n_body), axis
    command = forces0 + model.basis @ (-gain(model, r) @ deviation)
    if spinning_up:
        thrust = 3.0 * model.f_max   # spin up as fast as the rotors allow: yaw torque, lift, stiffness all grow
    return _keep_thrust(model, command, thrust), axis


@njit(cache=True)
def arrest(model, rates, n_body):  # pragma: no cover (compiled)
    """Spin up flat out and damp the roll/pitch rate left by the detection delay (the upset of Sun et al.,
    "Upset recovery control for quadrotors subjected to a complete rotor failure from large initial
    disturbances", ICRA 2020), toward the rate that rights the thrust axis.

    Rate target: with `arrest_attitude_gain` k > 0 and the commanded axis n_B = R^T n_des, the proportional
    reduced-attitude law omega_xy = k ((-z) x n_B)_xy = k (n_By, -n_Bx) turns the thrust axis toward n_des
    (the primary-axis error of Sun et al., RA-L 2018, taken about the thrust axis while the spin is too slow
    to hold a tilted primary axis); k = 0 damps the rate to zero. Damping alone freezes the tilt the loss
    left: the spin's gyroscopic stiffness then holds it in the world, and the thrust, flat out, pushes the
    vehicle sideways.
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
    pair = np.flatnonzero(model.pair)
    a, b = pair[0], pair[1]
    per_newton = (model.balance_rows[:2, a] - model.balance_rows[:2, b]) / 2.0 / model.inertia[:2]
    rate_target = np.zeros(2)
    if model.arrest_attitude_gain != 0.0:
        # body rate that turns the thrust axis -z toward n_des: k (-z) x n_B = k (n_y, -n_x, 0)
        rate_target = model.arrest_attitude_gain * np.array([n_body[1], -n_body[0]])
        if model.fades:
            # toward zero as the spin nears the hand-over to the LQR: it takes over with the rate damped
            share = abs(rates[2]) / (model.boost_until * abs(model.r_bar))
            rate_target *= min(max((1.0 - share) / model.arrest_attitude_fade, 0.0), 1.0)
    desired = -model.arrest_gain * (rates[:2] - rate_target)
    differential = np.dot(per_newton, desired) / np.dot(per_newton, per_newton)
    forces = np.full(3, model.f_min)
    forces[a] = max(model.f_max + min(0.0, differential), model.f_min)
    forces[b] = max(model.f_max - max(0.0, differential), model.f_min)
    return forces


@njit(cache=True)
def _keep_thrust(model, command, thrust):  # pragma: no cover (compiled)
    """Clip to the rotor limits, then give the adjacent pair (whose common change moves neither roll nor
    pitch) what clipping took from, or added to, the collective thrust, as far as the pair can take it
    without losing its differential."""
    clipped = np.minimum(np.maximum(command, model.f_min), model.f_max)
    pair = clipped[model.pair]
    shift = min(max((thrust - clipped.sum()) / 2.0, model.f_min - pair.min()), model.f_max - pair.max())
    clipped[model.pair] += shift
    return clipped
