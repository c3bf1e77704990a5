"""qp-no-fault-long's per-episode mean wind (benchmark.random_wind) and the airdata scenarios' registration."""
import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401  (registers the env ids)
from ftcgym.benchmark import metrics
from ftcgym.benchmark.random_wind import RandomMeanWind
from ftcgym.benchmark.scenarios import get_scenario
from ftcgym.task_envs.autopilot import QuadPlaneAutopilotEnv


def test_mean_wind_is_drawn_per_seed_and_reaches_the_plane():
    env = RandomMeanWind(gym.make("ftcgym/QuadPlaneAutopilot-v0", max_episode_seconds=1.0), (0.0, 9.0))
    winds = {}
    for seed in (1, 2, 3, 1):
        _, info = env.reset(seed=seed)
        plane = env.unwrapped.plane
        assert np.allclose(plane.wind.mean, info["mean_wind"]) and info["mean_wind"][2] == 0.0
        assert 0.0 <= np.hypot(*info["mean_wind"][:2]) <= 9.0
        winds.setdefault(seed, []).append(info["mean_wind"])
    assert winds[1][0] == winds[1][1] and winds[1][0] != winds[2][0] != winds[3][0]   # the seed fixes the wind
    env.close()
    with pytest.raises(ValueError, match="speed_range"):
        RandomMeanWind(gym.make("ftcgym/QuadPlaneAutopilot-v0"), (5.0, 1.0))


def test_the_drawn_wind_keeps_the_envs_turbulence_airspeed():
    """The drawn mean wind keeps the airspeed setting of the env's own wind: the quad-plane's default ("vehicle")
    or the one given, through gym.make's spec or, for an env made without one, from the env itself."""
    env = RandomMeanWind(gym.make("ftcgym/QuadPlaneAutopilot-v0", max_episode_seconds=1.0))
    env.reset(seed=1)
    assert env.unwrapped.plane.wind.follows_vehicle
    env.close()
    mean_setting = {"mean": [0.0, 0.0, 0.0], "turbulence": "light", "airspeed": "mean"}
    made = gym.make("ftcgym/QuadPlaneAutopilot-v0", max_episode_seconds=1.0, wind=mean_setting)
    unmade = QuadPlaneAutopilotEnv(max_episode_seconds=1.0, wind=mean_setting)
    for env in (RandomMeanWind(made), RandomMeanWind(unmade)):
        assert env.airspeed == "mean"
        _, info = env.reset(seed=1)
        wind = env.unwrapped.plane.wind
        assert not wind.follows_vehicle and wind.airspeed == max(np.linalg.norm(info["mean_wind"]), 1.0)
    env.close()


def test_airdata_scenarios_and_isolation_targets():
    for name in ("qp-gnss-fault", "qp-rpm-sensor-fault", "qp-no-fault-long"):
        scenario = get_scenario(name)
        assert scenario.detector == "airdata_ekf" and not scenario.default       # not in `make bench`
    assert get_scenario("qp-no-fault-long").wrappers and "faults" not in get_scenario("qp-no-fault-long").env_kwargs
    assert metrics.isolation_target("gnss", None) == "gnss"
    assert metrics.isolation_target("pusher_rpm_sensor", None) == "pusher_rpm"
