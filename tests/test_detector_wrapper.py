"""DetectorWrapper's per-step contract: a new observation dict holding the env's own arrays and the detector's
outputs, the env's `info` with `info["fdd"]` keeping the entries of inner detector wrappers, and outputs that later
steps leave unchanged."""
import gymnasium as gym
import numpy as np
import pytest
from conftest import LIGHT_WIND, make_env

from ftcgym.fdd import wrap_with_detector


class _Spy(gym.Wrapper):
    """Keeps the last (obs, reward, terminated, truncated, info) of the env it wraps."""

    def step(self, action):
        self.last = self.env.step(action)
        return self.last


def test_stacked_wrappers_pass_the_env_arrays_and_keep_each_status():
    spy = _Spy(make_env(wind=LIGHT_WIND))
    env = wrap_with_detector("loe_kalman", wrap_with_detector("loe_cusum", spy))
    obs, info = env.reset(seed=5)
    assert set(info["fdd"]) == {"loe_cusum", "loe_kalman"} and env.observation_space.contains(obs)
    hover = np.full(4, 0.5, dtype=np.float32)
    published = []
    for _ in range(50):
        obs, _, _, _, info = env.step(hover)
        env_obs, env_info = spy.last[0], spy.last[4]
        assert obs is not env_obs and all(obs[key] is value for key, value in env_obs.items())
        assert info is env_info and set(info["fdd"]) == {"loe_cusum", "loe_kalman"}
        assert info["fdd"]["loe_kalman"] == env.detector.status()
        published.append((obs, {key: obs[key].copy() for key in obs if key.startswith("fdd/")}))
    assert set(obs) == set(env.observation_space.spaces) and env.observation_space.contains(obs)
    for obs, copies in published:                               # no output array was reused or changed in place
        assert all(np.array_equal(obs[key], value) for key, value in copies.items())


def _readings_of(env_id: str) -> dict:
    env = gym.make(env_id)
    obs, _ = env.reset(seed=0)
    env.close()
    return obs


@pytest.mark.parametrize("name, env_id", [("loe_kalman", "ftcgym/Quadrotor-v0"), ("loe_cusum", "ftcgym/Quadrotor-v0"),
                                          ("aekf", "ftcgym/Quadrotor-v0"), ("iv_change", "ftcgym/Quadrotor-v0"),
                                          ("airdata_ekf", "ftcgym/QuadPlaneAutopilot-v0"),
                                          ("propulsion_bayes", "ftcgym/QuadPlaneAutopilot-v0")])
def test_a_detector_fed_by_hand_refuses_a_time_of_nan(name, env_id):
    detector = wrap_with_detector(name, gym.make(env_id)).detector
    with pytest.raises(ValueError, match=r"(time must be a finite number of seconds|must be finite)"):
        detector.update(_readings_of(env_id), float("nan"))
    assert not detector.status()["alarm"]


@pytest.mark.parametrize("name", ["loe_kalman", "loe_cusum", "propulsion_bayes"])
def test_a_detector_fed_by_hand_names_a_missing_reading(name):

    env_id = "ftcgym/QuadPlaneAutopilot-v0" if name == "propulsion_bayes" else "ftcgym/Quadrotor-v0"
    detector = wrap_with_detector(name, gym.make(env_id)).detector
    readings = _readings_of(env_id)
    readings.pop("pusher_current" if name == "propulsion_bayes" else "gyro")
    with pytest.raises(ValueError, match=rf"{name}: readings: missing \['(gyro|pusher_current)'\]; it reads"):
        detector.update(readings, 0.0)


def test_airdata_ekf_refuses_a_nan_height_before_take_off():
    detector = wrap_with_detector("airdata_ekf", gym.make("ftcgym/QuadPlaneAutopilot-v0")).detector
    readings = _readings_of("ftcgym/QuadPlaneAutopilot-v0")
    readings["position"] = np.array([0.0, 0.0, np.nan])
    with pytest.raises(ValueError, match="airdata_ekf: reading 'position' is not finite"):
        detector.update(readings, 0.0)
