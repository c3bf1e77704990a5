"""Forces and moments on the VSQP quad-plane, except gravity: 001's component model, made valid everywhere.

001 eq. (6): the total force is the sum of the fuselage, hover rotors, wing and pusher. 001 writes each
part with small angles and airspeed along body x (it was fitted on forward-flight and wind-tunnel data); a
simulator also hovers in wind from any side, so each part here uses the full air-velocity vector and
reduces to 001's form for small angles (stated beside each). Lifting surfaces blend a linear lift curve
into a flat plate past the stall (Beard & McLain's sigmoid blend), so forces stay bounded at any angle.

Inputs: `air_velocity_body` is the velocity of the vehicle relative to the air mass, in body FRD
((u, v, w) = R^T (v_ground - v_wind)); `body_rates` (p, q, r) rad/s. Outputs are in body FRD about the CG.
Plain floats and numpy arrays, no simulator import. `QuadPlaneAero` holds the model of one parameter set
(the physics loop keeps one); the module functions take the parameter set and use a cached `QuadPlaneAero`.
"""
from __future__ import annotations

import math

import numpy as np

PI = math.pi
HALF_PI = 0.5 * PI
TWO_PI = 2.0 * PI


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


def surface_coefficients(alpha: float, surface: tuple):
    """(C_L, C_D, attached weight, sin alpha) of a lifting surface at any alpha in [-pi, pi]; `surface` is
    (C_L0, C_La, stall_pos, stall_neg, C_D0, k_induced, C_N90, blend) (`QuadPlaneAero` builds them).

    Attached: 001 eq. (21) C_L = C_L0 + C_La alpha and eq. (23) C_D = C_D0 + C_L^2 / (pi A e).
    Separated: flat plate with normal force C_N90 sin(alpha): C_L = C_N90 sin cos, C_D = C_D0 + C_N90 sin^2.
    The attached weight is 1 between the stall angles and falls smoothly to 0 outside them (two logistic
    sigmoids, expit(x) = (1 + tanh(x / 2)) / 2).
    """
    cl0, cl_alpha, stall_pos, stall_neg, cd0, k_induced, cn90, blend = surface
    attached = (0.5 * (1.0 + math.tanh(0.5 * (blend * (stall_pos - alpha))))
                * (0.5 * (1.0 + math.tanh(0.5 * (blend * (alpha - stall_neg))))))
    cl_lin = cl0 + cl_alpha * alpha
    sa = math.sin(alpha)
    plate = (1.0 - attached) * cn90 * sa                  # the separated share of the plate's normal force
    cl = attached * cl_lin + plate * math.cos(alpha)
    cd = cd0 + attached * k_induced * cl_lin * cl_lin + plate * sa
    return cl, cd, attached, sa


def _wrap(angle: float) -> float:
    return (angle + PI) % TWO_PI - PI


def _in_plane_force(half_rho_area, v_chord, v_normal, cl, cd):
    """Lift (perpendicular to the in-plane velocity) and drag (against it) resolved on the surface's chord
    and normal axes; for v = V (cos a, sin a) this is 001 eq. (18)-(19):
    F_chord = q S (C_L sin a - C_D cos a), F_normal = q S (-C_L cos a - C_D sin a)."""
    k = half_rho_area * math.hypot(v_chord, v_normal)
    return k * (cl * v_normal - cd * v_chord), k * (-cl * v_chord - cd * v_normal)


class QuadPlaneAero:
    """The component model of one parameter set (`VsqpParams`), on plain floats.

    The products of parameters that lead a formula are computed here once, in the formula's own order, so
    every force has the bits of the formula evaluated term by term. The hover-rotor geometry and the skew's
    sine and cosine are kept for the last skew (it changes only while the wing moves).
    """

    def __init__(self, params):
        p = self.params = params
        half_rho = self.half_rho = 0.5 * p.air_density
        # Fuselage: -1/2 rho CdA_x, -1/2 rho (times |V|, then CdA_y), -1/2 rho CdA_z.
        ax, ay, az = p.fuselage_drag_area
        self.fuselage_x, self.fuselage_z = -half_rho * ax, -half_rho * az
        self.neg_half_rho, self.drag_area_y = -half_rho, ay
        # Wing: its lifting surface, 1/2 rho S, -1/2 rho S C_f, the moments' factors, pi A for the downwash.
        k_induced = 1.0 / (math.pi * p.aspect_ratio * p.wing_oswald)           # 001 eq. (23)
        self.wing_surface = (p.wing_cl0, p.wing_cl_alpha, *p.wing_alpha_stall, p.wing_cd0, k_induced, p.wing_cn90,
                             p.stall_blend)
        self.wing_incidence, self.wing_cm0, self.wing_cn90 = p.wing_incidence, p.wing_cm0, p.wing_cn90
        self.half_rho_wing = half_rho * p.wing_area
        self.spanwise_drag = -half_rho * p.wing_area * p.wing_spanwise_friction
        self.wing_area, self.wing_span, self.wing_chord = p.wing_area, p.wing_span, p.wing_chord
        self.wing_ac_offset, self.aileron_coefficient = p.wing_ac_offset, p.aileron_roll_coefficient
        self.quarter_rho, self.neg_roll_damping = 0.25 * p.air_density, -p.wing_roll_damping
        self.strip_damping = p.air_density * p.wing_cn90 * p.wing_chord * p.wing_span ** 4 / 64.0
        self.pi_aspect_ratio = math.pi * p.aspect_ratio
        # Tail: stabilator and fin surfaces (induced drag with e = 0.8), 1/2 rho S of each, arms.
        stall_and_cd0 = (p.htail_alpha_stall, -p.htail_alpha_stall, p.tail_cd0)
        k_h = 1.0 / (math.pi * 0.8 * p.htail_span ** 2 / p.htail_area)
        k_v = 1.0 / (math.pi * 0.8 * p.vtail_height ** 2 / p.vtail_area)
        self.htail_surface = (0.0, p.htail_cl_alpha, *stall_and_cd0, k_h, p.tail_cn90, p.stall_blend)
        self.vtail_surface = (0.0, p.vtail_cl_alpha, *stall_and_cd0, k_v, p.tail_cn90, p.stall_blend)
        self.half_rho_htail, self.half_rho_vtail = half_rho * p.htail_area, half_rho * p.vtail_area
        self.tail_arm, self.neg_tail_arm, self.fin_z = p.tail_arm, -p.tail_arm, -0.5 * p.vtail_height
        self.rudder_effectiveness = p.rudder_effectiveness
        # Hover rotors: k_f, c_Q, -k_d, -yaw sign of each.
        self.k_f, self.c_q = p.hover_thrust_coefficient, p.hover_torque_coefficient
        self.neg_k_d, self.neg_yaw_signs = -p.hover_drag_coefficient, tuple(-s for s in p.hover_yaw_signs)
        self._skew, self._at_skew = None, None

    def at_skew(self, skew: float) -> tuple:
        """(sin L, cos L, hover-rotor positions, axes) at skew L (`VsqpParams.hover_rotor_geometry`)."""
        if skew != self._skew:
            self._skew = skew
            self._at_skew = (math.sin(skew), math.cos(skew), *self.params.hover_rotor_geometry(skew))
        return self._at_skew

    def wrench(self, vel, rates, skew, surfaces, omega, effectiveness, pusher_thrust, pusher_torque):
        """`aero_wrench` on plain floats (the physics loop's form): (force, moment) as 3-tuples."""
        aileron, elevator, rudder = surfaces
        sin_skew, cos_skew, positions, axes = self.at_skew(skew)
        speed_sq = vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2
        fx, fy, fz = self.fuselage_force(vel, speed_sq)
        (wx, wy, wz), (wl, wm, wn), downwash = self.wing_wrench(vel, rates, sin_skew, cos_skew, aileron)
        (tx, ty, tz), (tl, tm, tn) = self.tail_wrench(vel, rates, elevator, rudder, downwash, speed_sq)
        (rx, ry, rz), (rl, rm, rn) = self.hover_rotor_wrench(vel, rates, positions, axes, omega, effectiveness)
        # 001 eq. (6); the pusher's thrust line passes through the CG (001 eq. 14)
        return ((fx + pusher_thrust + wx + tx + rx, fy + wy + ty + ry, fz + wz + tz + rz),
                (pusher_torque + wl + tl + rl, wm + tm + rm, wn + tn + rn))

    def fuselage_force(self, vel, speed_sq):
        """001 eq. (8) F_x = K_xf u^2 (drag, against u) and eq. (10) F_y = K_yfb beta V^2 with beta ~ v / V,
        written -1/2 rho |V| CdA_y v so it holds at any sideslip. 001 neglects the z force; we keep only a
        cross-flow drag -1/2 rho CdA_z w |w| (quadratic, so negligible at small alpha) for vertical flow."""
        u, v, w = vel
        return (self.fuselage_x * u * abs(u), self.neg_half_rho * math.sqrt(speed_sq) * self.drag_area_y * v,
                self.fuselage_z * w * abs(w))

    def wing_coefficients(self, alpha_section: float):
        """(C_L, C_D, C_m) of the wing at section angle of attack alpha (incidence included), C_m about the AC;
        past the stall the centre of pressure moves to mid-chord (C_m = -0.25 C_N90 sin alpha)."""
        cl, cd, attached, sa = surface_coefficients(_wrap(alpha_section), self.wing_surface)
        return cl, cd, attached * self.wing_cm0 - (1.0 - attached) * 0.25 * self.wing_cn90 * sa

    def wing_flow(self, vel, sin_skew, cos_skew):
        """The skewed wing's force, 001 eq. (27)-(30) generalised, and the flow quantities its moments need:
        (force body FRD N, chordwise speed V_c, normal speed w, C_L, C_m).

        The lift comes from the chordwise component V_c = u sin L - v cos L (eq. 27: V_n = V_a sin L), so the
        force scales with sin^2 L as eq. (28)-(29); resolving the section forces on the skewed chord (the
        leading-edge direction (sin L, -cos L, 0)) also gives the side force that eq. (30) fits empirically
        (zero at 0 and 90 deg, largest in between; 001 App. A compares this physical form, eq. 42, with eq. 30).
        Spanwise flow, along (cos L, sin L, 0), only rubs (skin friction).
        """
        u, v, w = vel
        v_chord = u * sin_skew - v * cos_skew                  # 001 eq. (27)
        v_span = u * cos_skew + v * sin_skew
        cl, cd, cm = self.wing_coefficients(math.atan2(w, v_chord) + self.wing_incidence)
        f_chord, f_normal = _in_plane_force(self.half_rho_wing, v_chord, w, cl, cd)
        f_span = self.spanwise_drag * abs(v_span) * v_span
        force = (f_chord * sin_skew + f_span * cos_skew, f_chord * -cos_skew + f_span * sin_skew, f_normal)
        return force, v_chord, w, cl, cm

    def wing_wrench(self, vel, rates, sin_skew, cos_skew, aileron):
        """The skewed wing's force (`wing_flow`) plus its pitching moment, roll damping and ailerons, and the
        downwash term the tail reads."""
        (fx, fy, fz), v_chord, w, cl, cm = self.wing_flow(vel, sin_skew, cos_skew)
        chord_x, chord_y = sin_skew, -cos_skew                  # leading-edge direction; span (cos L, sin L, 0)
        flow_sq = v_chord * v_chord + w * w
        ac_x, ac_y = self.wing_ac_offset * chord_x, self.wing_ac_offset * chord_y   # r_ac x F about the CG
        s, b = self.wing_area, self.wing_span
        pitch = self.half_rho * flow_sq * s * self.wing_chord * cm          # nose-up about the span axis
        # Roll damping about the chord axis: linear Cl_p term in flow, flat-plate strips when still (hover).
        rate_chord = rates[0] * chord_x + rates[1] * chord_y
        linear = self.quarter_rho * math.sqrt(flow_sq) * s * b * b * self.neg_roll_damping
        damping = -(linear + self.strip_damping * abs(rate_chord)) * rate_chord
        # Ailerons, 001 eq. (8.3): moment q_c S b Cl_da delta_a about the chord axis, i.e. roll ~ sin^3 L and
        # pitch ~ -cos L sin^2 L (q_c = 1/2 rho V_c^2 = q sin^2 L). No effect in reversed chordwise flow.
        roll = self.half_rho * max(v_chord, 0.0) ** 2 * s * b * self.aileron_coefficient * aileron
        moment = (ac_y * fz + pitch * cos_skew + damping * chord_x + roll * chord_x,
                  -(ac_x * fz) + pitch * sin_skew + damping * chord_y + roll * chord_y,
                  ac_x * fy - ac_y * fx)
        return (fx, fy, fz), moment, 2.0 * cl * flow_sq / self.pi_aspect_ratio

    def tail_wrench(self, vel, rates, elevator, rudder, downwash_term, speed_sq):
        """Stabilator and fin at `tail_arm` behind the CG (001 App. B): lifting surfaces with a flat-plate
        post-stall (C_d 1.17), fed by the local velocity v + w x r, so they give the static stability and
        the pitch/yaw damping (App. B's M_z = 1/2 rho r^2 C_d S b_h^3 in a pure spin) without extra terms.

        Surface moments ~ delta q as 001 eq. (8.3): the stabilator angle adds to the tail's angle of attack
        (positive = trailing edge down, nose-down moment); the rudder shifts the fin's angle by -tau delta_r
        (positive rudder, nose left). `downwash_term` comes from `wing_wrench`, `speed_sq` is |v|^2.
        """
        u, v, w = vel
        p, q, r = rates
        arm, fin_z = self.tail_arm, self.fin_z
        # Horizontal stabilator at (-arm, 0, 0) in the body x-z plane.
        wh = w + q * arm
        epsilon = min(max(downwash_term / max(speed_sq, 1e-6), -0.35), 0.35)
        cl, cd, _, _ = surface_coefficients(_wrap(math.atan2(wh, u) - epsilon + elevator), self.htail_surface)
        fx_h, fz_h = _in_plane_force(self.half_rho_htail, u, wh, cl, cd) if u * u + wh * wh > 0.0 else (0.0, 0.0)
        # Vertical fin at (-arm, 0, fin_z) in the body x-y plane (its "normal" axis is y).
        uv, vv = u + q * fin_z, v + (r * self.neg_tail_arm - p * fin_z)
        beta_v = _wrap(math.atan2(vv, uv) - self.rudder_effectiveness * rudder)
        cl, cd, _, _ = surface_coefficients(beta_v, self.vtail_surface)
        fx_v, fy_v = _in_plane_force(self.half_rho_vtail, uv, vv, cl, cd)
        return (fx_h + fx_v, fy_v, fz_h), (-(fin_z * fy_v), arm * fz_h + fin_z * fx_v, self.neg_tail_arm * fy_v)

    def hover_rotor_wrench(self, vel, rates, positions, axes, omega, effectiveness):
        """Hover rotors: thrust k_f w^2 along each tilted axis (001 eq. 15, per rotor, scaled by the
        effectiveness), drag torque -sign c_Q w^2 about the axis, and rotor drag -k_d w v_inplane at each hub
        (001 eq. 16-17: linear in the cross-flow, slope growing with w; 001 App. A), all with moments about the
        CG from the skew-dependent hub positions (`at_skew`). Summed rotor by rotor in index order."""
        u, v, w_air = vel
        p, q, r = rates
        k_f, c_q, neg_k_d = self.k_f, self.c_q, self.neg_k_d
        fx = fy = fz = mx = my = mz = 0.0
        for (px, py, pz), (ax, ay, az), neg_sign, w, eff in zip(positions, axes, self.neg_yaw_signs, omega,
                                                                  effectiveness):
            if w == 0.0 or eff == 0.0:
                continue
            thrust = eff * k_f * w * w
            hx, hy, hz = u + (q * pz - r * py), v + (r * px - p * pz), w_air + (p * py - q * px)   # v + w x r
            axial = hx * ax + hy * ay + hz * az
            drag = neg_k_d * eff * abs(w)
            f0, f1, f2 = (thrust * ax + drag * (hx - axial * ax), thrust * ay + drag * (hy - axial * ay),
                          thrust * az + drag * (hz - axial * az))
            torque = neg_sign * eff * c_q * w * w
            fx, fy, fz = fx + f0, fy + f1, fz + f2
            mx = mx + (py * f2 - pz * f1) + torque * ax
            my = my + (pz * f0 - px * f2) + torque * ay
            mz = mz + (px * f1 - py * f0) + torque * az
        return (fx, fy, fz), (mx, my, mz)


_MODELS: dict = {}      # id(params) -> (params, QuadPlaneAero): the few parameter sets in use at once
_MAX_MODELS = 8


def aero_model(params) -> QuadPlaneAero:
    """The `QuadPlaneAero` of a parameter set, built on first use and kept (the last few sets)."""
    entry = _MODELS.get(id(params))
    if entry is None or entry[0] is not params:
        if len(_MODELS) >= _MAX_MODELS:
            del _MODELS[next(iter(_MODELS))]
        entry = _MODELS[id(params)] = (params, QuadPlaneAero(params))
    return entry[1]


def _floats(values) -> tuple:
    return tuple(map(float, values))


def wing_coefficients(params, alpha_section: float):
    """(C_L, C_D, C_m) of the wing (`QuadPlaneAero.wing_coefficients`)."""
    return aero_model(params).wing_coefficients(alpha_section)


def wing_lift_coefficient_max(params) -> float:
    """Largest wing C_L of the model (a fine grid over the attached range and past the stall)."""
    grid = np.radians(np.arange(-5.0, 25.0, 0.01))
    return max(wing_coefficients(params, a)[0] for a in grid)


def stall_speed(params) -> float:
    """1 g stall speed, wing alone at full skew: m g = 1/2 rho V^2 S C_Lmax (m/s)."""
    return math.sqrt(2.0 * params.weight / (params.air_density * params.wing_area
                                           * wing_lift_coefficient_max(params)))


def fuselage_force(params, vel) -> tuple:
    """The fuselage's force (`QuadPlaneAero.fuselage_force`), a 3-tuple."""
    return aero_model(params).fuselage_force(vel, vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2)


def wing_flow(params, vel, skew: float):
    """(force, V_c, w, C_L, C_m) of the skewed wing (`QuadPlaneAero.wing_flow`)."""
    aero = aero_model(params)
    sin_skew, cos_skew, _, _ = aero.at_skew(skew)
    return aero.wing_flow(vel, sin_skew, cos_skew)


def wing_wrench(params, vel, rates, skew: float, aileron: float):
    """(force, moment, downwash term) of the wing (`QuadPlaneAero.wing_wrench`)."""
    aero = aero_model(params)
    sin_skew, cos_skew, _, _ = aero.at_skew(skew)
    return aero.wing_wrench(vel, rates, sin_skew, cos_skew, aileron)


def hover_rotor_wrench(params, vel, rates, skew: float, omega, effectiveness):
    """(force, moment) of the hover rotors (`QuadPlaneAero.hover_rotor_wrench`); omega, effectiveness (4,)."""
    aero = aero_model(params)
    _, _, positions, axes = aero.at_skew(skew)
    return aero.hover_rotor_wrench(vel, rates, positions, axes, _floats(omega), _floats(effectiveness))


def aero_wrench(params, air_velocity_body, body_rates, skew, surfaces, hover_omega, hover_effectiveness,
                pusher_thrust, pusher_torque):
    """Total force and moment (body FRD, about the CG) of everything but gravity, 001 eq. (6) plus moments.

    surfaces = (aileron, elevator, rudder) rad; hover_omega, hover_effectiveness: (4,) in rotor order 0 front,
    1 right, 2 rear, 3 left; pusher_thrust (N, along +x, through the CG) and pusher_torque (N m about +x,
    the reaction on the airframe) come from `PusherMotor`. Returns (force (3,), moment (3,)) arrays.
    """
    force, moment = aero_model(params).wrench(_floats(air_velocity_body), _floats(body_rates), float(skew),
                                         _floats(surfaces), _floats(hover_omega), _floats(hover_effectiveness),
                                         float(pusher_thrust), float(pusher_torque))
    return np.array(force), np.array(moment)
