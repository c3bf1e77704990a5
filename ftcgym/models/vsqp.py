"""Variable Skew Quad Plane (VSQP) parameter set: plain data, every number with its source.

Pure numpy (no simulator import). The aerodynamic model that uses these numbers is
`ftcgym/models/quadplane_aero.py`; the pusher's electric propulsion model is `ftcgym/models/pusher.py`.

Frames and signs. Body FRD (x forward, y right, z down), SI units, angles in rad. Skew Lambda: 0 = hover
(wing along the fuselage, over it), pi/2 = forward flight (wing spanwise), 001 Sec. 2. The wing's span
direction is s = (cos L, sin L, 0): its "right" half points forward in hover and swings to the right.
Hover rotors, index order (arrays, fault targets):

    0 front  (on the fuselage, x = +l)                                     yaw sign +1
    1 right  (on the right arm, perpendicular to the wing: (0, +l) at L = 0, (-l, 0) at L = 90 deg)
                                                                           yaw sign -1
    2 rear   (on the fuselage, x = -l)                                     yaw sign +1
    3 left   (on the left arm: (0, -l) at L = 0, (+l, 0) at L = 90 deg)    yaw sign -1

with l = 0.435 m. At L = 90 deg the arm rotors sit over the fuselage rotors ("stowed", 001 Sec. 2); they
are stopped in forward flight, and blade interference is not modelled.

Yaw sign +1: the rotor's drag (reaction) torque on the body is about the body +z axis (quadrotor
convention, vehicles.py). Each rotor is tilted by `hover_tilt` (3 deg, 001 App. B) about its arm so that
its thrust's tangential part yaws the body in the same sense as its drag torque (001 Sec. 5.1.2: tilted
motors for more yaw authority; App. B: M_z = f sin(beta) l). Thrust points along -z tilted.

Control surfaces (aileron, elevator, rudder) follow Beard & McLain's convention: a positive aileron rolls
right (+L), a positive (trailing-edge-down) stabilator pitches nose down (-M), a positive rudder yaws nose
left (-N).

## Derivation of the coefficients

001 gives the model's form (eq. 6-30, 8.3) and magnitudes, not every coefficient. Each number below says
whether it is given (printed in a source), derived (computed from given numbers) or assumed (chosen, with the
reason); docs/vehicles.md, "Derivation of the coefficients", tabulates them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .checks import FINITE, NON_NEGATIVE, POSITIVE, Range
from .constants import GRAVITY
from .pyfloat import py_hypot
from .quadrotor import named_params

RPM = math.pi / 30.0   # rad/s per RPM
INCH = 0.0254          # m

_LAROCQUE = "001 (Larocque 2023)"


@dataclass(frozen=True)
class VsqpParams:
    """Physical parameters of the VSQP quad-plane (SI units, body FRD). See the module docstring."""

    name: str
    mass: float                        # kg
    inertia: tuple                     # (Ixx, Iyy, Izz) kg m^2, constant (001 eq. 8.1 "constant inertia I_v")
    air_density: float                 # kg/m^3
    # Hover rotors (001 eq. 15-17, App. B).
    hover_thrust_coefficient: float    # k_f: T = k_f w^2, N/(rad/s)^2
    hover_torque_coefficient: float    # k_t k_f: Q = c_Q w^2, N m/(rad/s)^2
    hover_omega_min: float             # rad/s (0: motors stop in forward flight, 001 Sec. 2)
    hover_omega_max: float             # rad/s
    hover_time_constant: float         # s, first-order motor lag
    hover_max_acceleration: float      # rad/s^2
    hover_yaw_signs: tuple             # (4,), drag-torque sign about body +z, rotors 0..3
    hover_tilt: float                  # rad, tilt about the arm (001 App. B beta)
    propeller_inertia: float           # kg m^2, hover rotor about its spin axis
    hover_fuselage_arm: float          # m, |x| of rotors 0 and 2
    hover_wing_arm: float              # m, arm length of rotors 1 and 3 (they turn with the skew)
    hover_rotor_height: float          # m, z of the rotor hubs (negative: above the CG)
    hover_drag_coefficient: float      # N s/m per rad/s per rotor: F = -k w v_inplane (001 eq. 16-17)
    hover_propeller_diameter: float    # m
    # Pusher: 001 eq. 11-14 (thrust) and 003 eq. 1-5 (torque balance, C_Q(J), current).
    pusher_diameter: float             # D, m
    pusher_thrust_coefficients: tuple  # (b, a): C_T = b + a J, J = V/(n D) (001 eq. 12)
    pusher_thrust_k3: float            # N/(m/s): 001 eq. 14's K_xp3 u term
    pusher_torque_coefficients: tuple  # (C_Q0, C_Q1, C_Q2), 003 eq. 3
    pusher_inertia: float              # Theta, kg m^2 (003 eq. 1)
    pusher_motor_constant: float       # k_e, N m/A = V s/rad (003 eq. 1)
    pusher_resistance: float           # ohm, motor + ESC (our electrical model: I = (u V_bat - k_e w)/R)
    pusher_zero_load_current: float    # I_0, A (003 eq. 1); fault handle static_friction
    pusher_viscous_friction: float     # c_v, N m s (003 eq. 1); fault handle viscous_friction
    pusher_icing: float                # theta_1 nominal (003 eq. 5): 1
    battery_voltage: float             # V
    pusher_max_current: float          # A, ESC current limit
    pusher_omega_max: float            # rad/s, limit of the speed (trim and observation bounds)
    pusher_spin_direction: float       # +1: propeller spins positively about body +x
    # Wing (001 eq. 18-30).
    wing_area: float                   # S, m^2
    wing_span: float                   # b, m
    wing_chord: float                  # c, m
    wing_incidence: float              # rad, wing chord vs body x at skew 90 deg
    wing_cl0: float                    # C_L at zero wing alpha (001 eq. 21's C_L0)
    wing_cl_alpha: float               # /rad (001 eq. 21)
    wing_cd0: float                    # 001 eq. 23
    wing_oswald: float                 # e, 001 eq. 23
    wing_cm0: float                    # pitching moment coefficient about the AC
    wing_ac_offset: float              # m, AC ahead of the pivot/CG along the chord direction
    wing_alpha_stall: tuple            # (positive, negative) rad, wing alpha where the flat-plate blend is half
    wing_cn90: float                   # flat-plate normal-force coefficient at 90 deg
    wing_spanwise_friction: float      # C_f on the spanwise flow (both sides)
    wing_roll_damping: float           # Cl_p (ref S b, p b / 2V)
    stall_blend: float                 # /rad, sharpness of the attached/flat-plate blend
    # Fuselage (001 eq. 7-10).
    fuselage_drag_area: tuple          # (x, y, z) Cd A, m^2
    # Tail (001 App. B "VSQP_V2") and control surfaces (001 eq. 8.3).
    tail_arm: float                    # m, CG to the tail's aerodynamic centre
    htail_area: float                  # m^2, all-moving stabilator
    htail_span: float                  # m
    htail_cl_alpha: float              # /rad
    htail_alpha_stall: float           # rad
    vtail_area: float                  # m^2
    vtail_height: float                # m, the fin's centre sits at z = -height/2
    vtail_cl_alpha: float              # /rad
    tail_cd0: float
    tail_cn90: float                   # flat plate C_d (001 App. B: 1.17)
    rudder_effectiveness: float        # tau: equivalent fin angle per rad of rudder
    aileron_roll_coefficient: float    # Cl_delta_a /rad, ref S b, full skew
    surface_limit: tuple               # (aileron, elevator, rudder) rad
    skew_rate_limit: float             # rad/s
    transition_start_speed: float      # m/s, skew leaves 0 (skew_schedule)
    transition_end_speed: float        # m/s, skew reaches 90 deg
    body_size: tuple = (1.30, 0.90, 0.25)  # m, collision box (x, y, z)
    sources: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def weight(self) -> float:
        return self.mass * GRAVITY

    @property
    def hover_omega(self) -> float:
        """Speed at which the four (tilted) hover rotors carry the weight: m g = 4 k_f w^2 cos(tilt)."""
        per_rotor = self.weight / (4.0 * math.cos(self.hover_tilt))
        return math.sqrt(per_rotor / self.hover_thrust_coefficient)

    @property
    def aspect_ratio(self) -> float:
        return self.wing_span ** 2 / self.wing_area

    def hover_rotor_geometry(self, skew: float) -> tuple:
        """(positions, axes) of the 4 hover rotors as tuples of (x, y, z): plain floats (`rotor_geometry`)."""
        return rotor_geometry(math.sin(skew), math.cos(skew), float(self.hover_fuselage_arm),
                              float(self.hover_wing_arm), float(self.hover_rotor_height), float(self.hover_tilt),
                              tuple(map(float, self.hover_yaw_signs)))

    def hover_rotor_positions(self, skew: float) -> np.ndarray:
        """(4, 3) hub positions in body FRD, rotor order 0 front, 1 right, 2 rear, 3 left."""
        return np.array(self.hover_rotor_geometry(skew)[0])

    def hover_thrust_axes(self, skew: float) -> np.ndarray:
        """(4, 3) unit thrust directions in body FRD (see `hover_rotor_geometry`)."""
        return np.array(self.hover_rotor_geometry(skew)[1])


class ParamsCache:
    """`build(params)` for a parameter set, built on first use and kept for the last `size` sets (the few in
    use at once), looked up by identity (a parameter set is immutable)."""

    def __init__(self, build, size: int = 8):
        self.build, self.size, self._built = build, size, {}

    def __call__(self, params):
        entry = self._built.get(id(params))
        if entry is None or entry[0] is not params:
            if len(self._built) >= self.size:
                del self._built[next(iter(self._built))]
            entry = self._built[id(params)] = (params, self.build(params))
        return entry[1]


@njit(cache=True)
def rotor_geometry(sin_skew, cos_skew, fuselage_arm, wing_arm, height, tilt, yaw_signs):  # pragma: no cover (compiled)
    """(positions, axes) of the 4 hover rotors at the skew L of sine and cosine `sin_skew`, `cos_skew`.

    Rotors 1 (right) and 3 (left) ride on arms perpendicular to the wing, so they swing from (0, +-l)
    at skew 0 to (-+l, 0) at skew 90 deg (001 Sec. 3 Fig. 3.2). Each thrust axis is -z tilted by
    `tilt` toward the tangential direction whose yaw moment has the rotor's yaw sign (001 App. B:
    M_z = f sin(beta) l adds to the drag torque).
    """
    s, c, lf, lw, z = sin_skew, cos_skew, fuselage_arm, wing_arm, height
    positions = ((lf, 0.0, z), (-lw * s, lw * c, z), (-lf, 0.0, z), (lw * s, -lw * c, z))
    st, ct = math.sin(tilt), math.cos(tilt)
    axes = (_thrust_axis(positions[0], yaw_signs[0], st, ct), _thrust_axis(positions[1], yaw_signs[1], st, ct),
            _thrust_axis(positions[2], yaw_signs[2], st, ct), _thrust_axis(positions[3], yaw_signs[3], st, ct))
    return positions, axes


@njit(cache=True)
def _thrust_axis(position, sign, sin_tilt, cos_tilt):  # pragma: no cover (compiled)
    """-z tilted toward the tangential direction z x radial of the hub at `position`, times the yaw sign."""
    x, y = position[0], position[1]
    r = py_hypot(x, y)
    return (-y / r * sin_tilt * sign, x / r * sin_tilt * sign, -cos_tilt)


VSQP = VsqpParams(
    name="vsqp",
    mass=6.5,                                             # 001 App. B "VSQP_V2" m
    inertia=(2.862e-2, 2.158e-1 - 2.862e-2, 2.158e-1),    # 001 App. B I_xx_T, I_zz_T; Iyy = Izz - Ixx (flat body)
    air_density=1.225,                                    # 001 App. B rho
    hover_thrust_coefficient=((1.27e-6 + 8.75e-7) / 2.0) / RPM ** 2,  # 001 App. B k_f (N/RPM^2 -> N/(rad/s)^2)
    hover_torque_coefficient=2.85e-2 * ((1.27e-6 + 8.75e-7) / 2.0) / RPM ** 2,  # 001 App. B k_t = 2.85e-2 m
    hover_omega_min=0.0,                                  # 001 Sec. 2: hover motors stop in forward flight
    hover_omega_max=5400.0 * RPM,                         # assumed: T/W = (5400/3858)^2 = 1.96 (001 Table 5.1: 2)
    hover_time_constant=0.08,                             # assumed: 17 in propeller, slower than bebop2's 1/30 s
    hover_max_acceleration=2500.0,                        # assumed: (~1.5 N m peak - drag torque) / 5e-4 kg m^2
    hover_yaw_signs=(1.0, -1.0, 1.0, -1.0),               # alternate so drag torques cancel in hover (001 Fig. 1a)
    hover_tilt=math.radians(3.0),                         # 001 App. B beta = 3 deg
    propeller_inertia=5.0e-4,                             # assumed: 17 in, ~30 g blade (m L^2/12 = 4.7e-4) + motor bell
    hover_fuselage_arm=(0.470 + 0.400) / 2.0,             # 001 App. B l = (470+400)/2 mm "average between fuselage
    hover_wing_arm=(0.470 + 0.400) / 2.0,                 # motor and arms length": one l, so hover is balanced
    hover_rotor_height=-0.08,                             # assumed: hubs 8 cm above the CG (on top of fuselage/wing)
    hover_drag_coefficient=0.75 / (4.0 * 4000.0 * RPM),   # 001 App. A: -0.75 N s/m (4 rotors) at 4,000 RPM
    hover_propeller_diameter=17.0 * INCH,                 # 001 App. B: Tarot 17x5.0
    pusher_diameter=13.0 * INCH,                          # assumed 13x8: 30 N static at ~9,900 RPM
    pusher_thrust_coefficients=(0.075, -0.095),           # assumed (b, a) of 001 eq. 12: zero thrust at J = 0.79
    pusher_thrust_k3=0.0,                                 # 001 eq. 14 K_xp3: a wind-tunnel fit term, not needed here
    pusher_torque_coefficients=(0.0065, -0.0021, -0.0052),  # assumed 003 eq. 3 (see the table)
    pusher_inertia=3.0e-4,                                # assumed: 13 in propeller ~2.5e-4 + rotor bell 5e-5
    pusher_motor_constant=60.0 / (2.0 * math.pi * 500.0),  # assumed 500 kV: k_e = 1/kv = 0.0191 V s/rad
    pusher_resistance=0.05,                               # assumed: winding ~35 mOhm + ESC and wires
    pusher_zero_load_current=1.0,                         # assumed: typical no-load current of a 500 kV outrunner
    pusher_viscous_friction=1.0e-5,                       # assumed: ~0.01 N m bearing/eddy torque at 1,000 rad/s
    pusher_icing=1.0,                                     # 003 eq. 5 nominal theta_1* = 1
    battery_voltage=22.2,                                 # assumed 6S LiPo nominal (the MN3520 400 kV is a 6S motor)
    pusher_max_current=60.0,                              # assumed: 60 A ESC (full throttle holds ~46 A static)
    pusher_omega_max=10000.0 * RPM,                       # assumed: above the full-throttle static ~9,900 RPM
    pusher_spin_direction=1.0,                            # assumed: clockwise seen from behind (+x)
    wing_area=0.5,                                        # assumed, see the table
    wing_span=2.0,                                        # assumed
    wing_chord=0.25,                                      # S / b
    wing_incidence=math.radians(1.2),                     # assumed, see the table
    wing_cl0=0.30,                                        # assumed cambered airfoil (001 eq. 21 C_L0)
    wing_cl_alpha=2.0 * math.pi * 8.0 / (2.0 + math.sqrt(8.0 ** 2 + 4.0)),  # Helmbold, A = 8: 4.91 /rad
    wing_cd0=0.012,                                       # assumed
    wing_oswald=0.80,                                     # assumed
    wing_cm0=-0.07,                                       # assumed cambered airfoil
    wing_ac_offset=0.02,                                  # assumed: pivot = CG (001 Sec. 8.1.1), AC 2 cm ahead
    wing_alpha_stall=(math.radians(13.0), math.radians(-8.0)),  # assumed low-Re airfoil, AR 8: C_Lmax 1.13 at 10.7 deg
    wing_cn90=1.17,                                       # Hoerner flat plate, as 001 App. B's tail
    wing_spanwise_friction=0.01,                          # assumed: 2 x turbulent skin friction ~0.005
    wing_roll_damping=-0.45,                              # strip theory -a/6 reduced for induced effects
    stall_blend=60.0,                                     # assumed: blend over ~2 deg (a rounded lift peak)
    fuselage_drag_area=(0.012, 0.25, 0.20),               # assumed, see the table (001 eq. 8, 10)
    tail_arm=0.757,                                       # 001 App. B b_h
    htail_area=0.075,                                     # assumed stabilator 0.5 x 0.15 m
    htail_span=0.5,                                       # assumed (A = 3.33)
    htail_cl_alpha=2.0 * math.pi * 3.33 / (2.0 + math.sqrt(3.33 ** 2 + 4.0)),  # Helmbold, A = 3.33: 3.55 /rad
    htail_alpha_stall=math.radians(15.0),                 # assumed symmetric, low aspect ratio
    vtail_area=0.17 * 0.25,                               # 001 App. B h_tail_width x h_tail_height
    vtail_height=0.25,                                    # 001 App. B (b_v = height / 2)
    vtail_cl_alpha=2.0 * math.pi * 1.47 / (2.0 + math.sqrt(1.47 ** 2 + 4.0)),  # Helmbold, A = 0.25^2/0.0425
    tail_cd0=0.01,                                        # assumed
    tail_cn90=1.17,                                       # 001 App. B Cd = 1.17 (Hoerner 1992, p. 3-17)
    rudder_effectiveness=0.5,                             # assumed: 40% chord rudder
    aileron_roll_coefficient=0.20,                        # assumed (Aerosonde-class UAVs: 0.17-0.25)
    surface_limit=(math.radians(20.0), math.radians(20.0), math.radians(25.0)),  # assumed servo throws
    skew_rate_limit=0.6,                                  # assumed: 90 deg in 2.6 s (001: transition in 4-5 s)
    transition_start_speed=4.0,                           # 001 Sec. 8.1.2: wing starts to skew near 5 m/s
    transition_end_speed=14.5,                            # assumed: above the 1 g stall speed (13.55 m/s)
    body_size=(1.30, 0.90, 0.25),                         # assumed: fuselage length x landing-gear track x height
    sources={
        "general": f"{_LAROCQUE} Part II App. B 'VSQP_V2', Part I Sec. 4 and App. A; docs/vehicles.md",
        "pusher": "003 (Haaland et al.) eq. 1-5 with assumed 13x8 propeller and 500 kV motor",
        "derivations": "module docstring of ftcgym/models/vsqp.py; docs/vehicles.md",
    },
)

QUADPLANE_VEHICLES = {VSQP.name: VSQP}

_SIGN = Range(-1.0, 1.0)                       # with the relation below: exactly -1 or +1
_ANGLE = Range(-math.pi / 2, math.pi / 2, open_low=True, open_high=True)
#: the values each field accepts (`vehicle_overrides` are checked against them; the built-in set satisfies them)
VSQP_RANGES = {
    **{name: POSITIVE for name in (
        "mass", "inertia", "air_density", "hover_thrust_coefficient", "hover_omega_max", "hover_time_constant",
        "hover_max_acceleration", "hover_fuselage_arm", "hover_wing_arm", "hover_propeller_diameter",
        "pusher_diameter", "pusher_inertia", "pusher_motor_constant", "pusher_resistance", "pusher_icing",
        "battery_voltage", "pusher_max_current", "pusher_omega_max", "wing_area", "wing_span", "wing_chord",
        "wing_cl_alpha", "stall_blend", "tail_arm", "htail_span", "htail_alpha_stall", "vtail_height",
        "skew_rate_limit", "transition_end_speed", "body_size")},
    **{name: NON_NEGATIVE for name in (
        "hover_torque_coefficient", "hover_omega_min", "propeller_inertia", "hover_drag_coefficient",
        "pusher_zero_load_current", "pusher_viscous_friction", "wing_cd0", "wing_cn90", "wing_spanwise_friction",
        "fuselage_drag_area", "htail_area", "htail_cl_alpha", "vtail_area", "vtail_cl_alpha", "tail_cd0",
        "tail_cn90", "transition_start_speed")},
    **{name: FINITE for name in (
        "hover_rotor_height", "pusher_thrust_coefficients", "pusher_thrust_k3", "pusher_torque_coefficients",
        "wing_cl0", "wing_cm0", "wing_ac_offset", "wing_roll_damping", "rudder_effectiveness",
        "aileron_roll_coefficient")},
    "hover_yaw_signs": _SIGN, "pusher_spin_direction": _SIGN,
    "hover_tilt": _ANGLE, "wing_incidence": _ANGLE, "wing_alpha_stall": _ANGLE,
    "wing_oswald": Range(0.0, 1.0, open_low=True),
    "surface_limit": Range(0.0, math.pi / 2, open_low=True, open_high=True),
}
#: rules between fields: (holds(params), the rule as the error states it)
VSQP_RELATIONS = (
    (lambda p: p.hover_omega_min < p.hover_omega_max, "hover_omega_min must be below hover_omega_max"),
    (lambda p: all(abs(s) == 1.0 for s in (*p.hover_yaw_signs, p.pusher_spin_direction)),
     "hover_yaw_signs and pusher_spin_direction must each be -1 or +1"),
    (lambda p: p.wing_alpha_stall[1] < 0.0 < p.wing_alpha_stall[0], "wing_alpha_stall must be (positive, negative)"),
    (lambda p: p.transition_start_speed < p.transition_end_speed,
     "transition_start_speed must be below transition_end_speed"),
)


def make_vsqp_params(vehicle: str = "vsqp", overrides: dict | None = None) -> VsqpParams:
    """The named quad-plane parameter set with `overrides` applied (as `vehicles.make_params`)."""
    return named_params(QUADPLANE_VEHICLES, vehicle, overrides, VSQP_RANGES, VSQP_RELATIONS)
