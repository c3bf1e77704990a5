"""IvChangeDetector (004): the IV cost recursion, detection on a known submodel, real flights, input checks."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import LIGHT_WIND, make_env

from ftcgym.agents import make_policy
from ftcgym.fdd.base import Detector
from ftcgym.fdd.iv_change import IvChangeDetector, IvCost, IvEstimate, SixDofResidual, iv_change_wrapper
from ftcgym.models.quadrotor import make_params

# 004 Table 1: m = 0.5 kg, lambda_1 = 0.36 N s/m (c = lambda_1 / m = 0.72 1/s).
MASS, LAMBDA_1, DT = 0.5, 0.36, 0.002


def batch_cost(Z, r, lam, n_w, t):
    """004 eq. (30) summed directly: S(t) = sum_{i=t-N_w+1}^{t} lam^(t-i) Z(i) r(i), J = ||S||."""
    i = np.arange(max(0, t - n_w + 1), t + 1)
    S = np.einsum("i,imd->md", lam ** (t - i) * 1.0, Z[i] * r[i][:, :, None])
    return np.linalg.norm(S, axis=1)


def test_iv_cost_recursion_matches_the_batch_sum_of_eq_30():
    rng = np.random.default_rng(3)
    lam, n_w, n = 0.97, 50, 400
    Z, r = rng.normal(size=(n, 2, 3)), rng.normal(size=(n, 2))
    cost = IvCost(lam, n_w)
    worst = 0.0
    for t in range(n):
        J = cost.update(Z[t], r[t])
        worst = max(worst, np.abs(J - batch_cost(Z, r, lam, n_w, t)).max())
    assert worst < 1e-10


def test_iv_estimate_is_consistent_where_least_squares_is_biased():
    """y = c phi + e with e correlated with phi (as wind in the closed loop) but not with the instrument z."""
    rng = np.random.default_rng(4)
    c, n = 0.72, 200_000
    z = rng.normal(size=n)                      # instrument: driven by the reference only
    e = rng.normal(size=n)                      # disturbance, also feeding the regressor
    phi = z + 0.8 * e + 0.3 * rng.normal(size=n)
    y = c * phi + e
    est = IvEstimate(lam=1.0 - 1e-6)
    for k in range(0, n, 1000):                 # pooled update over blocks: the same sums
        est.N = est.lam ** 1000 * est.N + float(z[k:k + 1000] @ y[k:k + 1000])
        est.D = est.lam ** 1000 * est.D + float(z[k:k + 1000] @ phi[k:k + 1000])
    least_squares = float(phi @ y / (phi @ phi))
    assert abs(est.N / est.D - c) < 0.01
    assert least_squares - c > 0.3              # biased by the disturbance/regressor correlation


def test_iv_estimate_recursion_matches_the_batch_sums():
    rng = np.random.default_rng(5)
    lam, n = 0.99, 300
    zeta, y, phi = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    est = IvEstimate(lam)
    for t in range(n):
        est.update(zeta[t], y[t], phi[t])
    weights = lam ** np.arange(n - 1, -1, -1)
    assert pytest.approx(float(weights @ np.einsum("ij,ij->i", zeta, y)), rel=1e-12) == est.N
    assert pytest.approx(float(weights @ np.einsum("ij,ij->i", zeta, phi)), rel=1e-12) == est.D


def synthetic_flight(seconds: float, step_time: float, seed: int = 0):
    """Readings (500 Hz) of a closed loop that obeys the submodel (28) exactly, with 004 Table 1's c.

    Along x: a PD position loop with a lagged thrust tilt tracks a two-sine reference (other gains than
    the detector's reference model); v' = g tau - c (v - w), a_x = -c (v - w) + white noise, q = -tau_x'.
    w is coloured wind (first-order, 5 s, 0.1 m/s) on both axes. The mass steps 0.5 -> 1 kg at step_time.
    The wind test's readings: level attitude, the ground velocity v, rotor speeds 0 (no rotor drag).
    """
    rng = np.random.default_rng(seed)
    g, kp, kd, k_att = 9.81, 1.2, 2.0, 9.0
    a_w = math.exp(-DT / 5.0)
    s_w = 0.1 * math.sqrt(1.0 - a_w * a_w)
    x, v, tau, w = np.zeros(2), np.array([2.25, 0.0]), np.zeros(2), np.zeros(2)
    for k in range(int(round(seconds / DT))):
        t = k * DT
        c = LAMBDA_1 / (MASS if t < step_time else 2 * MASS)
        x_ref = np.array([2.0 * math.sin(0.6 * t) + 0.5 * math.sin(2.1 * t), 0.0])
        v_ref = np.array([1.2 * math.cos(0.6 * t) + 1.05 * math.cos(2.1 * t), 0.0])
        dtau = k_att * ((kp * (x_ref - x) + kd * (v_ref - v)) / g - tau)
        accel = -c * (v - w) + rng.normal(0.0, 0.01, 2)
        yield {"gyro": np.array([dtau[1], -dtau[0], 0.0]), "accel": np.array([*accel, -g]),
               "reference_position": np.array([*x_ref, -5.0]), "reference_velocity": np.array([*v_ref, 0.0]),
               "reference_yaw": np.array([0.0]), "attitude": np.array([0.0, 0.0, 0.0, 1.0]),
               "velocity": np.array([*v, 0.0]), "rotor_speed": np.zeros(4)}, t
        x, v, tau = x + DT * v, v + DT * (g * tau - c * (v - w)), tau + DT * dtau
        w = a_w * w + s_w * rng.normal(size=2)


@pytest.mark.parametrize("step_time", [30.0, None])
def test_synthetic_mass_step_is_detected_and_nothing_before(step_time):
    """The IV test (default settings otherwise): c_hat stays within 5% of c and the CUSUM near 0 before the step;
    then c_hat falls and the CUSUM (drift ~0.3 per s here, toward 0.8 c) crosses its threshold within 15 s."""
    detector = IvChangeDetector(MASS, LAMBDA_1, DT, test="iv")
    ratio_before, cusum_before = [], []
    for readings, t in synthetic_flight(46.0, step_time or np.inf):
        detector.update(readings, t)
        if detector.warmup <= t < (step_time or np.inf):
            ratio_before.append(detector.c_hat / detector.c)
            cusum_before.append(detector.cusum)
    status = detector.status()
    assert min(ratio_before) > 0.95 and max(ratio_before) < 1.05
    assert max(cusum_before) < 0.05 * detector.cusum_threshold
    if step_time is None:
        assert not status["alarm"] and status["cusum"] < 0.05 * detector.cusum_threshold
    else:
        assert status["alarm"] and step_time + 5.0 < status["alarm_time"] < step_time + 15.0
        assert status["c_ratio"] < 0.6                            # c halves: 0.5 once the memory has forgotten
    assert status["isolated"] is None


@pytest.mark.parametrize("step_time", [30.0, None])
def test_wind_test_detects_the_synthetic_mass_step_within_seconds(step_time):
    """The wind test (default settings) on the same flight, whose wind (first-order, 5 s, 0.1 m/s) is far calmer
    than the light turbulence the test models: it takes one of its calmer turbulence levels, its CUSUM stays
    under half its threshold without the step and crosses it within 3 s of it, while the IV CUSUM
    (published, not alarming) needs 5-15 s."""
    detector = IvChangeDetector(MASS, LAMBDA_1, DT)
    peak_before = 0.0
    for readings, t in synthetic_flight(40.0, step_time or np.inf):
        detector.update(readings, t)
        if t < (step_time or np.inf):
            peak_before = max(peak_before, detector.wind_cusum)
    status = detector.status()
    assert peak_before < detector.wind_threshold / 2
    if step_time is None:
        assert not status["alarm"]
    else:
        assert status["alarm"] and step_time < status["alarm_time"] < step_time + 3.0
        assert status["cusum"] < detector.cusum_threshold       # the IV CUSUM has not got there yet
    assert detector.wind_test.level < len(detector.wind_test.levels) - 1   # a calmer level than the light one


def test_wind_test_settings_are_checked():
    for bad in ({"test": "glr"}, {"mass_ratio": 1.0}, {"period": 0.0}, {"air_cutoff_hz": 300.0},
                {"rotor_drag": (-1.0, 0.0)}, {"turbulence_levels": ()}, {"turbulence_levels": (0.0, 1.0)},
                {"level_memory": 0.0}):
        with pytest.raises(ValueError):
            IvChangeDetector(MASS, LAMBDA_1, DT, **bad)


@pytest.mark.parametrize("seed", [1000, 1001])
def test_real_flight_payload_change_alarms_after_onset_only(seed):
    """004 Sec. 5.1 with heading changes (cut at 50 s): +0.5 kg over 2 s from 40 s.

    Seeds 1000, 1001 are tuning seeds, so this pins the tuned behaviour, it does not measure it (held-out
    figures: module docstring of `ftcgym.fdd.iv_change`)."""
    onset = 40.0
    env = iv_change_wrapper(make_env(vehicle="mueller2014", wind=LIGHT_WIND, max_episode_seconds=onset + 10.0,
                                     task={"name": "square", "altitude": 8.0, "heading_changes": True},
                                     faults=[{"kind": "payload", "time": onset, "magnitude": 0.5, "duration": 2.0}]))
    obs, info = env.reset(seed=seed)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    assert env.observation_space.contains(obs)
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs, info))
        if terminated or truncated:
            break
    env.close()
    status = info["fdd"]["iv_change"]
    assert not info["crashed"]
    assert status["alarm"] and onset < status["alarm_time"] < onset + 10.0
    assert obs["fdd/iv_change/J"].shape == (2,) and obs["fdd/iv_change/residual"].shape == (2,)
    assert obs["fdd/iv_change/c_hat"][0] < 0.8 * env.detector.c          # the estimate fell with the mass


def test_readings_as_lists_other_dtypes_or_strided_views_give_the_same_detector():
    """The env's float64 arrays reach the compiled sample as they are; float32, 2-D and strided arrays are
    converted by it, lists and object arrays (which numba cannot take) in Python: all give the same bits."""
    detectors = [IvChangeDetector(MASS, LAMBDA_1, DT) for _ in range(5)]
    table = np.zeros((3, 2))
    for readings, t in synthetic_flight(12.0, 6.0):
        readings = {key: value.astype(np.float32).astype(np.float64) for key, value in readings.items()}
        table[:, 1] = readings["velocity"]
        variants = (readings, {key: value.astype(np.float32) for key, value in readings.items()},
                    {**readings, "velocity": table[:, 1], "gyro": readings["gyro"][:, None]},
                    {key: value.tolist() for key, value in readings.items()},
                    {**readings, "accel": readings["accel"].astype(object)})
        for detector, variant in zip(detectors, variants):
            detector.update(variant, t)
    assert detectors[0].c_hat != 0.0
    for detector in detectors[1:]:
        assert np.array_equal(detector._state, detectors[0]._state, equal_nan=True)     # NaN: a time not yet set
        assert detector.status() == detectors[0].status()


def test_protocol_and_non_finite_readings():
    detector = IvChangeDetector(MASS, LAMBDA_1, DT)
    assert isinstance(detector, Detector) and detector.name == "iv_change"
    readings, t = next(synthetic_flight(1.0, np.inf))
    detector.update(readings, t)
    assert set(detector.outputs()) == set(detector.output_fields)
    for key in ("gyro", "accel", "reference_position", "attitude", "velocity", "rotor_speed"):
        bad = {**readings, key: np.array([0.0, np.nan, 0.0])}
        with pytest.raises(ValueError, match=key):
            detector.update(bad, t + DT)
    six_dof = SixDofResidual(make_params("mueller2014"), DT)
    with pytest.raises(ValueError, match="accel"):
        six_dof.update({"gyro": np.zeros(3), "accel": np.array([np.inf, 0.0, 0.0]), "rotor_speed": np.zeros(4)})


def test_accelerometer_bias_estimate_removes_the_heading_step_error():
    """Calm air (mean wind only), heading changes, no fault, 36 s (three heading steps; seed 9000, where the
    error was diagnosed). The yaw coupling turns the accelerometer's bias with the body: without the
    estimate the CUSUM climbs to 3.6 (84% of its threshold) at the 27 s heading step, with it it stays
    under 1 and the estimate lands within 0.03 m/s^2 of the simulated bias. The wind test's CUSUM peaks at
    5.2 (of 14): it takes its calmest turbulence level; held at the light level alone it alarmed at 23.2 s."""
    env = make_env(vehicle="mueller2014", wind={"mean": [1.0, -1.0, 0.0], "turbulence": "none"},
                   max_episode_seconds=36.0, task={"name": "square", "altitude": 8.0, "heading_changes": True})
    obs, info = env.reset(seed=9000)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    detectors = [IvChangeDetector.from_params(env.unwrapped.params, 1.0 / env.unwrapped.agent_hz, **kwargs)
                 for kwargs in ({}, {"accel_bias_prior": None})]
    peaks, wind_peak = [0.0, 0.0], 0.0
    while True:
        for i, detector in enumerate(detectors):
            detector.update(obs, info["time"])
            peaks[i] = max(peaks[i], detector.cusum)
        wind_peak = max(wind_peak, detectors[0].wind_cusum)
        obs, _, terminated, truncated, info = env.step(policy.act(obs, info))
        if terminated or truncated:
            break
    true_bias = env.unwrapped.sensors.accel_bias[:2]
    env.close()
    assert peaks[0] < 1.0 and peaks[1] > 3.0
    assert np.allclose(detectors[0].status()["accel_bias"], true_bias, atol=0.03)
    assert detectors[1].status()["accel_bias"] == [0.0, 0.0]
    assert wind_peak < 0.6 * detectors[0].wind_threshold and not detectors[0].latch.alarm
