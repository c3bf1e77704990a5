"""Quadrotor parameter sets: plain data, every number with its source.

Rotor numbering and geometry follow 000 Fig. 2 / eq. (4): r1 = (h, -b) front-left, r2 = (h, b)
front-right, r3 = (-h, b) rear-right, r4 = (-h, -b) rear-left, in body FRD. Rotors 1 and 3 turn
opposite to 2 and 4; the yaw reaction torque signs are (+, -, +, -) as in 004 eq. (7). In code the
rotors are indexed 0..3 (index 0 is r1).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numba.extending import register_jitable

from .checks import NON_NEGATIVE, POSITIVE, Range, no_unknown, numbers
from .constants import GRAVITY

#: yaw reaction-torque sign per rotor (004 eq. 7; docs/concepts.md, 'Rotor numbering'): + means +z (FRD)
#: torque on the body.
YAW_SIGNS = (1.0, -1.0, 1.0, -1.0)


def rotor_wrench_matrix(positions, thrust_coefficient: float, torque_coefficient: float,
                        yaw_signs=YAW_SIGNS) -> np.ndarray:
    """The (4, n) matrix A with [T, tau_x, tau_y, tau_z] = A (k omega^2) for rotors at `positions` (body FRD,
    thrust along -z): collective thrust and moments r_i x (0, 0, -T_i) (000 eq. 4, 8) and drag torques
    c_Q s_i (004 eq. 7)."""
    pos = np.asarray(positions, dtype=float)
    c_t, c_q = thrust_coefficient, torque_coefficient
    return np.vstack([np.full(len(pos), c_t), -c_t * pos[:, 1], c_t * pos[:, 0], c_q * np.asarray(yaw_signs)])


@register_jitable
def rotational_drag_moment(linear: np.ndarray, quadratic: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Aerodynamic damping moment -(D1 + D2 |w|) w per body axis: linear as 004 eq. (11) and quadratic as
    Sun et al.'s Bebop2 model (simpleAeroModel.m: MDrag = -sign(w) rotDrag w^2)."""
    return -(linear + quadratic * np.abs(rates)) * rates


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of an X-configuration quadrotor (SI units)."""

    name: str
    mass: float                     # kg
    inertia: tuple                  # (Ixx, Iyy, Izz) kg m^2, body FRD principal axes
    arm_x: float                    # h: rotor distance along body x, m (000 Fig. 2)
    arm_y: float                    # b: rotor distance along body y, m (000 Fig. 2)
    thrust_coefficient: float       # c_T: thrust = c_T * k_i * omega^2, N/(rad/s)^2 (000 eq. 3)
    torque_coefficient: float       # c_Q: drag torque = c_Q * k_i * omega^2, N m/(rad/s)^2
    omega_min: float                # rad/s, ESC idle speed (command 0)
    omega_max: float                # rad/s, speed at command 1
    motor_time_constant: float      # s, first-order motor lag
    max_rotor_acceleration: float   # rad/s^2, |d omega/dt| limit
    propeller_radius: float         # m
    propeller_inertia: float        # kg m^2 about the spin axis (rotor gyroscopic moments)
    rotor_drag_coefficient: float   # N s^2/m per rotor: F = -k * omega * v_inplane (001 Sec. 4.3)
    body_drag: tuple                # (x, y, z) N s/m, linear body drag in FRD (004 eq. 9)
    rotational_drag: tuple          # (p, q, r) N m s, linear rotational damping (004 eq. 11)
    unloaded_speed_ratio: float     # steady speed of a motor that lost its propeller / loaded speed
    unloaded_time_constant: float   # s, motor lag without the propeller's inertia
    body_size: tuple = (0.2, 0.2, 0.05)  # m, collision box (x, y, z)
    rotational_drag_quadratic: tuple = (0.0, 0.0, 0.0)  # (p, q, r) N m s^2: -D2 |w| w (Sun's Bebop2 model)
    sources: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def rotor_positions(self) -> np.ndarray:
        """Rotor positions in body FRD, rows r1..r4 (000 eq. 4)."""
        h, b = self.arm_x, self.arm_y
        return np.array([[h, -b, 0.0], [h, b, 0.0], [-h, b, 0.0], [-h, -b, 0.0]])

    def rotational_drag_moment(self, rates) -> np.ndarray:
        """The aerodynamic damping moment on the body at body rates `rates` (`rotational_drag_moment`)."""
        return rotational_drag_moment(np.asarray(self.rotational_drag, dtype=float),
                                      np.asarray(self.rotational_drag_quadratic, dtype=float),
                                      np.asarray(rates, dtype=float))

    @property
    def hover_omega(self) -> float:
        """Rotor speed at which four rotors carry the weight: sqrt(m g / (4 c_T))."""
        return float(np.sqrt(self.mass * GRAVITY / (4.0 * self.thrust_coefficient)))

    @property
    def effectiveness_G(self) -> np.ndarray:
        """000 eq. (8)-(9): G = [c_T b / Ix, c_T h / Iy, c_T / m]."""
        ixx, iyy, _ = self.inertia
        c = self.thrust_coefficient
        return np.array([c * self.arm_y / ixx, c * self.arm_x / iyy, c / self.mass])


_SUN = "SihaoSun/INDI_Quadrotor_FTC Bebop2Model (docs/vehicles.md)"

BEBOP2 = QuadrotorParams(
    name="bebop2",
    mass=0.374,                                   # _SUN
    inertia=(1.448e-3, 1.255e-3, 2.520e-3),       # _SUN (Ixz 2.3e-5 neglected: diagonal as 000 eq. 8)
    arm_x=0.0875,                                 # h, _SUN; 000 Fig. 2
    arm_y=0.115,                                  # b, _SUN; 000 Fig. 2
    thrust_coefficient=1.9035e-6,                 # _SUN
    torque_coefficient=1.9203e-8,                 # _SUN (c_Q / c_T = 0.0101 m)
    # _SUN simParams.m wMin = 0: the FTC firmware may stop a motor. (000 Sec. IV-A's ~3000 RPM is the stock
    # ESC's idle; with it the opposite rotor tips the body toward the lost one and no spin recovery holds.)
    omega_min=0.0,
    omega_max=1200.0,                             # _SUN: rotor speed up to 1200 rad/s (~12000 RPM, 000 Sec. IV-A)
    motor_time_constant=1.0 / 30.0,               # _SUN
    max_rotor_acceleration=5.0e4,                 # _SUN
    propeller_radius=0.075,                       # _SUN
    propeller_inertia=8.0e-6,                     # _SUN, spin axis
    rotor_drag_coefficient=1.0e-5,                # assumed: 001 Sec. 4.3 form; ~0.029 N/(m/s) for 4 rotors at hover
    body_drag=(0.02, 0.02, 0.04),                 # assumed, order of 004 eq. (9) lambda
    rotational_drag=(0.0, 0.0, 0.0),              # _SUN has no linear term
    unloaded_speed_ratio=1.3,                     # assumed: 000 Fig. 8 shows the unloaded motor speeding up
    unloaded_time_constant=0.01,                  # assumed: no propeller inertia, motor spins up fast
    body_size=(0.33, 0.38, 0.09),                 # Parrot Bebop 2 public spec (328 x 382 x 89 mm)
    rotational_drag_quadratic=(5.0e-5, 5.0e-5, 1.0e-4),  # _SUN simParams.m rotDrag, quadratic in rate
    sources={"general": _SUN, "G": "000 Table II: G_p = G_q = 100e-6, G_az = 5e-6 (same order, see effectiveness_G)"},
)

MUELLER2014 = QuadrotorParams(
    name="mueller2014",
    mass=0.5,                                     # 001 Part II App. B "mueller"
    inertia=(3.2e-3, 3.2e-3, 5.5e-3),             # 001 App. B "mueller": I_xx_T = I_yy, I_zz_T
    # Mueller's rotors sit on the body axes at l = 0.17 m ("+"). We keep 000's X numbering by rotating
    # the body axes 45 deg: h = b = l / sqrt(2). With Ixx = Iyy the vehicle is physically the same.
    arm_x=0.17 / np.sqrt(2.0),
    arm_y=0.17 / np.sqrt(2.0),
    thrust_coefficient=6.41e-6,                   # 001 App. B "mueller" k_f
    torque_coefficient=6.41e-6 * 1.69e-2,         # k_t = 1.69e-2 m (torque/thrust), 001 App. B
    omega_min=100.0,                              # assumed idle
    omega_max=700.0,                              # assumed: 3.1 N per rotor, thrust-to-weight 2.6
    motor_time_constant=0.015,                    # assumed, typical small brushless motor
    max_rotor_acceleration=5.0e4,                 # assumed, as bebop2
    propeller_radius=0.1,                         # assumed
    propeller_inertia=1.5e-5,                     # 001 App. B (without its 1e-6 unit slip, docs/vehicles.md)
    rotor_drag_coefficient=1.0e-5,                # assumed, as bebop2
    body_drag=(0.03, 0.03, 0.05),                 # assumed
    rotational_drag=(1.0e-4, 1.0e-4, 2.75e-3),    # yaw: gamma_1_z = 2.75e-3 N m s (001 App. B); roll/pitch assumed
    unloaded_speed_ratio=1.3,                     # assumed, as bebop2
    unloaded_time_constant=0.008,                 # assumed
    body_size=(0.35, 0.35, 0.08),                 # assumed from arm length
    sources={"general": "001 Part II App. B 'mueller' case; unlisted numbers assumed"},
)

VEHICLES = {p.name: p for p in (BEBOP2, MUELLER2014)}

#: the values each field accepts (`vehicle_overrides` are checked against them; a built-in set satisfies them)
QUADROTOR_RANGES = {
    "mass": POSITIVE, "inertia": POSITIVE, "arm_x": POSITIVE, "arm_y": POSITIVE,
    "thrust_coefficient": POSITIVE, "torque_coefficient": NON_NEGATIVE,
    "omega_min": NON_NEGATIVE, "omega_max": POSITIVE, "motor_time_constant": POSITIVE,
    "max_rotor_acceleration": POSITIVE, "propeller_radius": POSITIVE, "propeller_inertia": NON_NEGATIVE,
    "rotor_drag_coefficient": NON_NEGATIVE, "body_drag": NON_NEGATIVE, "rotational_drag": NON_NEGATIVE,
    "unloaded_speed_ratio": Range(1.0),    # a motor that lost its propeller does not slow down (000 Fig. 8)
    "unloaded_time_constant": POSITIVE, "body_size": POSITIVE, "rotational_drag_quadratic": NON_NEGATIVE,
}
#: rules between fields: (holds(params), the rule as the error states it)
QUADROTOR_RELATIONS = (
    (lambda p: p.omega_min < p.omega_max, "omega_min must be below omega_max"),
)


def make_params(vehicle: str, overrides: dict | None = None) -> QuadrotorParams:
    """The named parameter set with `overrides` applied; unknown names raise ValueError."""
    return named_params(VEHICLES, vehicle, overrides, QUADROTOR_RANGES, QUADROTOR_RELATIONS)


#: how far an override may scale a parameter of the named set, either way: the sets are small UAVs, and a value
#: outside is a unit slip or another vehicle whose physics would leave the float range in a step
SCALE_LIMIT = 1e3


def _scale(catalogue: dict, params, key: str) -> np.ndarray:
    """The magnitude an override of `key` is measured against, per element: the named set's value, or where that
    is 0 the largest of the catalogue's sets (0 where all are: no limit)."""
    named = np.abs(np.asarray(getattr(params, key), dtype=float))
    largest = np.max([np.abs(np.asarray(getattr(p, key), dtype=float)) for p in catalogue.values()], axis=0)
    return np.where(named > 0, named, largest)


def _check_scale(values: np.ndarray, scale: np.ndarray, where: str) -> None:
    """ValueError unless every non-zero value lies within SCALE_LIMIT of its scale, either way (0 stays 0)."""
    magnitude = np.abs(values)
    bad = (scale > 0) & ((magnitude > SCALE_LIMIT * scale) | ((magnitude > 0) & (magnitude < scale / SCALE_LIMIT)))
    if np.any(bad):
        low, high = (np.min(scale[scale > 0]) / SCALE_LIMIT, np.max(scale) * SCALE_LIMIT)
        raise ValueError(f"{where}: {values.tolist() if values.ndim else float(values)!r} is more than "
                         f"{SCALE_LIMIT:g} times off the parameter set's magnitude; accepted magnitudes "
                         f"{low:.3g} to {high:.3g} (or 0 where the field allows it)")


def named_params(catalogue: dict, vehicle: str, overrides: dict | None, ranges: dict, relations=()):
    """`catalogue[vehicle]` (a frozen dataclass) with `overrides` applied. Each override must be real numbers
    of its field's shape inside `ranges[field]` and within SCALE_LIMIT of the set's own magnitude (`_scale`), and
    the result must satisfy every `(holds, rule)` of `relations`; otherwise ValueError names the field, the value
    and what is accepted."""
    if not isinstance(vehicle, str) or vehicle not in catalogue:
        raise ValueError(f"vehicle: unknown parameter set {vehicle!r}; accepted: {sorted(catalogue)}")
    params = catalogue[vehicle]
    if not overrides:
        return params
    if not isinstance(overrides, dict):
        raise ValueError(f"vehicle_overrides: expected a dict of field -> value, got {overrides!r}")
    no_unknown(overrides, ranges, "vehicle_overrides field")
    clean = {}
    for key, value in overrides.items():
        where = f"vehicle_overrides[{key!r}]"
        arr = numbers(value, where, np.shape(getattr(params, key)), ranges[key])
        _check_scale(arr, _scale(catalogue, params, key), where)
        clean[key] = tuple(arr.tolist()) if arr.ndim else float(arr)
    params = dataclasses.replace(params, **clean)
    for holds, rule in relations:
        if not holds(params):
            raise ValueError(f"vehicle_overrides: {rule} (with {clean})")
    return params
