"""Electric pusher propulsion of the quad-plane: 003 eq. (1)-(5) with 001 eq. (11)-(14) for the thrust.

003 eq. (1)  Theta dw/dt = k_e (I_e - I_0) - c_v w - Q_a          torque balance of motor + propeller
003 eq. (2)  Q_a = rho w^2 / (4 pi^2) D^5 C_Q(J)                   aerodynamic (drag) torque
003 eq. (3)  C_Q(J) = C_Q0 + C_Q1 J + C_Q2 J^2
003 eq. (4)  J = 2 pi V_a / (D w)                                  advance ratio (= V / (n D), n in rev/s)
003 eq. (5)  Q_a = theta_1 Q_a*                                    icing scales the torque (theta_1* = 1)
001 eq. (11)-(14)  T = rho n^2 D^4 C_T(J), C_T = b + a J (+ K_xp3 V)

003 takes the current I_e as measured; a simulator must produce it. We add the usual DC-motor electrical
equation (our assumption, not in 003): the ESC applies u V_bat, so I_e = (u V_bat - k_e w) / R, clipped
at 0 (no regeneration) and at the ESC's current limit (without it a throttle step from rest would draw
V_bat / R = 444 A and kick the airframe with 8 N m). Erratum (docs/references.md, 'Known errata'): 003 eq. (9)
prints y = -k_e I_e; eq. (1) gives y = k_e I_e - Theta dw/dt, which is what `steady_state_current` inverts.

Terms are written expanded in n and V (C_Q0 n^2 + C_Q1 n V / D + C_Q2 V^2 / D^2), which equals eq. (2)-(4)
for w > 0 and stays finite at w = 0. Axial airspeed below 0 (flow from behind) is treated as 0.
"""
from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def _revs(omega):
    return omega / TWO_PI


def _forward(speed):
    """Axial airspeed with flow from behind taken as 0 (floats or numpy arrays)."""
    return max(speed, 0.0) if isinstance(speed, float) else np.maximum(speed, 0.0)


def pusher_thrust(params, omega: float, axial_speed: float) -> float:
    """Thrust along body +x, N: 001 eq. (13)-(14), T = rho D^4 (b n^2 + a n V / D) + K_xp3 V."""
    n, v, d = _revs(omega), max(axial_speed, 0.0), params.pusher_diameter
    b, a = params.pusher_thrust_coefficients
    return params.air_density * d ** 4 * (b * n * n + a * n * v / d) + params.pusher_thrust_k3 * v


def pusher_aero_torque(params, omega, axial_speed, theta_1: float = 1.0):
    """Q_a, N m, 003 eq. (2)-(5): theta_1 rho n^2 D^5 C_Q(J); floats, or numpy arrays of speeds."""
    n, v, d = _revs(omega), _forward(axial_speed), params.pusher_diameter
    cq0, cq1, cq2 = params.pusher_torque_coefficients
    return theta_1 * params.air_density * d ** 5 * (cq0 * n * n + cq1 * n * v / d + cq2 * v * v / (d * d))


def steady_state_current(params, omega: float, axial_speed: float, theta_1: float | None = None,
                         c_v: float | None = None, I_0: float | None = None) -> float:
    """I_e holding w constant: 003 eq. (1) with dw/dt = 0, I_e = I_0 + (c_v w + Q_a) / k_e."""
    theta_1 = params.pusher_icing if theta_1 is None else theta_1
    c_v = params.pusher_viscous_friction if c_v is None else c_v
    I_0 = params.pusher_zero_load_current if I_0 is None else I_0
    load = c_v * omega + pusher_aero_torque(params, omega, axial_speed, theta_1)
    return I_0 + load / params.pusher_motor_constant


def throttle_for_speed(params, omega: float, axial_speed: float, **faults) -> float:
    """Throttle (fraction of battery voltage) that holds w: u V_bat = k_e w + R I_e (may exceed 1)."""
    current = steady_state_current(params, omega, axial_speed, **faults)
    voltage = params.pusher_motor_constant * omega + params.pusher_resistance * current
    return voltage / params.battery_voltage


class PusherMotor:
    """Pusher motor + propeller state. Fault handles `theta_1`, `c_v`, `I_0` (003 Sec. II-B) may be set at
    any time; they start at the nominal values of the parameter set.

    Attributes after `step`: `omega` (rad/s), `current` (A, I_e), `thrust` (N, along body +x) and `torque`
    (N m about body +x: the reaction on the airframe, -spin (Q_a + Theta dw/dt)).
    """

    def __init__(self, params):
        self.params = params
        d = params.pusher_diameter
        # the formulas' constant factors, for `step` (equal to the module functions' own, bit for bit)
        self._d, self._d2, self._d5, self._rho_d4 = d, d * d, d ** 5, params.air_density * d ** 4
        self.theta_1 = params.pusher_icing
        self.c_v = params.pusher_viscous_friction
        self.I_0 = params.pusher_zero_load_current
        self.reset()

    def reset(self, omega: float = 0.0, axial_airspeed: float = 0.0) -> None:
        """Nominal faults; rotor at `omega` in equilibrium with `axial_airspeed` (current that holds it)."""
        p = self.params
        self.theta_1, self.c_v, self.I_0 = p.pusher_icing, p.pusher_viscous_friction, p.pusher_zero_load_current
        self.omega = float(min(max(omega, 0.0), p.pusher_omega_max))
        self.current = steady_state_current(p, self.omega, axial_airspeed) if self.omega > 0.0 else 0.0
        self.thrust = pusher_thrust(p, self.omega, axial_airspeed)
        spin_torque = pusher_aero_torque(p, self.omega, axial_airspeed) if self.omega > 0.0 else 0.0
        self.torque = -p.pusher_spin_direction * spin_torque

    def _electric_current(self, throttle: float, omega: float) -> float:
        p = self.params
        current = (throttle * p.battery_voltage - p.pusher_motor_constant * omega) / p.pusher_resistance
        return min(max(current, 0.0), p.pusher_max_current)   # no regeneration; the ESC's current limit

    def _aero_torque(self, n: float, v: float) -> float:
        """`pusher_aero_torque` at n rev/s and forward airspeed v >= 0 (003 eq. 2-5), with this motor's theta_1."""
        cq0, cq1, cq2 = self.params.pusher_torque_coefficients
        return self.theta_1 * self.params.air_density * self._d5 * (cq0 * n * n + cq1 * n * v / self._d
                                                                    + cq2 * v * v / self._d2)

    def _aero_torque_slope(self, n: float, v: float) -> float:
        """dQ_a/dw (d/dw of `_aero_torque`, n = w / 2 pi), for the linearly implicit integration step."""
        cq0, cq1, _ = self.params.pusher_torque_coefficients
        return self.theta_1 * self.params.air_density * self._d5 * (2.0 * cq0 * n + cq1 * v / self._d) / TWO_PI

    def _thrust(self, n: float, v: float) -> float:
        """`pusher_thrust` at n rev/s and forward airspeed v >= 0 (001 eq. 13-14)."""
        b, a = self.params.pusher_thrust_coefficients
        return self._rho_d4 * (b * n * n + a * n * v / self._d) + self.params.pusher_thrust_k3 * v

    def step(self, throttle: float, axial_airspeed: float, dt: float) -> None:
        """Advance w by dt with 003 eq. (1), linearly implicit in w so any dt is stable."""
        if not (math.isfinite(throttle) and math.isfinite(axial_airspeed) and dt > 0.0):
            raise ValueError(f"PusherMotor.step: throttle {throttle!r} and airspeed {axial_airspeed!r} must be "
                             f"finite and dt {dt!r} positive")
        p, k_e = self.params, self.params.pusher_motor_constant
        u, v = min(max(throttle, 0.0), 1.0), max(axial_airspeed, 0.0)
        w = self.omega
        n = w / TWO_PI
        current = self._electric_current(u, w)
        net = k_e * (current - self.I_0) - self.c_v * w - self._aero_torque(n, v)   # 003 eq. (1) right side
        back_emf_slope = k_e * k_e / p.pusher_resistance if 0.0 < current < p.pusher_max_current else 0.0
        damping = back_emf_slope + self.c_v + self._aero_torque_slope(n, v)
        w_new = w + dt * net / (p.pusher_inertia + dt * max(damping, 0.0))
        w_new = min(max(w_new, 0.0), p.pusher_omega_max)   # static friction holds it at 0; ESC speed limit
        omega_dot = (w_new - w) / dt
        n = w_new / TWO_PI
        self.omega = w_new
        self.current = self._electric_current(u, w_new)
        self.thrust = self._thrust(n, v)
        q_new = self._aero_torque(n, v) if w_new > 0.0 else 0.0
        self.torque = -p.pusher_spin_direction * (q_new + p.pusher_inertia * omega_dot)
