"""Forces and moments on the VSQP quad-plane, except gravity: 001's component model, made valid everywhere.

001 eq. (6): the total force is the sum of the fuselage, hover rotors, wing and pusher. 001 writes each
part with small angles and airspeed along body x (it was fitted on forward-flight and wind-tunnel data); a
simulator also hovers in wind from any side, so each part here uses the full air-velocity vector and
reduces to 001's form for small angles (stated beside each). Lifting surfaces blend a linear lift curve
into a flat plate past the stall (Beard & McLain's sigmoid blend), so forces stay bounded at any angle.

Inputs: `air_velocity_body` is the velocity of the vehicle relative to the air mass, in body FRD
((u, v, w) = R^T (v_ground - v_wind)); `body_rates` (p, q, r) rad/s. Outputs are in body FRD about the CG.
Pure functions of plain floats and numpy arrays: no simulator import.
"""
from __future__ import annotations

import math

import numpy as np

from .geometry import cross3

HALF_PI = 0.5 * math.pi


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


def _expit(x: float) -> float:
    return 0.5 * (1.0 + math.tanh(0.5 * x))


def surface_coefficients(alpha, cl0, cl_alpha, stall_pos, stall_neg, cd0, k_induced, cn90, blend):
    """(C_L, C_D, attached weight) of a lifting surface at any alpha in [-pi, pi].

    Attached: 001 eq. (21) C_L = C_L0 + C_La alpha and eq. (23) C_D = C_D0 + C_L^2 / (pi A e).
    Separated: flat plate with normal force C_N90 sin(alpha): C_L = C_N90 sin cos, C_D = C_D0 + C_N90 sin^2.
    The attached weight is 1 between the stall angles and falls smoothly to 0 outside them.
    """
    attached = _expit(blend * (stall_pos - alpha)) * _expit(blend * (alpha - stall_neg))
    cl_lin = cl0 + cl_alpha * alpha
    sa, ca = math.sin(alpha), math.cos(alpha)
    cl = attached * cl_lin + (1.0 - attached) * cn90 * sa * ca
    cd = cd0 + attached * k_induced * cl_lin * cl_lin + (1.0 - attached) * cn90 * sa * sa
    return cl, cd, attached


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def wing_coefficients(params, alpha_section: float):
    """(C_L, C_D, C_m) of the wing at section angle of attack alpha (incidence included), C_m about the AC;
    past the stall the centre of pressure moves to mid-chord (C_m = -0.25 C_N90 sin alpha)."""
    alpha = _wrap(alpha_section)
    k_induced = 1.0 / (math.pi * params.aspect_ratio * params.wing_oswald)   # 001 eq. (23)
    stall_pos, stall_neg = params.wing_alpha_stall
    cl, cd, attached = surface_coefficients(alpha, params.wing_cl0, params.wing_cl_alpha, stall_pos, stall_neg,
                                            params.wing_cd0, k_induced, params.wing_cn90, params.stall_blend)
    cm = attached * params.wing_cm0 - (1.0 - attached) * 0.25 * params.wing_cn90 * math.sin(alpha)
    return cl, cd, cm


def wing_lift_coefficient_max(params) -> float:
    """Largest wing C_L of the model (a fine grid over the attached range and past the stall)."""
    grid = np.radians(np.arange(-5.0, 25.0, 0.01))
    return max(wing_coefficients(params, a)[0] for a in grid)


def stall_speed(params) -> float:
    """1 g stall speed, wing alone at full skew: m g = 1/2 rho V^2 S C_Lmax (m/s)."""
    return math.sqrt(2.0 * params.weight / (params.air_density * params.wing_area
                                           * wing_lift_coefficient_max(params)))


def _in_plane_force(half_rho_area, v_chord, v_normal, cl, cd):
    """Lift (perpendicular to the in-plane velocity) and drag (against it) resolved on the surface's chord
    and normal axes; for v = V (cos a, sin a) this is 001 eq. (18)-(19):
    F_chord = q S (C_L sin a - C_D cos a), F_normal = q S (-C_L cos a - C_D sin a)."""
    speed = math.hypot(v_chord, v_normal)
    k = half_rho_area * speed
    return k * (cl * v_normal - cd * v_chord), k * (-cl * v_chord - cd * v_normal)



def _add(acc, vec, scale=1.0):
    acc[0] += scale * vec[0]
    acc[1] += scale * vec[1]
    acc[2] += scale * vec[2]


def fuselage_force(params, vel):
    """001 eq. (8) F_x = K_xf u^2 (drag, against u) and eq. (10) F_y = K_yfb beta V^2 with beta ~ v / V,
    written -1/2 rho |V| CdA_y v so it holds at any sideslip. 001 neglects the z force; we keep only a
    cross-flow drag -1/2 rho CdA_z w |w| (quadratic, so negligible at small alpha) for vertical flow."""
    speed = math.sqrt(vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2)
    half_rho = 0.5 * params.air_density
    ax, ay, az = params.fuselage_drag_area
    return (-half_rho * ax * vel[0] * abs(vel[0]), -half_rho * speed * ay * vel[1],
            -half_rho * az * vel[2] * abs(vel[2]))


def wing_flow(params, vel, skew):
    """The skewed wing's force, 001 eq. (27)-(30) generalised, and the flow quantities its moments need:
    (force [3] body FRD N, chord and span directions, chordwise speed V_c, normal speed w, C_L, C_m).

    The lift comes from the chordwise component V_c = u sin L - v cos L (eq. 27: V_n = V_a sin L), so the
    force scales with sin^2 L as eq. (28)-(29); resolving the section forces on the skewed chord also gives
    the side force that eq. (30) fits empirically (zero at 0 and 90 deg, largest in between; 001 App. A
    compares this physical form, eq. 42, with eq. 30). Spanwise flow only rubs (skin friction).
    """
    sl, cl_ = math.sin(skew), math.cos(skew)
    chord = (sl, -cl_, 0.0)                      # leading-edge direction
    span = (cl_, sl, 0.0)
    u, v, w = vel
    v_chord = u * sl - v * cl_                   # 001 eq. (27)
    v_span = u * cl_ + v * sl
    alpha = math.atan2(w, v_chord) + params.wing_incidence
    cl, cd, cm = wing_coefficients(params, alpha)
    half_rho = 0.5 * params.air_density
    f_chord, f_normal = _in_plane_force(half_rho * params.wing_area, v_chord, w, cl, cd)
    f_span = -half_rho * params.wing_area * params.wing_spanwise_friction * abs(v_span) * v_span
    force = [f_chord * chord[0] + f_span * span[0], f_chord * chord[1] + f_span * span[1], f_normal]
    return force, chord, span, v_chord, w, cl, cm


def wing_wrench(params, vel, rates, skew, aileron):
    """The skewed wing's force (`wing_flow`) plus its pitching moment, roll damping and ailerons."""
    force, chord, span, v_chord, w, cl, cm = wing_flow(params, vel, skew)
    half_rho = 0.5 * params.air_density
    q_in = half_rho * (v_chord * v_chord + w * w)
    ac = tuple(params.wing_ac_offset * c for c in chord)
    moment = list(cross3(ac, force))
    _add(moment, span, q_in * params.wing_area * params.wing_chord * cm)      # nose-up about the span axis
    # Roll damping about the chord axis: linear Cl_p term in flow, flat-plate strips when still (hover).
    rate_chord = rates[0] * chord[0] + rates[1] * chord[1]
    b, s = params.wing_span, params.wing_area
    linear = 0.25 * params.air_density * math.sqrt(v_chord * v_chord + w * w) * s * b * b * (-params.wing_roll_damping)
    quadratic = params.air_density * params.wing_cn90 * params.wing_chord * b ** 4 / 64.0 * abs(rate_chord)
    _add(moment, chord, -(linear + quadratic) * rate_chord)
    # Ailerons, 001 eq. (8.3): moment q_c S b Cl_da delta_a about the chord axis, i.e. roll ~ sin^3 L and
    # pitch ~ -cos L sin^2 L (q_c = 1/2 rho V_c^2 = q sin^2 L). No effect in reversed chordwise flow.
    q_chord = half_rho * max(v_chord, 0.0) ** 2
    _add(moment, chord, q_chord * s * b * params.aileron_roll_coefficient * aileron)
    downwash = 2.0 * cl * (v_chord * v_chord + w * w) / (math.pi * params.aspect_ratio)
    return force, moment, downwash


def _tail_local_velocity(vel, rates, position):
    rot = cross3(rates, position)
    return (vel[0] + rot[0], vel[1] + rot[1], vel[2] + rot[2])


def tail_wrench(params, vel, rates, elevator, rudder, downwash_term):
    """Stabilator and fin at `tail_arm` behind the CG (001 App. B): lifting surfaces with a flat-plate
    post-stall (C_d 1.17), fed by the local velocity v + w x r, so they give the static stability and
    the pitch/yaw damping (App. B's M_z = 1/2 rho r^2 C_d S b_h^3 in a pure spin) without extra terms.

    Surface moments ~ delta q as 001 eq. (8.3): the stabilator angle adds to the tail's angle of attack
    (positive = trailing edge down, nose-down moment); the rudder shifts the fin's angle by -tau delta_r
    (positive rudder, nose left).
    """
    half_rho = 0.5 * params.air_density
    force, moment = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    # Horizontal stabilator in the body x-z plane.
    r_h = (-params.tail_arm, 0.0, 0.0)
    uh, _, wh = _tail_local_velocity(vel, rates, r_h)
    speed_sq = uh * uh + wh * wh
    epsilon = min(max(downwash_term / max(vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2, 1e-6), -0.35), 0.35)
    alpha_h = _wrap(math.atan2(wh, uh) - epsilon + elevator)
    k_h = 1.0 / (math.pi * 0.8 * params.htail_span ** 2 / params.htail_area)
    cl, cd, _ = surface_coefficients(alpha_h, 0.0, params.htail_cl_alpha, params.htail_alpha_stall,
                                     -params.htail_alpha_stall, params.tail_cd0, k_h, params.tail_cn90,
                                     params.stall_blend)
    fx, fz = _in_plane_force(half_rho * params.htail_area, uh, wh, cl, cd) if speed_sq > 0.0 else (0.0, 0.0)
    f_h = (fx, 0.0, fz)
    _add(force, f_h)
    _add(moment, cross3(r_h, f_h))
    # Vertical fin in the body x-y plane (its "normal" axis is y).
    r_v = (-params.tail_arm, 0.0, -0.5 * params.vtail_height)
    uv, vv, _ = _tail_local_velocity(vel, rates, r_v)
    beta_v = _wrap(math.atan2(vv, uv) - params.rudder_effectiveness * rudder)
    k_v = 1.0 / (math.pi * 0.8 * params.vtail_height ** 2 / params.vtail_area)
    cl, cd, _ = surface_coefficients(beta_v, 0.0, params.vtail_cl_alpha, params.htail_alpha_stall,
                                     -params.htail_alpha_stall, params.tail_cd0, k_v, params.tail_cn90,
                                     params.stall_blend)
    fx, fy = _in_plane_force(half_rho * params.vtail_area, uv, vv, cl, cd)
    f_v = (fx, fy, 0.0)
    _add(force, f_v)
    _add(moment, cross3(r_v, f_v))
    return force, moment


_geometry_cache = [None, None, None]   # (params, skew, geometry) of the last call: skew is often constant


def _rotor_geometry(params, skew):
    if _geometry_cache[0] is not params or _geometry_cache[1] != skew:
        _geometry_cache[:] = [params, skew, params.hover_rotor_geometry(skew)]
    return _geometry_cache[2]


def hover_rotor_wrench(params, vel, rates, skew, omega, effectiveness):
    """Hover rotors: thrust k_f w^2 along each tilted axis (001 eq. 15, per rotor, scaled by the
    effectiveness), drag torque -sign c_Q w^2 about the axis, and rotor drag -k_d w v_inplane at each hub
    (001 eq. 16-17: linear in the cross-flow, slope growing with w; 001 App. A), all with moments about the
    CG from the skew-dependent hub positions. Plain floats: four rotors are faster without numpy."""
    positions, axes = _rotor_geometry(params, skew)
    k_f, c_q, k_d = params.hover_thrust_coefficient, params.hover_torque_coefficient, params.hover_drag_coefficient
    force, moment = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for i in range(4):
        w, eff = float(omega[i]), float(effectiveness[i])
        if w == 0.0 or eff == 0.0:
            continue
        pos, axis = positions[i], axes[i]
        thrust = eff * k_f * w * w
        rot = cross3(rates, pos)
        hub = (vel[0] + rot[0], vel[1] + rot[1], vel[2] + rot[2])
        axial = hub[0] * axis[0] + hub[1] * axis[1] + hub[2] * axis[2]
        drag = -k_d * eff * abs(w)
        f = tuple(thrust * axis[j] + drag * (hub[j] - axial * axis[j]) for j in range(3))
        _add(force, f)
        _add(moment, cross3(pos, f))
        _add(moment, axis, -params.hover_yaw_signs[i] * eff * c_q * w * w)
    return force, moment


def aero_wrench(params, air_velocity_body, body_rates, skew, surfaces, hover_omega, hover_effectiveness,
                pusher_thrust, pusher_torque):
    """Total force and moment (body FRD, about the CG) of everything but gravity, 001 eq. (6) plus moments.

    surfaces = (aileron, elevator, rudder) rad; hover_omega, hover_effectiveness: (4,) in rotor order 0 front,
    1 right, 2 rear, 3 left; pusher_thrust (N, along +x, through the CG) and pusher_torque (N m about +x,
    the reaction on the airframe) come from `PusherMotor`. Returns (force (3,), moment (3,)) arrays.
    """
    force, moment = aero_wrench_floats(params, air_velocity_body, body_rates, skew, surfaces, hover_omega,
                                       hover_effectiveness, pusher_thrust, pusher_torque)
    return np.array(force), np.array(moment)


def aero_wrench_floats(params, air_velocity_body, body_rates, skew, surfaces, hover_omega, hover_effectiveness,
                       pusher_thrust, pusher_torque):
    """`aero_wrench` returning (force, moment) as lists of 3 floats (the physics loop's form)."""
    vel = (float(air_velocity_body[0]), float(air_velocity_body[1]), float(air_velocity_body[2]))
    rates = (float(body_rates[0]), float(body_rates[1]), float(body_rates[2]))
    aileron, elevator, rudder = (float(s) for s in surfaces)
    force = list(fuselage_force(params, vel))
    moment = [pusher_torque, 0.0, 0.0]
    force[0] += pusher_thrust                                           # 001 eq. (14), thrust line through the CG
    f_w, m_w, downwash_term = wing_wrench(params, vel, rates, skew, aileron)
    _add(force, f_w)
    _add(moment, m_w)
    f_t, m_t = tail_wrench(params, vel, rates, elevator, rudder, downwash_term)
    _add(force, f_t)
    _add(moment, m_t)
    f_r, m_r = hover_rotor_wrench(params, vel, rates, skew, hover_omega, hover_effectiveness)
    _add(force, f_r)
    _add(moment, m_r)
    return force, moment
