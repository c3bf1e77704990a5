"""loe_kalman (000 Sec. IV): the Kalman step, the probability test, the filter, and detection in the simulator."""
import math
import re

import numpy as np
import pytest
from conftest import LIGHT_WIND, make_env
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal
from scipy.stats import norm

from ftcgym.agents import make_policy
from ftcgym.fdd import LoeKalmanDetector, loe_kalman_wrapper
from ftcgym.fdd.base import Biquad, biquad_constants, biquad_step
from ftcgym.fdd.loe_kalman import (
    SIGNS_000,
    LoeKalmanSettings,
    _failure_probability,
    _kalman_step,
    failure_probability,
    kalman_step,
    lowpass_coefficients,
)


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


def _plain_cholesky_step(x, P, z, H, Q, r, k_bounds):
    """`_kalman_step` in plain numpy and Python floats, the detector's step before it was compiled."""
    P = P + Q
    U = P.dot(H.T)
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = H.dot(U).tolist()
    l00 = math.sqrt(s00 + r)
    l10, l20 = s01 / l00, s02 / l00
    l11 = math.sqrt(s11 + r - l10 * l10)
    l21 = (s12 - l20 * l10) / l11
    l22 = math.sqrt(s22 + r - l20 * l20 - l21 * l21)
    m00, m11, m22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    m10 = -m11 * l10 * m00
    L_inv = ((m00, 0.0, 0.0), (m10, m11, 0.0), (-m22 * (l20 * m00 + l21 * m10), -m22 * l21 * m11, m22))
    (i00, _, _), (i10, i11, _), (i20, i21, i22) = L_inv
    V = U.dot(np.array(L_inv).T)
    (z0, z1, z2), (h0, h1, h2) = z, H.dot(x).tolist()
    y0, y1, y2 = z0 - h0, z1 - h1, z2 - h2
    w0, w1, w2 = i00 * y0, i10 * y0 + i11 * y1, i20 * y0 + i21 * y1 + i22 * y2
    lo, hi = k_bounds
    x = [min(max(k + v0 * w0 + v1 * w1 + v2 * w2, lo), hi) for k, (v0, v1, v2) in zip(x.tolist(), V.tolist())]
    return np.array(x), P - V.dot(V.T)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(300, 1300), min_size=4, max_size=4), st.lists(st.floats(-200, 200), min_size=3, max_size=3),
       st.lists(st.floats(0.0, 1.5), min_size=4, max_size=4), st.integers(0, 2**32 - 1))
def test_compiled_kalman_step_equals_the_plain_step_and_the_joseph_form_step(omega, z, x, seed):
    """The detector's compiled Kalman step (gain through the Cholesky factor of S) has the bits of the same step in
    plain numpy, and is `kalman_step` (solve, Joseph form) up to rounding, on random states and covariances."""
    A = np.random.default_rng(seed).normal(0.0, 0.2, (4, 4))
    x, P = np.array(x), A @ A.T + 1e-4 * np.eye(4)
    H, Q = LoeKalmanDetector(1 / 500).B * np.square(omega), 2e-3 * np.eye(4)
    x_plain, P_plain = _plain_cholesky_step(x, P, z, H, Q, 0.7, (0.0, 1.5))
    x_ref, P_ref = kalman_step(x, P, np.array(z), H, Q, 0.7 * np.eye(3))
    _kalman_step(x, P, tuple(z), H, Q, 0.7, 0.0, 1.5)                   # in place
    assert np.array_equal(x, x_plain) and np.array_equal(P, P_plain)
    np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-11)           # 6e-13 at most in 5000 random cases
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=1e-11 * np.abs(P_ref).max())   # there 4e-13
    assert np.array_equal(P, P.T)


def test_compiled_lowpass_gives_the_bits_of_biquad():
    """`biquad_step` on `biquad_constants` (the detectors' compiled low-pass) is `Biquad` on an array and on floats."""
    b, a = lowpass_coefficients(50.0, 0.55, 1 / 500)
    samples = np.random.default_rng(2).normal(700.0, 30.0, (200, 7))
    on_array, per_channel = Biquad(b, a), [Biquad(b, a) for _ in range(7)]
    constants, memory = biquad_constants(b, a), np.empty((2, 7))
    for i, sample in enumerate(samples):
        compiled = biquad_step(constants, memory, sample, i == 0).tolist()
        assert compiled == on_array(sample).tolist() == [f(v) for f, v in zip(per_channel, sample.tolist())]


def test_compiled_failure_probability_has_the_bits_of_scipys_erf():
    """P_fail compiled (scipy's erf through its Cython API) equals `failure_probability` on numpy arrays bit for
    bit, over the estimates' range and variances from 0 to far beyond the published ceiling."""
    rng = np.random.default_rng(5)
    k_hat = np.concatenate((rng.uniform(-0.5, 2.0, 20000), [0.25, 0.25, 1.0]))
    variance = np.concatenate((10.0 ** rng.uniform(-14, 9, 20000), [0.0, 1e-300, 1e6]))
    compiled = [_failure_probability(k, v, 0.25) for k, v in zip(k_hat.tolist(), variance.tolist())]
    assert np.array_equal(compiled, failure_probability(k_hat, variance, 0.25))


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
    with pytest.raises(ValueError, match=r"loe_kalman.R: must be (> 0|finite \(no NaN or inf\)), got"):
        LoeKalmanDetector(1 / 500, R=R)
    with pytest.raises(ValueError, match="R: must be a finite number > 0"):     # a settings object is checked too
        LoeKalmanDetector(1 / 500, LoeKalmanSettings(R=R))


@pytest.mark.parametrize("overrides, message", [
    ({"G": [float("nan"), 1, 1]}, "loe_kalman.G[0]: must be finite (no NaN or inf), got nan"),
    ({"G": [1e-4, 1e-4]}, "loe_kalman.G: expected 3 numbers like [0.0001, 0.0001, 5e-06], got 2"),
    ({"Q": float("nan")}, "loe_kalman.Q: must be finite (no NaN or inf), got nan"),
    ({"Q": [1, 2]}, "loe_kalman.Q: expected a number > 0, got list [1, 2]"),
    ({"k_threshold": "x"}, "loe_kalman.k_threshold: expected a number in (0, 1), got str 'x'"),
    ({"p_fail_threshold": 2}, "loe_kalman.p_fail_threshold: must be in (0, 1), got 2.0"),
    ({"initial_variance": -1}, "loe_kalman.initial_variance: must be > 0, got -1.0"),
    ({"filter_wn": 0}, "loe_kalman.filter_wn: must be > 0, got 0.0"),
    ({"takeoff_fraction": float("nan")}, "loe_kalman.takeoff_fraction: must be finite (no NaN or inf), got nan"),
    ({"k_bounds": [1, 0]}, "k_bounds: must be (low, high) with low < high, got (1.0, 0.0)"),
])
def test_settings_that_would_silence_the_detector_are_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        LoeKalmanDetector(1 / 500, **overrides)


@pytest.mark.parametrize("key, index", [("gyro", 1), ("accel", 2), ("rotor_speed", 3)])  # the elements it reads
def test_nan_reading_is_rejected_naming_it_and_leaves_the_state(key, index):
    det = LoeKalmanDetector(1 / 500)
    readings = {"gyro": np.zeros(3), "accel": np.array([0.0, 0.0, -9.81]), "rotor_speed": np.full(4, 700.0)}
    det.update(readings, 0.0)
    before = {**det.outputs(), **det.status()}
    readings[key][index] = np.inf
    with pytest.raises(ValueError, match=key):
        det.update(readings, 0.002)
    after = {**det.outputs(), **det.status()}
    assert before.keys() == after.keys() and all(np.array_equal(before[k], after[k]) for k in before)


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
