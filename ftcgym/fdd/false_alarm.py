"""False-detection probability of a threshold criterion, and thresholds for a false-alarm budget.

001 (Larocque 2023) Sec. 6.1: a criterion "|s| >= Z for T" on a signal sampled at f (the EKF rate) fires
on n = ceil(f T) consecutive samples above Z. With p_single = P(|s| >= Z) for one sample and samples
assumed independent,

    p_seq    = p_single ** (f T)                        (eq. 40, with f T rounded up to n samples)
    p_flight = 1 - (1 - p_seq) ** (T_flight f)          (eq. 41)

is the probability of at least one false detection in a flight of T_flight s. 001 keeps p_flight per flight
hour below 0.1% (1e-3) and checks independence with the autocorrelation of the fault-free signal (Fig. 4):
eq. (41) only holds where it is small.

`propose_threshold` inverts eq. (40)-(41): from the target rate it gets the p_single the criterion may have,
and reads Z off the fault-free distribution of |s|. That p_single is usually far out in the tail (1e-3 per
hour, n = 3 at 25 Hz: p_single = 2.2e-3; n = 1: 1.1e-8), beyond what a few flight hours sample, so the tail is
either read from the data ("empirical", only where >= `MIN_TAIL_SAMPLES` samples lie beyond Z), fitted with a
zero-mean Gaussian ("gaussian", the closed form for white Gaussian noise) or extrapolated with an exponential
peaks-over-threshold fit ("exponential": P(|s| >= z) = p_u exp(-(z - u) / beta) above the 99th percentile u,
beta the mean excess; conservative for Gaussian tails). "auto" takes the empirical tail where it is sampled
well enough, else the exponential one.

For a signal whose samples are correlated (the low-passed residual, a CUSUM statistic), eq. (40)-(41)'s
independence does not hold (001 says so of its residual, and hand-tunes that threshold). The report then
counts the criterion's alarms directly: `run_rate` is how many times per flight hour |s| stayed >= Z for n
samples (each run once: the alarms of a criterion re-armed after each), and `run_rate_threshold` extrapolates
that rate's exponential tail (log-linear in Z, fitted on the levels with >= MIN_RUNS runs, as the level
up-crossing rate of a stationary process decays) to the level where it meets the target.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

SECONDS_PER_HOUR = 3600.0
MIN_TAIL_SAMPLES = 20          # empirical tail only where this many samples lie beyond the threshold
TAIL_QUANTILE = 0.99           # exponential fit above this quantile of |s|
TAILS = ("auto", "empirical", "gaussian", "exponential")
MIN_RUNS = 5                   # run-rate fit: levels with at least this many runs


def sequence_length(hold_time: float, sample_hz: float) -> int:
    """n = ceil(f T), at least 1: the consecutive samples a criterion "for T" needs (eq. 40)."""
    if not (hold_time >= 0 and sample_hz > 0):
        raise ValueError(f"hold_time {hold_time!r} must be >= 0 and sample_hz {sample_hz!r} > 0")
    return max(1, math.ceil(sample_hz * hold_time - 1e-9))


def sequence_probability(p_single: float, n: int) -> float:
    """eq. (40): p_seq = p_single ** n."""
    return float(p_single) ** int(n)


def flight_probability(p_seq: float, flight_seconds: float, sample_hz: float, bound: bool = False) -> float:
    """eq. (41): 1 - (1 - p_seq) ** (T_flight f); with `bound`, the union bound T_flight f p_seq (any correlation)."""
    trials = flight_seconds * sample_hz
    if bound:
        return float(trials * p_seq)
    return float(-math.expm1(trials * math.log1p(-min(p_seq, 1.0 - 1e-16))))


def required_single_probability(target_per_hour: float, n: int, sample_hz: float, bound: bool = False) -> float:
    """The largest p_single for which eq. (40)-(41) keep one flight hour's false detection <= the target."""
    if not (0.0 < target_per_hour < 1.0):
        raise ValueError(f"target_per_hour {target_per_hour!r} must lie in (0, 1)")
    trials = SECONDS_PER_HOUR * sample_hz
    p_seq = target_per_hour / trials if bound else -math.expm1(math.log1p(-target_per_hour) / trials)
    return p_seq ** (1.0 / n)


def _magnitudes(samples) -> np.ndarray:
    values = np.abs(np.asarray(samples, dtype=float).reshape(-1))
    if values.size == 0:
        raise ValueError("false_alarm: no samples")
    if not np.all(np.isfinite(values)):
        raise ValueError("false_alarm: samples contain NaN or infinity")
    return values


def exceedance_probability(samples, threshold: float, tail: str = "auto") -> float:
    """p_single = P(|s| >= threshold) from fault-free samples, with the tail model `tail` (see module doc)."""
    values = _magnitudes(samples)
    tail = _pick_tail(values, tail, np.count_nonzero(values >= threshold))
    if tail == "empirical":
        return float(np.mean(values >= threshold))
    if tail == "gaussian":
        sigma = float(np.sqrt(np.mean(values ** 2)))
        return float(2.0 * stats.norm.sf(threshold / sigma))
    u, beta, p_u = _exponential_tail(values)
    if threshold <= u:
        return float(np.mean(values >= threshold))
    return float(p_u * math.exp(-(threshold - u) / beta))


def propose_threshold(samples, hold_time: float, sample_hz: float, target_per_hour: float = 1e-3,
                      tail: str = "auto", bound: bool = False) -> float:
    """The lowest Z for which "|s| >= Z for hold_time" keeps eq. (41)'s false detection per flight hour at or
    below `target_per_hour` (001 Sec. 6.1: 0.1%), |s| distributed as the fault-free `samples`."""
    values = _magnitudes(samples)
    p = required_single_probability(target_per_hour, sequence_length(hold_time, sample_hz), sample_hz, bound)
    tail = _pick_tail(values, tail, p * values.size)
    if tail == "empirical":
        return float(np.quantile(values, 1.0 - p))
    if tail == "gaussian":
        return float(np.sqrt(np.mean(values ** 2)) * stats.norm.isf(p / 2.0))
    u, beta, p_u = _exponential_tail(values)
    return float(np.quantile(values, 1.0 - p)) if p >= p_u else float(u + beta * math.log(p_u / p))


def _pick_tail(values: np.ndarray, tail: str, tail_count: float) -> str:
    if tail not in TAILS:
        raise ValueError(f"tail: {tail!r}; accepted: {list(TAILS)}")
    if tail != "auto":
        return tail
    if tail_count >= MIN_TAIL_SAMPLES:
        return "empirical"
    # no tail to fit (e.g. a one-sided signal that is almost always 0): the data are all there is
    u = np.quantile(values, TAIL_QUANTILE)
    return "exponential" if np.count_nonzero(values > u) >= MIN_TAIL_SAMPLES else "empirical"


def _exponential_tail(values: np.ndarray) -> tuple[float, float, float]:
    """(u, beta, p_u): threshold u = the TAIL_QUANTILE of |s|, beta = mean excess over u, p_u = P(|s| >= u)."""
    u = float(np.quantile(values, TAIL_QUANTILE))
    excess = values[values > u] - u
    if excess.size < MIN_TAIL_SAMPLES:
        raise ValueError(f"false_alarm: {excess.size} samples above the {TAIL_QUANTILE} quantile; "
                         f"need {MIN_TAIL_SAMPLES} for the exponential tail")
    return u, float(excess.mean()), float(np.mean(values >= u))


def autocorrelation(segments, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation rho(0..max_lag) (001 Fig. 4) pooled over `segments` (one array per flight,
    so no lag spans two flights): sum of lagged products of the de-meaned samples over the sum of squares."""
    segments = [np.asarray(s, dtype=float).reshape(-1) for s in segments]
    if not segments or any(not np.all(np.isfinite(s)) for s in segments):
        raise ValueError("autocorrelation: need segments of finite samples")
    mean = np.concatenate(segments).mean()
    num, den = np.zeros(max_lag + 1), 0.0
    for s in segments:
        d = s - mean
        den += float(d @ d)
        for lag in range(min(max_lag, d.size - 1) + 1):
            num[lag] += float(d[lag:] @ d[:d.size - lag])
    if den <= 0:
        raise ValueError("autocorrelation: the samples are constant")
    return num / den


def criterion_report(segments, threshold: float, hold_time: float, sample_hz: float,
                     target_per_hour: float = 1e-3, tail: str = "auto", max_lag: int = 25,
                     correlation_limit: float = 0.2) -> dict:
    """One criterion's statistics on fault-free `segments` (one array per flight): p_single at `threshold`,
    p_seq (eq. 40), p_flight per hour (eq. 41), rho(1..max_lag) (Fig. 4), whether |rho| <= `correlation_limit`
    from lag 1 (eq. 41 usable), the runs of >= n samples above `threshold` seen, and the proposed threshold
    for `target_per_hour`: eq. (40)-(41) where the samples are independent, else `run_rate_threshold`."""
    values = np.concatenate([np.asarray(s, dtype=float).reshape(-1) for s in segments])
    n = sequence_length(hold_time, sample_hz)
    p_single = exceedance_probability(values, threshold, tail)
    p_seq = sequence_probability(p_single, n)
    if np.ptp(values) == 0.0:       # a constant signal (a one-sided one that never leaves 0): nothing correlates
        rho = np.concatenate([[1.0], np.zeros(max_lag)])
    else:
        rho = autocorrelation(segments, max_lag)
    independent = bool(np.all(np.abs(rho[1:]) <= correlation_limit))
    if independent:
        proposed, method = propose_threshold(values, hold_time, sample_hz, target_per_hour, tail), "eq. 40-41"
    else:
        try:
            proposed, method = run_rate_threshold(segments, n, sample_hz, target_per_hour), "run rate"
        except ValueError:
            proposed, method = None, "run rate: too few runs"
    return {
        "threshold": float(threshold), "hold_time": float(hold_time), "samples_in_sequence": n,
        "samples": int(values.size), "hours": values.size / sample_hz / SECONDS_PER_HOUR,
        "p_single": p_single, "p_seq": p_seq,
        "p_flight_hour": flight_probability(p_seq, SECONDS_PER_HOUR, sample_hz),
        "run_rate_per_hour": run_rate(segments, threshold, n, sample_hz),
        "rho_lag1": float(rho[1]) if max_lag >= 1 else None,
        "max_abs_rho": float(np.max(np.abs(rho[1:]))) if max_lag >= 1 else None,
        "independent": independent,
        "proposed_threshold": proposed, "method": method,
        "runs_seen": sum(count_runs(s, threshold, n) for s in segments),
    }


def run_rate(segments, threshold: float, n: int, sample_hz: float) -> float:
    """Runs of >= n consecutive samples with |s| >= threshold per flight hour of `segments`."""
    hours = sum(np.asarray(s).size for s in segments) / sample_hz / SECONDS_PER_HOUR
    return sum(count_runs(s, threshold, n) for s in segments) / hours


def run_rate_threshold(segments, n: int, sample_hz: float, target_per_hour: float = 1e-3, levels: int = 60) -> float:
    """The level Z at which the criterion's alarm rate (`run_rate`, per hour) meets `target_per_hour`, from a
    log-linear fit of the rate over the levels that still see >= MIN_RUNS runs (the upper half of them)."""
    values = np.concatenate([_magnitudes(s) for s in segments])
    grid = np.linspace(np.quantile(values, 0.5), values.max(), levels)
    rates = np.array([run_rate(segments, z, n, sample_hz) for z in grid])
    hours = values.size / sample_hz / SECONDS_PER_HOUR
    usable = rates * hours >= MIN_RUNS
    if usable.sum() < 4:
        raise ValueError(f"run_rate_threshold: only {int(usable.sum())} levels see {MIN_RUNS} runs; fly more hours")
    z, rate = grid[usable][usable.sum() // 2:], rates[usable][usable.sum() // 2:]
    slope, intercept = np.polyfit(z, np.log(rate), 1)
    if slope >= 0:
        raise ValueError("run_rate_threshold: the run rate does not fall with the level")
    return float((math.log(-math.log1p(-target_per_hour)) - intercept) / slope)


def count_runs(samples, threshold: float, n: int) -> int:
    """How many times |s| >= threshold held for n consecutive samples (each run counted once): the criterion's
    alarms had it been re-armed after each."""
    above = np.abs(np.asarray(samples, dtype=float).reshape(-1)) >= threshold
    edges = np.flatnonzero(np.diff(np.concatenate(([0], above.astype(int), [0]))))
    return int(np.sum(edges[1::2] - edges[::2] >= n))
