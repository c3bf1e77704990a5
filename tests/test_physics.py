"""Physics of Quadrotor-v0 against closed-form values (000 eq. 8-9, 004 eq. 7, free fall, saturation)."""
import numpy as np
import pytest
from conftest import hover_command, make_env

from ftcgym.models.quadrotor import BEBOP2, GRAVITY, MUELLER2014, make_params
from ftcgym.models.sensors import GYRO_LIMIT


@pytest.mark.parametrize("vehicle", ["bebop2", "mueller2014"])
def test_hover_rotor_speed_matches_weight_balance(vehicle):
    """Hovering under the controller, the mean rotor speed is sqrt(m g / (4 c_T)) within 1%."""
    env = make_env(vehicle=vehicle, max_episode_seconds=6.0)
    obs, info = env.reset(seed=3)
    from ftcgym.agents import make_policy
    policy = make_policy("nominal", env)
    speeds = []
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs, info))
        if info["time"] > 3.0:
            speeds.append(info["truth"]["rotor_speed"].mean())
        if term or trunc:
            break
    p = env.unwrapped.params
    expected = np.sqrt(p.mass * GRAVITY / (4 * p.thrust_coefficient))
    assert abs(np.mean(speeds) / expected - 1) < 0.01


def test_effectiveness_G_matches_000_table_II_magnitudes():
    """000 eq. (8)-(9) with the bebop2 set: G_az = c_T/m within 5% of Table II's 5e-6; G_p, G_q of its order."""
    G = BEBOP2.effectiveness_G
    assert abs(G[2] / 5e-6 - 1) < 0.05
    assert 0.5 < G[0] / 100e-6 < 2 and 0.5 < G[1] / 100e-6 < 2


def _step_from_hover(env, commands, steps):
    env.reset(seed=0)
    u = env.unwrapped
    u.world.reset(np.array([0, 0, -5.0]), np.array([0, 0, 0, 1.0]), np.zeros(3), np.zeros(3))
    u._read_state()
    rates, speeds = [], []
    for _ in range(steps):
        _, _, _, _, info = env.step(commands)
        rates.append(info["truth"]["body_rates"])
        speeds.append(info["truth"]["rotor_speed"])
    return np.array(rates), np.array(speeds)


@pytest.mark.parametrize("rotor", [0, 1, 2, 3])
def test_single_rotor_step_gives_eq8_angular_acceleration(rotor, quiet_sensors):
    """A speed step on one rotor gives the roll/pitch accelerations of 000 eq. (8) within 5%."""
    env = make_env(sensors=quiet_sensors)
    p = env.unwrapped.params
    cmd = np.full(4, hover_command(p), dtype=np.float32)
    cmd[rotor] = hover_command(p, p.hover_omega * 1.15)
    dt = 1 / env.unwrapped.agent_hz
    rates, speeds = _step_from_hover(env, cmd, 25)
    measured = rates[-1, :2] / (25 * dt)                 # mean angular acceleration over the window
    signs = np.array([[1, -1, -1, 1], [1, 1, -1, -1]])
    G = p.effectiveness_G
    predicted = np.mean([G[:2] * (signs @ w2) for w2 in speeds ** 2], axis=0)
    assert np.allclose(measured, predicted, rtol=0.05, atol=0.0)
    assert np.all(np.abs(predicted) > 1.0)  # the step is large enough to matter


def test_yaw_torque_signs_follow_004_eq7(quiet_sensors):
    """Speeding up rotors 1 and 3 (indices 0, 2) and slowing 2 and 4 yaws the body positively (+, -, +, -)."""
    env = make_env(sensors=quiet_sensors)
    p = env.unwrapped.params
    up, down = hover_command(p, p.hover_omega * 1.1), hover_command(p, p.hover_omega * 0.9)
    rates, speeds = _step_from_hover(env, np.array([up, down, up, down], dtype=np.float32), 50)
    assert rates[-1, 2] > 0.5 and abs(rates[-1, 0]) < 0.05 and abs(rates[-1, 1]) < 0.05
    rates, _ = _step_from_hover(env, np.array([down, up, down, up], dtype=np.float32), 50)
    assert rates[-1, 2] < -0.5
    # Magnitude after the motors settle (0.3 s = 9 time constants, so the propellers' spin-up reaction has
    # died out): r_dot = (c_Q sum(s_i omega_i^2) - (D1 + D2 |r|) r) / Izz.
    rates, speeds = _step_from_hover(env, np.array([up, down, up, down], dtype=np.float32), 150)
    dt = 1 / env.unwrapped.agent_hz
    measured = (rates[-1, 2] - rates[-11, 2]) / (10 * dt)
    damping = p.rotational_drag_moment(rates[-5])[2]
    torque = p.torque_coefficient * (speeds[-5] ** 2 @ np.array([1, -1, 1, -1])) + damping
    assert abs(measured / (torque / p.inertia[2]) - 1) < 0.05


def test_rotational_drag_is_quadratic_on_bebop2_and_linear_on_mueller2014():
    """Sun's Bebop2 model damps -D2 |w| w (simParams.m rotDrag, N m s^2); 001 App. B's yaw damping is linear."""
    bebop, mueller = make_params("bebop2"), make_params("mueller2014")
    rates = np.array([2.0, -4.0, 20.0])
    assert bebop.rotational_drag_moment(rates) == pytest.approx([-2e-4, 8e-4, -0.04])
    assert mueller.rotational_drag_moment(rates) == pytest.approx([-2e-4, 4e-4, -0.055])


def test_free_fall_at_g_and_accelerometer_reads_zero(quiet_sensors):
    """All four propellers lost: the body falls at g and the accelerometer (specific force) reads ~0."""
    faults = [{"kind": "rotor_loss", "target": i, "time": 0.0} for i in range(4)]
    env = make_env(sensors=quiet_sensors, faults=faults, vehicle_overrides={"body_drag": [0.0, 0.0, 0.0]})
    obs, info = env.reset(seed=0)
    v0 = info["truth"]["velocity"][2]
    for _ in range(100):  # 0.2 s
        obs, _, _, _, info = env.step(np.full(4, 0.5, dtype=np.float32))
    accel_down = (info["truth"]["velocity"][2] - v0) / info["time"]
    assert abs(accel_down / GRAVITY - 1) < 0.01
    assert np.linalg.norm(obs["accel"]) < 0.05


def test_lost_propeller_motor_still_reports_a_higher_speed():
    """000 Sec. III-A: after an ejection the ESC still reports the (unloaded, faster) motor speed."""
    env = make_env(faults=[{"kind": "rotor_loss", "target": 2, "time": 0.1}], max_episode_seconds=0.3)
    obs, info = env.reset(seed=0)
    p = env.unwrapped.params
    cmd = np.full(4, hover_command(p), dtype=np.float32)
    before = None
    while True:
        obs, _, term, trunc, info = env.step(cmd)
        if before is None and info["time"] >= 0.1:
            before = obs["rotor_speed"][2]
        if term or trunc:
            break
    assert info["truth"]["rotor_effectiveness"][2] == 0.0
    assert obs["rotor_speed"][2] > 1.2 * before


def _gyro_after_spin(env, rates):
    env.reset(seed=0)
    u = env.unwrapped
    u.world.reset(np.array([0, 0, -5.0]), np.array([0, 0, 0, 1.0]), np.zeros(3), np.array(rates))
    u._read_state()
    obs, *_ = env.step(np.full(4, hover_command(u.params), dtype=np.float32))
    return obs["gyro"]


def test_gyro_saturates_at_2000_deg_s(quiet_sensors):
    """+-2000 deg/s full scale (000 Fig. 5); rates inside it read true. (p, 0, r) keeps p free of coupling."""
    env = make_env(sensors=quiet_sensors)
    gyro = _gyro_after_spin(env, [1.0, 0.0, 80.0])
    assert gyro[2] == GYRO_LIMIT and abs(gyro[0] - 1.0) < 0.01
    assert _gyro_after_spin(env, [0.0, -60.0, 0.0])[1] == -GYRO_LIMIT
    assert np.isclose(GYRO_LIMIT, np.deg2rad(2000))


def test_mueller2014_geometry_is_mueller_arm():
    """The X-numbered mueller2014 set keeps Mueller's 0.17 m rotor distance."""
    assert np.allclose(np.linalg.norm(MUELLER2014.rotor_positions, axis=1), 0.17)
