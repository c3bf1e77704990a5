"""The recovery task's features (`ftcgym.task_envs.rotor_loss_recovery.recovery_features`): the heading and the
half turn
about body z, symmetries of a quadrotor's recovery, leave them unchanged."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ftcgym.task_envs.rotor_loss_recovery import HALF_TURN_ROTORS, N_FEATURES, recovery_features, rotor_order

OMEGA_MAX = 1000.0
PREFIX = "fdd/loe_kalman/"


def _state(rng, isolated):
    """A random post-alarm observation, detector status and guidance (commanded axis, thrust share)."""
    obs = {"gyro": rng.normal(0, 5, 3), "attitude": Rotation.random(random_state=rng.integers(1000)).as_quat(),
           "position": rng.normal(0, 3, 3), "velocity": rng.normal(0, 2, 3),
           "reference_position": rng.normal(0, 3, 3), "reference_velocity": rng.normal(0, 2, 3),
           "rotor_speed": rng.uniform(0, OMEGA_MAX, 4), PREFIX + "k_hat": rng.uniform(0, 1.2, 4),
           PREFIX + "k_var": rng.uniform(1e-4, 1e-1, 4), PREFIX + "p_fail": rng.uniform(0, 1, 4)}
    axis = rng.normal(0, 1, 3)
    return obs, {"alarm": True, "isolated": isolated}, axis / np.linalg.norm(axis), rng.uniform(0.5, 1.5)


def _turned_world(obs, axis, yaw):
    """The same flight and commanded axis seen with the world turned by `yaw` about the vertical."""
    turn = Rotation.from_euler("z", yaw)
    out = dict(obs, attitude=(turn * Rotation.from_quat(obs["attitude"])).as_quat())
    for key in ("position", "velocity", "reference_position", "reference_velocity"):
        out[key] = turn.apply(obs[key])
    return out, turn.apply(axis)


def _half_turned_body(obs):
    """The same flight with the body labelled half a turn round about its z axis."""
    out = dict(obs, attitude=(Rotation.from_quat(obs["attitude"]) * Rotation.from_euler("z", np.pi)).as_quat(),
               gyro=obs["gyro"] * [-1, -1, 1])
    for key in ("rotor_speed", PREFIX + "k_hat", PREFIX + "k_var", PREFIX + "p_fail"):
        out[key] = obs[key][HALF_TURN_ROTORS]
    return out


@pytest.mark.parametrize("isolated", [0, 1, 2, 3])
def test_features_do_not_depend_on_the_heading(isolated):
    rng = np.random.default_rng(isolated)
    obs, status, axis, thrust = _state(rng, isolated)
    features = recovery_features(obs, status, OMEGA_MAX, axis, thrust)
    assert features.shape == (N_FEATURES,) and features.dtype == np.float32
    for yaw in (0.7, np.pi / 2, -2.5):
        turned, turned_axis = _turned_world(obs, axis, yaw)
        np.testing.assert_allclose(recovery_features(turned, status, OMEGA_MAX, turned_axis, thrust), features,
                                   atol=1e-5)
    # ... but they do see the flight and the guidance: a position error, a commanded axis, a thrust
    moved = dict(obs, position=obs["position"] + [1.0, 0.0, 0.0])
    assert np.abs(recovery_features(moved, status, OMEGA_MAX, axis, thrust) - features).max() > 0.1
    assert np.abs(recovery_features(obs, status, OMEGA_MAX, -axis, thrust) - features).max() > 0.1
    changed = recovery_features(obs, status, OMEGA_MAX, axis, thrust + 0.2) - features
    assert np.flatnonzero(changed).tolist() == [20] and changed[20] == pytest.approx(0.2)


@pytest.mark.parametrize("isolated", [2, 3])
def test_a_lost_back_rotor_reads_as_the_front_rotor_half_a_turn_round(isolated):
    obs, status, axis, thrust = _state(np.random.default_rng(10 + isolated), isolated)
    twin = _half_turned_body(obs), {"alarm": True, "isolated": isolated - 2}
    features = recovery_features(obs, status, OMEGA_MAX, axis, thrust)
    np.testing.assert_allclose(features, recovery_features(*twin, OMEGA_MAX, axis, thrust), atol=1e-5)
    # the canonical isolated rotor is r1 or r2, one-hot
    assert list(features[-4:]) == [isolated == 2, isolated == 3, 0, 0]


def test_the_guidance_reads_in_the_body_frame():
    obs, status, _, _ = _state(np.random.default_rng(3), 1)
    up = np.array([0.0, 0.0, -1.0])
    features = recovery_features(obs, status, OMEGA_MAX, up, 1.0)
    # the commanded axis straight up is the body's view of up, the features' vertical (R^T e_z) negated
    np.testing.assert_allclose(features[17:20], -features[3:6], atol=1e-6)
    assert features[20] == 0.0


def test_rotor_order_is_its_own_inverse():
    for isolated, expected in [(0, [0, 1, 2, 3]), (1, [0, 1, 2, 3]), (2, [2, 3, 0, 1]), (3, [2, 3, 0, 1])]:
        order = rotor_order({"alarm": True, "isolated": isolated})
        assert list(order) == expected and list(order[order]) == [0, 1, 2, 3]
    assert list(rotor_order({"alarm": False, "isolated": None})) == [0, 1, 2, 3]
