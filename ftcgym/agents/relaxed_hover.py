"""Relaxed hover of a quadrotor that lost one propeller: the steady spinning equilibrium.

Mueller & D'Andrea, "Stability and control of a quadrocopter despite the complete loss of one, two, or three
propellers", ICRA 2014, as reproduced in 001 Part II App. B ("Rotor Loss Initial Calculations"). The vehicle
spins at constant body rates Omega about a primary axis n = eps Omega (eq. 16-17) that stays fixed in the
world; pointing n up, the thrust averaged over a revolution carries the weight, f_sum n.(-z) = m g (eq. 18).

We solve the steady Euler equations in body FRD axes for the simulator's model (`ftcgym.envs.rotors`) and
any X geometry (the App. B script writes them, eq. 12-14, for Mueller's "+" vehicle):

    0 = sum_i r_i x (0, 0, -f_i) + (0, 0, (c_Q / c_T) sum_i s_i f_i)      rotor thrust and drag torques
        - Omega x (I Omega + h) - D Omega                                 body and propeller gyroscopics, damping
    f_sum |r| / |Omega| = m g                                             eq. (18) with n_z = -|r| / |Omega|

with f_i = c_T omega_i^2 (eq. 10), h = -I_p sum_i s_i omega_i z the angular momentum of the remaining
propellers (signed speeds: propeller i spins about -s_i z), and App. B's failed-propeller constraints: the
failed rotor gives nothing (w_4 = 0), the two rotors next to it share one force (w_1 = w_3) and the opposite
rotor gives rho times that force (rho = f_2 / f_1). Unknowns: the body rates (3) and the adjacent force.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import fsolve

from ..models.constants import GRAVITY
from ..models.geometry import cross
from ..models.quadrotor import YAW_SIGNS, QuadrotorParams, make_params

RESIDUAL_TOLERANCE = 1e-9   # N m and N: a root that misses by more is not an equilibrium


def resolve_params(vehicle, vehicle_overrides: dict | None = None) -> QuadrotorParams:
    """A parameter set from its name or a QuadrotorParams, with `vehicle_overrides` applied."""
    if not isinstance(vehicle, QuadrotorParams):
        return make_params(vehicle, vehicle_overrides)
    overrides = {key: tuple(np.asarray(value, float).tolist()) if np.ndim(value) else float(value)
                 for key, value in (vehicle_overrides or {}).items()}
    return dataclasses.replace(vehicle, **overrides)


def rotor_roles(failed_rotor: int) -> tuple[tuple[int, int], int]:
    """The two rotors next to `failed_rotor` (0-based) and the one opposite it, in the ring r1..r4."""
    if failed_rotor not in (0, 1, 2, 3):
        raise ValueError(f"failed_rotor: a rotor index 0..3 (0 is r1), got {failed_rotor!r}")
    return ((failed_rotor + 1) % 4, (failed_rotor + 3) % 4), (failed_rotor + 2) % 4


def spin_direction(failed_rotor: int) -> float:
    """Sign of the body yaw rate r: the adjacent rotors turn against the failed one and give the larger
    drag torque, s_adj (2 - rho) f_adj, so the body yaws with s_adj = -s_failed (004 eq. 7 signs)."""
    return -YAW_SIGNS[failed_rotor]


def rotor_forces_for(f_adjacent: float, rho: float, failed_rotor: int) -> np.ndarray:
    """App. B's failed-propeller constraints: w_failed = 0, adjacent forces equal, opposite = rho * adjacent."""
    (a, b), opposite = rotor_roles(failed_rotor)
    forces = np.zeros(4)
    forces[[a, b]] = f_adjacent
    forces[opposite] = rho * f_adjacent
    return forces


def rotor_moment(params: QuadrotorParams, forces: np.ndarray) -> np.ndarray:
    """Thrust moments sum r_i x (0, 0, -f_i) (000 eq. 4) plus drag torques (c_Q / c_T) s_i f_i (004 eq. 7)."""
    pos = params.rotor_positions
    yaw = params.torque_coefficient / params.thrust_coefficient * float(np.dot(YAW_SIGNS, forces))
    return np.array([-pos[:, 1] @ forces, pos[:, 0] @ forces, yaw])


def propeller_momentum(params: QuadrotorParams, omega: np.ndarray, loaded: np.ndarray) -> np.ndarray:
    """h = -I_p sum_i s_i omega_i z over the propellers still on (signed speeds; App. B's script sums
    unsigned speeds; docs/vehicles.md, 'mueller2014')."""
    return np.array([0.0, 0.0, -params.propeller_inertia * float(np.dot(np.asarray(YAW_SIGNS) * loaded, omega))])


def body_moment(params: QuadrotorParams, rates, forces, loaded) -> np.ndarray:
    """Net moment on the body at body rates `rates` with steady rotor forces (eq. 12-14 generalised)."""
    omega = np.sqrt(np.maximum(forces, 0.0) / params.thrust_coefficient)
    inertia = np.asarray(params.inertia, dtype=float)
    momentum = inertia * rates + propeller_momentum(params, omega, loaded)
    return rotor_moment(params, forces) - cross(rates, momentum) + params.rotational_drag_moment(rates)


def _residual(x, params, rho, failed_rotor, weight, loaded):
    rates, f_adjacent = x[:3], x[3]
    forces = rotor_forces_for(f_adjacent, rho, failed_rotor)
    moment = body_moment(params, rates, forces, loaded)
    vertical = forces.sum() * abs(rates[2]) / max(np.linalg.norm(rates), 1e-9) - weight   # eq. (18)
    return np.append(moment, vertical)


def _initial_guess(params, rho, failed_rotor, weight, loaded) -> np.ndarray:
    """Level spin first: yaw rate from drag torque = damping, then p, q from the linear roll/pitch balance."""
    f_adjacent = weight / (2.0 + rho)
    forces = rotor_forces_for(f_adjacent, rho, failed_rotor)
    yaw_torque = rotor_moment(params, forces)[2]
    d1, d2 = params.rotational_drag[2], params.rotational_drag_quadratic[2]   # torque = d1 r + d2 r^2
    r = 2.0 * abs(yaw_torque) / (d1 + np.sqrt(d1 * d1 + 4.0 * d2 * abs(yaw_torque))) if d1 + d2 > 0 else 60.0
    r = float(np.clip(abs(r), 5.0, 60.0)) * spin_direction(failed_rotor)
    ixx, iyy, izz = params.inertia
    omega = np.sqrt(forces / params.thrust_coefficient)
    h_z = propeller_momentum(params, omega, loaded)[2]
    dx, dy = params.rotational_drag[:2]   # the quadratic term vanishes at p = q = 0
    # Moment balance about x and y, linear in (p, q) for fixed r: -Omega x (I Omega + h) - D Omega = -M_thrust
    A = np.array([[-dx, -(izz - iyy) * r - h_z], [(izz - ixx) * r + h_z, -dy]])
    p, q = np.linalg.solve(A, -rotor_moment(params, forces)[:2])
    return np.array([p, q, r, f_adjacent])


def relaxed_hover_equilibrium(vehicle, rho: float, vehicle_overrides: dict | None = None, failed_rotor: int = 3,
                              weight: float | None = None) -> dict:
    """The spinning equilibrium after `failed_rotor` (0-based, 0 is r1) lost its propeller.

    vehicle: a parameter-set name or a QuadrotorParams; rho: force ratio opposite / adjacent rotor (App. B;
    with Ixx = Iyy nothing spins from rho = 2 on, where the drag torques cancel; with Ixx != Iyy the body's own
    gyroscopic yaw moment p q (Ixx - Iyy) can carry the spin a little further); weight: the vertical force
    to carry (default m g).
    Returns body-FRD quantities: `n` the primary axis (unit, pointing to the thrust side, n_z < 0),
    `body_rates` (3,), `rotor_forces` (4,) N, `rotor_speeds` (4,) rad/s (0 for the failed rotor),
    `yaw_rate` (r), `spin_rate` |Omega|, `tilt` the angle between n and the thrust axis -z (rad),
    `thrust` the sum of the forces, `rho`, `failed_rotor`, `adjacent`, `opposite`.
    Raises ValueError when rho is out of range, no root is found, or the root needs a working rotor
    outside [omega_min, omega_max] (as App. B finds for the VSQP prototype at thrust-to-weight 1.5).
    """
    params = resolve_params(vehicle, vehicle_overrides)
    if not (np.isfinite(rho) and rho >= 0.0):
        raise ValueError(f"rho: the force ratio opposite/adjacent must be a finite number >= 0, got {rho!r}")
    adjacent, opposite = rotor_roles(failed_rotor)
    weight = params.mass * GRAVITY if weight is None else float(weight)
    loaded = np.arange(4) != failed_rotor
    args = (params, rho, failed_rotor, weight, loaded)
    x, _, ier, message = fsolve(_residual, _initial_guess(*args), args=args, full_output=True, xtol=1e-13)
    residual = np.abs(_residual(x, *args)).max()
    if ier != 1 or residual > RESIDUAL_TOLERANCE or x[3] <= 0 or x[2] * spin_direction(failed_rotor) <= 0:
        raise ValueError(f"relaxed hover of {params.name!r} without rotor {failed_rotor} at rho={rho}: "
                         f"no equilibrium found ({message.strip()}; residual {residual:.2e})")
    rates, forces = x[:3], rotor_forces_for(x[3], rho, failed_rotor)
    speeds = np.sqrt(forces / params.thrust_coefficient)
    _check_rotor_limits(params, speeds, failed_rotor, rho)
    n = -np.sign(rates[2]) * rates / np.linalg.norm(rates)
    return {
        "n": n, "body_rates": rates, "rotor_forces": forces, "rotor_speeds": speeds,
        "yaw_rate": float(rates[2]), "spin_rate": float(np.linalg.norm(rates)),
        "tilt": float(np.arccos(np.clip(-n[2], -1.0, 1.0))), "thrust": float(forces.sum()),
        "rho": float(rho), "failed_rotor": failed_rotor, "adjacent": adjacent, "opposite": opposite,
    }


def _check_rotor_limits(params: QuadrotorParams, speeds: np.ndarray, failed_rotor: int, rho: float) -> None:
    working = np.delete(speeds, failed_rotor)
    if working.max() > params.omega_max:
        raise ValueError(f"relaxed hover of {params.name!r} at rho={rho}: needs a rotor at {working.max():.0f} rad/s, "
                         f"above omega_max = {params.omega_max:.0f} rad/s (not enough thrust-to-weight)")
    if working.min() < params.omega_min:
        raise ValueError(f"relaxed hover of {params.name!r} at rho={rho}: needs a rotor at {working.min():.0f} rad/s, "
                         f"below the idle speed omega_min = {params.omega_min:.0f} rad/s (raise rho)")
