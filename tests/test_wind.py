"""Statistics and API of the Dryden wind model (004 eq. (13)-(14), Sec. 5.1)."""
import math

import numpy as np
import pytest

from ftcgym.models.wind import TURBULENCE_PRESETS, DrydenWind

LIGHT_SIGMAS = np.array([1.1006, 0.6576, 0.4168])
LIGHT_LENGTHS = np.array([65.8567, 19.2356, 2.8])

# Long sample: dt is arbitrary since the discretisation is exact; 0.04 s keeps w's L/V = 0.28 s at
# 7 samples. T = 16,000 s is ~2,400 u correlation times; over 30 seeds the estimators below spread
# (1 sd) by 1.5% (u std), 4% (u correlation time), 0.008 (v autocorrelation), less for v, w std and
# w autocorrelation, so every tolerance is >= 5 sd wide.
DT, AIRSPEED, STEPS = 0.04, 10.0, 400_000


def run(wind, steps):
    return np.array([wind.step() for _ in range(steps)])


def autocorrelation(x):
    """Normalised sample autocorrelation via zero-padded FFT."""
    x = x - x.mean()
    spectrum = np.fft.rfft(x, 2 * len(x))
    acov = np.fft.irfft(spectrum * np.conj(spectrum))[: len(x)]
    return acov / acov[0]


@pytest.fixture(scope="module")
def long_sample():
    wind = DrydenWind(DT, turbulence="light", airspeed=AIRSPEED)
    wind.reset(np.random.default_rng(2024))
    return wind, run(wind, STEPS)


def test_presets_follow_004_and_our_scaling():
    assert TURBULENCE_PRESETS["light"]["sigmas"] == tuple(LIGHT_SIGMAS)
    assert TURBULENCE_PRESETS["light"]["lengths"] == tuple(LIGHT_LENGTHS)
    assert TURBULENCE_PRESETS["none"]["sigmas"] == (0.0, 0.0, 0.0)
    for name, factor in (("moderate", 2.0), ("severe", 4.0)):
        np.testing.assert_allclose(TURBULENCE_PRESETS[name]["sigmas"], factor * LIGHT_SIGMAS, rtol=1e-15)
        assert TURBULENCE_PRESETS[name]["lengths"] == tuple(LIGHT_LENGTHS)


def test_std_matches_sigmas(long_sample):
    wind, y = long_sample
    # Zero mean wind: u north, v east, w down.
    ratio = y.std(axis=0) / wind.sigmas
    np.testing.assert_allclose(ratio, 1.0, atol=0.10)


def test_u_correlation_time_is_L_over_V(long_sample):
    wind, y = long_sample
    rho = autocorrelation(y[:, 0])
    k = int(np.argmax(rho < math.exp(-1)))           # first lag below 1/e
    crossing = DT * (k - 1 + (rho[k - 1] - math.exp(-1)) / (rho[k - 1] - rho[k]))
    expected = LIGHT_LENGTHS[0] / AIRSPEED
    assert abs(crossing / expected - 1.0) < 0.20


@pytest.mark.parametrize("axis", [1, 2])
def test_lateral_autocorrelation_at_L_over_V(long_sample, axis):
    wind, y = long_sample
    rho = autocorrelation(y[:, axis])
    tau = LIGHT_LENGTHS[axis] / AIRSPEED
    lags = DT * np.arange(len(rho))
    measured = np.interp(tau, lags, rho)
    # Dryden: R(tau) / sigma^2 = (1 - V tau / (2 L)) exp(-V tau / L) = 0.5 / e at tau = L / V.
    assert abs(measured - 0.5 / math.e) < 0.05
    # and it decays: at 4 L/V the analytic value is -exp(-4) ~ -0.018.
    assert abs(np.interp(4 * tau, lags, rho) + math.exp(-4)) < 0.05


def test_stationary_start_has_full_variance():
    # Many fresh resets: the initial wind is already distributed with variance sigma^2 (no transient
    # from zero). 20,000 draws: sd of the std ratio ~0.5%, tolerance 3%.
    wind = DrydenWind(0.002, turbulence="light")  # default airspeed 1 m/s: L/V up to 66 s
    rng = np.random.default_rng(7)
    first = np.array([wind.reset(rng) for _ in range(20_000)])
    np.testing.assert_allclose(first.std(axis=0) / LIGHT_SIGMAS, 1.0, atol=0.03)
    np.testing.assert_allclose(first.mean(axis=0) / LIGHT_SIGMAS, 0.0, atol=0.03)


def test_mean_and_alignment_with_mean_wind():
    # Airspeed 50 m/s: L_u/V = 1.3 s, so over 10,000 s the sd of the u-mean estimate is
    # sigma_u sqrt(2 tau / T) ~ 0.018 m/s; tolerance 0.1 m/s.
    wind = DrydenWind(0.05, mean=(1.0, -1.0, 0.0), turbulence="light", airspeed=50.0)
    wind.reset(np.random.default_rng(11))
    y = run(wind, 200_000)
    np.testing.assert_allclose(y.mean(axis=0), [1.0, -1.0, 0.0], atol=0.1)
    # u lies along the mean wind's horizontal direction, v perpendicular to it, w down.
    e_u = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
    e_v = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    gust = y - wind.mean
    measured = np.array([(gust @ e_u).std(), (gust @ e_v).std(), gust[:, 2].std()])
    np.testing.assert_allclose(measured / LIGHT_SIGMAS, 1.0, atol=0.10)


def test_same_seed_same_sequence_different_seed_differs():
    def sequence(seed):
        wind = DrydenWind(0.002, mean=(2.0, 0.5, 0.0), turbulence="moderate")
        first = wind.reset(np.random.default_rng(seed))
        return np.vstack([first, run(wind, 3000)])   # crosses noise-block boundaries

    a, b, c = sequence(42), sequence(42), sequence(43)
    assert np.array_equal(a, b)
    assert not np.any(np.all(a == c, axis=1))


def test_reset_restarts_the_sequence():
    wind = DrydenWind(0.002, turbulence="light")
    wind.reset(np.random.default_rng(5))
    first = run(wind, 1500)
    wind.reset(np.random.default_rng(5))
    assert np.array_equal(run(wind, 1500), first)


def test_no_turbulence_is_exactly_the_mean_and_draws_nothing():
    wind = DrydenWind.from_config({"mean": (1.0, -1.0, 0.0), "turbulence": "none"}, dt=0.002)
    rng = np.random.default_rng(3)
    before = rng.bit_generator.state
    assert np.array_equal(wind.reset(rng), [1.0, -1.0, 0.0])
    y = run(wind, 100)
    assert np.array_equal(y, np.tile([1.0, -1.0, 0.0], (100, 1)))
    assert np.array_equal(wind.velocity, [1.0, -1.0, 0.0])
    assert rng.bit_generator.state == before


def test_zero_sigma_component_is_exactly_zero():
    wind = DrydenWind(0.002, turbulence={"sigmas": (1.0, 0.0, 0.5), "lengths": (10.0, 10.0, 3.0)})
    wind.reset(np.random.default_rng(0))
    y = run(wind, 2000)
    assert np.all(y[:, 1] == 0.0)          # zero mean: v is east
    assert y[:, 0].std() > 0.1 and y[:, 2].std() > 0.1


def test_from_config_defaults_and_velocity():
    for config in (None, {}):
        wind = DrydenWind.from_config(config, dt=0.002)
        assert np.array_equal(wind.mean, np.zeros(3)) and np.array_equal(wind.sigmas, np.zeros(3))
        assert wind.airspeed == 1.0 and wind.dt == 0.002
    wind = DrydenWind.from_config({"mean": (3.0, 4.0, 0.0), "turbulence": "severe"}, dt=0.01)
    assert wind.airspeed == 5.0                      # |mean| above the 1 m/s floor
    assert DrydenWind(0.01, airspeed=12.0).airspeed == 12.0
    wind.reset(np.random.default_rng(1))
    v = wind.step()
    assert v.shape == (3,) and v.dtype == np.float64
    assert np.array_equal(wind.velocity, v)
    v[:] = 0.0                                       # the returned array is the caller's
    assert not np.array_equal(wind.velocity, v)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"turbulence": "gale"}, "turbulence"),
        ({"turbulence": {"sigmas": (1.0, -0.1, 0.0), "lengths": (1.0, 1.0, 1.0)}}, "sigmas"),
        ({"turbulence": {"sigmas": (1.0, 1.0, 1.0), "lengths": (1.0, 0.0, 1.0)}}, "lengths"),
        ({"turbulence": {"sigmas": (1.0, 1.0, 1.0)}}, "turbulence"),
        ({"mean": (1.0, 2.0)}, "mean"),
        ({"mean": (1.0, float("nan"), 0.0)}, "mean"),
        ({"airspeed": 0.0}, "airspeed"),
        ({"dt": 0.0}, "dt"),
        ({"dt": -0.01}, "dt"),
    ],
)
def test_bad_input_names_the_field(kwargs, field):
    kwargs = {"dt": 0.002, **kwargs}
    with pytest.raises(ValueError, match=field):
        DrydenWind(**kwargs)


def test_unknown_config_key_is_named_with_accepted_keys():
    with pytest.raises(ValueError, match="gusts") as info:
        DrydenWind.from_config({"mean": (0.0, 0.0, 0.0), "gusts": 3}, dt=0.002)
    for key in ("mean", "turbulence", "airspeed"):
        assert key in str(info.value)


def test_unknown_preset_lists_presets():
    with pytest.raises(ValueError, match="gale") as info:
        DrydenWind.from_config({"turbulence": "gale"}, dt=0.002)
    for name in TURBULENCE_PRESETS:
        assert name in str(info.value)


# `airspeed="vehicle"`: the filters per metre flown, V_a from the vehicle's speed through the mean wind.

def followed(wind, speeds, steps_each):
    """Winds of a `follow`ing wind: `steps_each` steps at each speed (the vehicle flies along north)."""
    out = []
    for speed in speeds:
        wind.follow((speed + wind.mean[0], wind.mean[1], wind.mean[2]), steps_each)
        out.extend(wind.advance() for _ in range(steps_each))
    return np.array(out)


@pytest.mark.parametrize("speed, mean", [(0.4, (0.0, 0.0, 0.0)), (5.0, (3.0, 4.0, 0.0)), (18.0, (0.0, 0.0, 0.0))])
def test_following_a_steady_speed_gives_the_fixed_filters_winds(speed, mean):
    fixed = DrydenWind(0.002, mean=mean, turbulence="light", airspeed=max(speed, 1.0))
    follows = DrydenWind(0.002, mean=mean, turbulence="light", airspeed="vehicle")
    fixed.reset(np.random.default_rng(3))
    follows.reset(np.random.default_rng(3))
    # agent steps of 5 physics steps across noise blocks; the speed through the mean wind stays `speed` (0.4: the
    # 1 m/s floor)
    winds = followed(follows, [speed] * 700, 5)
    assert follows.airspeed == pytest.approx(max(speed, 1.0), abs=1e-12)
    np.testing.assert_allclose(winds, run(fixed, 3500), rtol=0, atol=1e-11)   # the same winds to rounding


def test_a_change_of_speed_keeps_sigma_and_scales_the_correlation_time():
    wind = DrydenWind(DT, turbulence="light", airspeed="vehicle")
    wind.reset(np.random.default_rng(2025))
    for speed in (10.0, 40.0):
        y = followed(wind, [speed] * 200, 1000)
        np.testing.assert_allclose(y.std(axis=0) / wind.sigmas, 1.0, atol=0.10)
        rho = autocorrelation(y[:, 0])
        k = int(np.argmax(rho < math.exp(-1)))
        assert abs(DT * k / (LIGHT_LENGTHS[0] / speed) - 1.0) < 0.25


def test_the_gust_at_a_change_of_speed_has_sigma():
    # The state per metre flown is stationary at any speed: no jump in variance when V_a goes from 1 to 30 m/s
    # (the time-domain filter's state, kept across the change, would give sqrt(30) sigma). 4,000 resets: sd of
    # the std ratio ~1.1%, tolerance 5%.
    wind = DrydenWind(0.002, turbulence="light", airspeed="vehicle")
    rng = np.random.default_rng(11)
    after = []
    for _ in range(4000):
        wind.reset(rng)
        followed(wind, [0.0], 1)
        after.append(followed(wind, [30.0], 2)[-1])
    np.testing.assert_allclose(np.std(after, axis=0) / LIGHT_SIGMAS, 1.0, atol=0.05)


def test_follow_floors_rounds_and_belongs_to_a_following_wind():
    wind = DrydenWind(0.002, mean=(0.3, 0.0, 0.0), turbulence="light", airspeed="vehicle")
    assert wind.follows_vehicle and wind.airspeed == 1.0          # before any follow: |mean| at least 1 m/s
    wind.reset(np.random.default_rng(0))
    wind.follow((0.0, 0.0, 0.0), 1)
    assert wind.airspeed == 1.0
    wind.follow((18.34, 0.0, 4.0), 1)                              # |(18.04, 0, 4)| = 18.478
    assert wind.airspeed == pytest.approx(18.5, abs=1e-12)
    with pytest.raises(RuntimeError, match="vehicle"):
        DrydenWind(0.002, turbulence="light").follow((0.0, 0.0, 0.0), 1)
    with pytest.raises(ValueError, match="airspeed") as info:
        DrydenWind(0.002, airspeed="cruise")
    assert "'vehicle'" in str(info.value)


def test_each_vehicle_has_its_default_airspeed_and_mean_names_the_other():
    """The quadrotor's turbulence takes the mean wind's speed unless told, the quad-plane's follows the vehicle;
    `airspeed="mean"` gives the quadrotor's on the quad-plane, also in a reset's own wind."""
    import gymnasium as gym

    import ftcgym  # noqa: F401  (registers the env ids)
    light = {"mean": [3.0, 4.0, 0.0], "turbulence": "light"}
    quadrotor, quadplane = gym.make("ftcgym/Quadrotor-v0", wind=light), gym.make("ftcgym/QuadPlane-v0", wind=light)
    assert quadrotor.unwrapped.wind.airspeed_setting == "mean" and not quadrotor.unwrapped.wind.follows_vehicle
    assert quadrotor.unwrapped.wind.airspeed == 5.0
    assert quadplane.unwrapped.wind.airspeed_setting == "vehicle" and quadplane.unwrapped.wind.follows_vehicle
    quadplane.reset(seed=0, options={"wind": {**light, "airspeed": "mean"}})
    assert not quadplane.unwrapped.wind.follows_vehicle and quadplane.unwrapped.wind.airspeed == 5.0
    quadplane.reset(seed=0, options={"wind": {**light, "airspeed": None}})
    assert quadplane.unwrapped.wind.follows_vehicle
    with pytest.raises(ValueError, match="'mean'"):
        gym.make("ftcgym/QuadPlane-v0", wind={**light, "airspeed": "average"})
    quadrotor.close()
    quadplane.close()


def test_an_agent_step_longer_than_a_noise_block_is_filtered_at_its_own_speed():
    """follow(v, steps) with steps > 1,024 (a noise block): the winds of one call all at its V_a. The first version
    refilled one block per call, so winds of the old V_a leaked into the next call, more with each."""
    def winds(chunk):
        wind = DrydenWind(0.002, turbulence="light", airspeed="vehicle")
        wind.reset(np.random.default_rng(9))
        return followed(wind, [v for v in (3.0, 25.0, 8.0) for _ in range(2000 // chunk)], chunk)
    np.testing.assert_allclose(winds(2000), winds(500), rtol=0, atol=1e-11)


def test_each_episode_starts_at_the_mean_winds_rounded_airspeed():
    wind = DrydenWind(0.002, mean=(3.0, 4.04, 0.0), turbulence="light", airspeed="vehicle")
    assert wind.airspeed == 5.0                                  # |mean| = 5.028, rounded to 0.1 m/s
    wind.reset(np.random.default_rng(0))
    followed(wind, [20.0], 5)
    assert wind.airspeed == 20.0
    wind.reset(np.random.default_rng(0))                         # not the last episode's 20 m/s
    assert wind.airspeed == 5.0
