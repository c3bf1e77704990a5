"""Forces and moments on the VSQP quad-plane, except gravity: 001's component model, made valid everywhere.

001 eq. (6): the total force is the sum of the fuselage, hover rotors, wing and pusher. 001 writes each
part with small angles and airspeed along body x (it was fitted on forward-flight and wind-tunnel data); a
simulator also hovers in wind from any side, so each part here uses the full air-velocity vector and
reduces to 001's form for small angles (stated beside each). Lifting surfaces blend a linear lift curve
into a flat plate past the stall (Beard & McLain's sigmoid blend), so forces stay bounded at any angle.

Inputs: `air_velocity_body` is the velocity of the vehicle relative to the air mass, in body FRD
((u, v, w) = R^T (v_ground - v_wind)); `body_rates` (p, q, r) rad/s. Outputs are in body FRD about the CG.
No simulator import. The formulas are compiled (numba, the `*_loads` functions) on plain floats and the
constants of one parameter set (`QuadPlaneAero.constants`), so the physics step runs them without the
interpreter; the module functions (`aero_wrench`, `wing_flow`, ...) take the parameter set and call them
with a cached `QuadPlaneAero`. They keep the operations and their order of the plain-Python model they
replaced, with Python's own pow and hypot (`pyfloat`), so every force keeps its bits.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .pyfloat import py_hypot, py_pow
from .vsqp import ParamsCache, rotor_geometry

PI = math.pi
HALF_PI = 0.5 * PI
TWO_PI = 2.0 * PI

#: indices into `QuadPlaneAero.constants` (what each holds: `QuadPlaneAero.__init__`)
(FUSELAGE_X, FUSELAGE_Z, NEG_HALF_RHO, DRAG_AREA_Y, HALF_RHO, WING_INCIDENCE, WING_CM0, WING_CN90, HALF_RHO_WING,
 SPANWISE_DRAG, WING_AREA, WING_SPAN, WING_CHORD, WING_AC_OFFSET, AILERON_COEFFICIENT, QUARTER_RHO,
 NEG_ROLL_DAMPING, STRIP_DAMPING, PI_ASPECT_RATIO, HALF_RHO_HTAIL, HALF_RHO_VTAIL, TAIL_ARM, NEG_TAIL_ARM, FIN_Z,
 RUDDER_EFFECTIVENESS, K_F, C_Q, NEG_K_D, FUSELAGE_ARM, WING_ARM, ROTOR_HEIGHT, ROTOR_TILT) = range(32)
YAW_SIGNS = 32                                              # 4 values, rotor order
#: where each lifting surface's 8 coefficients start (their order: CL0 ... BLEND below)
WING_SURFACE, HTAIL_SURFACE, VTAIL_SURFACE = 36, 44, 52
N_CONSTANTS = 60
CL0, CL_ALPHA, STALL_POS, STALL_NEG, CD0, K_INDUCED, CN90, BLEND = range(8)


def skew_schedule(params, airspeed: float) -> float:
    """Wing skew (rad) for an airspeed: 0 below `transition_start_speed`, 90 deg above
    `transition_end_speed`, a smoothstep between (zero slope at both ends, so the command is smooth).

    001 Sec. 8.1.2: the skew is scheduled on airspeed (the prototype skews from ~5 m/s and reaches 90 deg
    by ~12 m/s); ours ends above our stall speed so the wing can carry the weight once fully skewed.
    The schedule uses the airspeed it is given, right or wrong (001 Sec. 1: pitot faults).
    """
    if not math.isfinite(airspeed):
        raise ValueError(f"skew_schedule: airspeed must be finite, got {airspeed!r}")
    start, end = params.transition_start_speed, params.transition_end_speed
    x = min(max((airspeed - start) / (end - start), 0.0), 1.0)
    return HALF_PI * x * x * (3.0 - 2.0 * x)


class QuadPlaneAero:
    """The constants of the component model for one parameter set (`VsqpParams`): `constants`, a float array
    indexed by this module's names, the argument `c` of the compiled formulas.

    The products of parameters that lead a formula are computed here once, in the formula's own order, so
    every force has the bits of the formula evaluated term by term.
    """

    def __init__(self, params):
        p = self.params = params
        c = self.constants = np.zeros(N_CONSTANTS)
        half_rho = c[HALF_RHO] = 0.5 * p.air_density
        # Fuselage: -1/2 rho CdA_x, -1/2 rho (times |V|, then CdA_y), -1/2 rho CdA_z.
        ax, ay, az = p.fuselage_drag_area
        c[FUSELAGE_X], c[FUSELAGE_Z], c[NEG_HALF_RHO], c[DRAG_AREA_Y] = -half_rho * ax, -half_rho * az, -half_rho, ay
        # Wing: its lifting surface, 1/2 rho S, -1/2 rho S C_f, the moments' factors, pi A for the downwash.
        k_induced = 1.0 / (math.pi * p.aspect_ratio * p.wing_oswald)           # 001 eq. (23)
        c[WING_SURFACE:WING_SURFACE + 8] = (p.wing_cl0, p.wing_cl_alpha, *p.wing_alpha_stall, p.wing_cd0, k_induced,
                                            p.wing_cn90, p.stall_blend)
        c[WING_INCIDENCE], c[WING_CM0], c[WING_CN90] = p.wing_incidence, p.wing_cm0, p.wing_cn90
        c[HALF_RHO_WING] = half_rho * p.wing_area
        c[SPANWISE_DRAG] = -half_rho * p.wing_area * p.wing_spanwise_friction
        c[WING_AREA], c[WING_SPAN], c[WING_CHORD] = p.wing_area, p.wing_span, p.wing_chord
        c[WING_AC_OFFSET], c[AILERON_COEFFICIENT] = p.wing_ac_offset, p.aileron_roll_coefficient
        c[QUARTER_RHO], c[NEG_ROLL_DAMPING] = 0.25 * p.air_density, -p.wing_roll_damping
        c[STRIP_DAMPING] = p.air_density * p.wing_cn90 * p.wing_chord * p.wing_span ** 4 / 64.0
        c[PI_ASPECT_RATIO] = math.pi * p.aspect_ratio
        # Tail: stabilator and fin surfaces (induced drag with e = 0.8), 1/2 rho S of each, arms.
        stall_and_cd0 = (p.htail_alpha_stall, -p.htail_alpha_stall, p.tail_cd0)
        k_h = 1.0 / (math.pi * 0.8 * p.htail_span ** 2 / p.htail_area)
        k_v = 1.0 / (math.pi * 0.8 * p.vtail_height ** 2 / p.vtail_area)
        c[HTAIL_SURFACE:HTAIL_SURFACE + 8] = (0.0, p.htail_cl_alpha, *stall_and_cd0, k_h, p.tail_cn90, p.stall_blend)
        c[VTAIL_SURFACE:VTAIL_SURFACE + 8] = (0.0, p.vtail_cl_alpha, *stall_and_cd0, k_v, p.tail_cn90, p.stall_blend)
        c[HALF_RHO_HTAIL], c[HALF_RHO_VTAIL] = half_rho * p.htail_area, half_rho * p.vtail_area
        c[TAIL_ARM], c[NEG_TAIL_ARM], c[FIN_Z] = p.tail_arm, -p.tail_arm, -0.5 * p.vtail_height
        c[RUDDER_EFFECTIVENESS] = p.rudder_effectiveness
        # Hover rotors: k_f, c_Q, -k_d, the geometry of `rotor_geometry` and the yaw signs.
        c[K_F], c[C_Q], c[NEG_K_D] = p.hover_thrust_coefficient, p.hover_torque_coefficient, -p.hover_drag_coefficient
        c[FUSELAGE_ARM], c[WING_ARM] = p.hover_fuselage_arm, p.hover_wing_arm
        c[ROTOR_HEIGHT], c[ROTOR_TILT] = p.hover_rotor_height, p.hover_tilt
        c[YAW_SIGNS:YAW_SIGNS + 4] = p.hover_yaw_signs


@njit(cache=True)
def surface_coefficients(alpha, c, surface):  # pragma: no cover (compiled)
    """(C_L, C_D, attached weight, sin alpha) of a lifting surface at any alpha in [-pi, pi]; `surface` is where
    its coefficients start in `c` (C_L0, C_La, stall_pos, stall_neg, C_D0, k_induced, C_N90, blend).

    Attached: 001 eq. (21) C_L = C_L0 + C_La alpha (printed C_L0 alpha + C_L0, an erratum: docs/references.md,
    'Known errata', 5) and eq. (23) C_D = C_D0 + C_L^2 / (pi A e).
    Separated: flat plate with normal force C_N90 sin(alpha): C_L = C_N90 sin cos, C_D = C_D0 + C_N90 sin^2.
    The attached weight is 1 between the stall angles and falls smoothly to 0 outside them (two logistic
    sigmoids, expit(x) = (1 + tanh(x / 2)) / 2).
    """
    blend = c[surface + BLEND]
    attached = (0.5 * (1.0 + math.tanh(0.5 * (blend * (c[surface + STALL_POS] - alpha))))
                * (0.5 * (1.0 + math.tanh(0.5 * (blend * (alpha - c[surface + STALL_NEG]))))))
    cl_lin = c[surface + CL0] + c[surface + CL_ALPHA] * alpha
    sa = math.sin(alpha)
    plate = (1.0 - attached) * c[surface + CN90] * sa          # the separated share of the plate's normal force
    cl = attached * cl_lin + plate * math.cos(alpha)
    cd = c[surface + CD0] + attached * c[surface + K_INDUCED] * cl_lin * cl_lin + plate * sa
    return cl, cd, attached, sa


@njit(cache=True)
def _wrap(angle):  # pragma: no cover (compiled)
    return (angle + PI) % TWO_PI - PI


@njit(cache=True)
def _in_plane_force(half_rho_area, v_chord, v_normal, cl, cd):  # pragma: no cover (compiled)
    """Lift (perpendicular to the in-plane velocity) and drag (against it) resolved on the surface's chord
    and normal axes; for v = V (cos a, sin a) this is 001 eq. (18)-(19):
    F_chord = q S (C_L sin a - C_D cos a), F_normal = q S (-C_L cos a - C_D sin a)."""
    k = half_rho_area * py_hypot(v_chord, v_normal)
    return k * (cl * v_normal - cd * v_chord), k * (-cl * v_chord - cd * v_normal)


@njit(cache=True)
def speed_squared(u, v, w):  # pragma: no cover (compiled)
    """|V|^2 as u ** 2 + v ** 2 + w ** 2 (Python's pow, `py_pow`)."""
    return py_pow(u, 2.0) + py_pow(v, 2.0) + py_pow(w, 2.0)


@njit(cache=True)
def fuselage_loads(c, u, v, w, speed_sq):  # pragma: no cover (compiled)
    """001 eq. (8) F_x = K_xf u^2 (drag, against u) and eq. (10) F_y = K_yfb beta V^2 with beta ~ v / V,
    written -1/2 rho |V| CdA_y v so it holds at any sideslip (`speed_sq` = |V|^2). 001 neglects the z force;
    we keep only a cross-flow drag -1/2 rho CdA_z w |w| (quadratic, so negligible at small alpha) for
    vertical flow."""
    return (c[FUSELAGE_X] * u * abs(u), c[NEG_HALF_RHO] * math.sqrt(speed_sq) * c[DRAG_AREA_Y] * v,
            c[FUSELAGE_Z] * w * abs(w))


@njit(cache=True)
def wing_section(c, alpha_section):  # pragma: no cover (compiled)
    """(C_L, C_D, C_m) of the wing at section angle of attack alpha (incidence included), C_m about the AC;
    past the stall the centre of pressure moves to mid-chord (C_m = -0.25 C_N90 sin alpha)."""
    cl, cd, attached, sa = surface_coefficients(_wrap(alpha_section), c, WING_SURFACE)
    return cl, cd, attached * c[WING_CM0] - (1.0 - attached) * 0.25 * c[WING_CN90] * sa


@njit(cache=True)
def wing_flow_loads(c, u, v, w, sin_skew, cos_skew):  # pragma: no cover (compiled)
    """The skewed wing's force, 001 eq. (27)-(30) generalised, and the flow quantities its moments need:
    (force body FRD N, chordwise speed V_c, normal speed w, C_L, C_m).

    The lift comes from the chordwise component V_c = u sin L - v cos L (eq. 27: V_n = V_a sin L), so the
    force scales with sin^2 L as eq. (28)-(29); resolving the section forces on the skewed chord (the
    leading-edge direction (sin L, -cos L, 0)) also gives the side force that eq. (30) fits empirically
    (zero at 0 and 90 deg, largest in between; 001 App. A compares this physical form, eq. 42, with eq. 30).
    Spanwise flow, along (cos L, sin L, 0), only rubs (skin friction).
    """
    v_chord = u * sin_skew - v * cos_skew                  # 001 eq. (27)
    v_span = u * cos_skew + v * sin_skew
    cl, cd, cm = wing_section(c, math.atan2(w, v_chord) + c[WING_INCIDENCE])
    f_chord, f_normal = _in_plane_force(c[HALF_RHO_WING], v_chord, w, cl, cd)
    f_span = c[SPANWISE_DRAG] * abs(v_span) * v_span
    force = (f_chord * sin_skew + f_span * cos_skew, f_chord * -cos_skew + f_span * sin_skew, f_normal)
    return force, v_chord, w, cl, cm


@njit(cache=True)
def wing_loads(c, u, v, w, p, q, sin_skew, cos_skew, aileron):  # pragma: no cover (compiled)
    """The skewed wing's force (`wing_flow_loads`) plus its pitching moment, roll damping and ailerons, and the
    downwash term the tail reads: (force, moment, downwash term)."""
    (fx, fy, fz), v_chord, w, cl, cm = wing_flow_loads(c, u, v, w, sin_skew, cos_skew)
    chord_x, chord_y = sin_skew, -cos_skew                  # leading-edge direction; span (cos L, sin L, 0)
    flow_sq = v_chord * v_chord + w * w
    ac_x, ac_y = c[WING_AC_OFFSET] * chord_x, c[WING_AC_OFFSET] * chord_y   # r_ac x F about the CG
    s, b = c[WING_AREA], c[WING_SPAN]
    pitch = c[HALF_RHO] * flow_sq * s * c[WING_CHORD] * cm          # nose-up about the span axis
    # Roll damping about the chord axis: linear Cl_p term in flow, flat-plate strips when still (hover).
    rate_chord = p * chord_x + q * chord_y
    linear = c[QUARTER_RHO] * math.sqrt(flow_sq) * s * b * b * c[NEG_ROLL_DAMPING]
    damping = -(linear + c[STRIP_DAMPING] * abs(rate_chord)) * rate_chord
    # Ailerons, 001 eq. (8.3): moment q_c S b Cl_da delta_a about the chord axis, i.e. roll ~ sin^3 L and
    # pitch ~ -cos L sin^2 L (q_c = 1/2 rho V_c^2 = q sin^2 L). No effect in reversed chordwise flow.
    roll = c[HALF_RHO] * py_pow(max(v_chord, 0.0), 2.0) * s * b * c[AILERON_COEFFICIENT] * aileron
    moment = (ac_y * fz + pitch * cos_skew + damping * chord_x + roll * chord_x,
              -(ac_x * fz) + pitch * sin_skew + damping * chord_y + roll * chord_y,
              ac_x * fy - ac_y * fx)
    return (fx, fy, fz), moment, 2.0 * cl * flow_sq / c[PI_ASPECT_RATIO]


@njit(cache=True)
def tail_loads(c, u, v, w, p, q, r, elevator, rudder, downwash_term, speed_sq):  # pragma: no cover (compiled)
    """Stabilator and fin at `tail_arm` behind the CG (001 App. B): lifting surfaces with a flat-plate
    post-stall (C_d 1.17), fed by the local velocity v + w x r, so they give the static stability and
    the pitch/yaw damping (App. B's M_z = 1/2 rho r^2 C_d S b_h^3 in a pure spin) without extra terms.

    Surface moments ~ delta q as 001 eq. (8.3): the stabilator angle adds to the tail's angle of attack
    (positive = trailing edge down, nose-down moment); the rudder shifts the fin's angle by -tau delta_r
    (positive rudder, nose left). `downwash_term` comes from `wing_loads`, `speed_sq` is |v|^2.
    Returns (force, moment).
    """
    arm, fin_z = c[TAIL_ARM], c[FIN_Z]
    # Horizontal stabilator at (-arm, 0, 0) in the body x-z plane.
    wh = w + q * arm
    epsilon = min(max(downwash_term / max(speed_sq, 1e-6), -0.35), 0.35)
    cl, cd, _, _ = surface_coefficients(_wrap(math.atan2(wh, u) - epsilon + elevator), c, HTAIL_SURFACE)
    fx_h, fz_h = _in_plane_force(c[HALF_RHO_HTAIL], u, wh, cl, cd) if u * u + wh * wh > 0.0 else (0.0, 0.0)
    # Vertical fin at (-arm, 0, fin_z) in the body x-y plane (its "normal" axis is y).
    uv, vv = u + q * fin_z, v + (r * c[NEG_TAIL_ARM] - p * fin_z)
    beta_v = _wrap(math.atan2(vv, uv) - c[RUDDER_EFFECTIVENESS] * rudder)
    cl, cd, _, _ = surface_coefficients(beta_v, c, VTAIL_SURFACE)
    fx_v, fy_v = _in_plane_force(c[HALF_RHO_VTAIL], uv, vv, cl, cd)
    return (fx_h + fx_v, fy_v, fz_h), (-(fin_z * fy_v), arm * fz_h + fin_z * fx_v, c[NEG_TAIL_ARM] * fy_v)


@njit(cache=True)
def hover_rotor_loads(c, u, v, w_air, p, q, r, sin_skew, cos_skew, omega, effectiveness):  # pragma: no cover
    """Hover rotors: thrust k_f w^2 along each tilted axis (001 eq. 15, per rotor, scaled by the
    effectiveness), drag torque -sign c_Q w^2 about the axis, and rotor drag -k_d w v_inplane at each hub
    (001 eq. 16-17: linear in the cross-flow, slope growing with w; 001 App. A), all with moments about the
    CG from the skew-dependent hub positions (`rotor_geometry`). Summed rotor by rotor in index order.
    Returns (force, moment). (compiled)"""
    signs = c[YAW_SIGNS:YAW_SIGNS + 4]
    positions, axes = rotor_geometry(sin_skew, cos_skew, c[FUSELAGE_ARM], c[WING_ARM], c[ROTOR_HEIGHT],
                                     c[ROTOR_TILT], signs)
    k_f, c_q, neg_k_d = c[K_F], c[C_Q], c[NEG_K_D]
    fx = fy = fz = mx = my = mz = 0.0
    for i in range(4):
        w, eff = omega[i], effectiveness[i]
        if w == 0.0 or eff == 0.0:
            continue
        (px, py, pz), (ax, ay, az) = positions[i], axes[i]
        thrust = eff * k_f * w * w
        hx, hy, hz = u + (q * pz - r * py), v + (r * px - p * pz), w_air + (p * py - q * px)   # v + w x r
        axial = hx * ax + hy * ay + hz * az
        drag = neg_k_d * eff * abs(w)
        f0, f1, f2 = (thrust * ax + drag * (hx - axial * ax), thrust * ay + drag * (hy - axial * ay),
                      thrust * az + drag * (hz - axial * az))
        torque = -signs[i] * eff * c_q * w * w
        fx, fy, fz = fx + f0, fy + f1, fz + f2
        mx = mx + (py * f2 - pz * f1) + torque * ax
        my = my + (pz * f0 - px * f2) + torque * ay
        mz = mz + (px * f1 - py * f0) + torque * az
    return (fx, fy, fz), (mx, my, mz)


@njit(cache=True)
def rotor_inertia_moment(c, omega, omega_dot, spin, sin_skew, cos_skew, p, q, r,
                         pusher_momentum):  # pragma: no cover (compiled)
    """Moment (FRD, N m) of the spinning propellers on the body, which PyBullet integrates without them (Euler's
    equations of a body carrying rotors, as the quadrotor's `rotors.rotor_loads`): the reaction to each hover
    rotor's spin-up, -I_p s_i (d omega_i/dt) a_i, and the gyroscopic moment -Omega x H of the angular momentum
    H = sum I_p s_i omega_i a_i + `pusher_momentum` x_b, a_i the rotor's thrust axis at the skew
    (`rotor_geometry`). `spin`: I_p s_i per rotor, 0 for a lost propeller (`RotorSet`'s SPIN row). The pusher's
    own spin-up reaction is in its torque (`pusher.pusher_step`)."""
    _, axes = rotor_geometry(sin_skew, cos_skew, c[FUSELAGE_ARM], c[WING_ARM], c[ROTOR_HEIGHT], c[ROTOR_TILT],
                             c[YAW_SIGNS:YAW_SIGNS + 4])
    hx, hy, hz = pusher_momentum, 0.0, 0.0
    mx = my = mz = 0.0
    for i in range(4):
        ax, ay, az = axes[i]
        h, reaction = spin[i] * omega[i], -spin[i] * omega_dot[i]
        hx, hy, hz = hx + h * ax, hy + h * ay, hz + h * az
        mx, my, mz = mx + reaction * ax, my + reaction * ay, mz + reaction * az
    return mx - (q * hz - r * hy), my - (r * hx - p * hz), mz - (p * hy - q * hx)


@njit(cache=True)
def aero_loads(c, u, v, w, p, q, r, skew, aileron, elevator, rudder, omega, effectiveness, pusher_thrust,
               pusher_torque):  # pragma: no cover (compiled)
    """`aero_wrench` on floats (omega, effectiveness: arrays of the 4 hover rotors): (fx, fy, fz, l, m, n)."""
    sin_skew, cos_skew = math.sin(skew), math.cos(skew)
    speed_sq = speed_squared(u, v, w)
    fx, fy, fz = fuselage_loads(c, u, v, w, speed_sq)
    (wx, wy, wz), (wl, wm, wn), downwash = wing_loads(c, u, v, w, p, q, sin_skew, cos_skew, aileron)
    (tx, ty, tz), (tl, tm, tn) = tail_loads(c, u, v, w, p, q, r, elevator, rudder, downwash, speed_sq)
    (rx, ry, rz), (rl, rm, rn) = hover_rotor_loads(c, u, v, w, p, q, r, sin_skew, cos_skew, omega, effectiveness)
    # 001 eq. (6); the pusher's thrust line passes through the CG (001 eq. 14)
    return (fx + pusher_thrust + wx + tx + rx, fy + wy + ty + ry, fz + wz + tz + rz,
            pusher_torque + wl + tl + rl, wm + tm + rm, wn + tn + rn)


#: the `QuadPlaneAero` of a parameter set (built on first use, kept for the last few sets)
aero_model = ParamsCache(QuadPlaneAero)


def _constants(params) -> np.ndarray:
    return aero_model(params).constants


def _floats(values) -> tuple:
    return tuple(map(float, values))


def wing_coefficients(params, alpha_section: float):
    """(C_L, C_D, C_m) of the wing (`wing_section`)."""
    return wing_section(_constants(params), float(alpha_section))


def wing_lift_coefficient_max(params) -> float:
    """Largest wing C_L of the model (a fine grid over the attached range and past the stall)."""
    grid = np.radians(np.arange(-5.0, 25.0, 0.01))
    return max(wing_coefficients(params, a)[0] for a in grid)


def stall_speed(params) -> float:
    """1 g stall speed, wing alone at full skew: m g = 1/2 rho V^2 S C_Lmax (m/s)."""
    return math.sqrt(2.0 * params.weight / (params.air_density * params.wing_area
                                           * wing_lift_coefficient_max(params)))


def fuselage_force(params, vel) -> tuple:
    """The fuselage's force (`fuselage_loads`), a 3-tuple."""
    u, v, w = _floats(vel)
    return fuselage_loads(_constants(params), u, v, w, speed_squared(u, v, w))


def wing_flow(params, vel, skew: float):
    """(force, V_c, w, C_L, C_m) of the skewed wing (`wing_flow_loads`)."""
    return wing_flow_loads(_constants(params), *_floats(vel), math.sin(skew), math.cos(skew))


def wing_wrench(params, vel, rates, skew: float, aileron: float):
    """(force, moment, downwash term) of the wing (`wing_loads`)."""
    p, q, _ = _floats(rates)
    return wing_loads(_constants(params), *_floats(vel), p, q, math.sin(skew), math.cos(skew), float(aileron))


def hover_rotor_wrench(params, vel, rates, skew: float, omega, effectiveness):
    """(force, moment) of the hover rotors (`hover_rotor_loads`); omega, effectiveness (4,)."""
    return hover_rotor_loads(_constants(params), *_floats(vel), *_floats(rates), math.sin(skew), math.cos(skew),
                             np.asarray(omega, dtype=float), np.asarray(effectiveness, dtype=float))


def aero_wrench(params, air_velocity_body, body_rates, skew, surfaces, hover_omega, hover_effectiveness,
                pusher_thrust, pusher_torque):
    """Total force and moment (body FRD, about the CG) of everything but gravity, 001 eq. (6) plus moments.

    surfaces = (aileron, elevator, rudder) rad; hover_omega, hover_effectiveness: (4,) in rotor order 0 front,
    1 right, 2 rear, 3 left; pusher_thrust (N, along +x, through the CG) and pusher_torque (N m about +x,
    the reaction on the airframe) come from `PusherMotor`. Returns (force (3,), moment (3,)) arrays.
    """
    loads = aero_loads(_constants(params), *_floats(air_velocity_body), *_floats(body_rates), float(skew),
                       *_floats(surfaces), np.asarray(hover_omega, dtype=float),
                       np.asarray(hover_effectiveness, dtype=float), float(pusher_thrust), float(pusher_torque))
    return np.array(loads[:3]), np.array(loads[3:])
