"""VSQP quad-plane model: parameters, aerodynamics, pusher propulsion and trims, against numbers."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcgym.agents.quadplane_trim import trim
from ftcgym.models.pusher import (
    PusherMotor,
    pusher_aero_torque,
    pusher_thrust,
    steady_state_current,
    throttle_for_speed,
)
from ftcgym.models.quadplane_aero import aero_wrench, hover_rotor_wrench, skew_schedule, stall_speed
from ftcgym.models.vsqp import RPM, VSQP, make_vsqp_params

P = VSQP
HALF_PI = 0.5 * math.pi


def forward_speeds():
    return [stall_speed(P)] + [14.0, 16.0, 18.0, 20.0, 22.0]


# --- trims ---------------------------------------------------------------------------

def test_hover_trim_rotor_speeds_in_001_range_and_below_85_percent():
    row = trim(P, 0.0)
    rpm = np.array(row["hover_rpm"])
    assert np.all((rpm > 3800.0) & (rpm < 4100.0))              # 001 App. A: hover at 3,800-4,100 RPM
    assert row["hover_max_fraction"] < 0.85
    assert row["pusher_rpm"] == 0.0 and row["skew"] == 0.0


@pytest.mark.parametrize("scheduled", [False, True])
def test_forward_trims_from_stall_to_22_have_alpha_between_0_and_10_deg(scheduled):
    assert 12.0 <= stall_speed(P) <= 14.0
    for v in forward_speeds():
        row = trim(P, v) if scheduled else trim(P, v, skew=HALF_PI)
        assert row["mode"] == "wing-borne", v
        assert 0.0 <= math.degrees(row["alpha"]) <= 10.0, (v, math.degrees(row["alpha"]))
        assert max(row["hover_rpm"]) == 0.0
        assert abs(row["elevator"]) < P.surface_limit[1]


def test_cruise_pusher_near_8000_rpm_and_wing_lift_60_to_70_n():
    row = trim(P, 22.0)
    assert 7500.0 < row["pusher_rpm"] < 8500.0                  # 001: pusher ~8,000 RPM in forward flight
    assert 0.0 < row["pusher_thrust"] <= 30.0
    for v in (18.0, 20.0, 22.0):
        assert 60.0 <= trim(P, v)["wing_lift"] <= 70.0          # 001 App. A: wing ~60-70 N


def test_transition_trims_stay_inside_the_limits():
    for v in (2.0, 6.0, 10.0, 12.0):
        row = trim(P, v)
        assert row["hover_max_fraction"] < 0.85
        assert row["pusher_rpm"] * RPM <= P.pusher_omega_max
        assert 0.0 <= row["alpha"] <= math.radians(10.0)


def test_trim_without_solution_raises_a_clear_error():
    with pytest.raises(ValueError, match="no trim at 40.00 m/s"):
        trim(P, 40.0)
    with pytest.raises(ValueError, match="airspeed"):
        trim(P, float("nan"))


# --- pusher: 003 eq. (1)-(5) -------------------------------------------------------------------------------

def hand_current(omega, v, theta_1=1.0, c_v=P.pusher_viscous_friction, i_0=P.pusher_zero_load_current):
    """003 eq. (1)-(5) as printed, solved for I_e with d omega/dt = 0."""
    d = P.pusher_diameter
    j = 2.0 * math.pi * v / (d * omega)                                          # eq. (4)
    c_q0, c_q1, c_q2 = P.pusher_torque_coefficients
    c_q = c_q0 + c_q1 * j + c_q2 * j * j                                          # eq. (3)
    q_a = theta_1 * P.air_density * omega ** 2 / (4.0 * math.pi ** 2) * d ** 5 * c_q   # eq. (2), (3), (5)
    return i_0 + (c_v * omega + q_a) / P.pusher_motor_constant                   # eq. (1)


def settle(motor, throttle, v, seconds=2.0, dt=0.002):
    for _ in range(int(seconds / dt)):
        motor.step(throttle, v, dt)


def test_pusher_steady_state_matches_hand_computation():
    omega, v = 800.0, 15.0
    assert steady_state_current(P, omega, v) == pytest.approx(hand_current(omega, v), rel=1e-12)
    motor = PusherMotor(P)
    settle(motor, throttle_for_speed(P, omega, v), v)
    assert motor.omega == pytest.approx(omega, rel=1e-6)
    assert motor.current == pytest.approx(hand_current(omega, v), rel=1e-6)
    n = omega / (2.0 * math.pi)
    b, a = P.pusher_thrust_coefficients                                            # 001 eq. (11)-(12)
    assert motor.thrust == pytest.approx(P.air_density * n ** 2 * P.pusher_diameter ** 4
                                         * (b + a * v / (n * P.pusher_diameter)), rel=1e-9)
    # Reaction torque on the airframe equals the aerodynamic torque in steady state, opposite to the spin.
    assert motor.torque == pytest.approx(-(hand_current(omega, v) - P.pusher_zero_load_current
                                           - P.pusher_viscous_friction * omega / P.pusher_motor_constant)
                                         * P.pusher_motor_constant, rel=1e-6)


def test_pusher_static_thrust_about_30_n_at_full_throttle():
    motor = PusherMotor(P)
    settle(motor, 1.0, 0.0)
    assert 27.0 < motor.thrust < 33.0                           # 001 App. A: pusher up to ~30 N
    assert motor.omega <= P.pusher_omega_max
    assert pusher_thrust(P, 0.0, 20.0) == 0.0


def test_at_its_speed_limit_the_pusher_draws_the_current_that_holds_it():
    motor = PusherMotor(P)
    settle(motor, 1.0, 18.0)                 # full throttle at cruise speed: the propeller unloads to the limit
    assert motor.omega == P.pusher_omega_max
    # 003 eq. (1) at d omega/dt = 0, not (V_bat - k_e omega) / R: about 38 A, where the clamp alone read 44 A
    assert motor.current == pytest.approx(steady_state_current(P, P.pusher_omega_max, 18.0), rel=1e-9)
    assert motor.current < (P.battery_voltage - P.pusher_motor_constant * P.pusher_omega_max) / P.pusher_resistance


@pytest.mark.parametrize("handle, value", [("theta_1", 1.1), ("c_v", 1.1 * P.pusher_viscous_friction),
                                           ("I_0", 1.1 * P.pusher_zero_load_current)])
def test_faults_raise_current_at_the_same_speed(handle, value):
    """003's signature: icing, viscous and static friction (x1.1, 003 Sec. IV-A) need more current to hold
    the same propeller speed; at the same throttle the speed drops."""
    omega, v = 8000.0 * RPM, 20.0
    nominal = PusherMotor(P)
    settle(nominal, throttle_for_speed(P, omega, v), v)
    faulty = PusherMotor(P)
    setattr(faulty, handle, value)
    settle(faulty, throttle_for_speed(P, omega, v, **{handle: value}), v)
    assert faulty.omega == pytest.approx(omega, rel=1e-6)
    assert faulty.current > nominal.current + 1e-3
    same_throttle = PusherMotor(P)
    setattr(same_throttle, handle, value)
    settle(same_throttle, throttle_for_speed(P, omega, v), v)
    assert same_throttle.omega < nominal.omega


def test_pusher_motor_evaluates_the_module_formulas_bit_for_bit():
    """`PusherMotor.step` takes the formulas' constant factors once; its thrust and torque stay those of
    `pusher_thrust` and `pusher_aero_torque` (001 eq. 13-14, 003 eq. 2-5) exactly."""
    motor, dt = PusherMotor(P), 0.002
    motor.theta_1 = 1.3
    for throttle, v in [(1.0, 0.0)] * 50 + [(0.7, 12.0), (0.3, -2.0), (0.0, 20.0), (0.5, 25.0)]:
        before = motor.omega
        motor.step(throttle, v, dt)
        assert motor.thrust == pusher_thrust(P, motor.omega, v)
        q_a = pusher_aero_torque(P, motor.omega, v, 1.3) if motor.omega > 0.0 else 0.0
        omega_dot = (motor.omega - before) / dt
        assert motor.torque == -P.pusher_spin_direction * (q_a + P.pusher_inertia * omega_dot)
    assert motor.omega > 0.0


def test_pusher_rejects_non_finite_input():
    with pytest.raises(ValueError):
        PusherMotor(P).step(float("nan"), 10.0, 0.002)


# --- aerodynamics ------------------------------------------------------------------------------------------

def test_hover_rotor_drag_is_075_n_s_per_m_at_4000_rpm():
    u = 5.0
    force, _ = hover_rotor_wrench(P, (u, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, [4000.0 * RPM] * 4, [1.0] * 4)
    assert force[0] / u == pytest.approx(-0.75, rel=0.01)       # 001 App. A, Fig. 17a


def test_hover_at_hover_speed_is_balanced():
    force, moment = aero_wrench(P, np.zeros(3), np.zeros(3), 0.0, (0.0, 0.0, 0.0), np.full(4, P.hover_omega),
                                np.ones(4), 0.0, 0.0)
    assert force == pytest.approx([0.0, 0.0, -P.weight], abs=1e-9)
    assert moment == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)


def test_rotor_geometry_follows_the_skew():
    at_hover, at_cruise = P.hover_rotor_positions(0.0), P.hover_rotor_positions(HALF_PI)
    arm = 0.435                                                 # 001 App. B: (470 + 400) / 2 mm
    assert at_hover[:, :2] == pytest.approx(np.array([[arm, 0], [0, arm], [-arm, 0], [0, -arm]]), abs=1e-12)
    assert at_cruise[:, :2] == pytest.approx(np.array([[arm, 0], [-arm, 0], [-arm, 0], [arm, 0]]), abs=1e-12)
    axes = P.hover_thrust_axes(0.6)
    assert np.linalg.norm(axes, axis=1) == pytest.approx(np.ones(4))
    assert -axes[:, 2] == pytest.approx(np.full(4, math.cos(math.radians(3.0))))


def test_spinning_tail_damps_yaw_as_001_app_b():
    r = 2.0
    _, moment = aero_wrench(P, np.zeros(3), np.array([0.0, 0.0, r]), 0.0, (0.0, 0.0, 0.0), np.zeros(4),
                            np.ones(4), 0.0, 0.0)
    gamma_2_z = 0.5 * P.air_density * P.vtail_area * 1.17 * P.tail_arm ** 3     # 001 App. B
    assert moment[2] == pytest.approx(-gamma_2_z * r * r, rel=0.03)


def test_aileron_roll_scales_with_sin_cubed_skew():
    def roll_from_aileron(skew):
        args = (np.array([18.0, 0.0, 0.0]), np.zeros(3), skew)
        rest = (np.zeros(4), np.ones(4), 0.0, 0.0)
        with_aileron = aero_wrench(P, *args, (0.1, 0.0, 0.0), *rest)[1]
        without = aero_wrench(P, *args, (0.0, 0.0, 0.0), *rest)[1]
        return with_aileron - without
    full, half = roll_from_aileron(HALF_PI), roll_from_aileron(math.radians(45.0))
    assert full[0] > 0.0                                         # positive aileron rolls right
    assert half[0] / full[0] == pytest.approx(math.sin(math.radians(45.0)) ** 3, rel=1e-9)   # 001 eq. (8.3)
    assert half[1] < 0.0 and full[1] == pytest.approx(0.0, abs=1e-9)


def test_elevator_and_rudder_signs():
    args = (P, np.array([18.0, 0.0, 0.0]), np.zeros(3), HALF_PI)
    rest = (np.zeros(4), np.ones(4), 0.0, 0.0)
    base = aero_wrench(*args, (0.0, 0.0, 0.0), *rest)[1]
    assert aero_wrench(*args, (0.0, 0.1, 0.0), *rest)[1][1] < base[1]   # trailing edge down: nose down
    assert aero_wrench(*args, (0.0, 0.0, 0.1), *rest)[1][2] < base[2]   # positive rudder: nose left


def test_skew_schedule():
    assert skew_schedule(P, 0.0) == 0.0
    assert skew_schedule(P, P.transition_start_speed) == 0.0
    assert skew_schedule(P, P.transition_end_speed) == pytest.approx(HALF_PI)
    speeds = np.linspace(0.0, 30.0, 121)
    assert np.all(np.diff([skew_schedule(P, v) for v in speeds]) >= 0.0)
    assert P.transition_end_speed > stall_speed(P)


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=300, deadline=None)
@given(vel=st.lists(finite.filter(lambda x: abs(x) <= 80.0), min_size=3, max_size=3),
       rates=st.lists(finite.filter(lambda x: abs(x) <= 30.0), min_size=3, max_size=3),
       skew=st.floats(0.0, HALF_PI), surfaces=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
       omega=st.lists(st.floats(0.0, 600.0), min_size=4, max_size=4),
       eff=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
       thrust=st.floats(-10.0, 40.0), torque=st.floats(-2.0, 2.0))
def test_aero_wrench_is_finite_for_any_finite_input(vel, rates, skew, surfaces, omega, eff, thrust, torque):
    force, moment = aero_wrench(P, np.array(vel), np.array(rates), skew, surfaces, np.array(omega), np.array(eff),
                                thrust, torque)
    assert force.shape == (3,) and moment.shape == (3,)
    assert np.all(np.isfinite(force)) and np.all(np.isfinite(moment))


def test_aero_wrench_at_zero_airspeed_is_finite_and_only_gravity_free_thrust():
    force, moment = aero_wrench(P, np.zeros(3), np.zeros(3), 0.3, (0.2, -0.2, 0.1), np.zeros(4), np.ones(4), 0.0, 0.0)
    assert force == pytest.approx(np.zeros(3)) and moment == pytest.approx(np.zeros(3))


# --- parameters --------------------------------------------------------------------------------------------

def test_make_vsqp_params_overrides_and_rejections():
    heavier = make_vsqp_params("vsqp", {"mass": 7.0, "inertia": [0.03, 0.2, 0.22]})
    assert heavier.mass == 7.0 and heavier.inertia == (0.03, 0.2, 0.22)
    with pytest.raises(ValueError, match=r"vehicle_overrides field: unknown \['wingspan'\] \(did you mean 'wing_span'"):
        make_vsqp_params("vsqp", {"wingspan": 2.0})
    with pytest.raises(ValueError, match="'mass'.*finite"):
        make_vsqp_params("vsqp", {"mass": float("nan")})
    with pytest.raises(ValueError, match="'surface_limit'.*finite"):
        make_vsqp_params("vsqp", {"surface_limit": [0.3, float("inf"), 0.3]})
    with pytest.raises(ValueError, match="vehicle.*accepted"):
        make_vsqp_params("vsqp2")


def test_parameters_match_001_app_b():
    assert P.mass == 6.5
    assert P.hover_thrust_coefficient * RPM ** 2 == pytest.approx(1.0725e-6)    # N/RPM^2
    assert P.hover_torque_coefficient / P.hover_thrust_coefficient == pytest.approx(2.85e-2)
    thrust_to_weight = 4 * P.hover_thrust_coefficient * P.hover_omega_max ** 2 / P.weight
    assert 1.9 < thrust_to_weight < 2.1                         # 001 Table 5.1: thrust-to-weight 2


# --- the spinning propellers ----------------------------------------------------------

def test_spinning_propellers_give_their_spin_up_reaction_and_gyroscopic_moment():
    from ftcgym.models.quadplane_aero import FUSELAGE_ARM, ROTOR_TILT, QuadPlaneAero, rotor_inertia_moment
    from ftcgym.models.vsqp import rotor_geometry
    c = QuadPlaneAero(P).constants
    spin = P.propeller_inertia * np.asarray(P.hover_yaw_signs, dtype=float)
    _, axes = rotor_geometry(0.0, 1.0, *c[FUSELAGE_ARM:ROTOR_TILT + 1], np.asarray(P.hover_yaw_signs, dtype=float))
    # rotor 0 alone spinning up at 100 rad/s^2, the body still: -I_p s_0 (d omega/dt) a_0
    moment = rotor_inertia_moment(c, np.zeros(4), np.array([100.0, 0, 0, 0]), spin, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(moment, -spin[0] * 100.0 * np.array(axes[0]), rtol=1e-12)
    # the pusher's angular momentum H x_b under a pitch rate q: -Omega x H = (0, -r H, q H)
    moment = rotor_inertia_moment(c, np.zeros(4), np.zeros(4), spin, 1.0, 0.0, 0.0, 0.5, 0.0, 0.2)
    np.testing.assert_allclose(moment, (0.0, 0.0, 0.1), atol=1e-15)


def test_a_yaw_differential_step_yaws_the_quad_plane_by_the_spin_up_reaction():
    """+-20 rad/s on the two rotor pairs: the spin-up reaction, I_p sum s_i d omega_i/dt about 0.39 N m at once,
    is ten times the drag-torque change, and sets the yaw rate after 20 ms (about 0.046 rad/s; 0.004 without)."""
    import gymnasium as gym

    import ftcgym  # noqa: F401
    from ftcgym.models.geometry import quat_from_euler
    env = gym.make("ftcgym/QuadPlane-v0", task={"name": "hover", "altitude": 5.0}).unwrapped
    env.reset(seed=0)
    env.world.reset(np.array([0.0, 0.0, -50.0]), quat_from_euler(0.0, 0.0, 0.0), np.zeros(3), np.zeros(3))
    env._read_state()
    env.hover_rotors.reset(P.hover_omega)
    signs = np.asarray(P.hover_yaw_signs, dtype=float)
    action = np.zeros(9, dtype=np.float32)
    span = P.hover_omega_max - P.hover_omega_min
    action[:4] = (P.hover_omega + 20.0 * signs - P.hover_omega_min) / span
    for _ in range(2):
        obs, reward, terminated, truncated, info = env.step(action)
    expected = 0.02 * P.propeller_inertia * 4 * 20.0 / P.hover_time_constant / P.inertia[2]
    assert info["truth"]["body_rates"][2] == pytest.approx(expected, rel=0.1)
    env.close()
