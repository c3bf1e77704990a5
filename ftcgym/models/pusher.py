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

The formulas are compiled (numba: `thrust`, `aero_torque`, `pusher_step`) on the constants of one parameter set
(`pusher_constants`), so the physics step runs them without the interpreter; the module functions and
`PusherMotor` call them. They keep the operations and their order of the plain-Python model they replaced, so
the results keep their bits.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .vsqp import ParamsCache

TWO_PI = 2.0 * math.pi
#: indices into the array of `pusher_constants`
(RHO, D, D2, D5, RHO_D4, THRUST_B, THRUST_A, THRUST_K3, CQ0, CQ1, CQ2, INERTIA, K_E, RESISTANCE, BATTERY_VOLTAGE,
 MAX_CURRENT, OMEGA_MAX, SPIN_DIRECTION) = range(18)
#: indices into `PusherMotor.state`: speed (rad/s), current (A), thrust (N), torque (N m), fault handles
OMEGA, CURRENT, THRUST, TORQUE, ICING, VISCOUS_FRICTION, ZERO_LOAD_CURRENT = range(7)


def _pusher_constants(params) -> np.ndarray:
    d = params.pusher_diameter
    # the formulas' constant factors, each equal to the product it stands for in the formula, bit for bit
    return np.array([params.air_density, d, d * d, d ** 5, params.air_density * d ** 4,
                     *params.pusher_thrust_coefficients, params.pusher_thrust_k3, *params.pusher_torque_coefficients,
                     params.pusher_inertia, params.pusher_motor_constant, params.pusher_resistance,
                     params.battery_voltage, params.pusher_max_current, params.pusher_omega_max,
                     params.pusher_spin_direction], dtype=float)


#: the constants of the compiled formulas for a parameter set, indexed by RHO ... SPIN_DIRECTION (kept per set)
pusher_constants = ParamsCache(_pusher_constants)


def _revs(omega):
    return omega / TWO_PI


def _forward(speed):
    """Axial airspeed with flow from behind taken as 0 (floats or numpy arrays)."""
    return max(speed, 0.0) if isinstance(speed, float) else np.maximum(speed, 0.0)


@njit(cache=True)
def thrust(c, n, v):  # pragma: no cover (compiled)
    """Thrust along body +x, N, at n rev/s and forward airspeed v >= 0: 001 eq. (13)-(14),
    T = rho D^4 (b n^2 + a n V / D) + K_xp3 V."""
    return c[RHO_D4] * (c[THRUST_B] * n * n + c[THRUST_A] * n * v / c[D]) + c[THRUST_K3] * v


@njit(cache=True)
def aero_torque(c, theta_1, n, v):  # pragma: no cover (compiled)
    """Q_a, N m, at n rev/s and forward airspeed v >= 0 (floats or arrays), 003 eq. (2)-(5):
    theta_1 rho n^2 D^5 C_Q(J), expanded in n and V."""
    return theta_1 * c[RHO] * c[D5] * (c[CQ0] * n * n + c[CQ1] * n * v / c[D] + c[CQ2] * v * v / c[D2])


@njit(cache=True)
def _aero_torque_slope(c, theta_1, n, v):  # pragma: no cover (compiled)
    """dQ_a/dw (d/dw of `aero_torque`, n = w / 2 pi), for the linearly implicit integration step."""
    return theta_1 * c[RHO] * c[D5] * (2.0 * c[CQ0] * n + c[CQ1] * v / c[D]) / TWO_PI


@njit(cache=True)
def _electric_current(c, throttle, omega):  # pragma: no cover (compiled)
    """I_e = (u V_bat - k_e w) / R, at least 0 (no regeneration), at most the ESC's current limit."""
    current = (throttle * c[BATTERY_VOLTAGE] - c[K_E] * omega) / c[RESISTANCE]
    return min(max(current, 0.0), c[MAX_CURRENT])


@njit(cache=True)
def pusher_step(state, c, throttle, axial_airspeed, dt):  # pragma: no cover (compiled)
    """Advance the motor of `state` (in place: speed, current, thrust, torque; with its fault handles) by dt with
    003 eq. (1), linearly implicit in w so any dt is stable (`PusherMotor.step`)."""
    k_e, inertia = c[K_E], c[INERTIA]
    theta_1, c_v, i_0 = state[ICING], state[VISCOUS_FRICTION], state[ZERO_LOAD_CURRENT]      # the fault handles
    u, v = min(max(throttle, 0.0), 1.0), max(axial_airspeed, 0.0)
    w = state[OMEGA]
    n = w / TWO_PI
    current = _electric_current(c, u, w)
    net = k_e * (current - i_0) - c_v * w - aero_torque(c, theta_1, n, v)   # 003 eq. (1) right side
    back_emf_slope = k_e * k_e / c[RESISTANCE] if 0.0 < current < c[MAX_CURRENT] else 0.0
    damping = back_emf_slope + c_v + _aero_torque_slope(c, theta_1, n, v)
    w_new = w + dt * net / (inertia + dt * max(damping, 0.0))
    w_new = min(max(w_new, 0.0), c[OMEGA_MAX])   # static friction holds it at 0; ESC speed limit
    omega_dot = (w_new - w) / dt
    n = w_new / TWO_PI
    q_new = aero_torque(c, theta_1, n, v) if w_new > 0.0 else 0.0
    current = _electric_current(c, u, w_new)
    if w_new == c[OMEGA_MAX]:
        # The ESC's governor lowers the drive to hold its speed limit: the current 003 eq. (1) asks for there
        # (at most the drive's own), not the one full throttle would push, whose torque would have nowhere to go.
        current = min(current, i_0 + (c_v * w_new + q_new) / k_e)
    state[OMEGA] = w_new
    state[CURRENT] = current
    state[THRUST] = thrust(c, n, v)
    state[TORQUE] = -c[SPIN_DIRECTION] * (q_new + inertia * omega_dot)


def pusher_thrust(params, omega: float, axial_speed: float) -> float:
    """Thrust along body +x, N (`thrust`), at speed omega rad/s and axial airspeed (m/s)."""
    return thrust(pusher_constants(params), _revs(float(omega)), max(float(axial_speed), 0.0))


def pusher_aero_torque(params, omega, axial_speed, theta_1: float = 1.0):
    """Q_a, N m (`aero_torque`); floats, or numpy arrays of speeds."""
    return aero_torque(pusher_constants(params), float(theta_1), _revs(omega), _forward(axial_speed))


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


def _state_field(index: int, doc: str) -> property:
    """A float of `PusherMotor.state`, read and written by name."""
    def set_value(self, value) -> None:
        self.state[index] = value
    return property(lambda self: self.state.item(index), set_value, doc=doc)


class PusherMotor:
    """Pusher motor + propeller state. Fault handles `theta_1`, `c_v`, `I_0` (003 Sec. II-B) may be set at
    any time; they start at the nominal values of the parameter set.

    Attributes after `step`: `omega` (rad/s), `current` (A, I_e), `thrust` (N, along body +x) and `torque`
    (N m about body +x: the reaction on the airframe, -spin (Q_a + Theta dw/dt)). They and the fault handles
    are the floats of `state` (indexed by OMEGA ... ZERO_LOAD_CURRENT), which the compiled step updates in place.
    """

    omega = _state_field(OMEGA, "speed (rad/s)")
    current = _state_field(CURRENT, "motor current I_e (A)")
    thrust = _state_field(THRUST, "thrust along body +x (N)")
    torque = _state_field(TORQUE, "reaction torque on the airframe about body +x (N m)")
    theta_1 = _state_field(ICING, "icing factor on the aerodynamic torque (003 eq. 5)")
    c_v = _state_field(VISCOUS_FRICTION, "viscous friction (N m s, 003 eq. 1)")
    I_0 = _state_field(ZERO_LOAD_CURRENT, "zero-load current (A, 003 eq. 1)")

    def __init__(self, params):
        self.params = params
        self.constants = pusher_constants(params)
        self.state = np.zeros(7)
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

    def step(self, throttle: float, axial_airspeed: float, dt: float) -> None:
        """Advance w by dt with 003 eq. (1) (`pusher_step`)."""
        if not (math.isfinite(throttle) and math.isfinite(axial_airspeed) and dt > 0.0):
            raise ValueError(f"PusherMotor.step: throttle {throttle!r} and airspeed {axial_airspeed!r} must be "
                             f"finite and dt {dt!r} positive")
        pusher_step(self.state, self.constants, float(throttle), float(axial_airspeed), float(dt))
