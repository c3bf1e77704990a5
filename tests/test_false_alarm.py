"""False-detection probability (001 eq. 40-41), threshold proposals and the autocorrelation check (Fig. 4)."""
import math

import numpy as np
import pytest
from scipy import stats

from ftcgym.fdd import false_alarm as fa

HZ = 25.0


def test_eq_40_41_by_hand():
    """p_single 0.01 held 3 samples: p_seq 1e-6 (eq. 40); one hour at 25 Hz is 90,000 trials:
    p_flight = 1 - (1 - 1e-6)^90000 = 0.0861 (eq. 41), union bound 0.09."""
    assert fa.sequence_length(0.12, HZ) == 3 and fa.sequence_length(0.25, HZ) == 7 and fa.sequence_length(0, HZ) == 1
    p_seq = fa.sequence_probability(0.01, 3)
    assert p_seq == pytest.approx(1e-6)
    assert fa.flight_probability(p_seq, 3600.0, HZ) == pytest.approx(1 - (1 - 1e-6) ** 90000, rel=1e-9)
    assert fa.flight_probability(p_seq, 3600.0, HZ) == pytest.approx(0.0861, abs=1e-4)
    assert fa.flight_probability(p_seq, 3600.0, HZ, bound=True) == pytest.approx(0.09)


def test_table_2_derivative_probability_is_reproduced_by_the_inverse():
    """required_single_probability inverts eq. (40)-(41): feeding its p_single back gives the target."""
    for n in (1, 3, 7):
        p = fa.required_single_probability(1e-3, n, HZ)
        assert fa.flight_probability(fa.sequence_probability(p, n), 3600.0, HZ) == pytest.approx(1e-3, rel=1e-6)


def test_gaussian_threshold_matches_the_closed_form():
    """White N(0, 2^2) residual, target 0.1% per hour: Z = sigma * Phi^-1(1 - p/2) with p from eq. (40)-(41)."""
    rng = np.random.default_rng(0)
    samples = rng.normal(0.0, 2.0, 400_000)
    for hold in (0.12, 0.25):
        n = fa.sequence_length(hold, HZ)
        p_seq = 1.0 - (1.0 - 1e-3) ** (1.0 / (3600.0 * HZ))
        closed = 2.0 * stats.norm.isf(p_seq ** (1.0 / n) / 2.0)
        assert fa.propose_threshold(samples, hold, HZ, 1e-3, tail="gaussian") == pytest.approx(closed, rel=0.01)
    # n = 7: p_single = 0.073, well sampled: the empirical quantile agrees with the closed form too
    closed7 = 2.0 * stats.norm.isf((1.0 - (1.0 - 1e-3) ** (1.0 / 90000)) ** (1 / 7) / 2.0)
    assert closed7 == pytest.approx(3.58, abs=0.01)
    assert fa.propose_threshold(samples, 0.25, HZ, 1e-3, tail="empirical") == pytest.approx(closed7, rel=0.02)
    assert fa.propose_threshold(samples, 0.25, HZ, 1e-3, tail="auto") == pytest.approx(closed7, rel=0.02)


def test_exponential_tail_extrapolates_a_laplace_tail():
    """|Laplace(b = 1)| has P(|x| >= z) = exp(-z): the fit above the 99th percentile extrapolates to z = 12
    (6e-6, beyond the 2e5 samples) within 15%."""
    samples = np.random.default_rng(1).laplace(0.0, 1.0, 200_000)
    assert fa.exceedance_probability(samples, 12.0, tail="exponential") == pytest.approx(math.exp(-12.0), rel=0.15)
    assert fa.exceedance_probability(samples, 2.0, tail="auto") == pytest.approx(math.exp(-2.0), rel=0.03)


def test_autocorrelation_white_is_zero_beyond_lag_0_and_ar1_is_phi_to_the_k():
    rng = np.random.default_rng(2)
    white = [rng.normal(size=20_000) for _ in range(5)]
    rho = fa.autocorrelation(white, 10)
    assert rho[0] == pytest.approx(1.0) and np.all(np.abs(rho[1:]) < 4.0 / math.sqrt(100_000))
    e = rng.normal(size=100_000)
    ar = np.zeros_like(e)
    for k in range(1, e.size):
        ar[k] = 0.9 * ar[k - 1] + e[k]
    rho = fa.autocorrelation([ar], 3)
    assert rho[1:] == pytest.approx([0.9, 0.81, 0.729], abs=0.02)


def test_report_flags_correlation_and_counts_runs_instead():
    """White noise: eq. (40)-(41) apply. A 10-sample moving average of it (same variance, rho(1) = 0.9): not
    independent, so the proposal comes from the criterion's run rate, extrapolated; where the data reach the
    target rate (0.5 per hour here, 22 h of samples) it lands within 10% of the level read off directly, above it
    (the log-linear tail is conservative for a Gaussian process, whose rate falls as exp(-Z^2))."""
    rng = np.random.default_rng(3)
    white = rng.normal(size=100_000)
    report = fa.criterion_report([white], 3.0, 0.12, HZ)
    assert report["independent"] and report["method"] == "eq. 40-41"
    assert report["p_single"] == pytest.approx(2 * stats.norm.sf(3.0), rel=0.15)
    ar = np.convolve(rng.normal(size=2_000_000), np.ones(10) / math.sqrt(10), mode="same")
    corr = fa.criterion_report([ar], 3.0, 0.12, HZ, target_per_hour=0.5)
    assert not corr["independent"] and corr["rho_lag1"] == pytest.approx(0.9, abs=0.01) and corr["method"] == "run rate"
    levels = np.linspace(3.0, 6.0, 61)
    rates = np.array([fa.run_rate([ar], z, 3, HZ) for z in levels])
    direct = levels[np.argmax(rates <= -math.log1p(-0.5))]
    assert direct <= corr["proposed_threshold"] <= 1.1 * direct


def test_count_runs_and_bad_input():
    assert fa.count_runs([0, 5, 5, 5, 0, 5, 5, -5, 5, 0], 4.0, 3) == 2
    assert fa.count_runs([0, 5, 5, 0], 4.0, 3) == 0
    with pytest.raises(ValueError, match="NaN"):
        fa.exceedance_probability([1.0, float("nan")], 1.0)
    with pytest.raises(ValueError, match="tail"):
        fa.propose_threshold(np.ones(100), 0.1, HZ, tail="weibull")
    with pytest.raises(ValueError, match="target_per_hour"):
        fa.required_single_probability(0.0, 3, HZ)
