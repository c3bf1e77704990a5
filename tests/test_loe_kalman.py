"""loe_kalman (000 Sec. IV): the Kalman step, the probability test, the filter, and detection in the simulator."""
import numpy as np
import pytest
from conftest import LIGHT_WIND, make_env
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal
from scipy.stats import norm

from ftcgym.agents import make_policy
from ftcgym.fdd import LoeKalmanDetector, loe_kalman_wrapper
from ftcgym.fdd.base import Biquad
from ftcgym.fdd.loe_kalman import SIGNS_000, failure_probability, kalman_step, lowpass_coefficients


def test_kalman_step_matches_closed_form_information_update():
    """Algorithm 1 equals the information form P+ = (P-^-1 + H^T R^-1 H)^-1, x+ = x + P+ H^T R^-1 (z - H x)."""
    rng = np.random.default_rng(0)
    H = np.diag([1.5e-4, 1.3e-4, 5e-6]) @ SIGNS_000 * (690.0 ** 2 + rng.uniform(-1e4, 1e4, 4))
    x, P = np.ones(4), 0.01 * np.eye(4) + 1e-3 * np.ones((4, 4))
    Q, R = 2e-3 * np.eye(4), np.diag([1.0, 2.0, 0.5])
    z = H @ np.array([0.98, 1.01, 0.99, 1.0]) + rng.normal(0, 0.1, 3)
    x_new, P_new = kalman_step(x, P, z, H, Q, R)
    prior = P + Q
    P_closed = np.linalg.inv(np.linalg.inv(prior) + H.T @ np.linalg.inv(R) @ H)
    x_closed = x + P_closed @ H.T @ np.linalg.inv(R) @ (z - H @ x)
    assert np.allclose(x_new, x_closed, atol=1e-12, rtol=0)
    assert np.allclose(P_new, P_closed, atol=1e-12, rtol=0)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(300, 1300), min_size=4, max_size=4), st.lists(st.floats(-200, 200), min_size=3, max_size=3),
       st.integers(1, 30))
def test_covariance_stays_symmetric_positive_semidefinite(omega, z, steps):
    H = np.diag([1.5e-4, 1.3e-4, 5e-6]) @ SIGNS_000 * np.square(omega)
    x, P = np.ones(4), 0.01 * np.eye(4)
    for _ in range(steps):
        x, P = kalman_step(x, P, np.array(z), H, 2e-3 * np.eye(4), np.eye(3))
    assert np.array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > -1e-12
    assert np.all((x >= 0.0) & (x <= 1.5))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(300, 1300), min_size=4, max_size=4), st.lists(st.floats(-200, 200), min_size=3, max_size=3),
       st.lists(st.floats(0.0, 1.5), min_size=4, max_size=4), st.integers(0, 2**32 - 1))
def test_detector_step_by_cholesky_equals_the_joseph_form_step(omega, z, x, seed):
    """The detector's Kalman step (gain through the Cholesky factor of S) is `kalman_step` (solve, Joseph form) up
    to rounding, on random states and covariances."""
    det = LoeKalmanDetector(1 / 500, R=0.7)
    A = np.random.default_rng(seed).normal(0.0, 0.2, (4, 4))
    det.x, det.P = np.array(x), A @ A.T + 1e-4 * np.eye(4)
    H = det.B * np.square(omega)
    x_ref, P_ref = kalman_step(det.x, det.P, np.array(z), H, det.Q, 0.7 * np.eye(3))
    assert det._kalman_step(z, H) == det.x.tolist()
    np.testing.assert_allclose(det.x, x_ref, rtol=0, atol=1e-11)       # 6e-13 at most in 5000 random cases
    np.testing.assert_allclose(det.P, P_ref, rtol=0, atol=1e-11 * np.abs(P_ref).max())   # there 4e-13
    assert np.array_equal(det.P, det.P.T)


def test_lowpass_on_a_list_of_channels_gives_the_bits_of_the_array_path():
    b, a = lowpass_coefficients(50.0, 0.55, 1 / 500)
    samples = np.random.default_rng(2).normal(700.0, 30.0, (200, 7))
    on_array, on_list = Biquad(b, a), Biquad(b, a)
    for sample in samples:
        assert on_list(sample.tolist()) == on_array(sample).tolist()


@pytest.mark.parametrize("k_hat, var", [(1.0, 0.04), (0.3, 0.01), (0.1, 0.2), (0.25, 1.0)])
def test_failure_probability_is_the_normal_cdf(k_hat, var):
    """Corrected eq. (15): P(k < k_thres) for k ~ N(k_hat, var)."""
    expected = norm.cdf(0.25, loc=k_hat, scale=np.sqrt(var))
    assert failure_probability(np.array([k_hat]), np.array([var]), 0.25)[0] == pytest.approx(expected, abs=1e-12)


def test_lowpass_matches_the_analogue_prototype_below_20_hz():
    """Sec. IV-A filter (wn = 50 rad/s, zeta = 0.55) at 500 Hz: within 1 dB of H(s) below 20 Hz."""
    b, a = lowpass_coefficients(50.0, 0.55, 1 / 500)
    freqs_hz = np.linspace(0.1, 20.0, 200)
    _, h_digital = signal.freqz(b, a, worN=freqs_hz, fs=500)
    _, h_analog = signal.freqs([2500.0], [1.0, 55.0, 2500.0], worN=2 * np.pi * freqs_hz)
    assert np.max(np.abs(20 * np.log10(np.abs(h_digital) / np.abs(h_analog)))) < 1.0


def test_not_armed_on_the_ground():
    """Take-off gating (Sec. V-D): idle rotors on the ground raise no alarm and run no estimator."""
    det = LoeKalmanDetector(1 / 500, G=(1.5e-4, 1.3e-4, 5.1e-6))
    for i in range(500):
        det.update({"gyro": np.zeros(3), "accel": np.array([0, 0, -9.81]), "rotor_speed": np.full(4, 300.0)}, i / 500)
    assert not det.armed and not det.status()["alarm"] and np.all(det.x == 1.0)


@pytest.mark.parametrize("R", [0.0, -1.0, float("nan")])
def test_measurement_noise_must_be_positive(R):
    with pytest.raises(ValueError, match="R: must be a finite number > 0"):
        LoeKalmanDetector(1 / 500, R=R)


def test_nan_reading_is_rejected():
    det = LoeKalmanDetector(1 / 500)
    with pytest.raises(ValueError, match="gyro"):
        det.update({"gyro": np.array([np.nan, 0, 0]), "accel": np.zeros(3), "rotor_speed": np.ones(4)}, 0.0)


def _fly_with_detector(seed, faults, task="hover", seconds=6.0):
    env = loe_kalman_wrapper(make_env(faults=faults, task=task, wind=LIGHT_WIND, max_episode_seconds=seconds))
    obs, info = env.reset(seed=seed)
    assert {"fdd/loe_kalman/k_hat", "fdd/loe_kalman/p_fail"} <= set(obs) and env.observation_space.contains(obs)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs, info))
        if term or trunc:
            return info


@pytest.mark.parametrize("seed, rotor", [(31, 0), (32, 3)])
def test_rotor_loss_is_detected_and_isolated_within_000_bounds(seed, rotor):
    info = _fly_with_detector(seed, [{"kind": "rotor_loss", "target": rotor, "time": 3.0}])
    status = info["fdd"]["loe_kalman"]
    assert status["isolated"] == rotor
    assert 0.028 <= status["alarm_time"] - 3.0 <= 0.132
    # JSON-friendly: plain bools, ints and floats (arrays for vectors), no numpy scalars
    assert {type(v).__name__ for v in status.values()} <= {"bool", "int", "float", "list", "ndarray", "NoneType"}
    assert not any(isinstance(v, np.generic) for v in status.values())


def test_no_false_alarm_in_a_fault_free_manoeuvring_flight():
    info = _fly_with_detector(33, None, task={"name": "square", "speed": 2.0, "heading_changes": True}, seconds=25)
    assert not info["crashed"] and info["fdd"]["loe_kalman"]["alarm"] is False
    assert np.allclose(info["fdd"]["loe_kalman"]["k_hat"], 1.0, atol=0.1)


def test_gymnasium_check_env_on_the_wrapped_env():
    """The detector's keys and spaces pass the checker; its only remark is its generic advice to check
    `env.unwrapped`, which would leave the wrapper out."""
    import warnings

    from gymnasium.utils.env_checker import check_env
    env = loe_kalman_wrapper(make_env(wind=LIGHT_WIND))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    remarks = [str(w.message) for w in caught if "different from the unwrapped version" not in str(w.message)]
    assert remarks == []
