"""Trim of the VSQP quad-plane: steady, wings-level, straight flight at an airspeed and flight-path angle.

Longitudinal balance only (body x and z forces, pitch moment; no wind, zero sideslip and rates), solved
with scipy.optimize.least_squares on `quadplane_aero.aero_wrench` and the pusher model, so the trims are
those of the simulated vehicle. The lateral residue of the skewed wing in transition (side force, roll)
is left to the autopilot.

Which unknowns are free depends on the flight regime (4 actuators for 3 equations in transition):
- wing-borne: angle of attack, pusher speed and stabilator; hover rotors stopped. Accepted when the
  angle of attack stays at or below `alpha_cap(skew)`.
- rotor-assisted (hover, transition, below the stall speed): the angle of attack is fixed at
  `alpha_cap(skew)`, which grows from 0 in hover to 10 deg at full skew (MAX_TRIM_ALPHA, the largest alpha a
  trim may use), so the wing takes as much of the weight as it can at that attitude; pusher speed and
  collective hover-rotor speed are free, and the pitch moment is taken by the stabilator or, where it
  lacks authority (low airspeed), by a front/rear rotor thrust difference.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from ftcgym.models.constants import GRAVITY
from ftcgym.models.pusher import pusher_thrust, steady_state_current, throttle_for_speed
from ftcgym.models.quadplane_aero import aero_wrench, skew_schedule, stall_speed, wing_wrench
from ftcgym.models.vsqp import RPM

MAX_TRIM_ALPHA = math.radians(10.0)   # largest trim alpha, below the wing's C_Lmax at 10.7 deg
MIN_TRIM_ALPHA = math.radians(-10.0)  # above ~22 m/s the wing-borne alpha may go below 0
HOVER_SPEED = 0.5                     # m/s: below it the trim is the hover one (pitch level)
PUSHER_OFF = 2.0                      # rad/s: a pusher trim below this is reported as stopped
RESIDUAL_TOLERANCE = 1e-6             # of the weight (forces) and of weight x 1 m (moment)


def alpha_cap(skew: float) -> float:
    """Largest trim angle of attack at a skew: 10 deg sin^2(skew), i.e. level in hover and the full wing
    range once the wing is spanwise (its lift grows as sin^2, 001 eq. 27-29)."""
    return MAX_TRIM_ALPHA * math.sin(skew) ** 2


def _hover_speeds(collective: float, pitch_split: float) -> np.ndarray:
    """Rotor speeds 0 front, 1 right, 2 rear, 3 left: front/rear thrust = k w_c^2 (1 +- split)."""
    front = collective * math.sqrt(max(1.0 + pitch_split, 0.0))
    rear = collective * math.sqrt(max(1.0 - pitch_split, 0.0))
    return np.array([front, collective, rear, collective])


def _residual(params, airspeed, gamma, skew, alpha, pusher_omega, hover_omega, elevator):
    """(F_x, F_z, M_y) with gravity, scaled by the weight (and 1 m for the moment)."""
    pitch = alpha + gamma
    velocity = airspeed * np.array([math.cos(alpha), 0.0, math.sin(alpha)])
    thrust = pusher_thrust(params, pusher_omega, velocity[0])
    force, moment = aero_wrench(params, velocity, np.zeros(3), skew, (0.0, elevator, 0.0), hover_omega,
                                np.ones(4), thrust, 0.0)
    weight = params.weight
    return np.array([(force[0] - weight * math.sin(pitch)) / weight,
                     (force[2] + weight * math.cos(pitch)) / weight,
                     moment[1] / weight])


def _solve(fun, x0, lower, upper):
    result = least_squares(fun, x0, bounds=(lower, upper), xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return result.x, float(np.max(np.abs(result.fun)))


def _wing_borne(params, airspeed, gamma, skew):
    """Unknowns alpha, pusher speed, elevator; hover rotors stopped. None if it needs alpha > the cap."""
    cap = alpha_cap(skew)
    limit = params.surface_limit[1]
    stopped = np.zeros(4)

    def fun(x):
        return _residual(params, airspeed, gamma, skew, x[0], x[1] * params.pusher_omega_max, stopped, x[2])

    start = [min(max(0.5 * cap, MIN_TRIM_ALPHA), cap), 0.8, 0.0]
    if cap <= MIN_TRIM_ALPHA:
        return None
    x, worst = _solve(fun, start, [MIN_TRIM_ALPHA, 0.0, -limit], [cap, 1.0, limit])
    if worst > RESIDUAL_TOLERANCE:
        return None
    return {"alpha": x[0], "pusher_omega": x[1] * params.pusher_omega_max, "hover_omega": stopped,
            "elevator": x[2], "mode": "wing-borne"}


def _rotor_assisted(params, airspeed, gamma, skew):
    """Alpha at the cap (level in hover); pusher, collective and either elevator or a pitch split free."""
    alpha = alpha_cap(skew) if airspeed > HOVER_SPEED else 0.0
    limit = params.surface_limit[1]
    omega_max = params.hover_omega_max
    p_max = params.pusher_omega_max
    start = [0.5, params.hover_omega / omega_max, 0.0]

    def with_elevator(x):
        return _residual(params, airspeed, gamma, skew, alpha, x[0] * p_max, _hover_speeds(x[1] * omega_max, 0.0),
                         x[2])

    def with_split(x):
        return _residual(params, airspeed, gamma, skew, alpha, x[0] * p_max,
                         _hover_speeds(x[1] * omega_max, x[2]), 0.0)

    x, worst = _solve(with_elevator, start, [0.0, 0.0, -limit], [1.0, 1.0, limit])
    if worst <= RESIDUAL_TOLERANCE:
        return {"alpha": alpha, "pusher_omega": x[0] * p_max, "hover_omega": _hover_speeds(x[1] * omega_max, 0.0),
                "elevator": x[2], "mode": "rotor-assisted" if airspeed > HOVER_SPEED else "hover"}
    x, worst = _solve(with_split, start, [0.0, 0.0, -0.9], [1.0, 1.0, 0.9])
    speeds = _hover_speeds(x[1] * omega_max, x[2])
    if worst > RESIDUAL_TOLERANCE or speeds.max() > omega_max * (1.0 + 1e-9):
        return None
    return {"alpha": alpha, "pusher_omega": x[0] * p_max, "hover_omega": speeds, "elevator": 0.0,
            "mode": "rotor-assisted"}


def _describe(params, airspeed, gamma, skew, solution):
    """The trim dict: attitude, actuators (rad/s and RPM), pusher electrics, wing lift."""
    alpha, w_p, hover = solution["alpha"], solution["pusher_omega"], solution["hover_omega"]
    w_p = w_p if w_p > PUSHER_OFF else 0.0
    u = airspeed * math.cos(alpha)
    velocity = (u, 0.0, airspeed * math.sin(alpha))
    wing_force, _, _ = wing_wrench(params, velocity, (0.0, 0.0, 0.0), skew, 0.0)
    wing_lift = wing_force[0] * math.sin(alpha) - wing_force[2] * math.cos(alpha)   # perpendicular to V
    return {
        "airspeed": airspeed, "flight_path_angle": gamma, "skew": skew, "mode": solution["mode"],
        "alpha": alpha, "pitch": alpha + gamma, "elevator": solution["elevator"],
        "pusher_omega": w_p, "pusher_rpm": w_p / RPM, "pusher_thrust": pusher_thrust(params, w_p, u),
        "pusher_current": steady_state_current(params, w_p, u) if w_p > 0.0 else 0.0,
        "pusher_throttle": throttle_for_speed(params, w_p, u) if w_p > 0.0 else 0.0,
        "hover_omega": [float(w) for w in hover], "hover_rpm": [float(w / RPM) for w in hover],
        "hover_max_fraction": float(np.max(hover) / params.hover_omega_max),
        "wing_lift": wing_lift,
    }


def trim(params, airspeed: float, flight_path_angle: float = 0.0, skew: float | None = None) -> dict:
    """Steady longitudinal trim at `airspeed` (m/s) and `flight_path_angle` (rad, climb positive).

    `skew` defaults to `skew_schedule(params, airspeed)`. Returns a dict (angles in rad; speeds in rad/s
    and RPM; `hover_omega` in rotor order 0 front, 1 right, 2 rear, 3 left). Raises ValueError when no
    trim exists within the actuator limits. Below `HOVER_SPEED` the trim is the level hover one.
    """
    if not (math.isfinite(airspeed) and airspeed >= 0.0 and math.isfinite(flight_path_angle)):
        raise ValueError(f"trim: airspeed must be finite and >= 0 and the flight-path angle finite, got "
                         f"{airspeed!r}, {flight_path_angle!r}")
    skew = skew_schedule(params, airspeed) if skew is None else float(skew)
    if airspeed <= HOVER_SPEED:
        flight_path_angle = 0.0   # a flight path has no meaning in hover: the trim is level
    solution = _wing_borne(params, airspeed, flight_path_angle, skew) if airspeed > HOVER_SPEED else None
    if solution is None:
        solution = _rotor_assisted(params, airspeed, flight_path_angle, skew)
    if solution is None:
        raise ValueError(f"trim: no trim at {airspeed:.2f} m/s, flight path {math.degrees(flight_path_angle):.1f}"
                         f" deg, skew {math.degrees(skew):.1f} deg within the limits (alpha <= "
                         f"{math.degrees(alpha_cap(skew)):.1f} deg, pusher <= {params.pusher_omega_max / RPM:.0f}"
                         f" RPM, hover rotors <= {params.hover_omega_max / RPM:.0f} RPM, elevator <= "
                         f"{math.degrees(params.surface_limit[1]):.0f} deg)")
    return _describe(params, airspeed, flight_path_angle, skew, solution)


def trim_table(params, airspeeds) -> list[dict]:
    """`trim` at each airspeed (level flight, scheduled skew)."""
    return [trim(params, float(v)) for v in airspeeds]


def format_trim_table(rows) -> str:
    """Markdown table of trim rows (degrees and RPM for reading)."""
    header = ("| airspeed m/s | mode | skew deg | alpha deg | elevator deg | pusher RPM | pusher N | pusher A "
              "| hover RPM (front, right, rear, left) | hover max % | wing lift N |")
    lines = [header, "|" + "---|" * 11]
    for r in rows:
        hover = ", ".join(f"{w:.0f}" for w in r["hover_rpm"])
        lines.append(f"| {r['airspeed']:.1f} | {r['mode']} | {math.degrees(r['skew']):.1f} | "
                     f"{math.degrees(r['alpha']):.2f} | {math.degrees(r['elevator']):.2f} | {r['pusher_rpm']:.0f} | "
                     f"{r['pusher_thrust']:.1f} | {r['pusher_current']:.1f} | {hover} | "
                     f"{100 * r['hover_max_fraction']:.0f} | {r['wing_lift']:.1f} |")
    return "\n".join(lines)


def default_airspeeds(params) -> list[float]:
    """Hover, the transition, the stall speed and forward flight to 24 m/s."""
    speeds = [0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, round(stall_speed(params), 2), 14.5, 16.0, 18.0, 20.0, 22.0, 24.0]
    return sorted(set(speeds))


__all__ = ["GRAVITY", "MAX_TRIM_ALPHA", "alpha_cap", "default_airspeeds", "format_trim_table", "trim", "trim_table"]
