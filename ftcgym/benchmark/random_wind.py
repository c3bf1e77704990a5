"""A wrapper that gives every episode its own mean wind, for fault-free hours in varied wind.

The env's `wind` kwarg is one fixed mean; `qp-no-fault-long` wants many flights in different winds to count
false alarms. `RandomMeanWind` passes each reset the option `wind` with a mean of uniform speed in
`speed_range` m/s from a uniform direction (horizontal), the given turbulence and the `airspeed` of the env's own
`wind` kwarg (for example "mean"; `models/wind.py`), if it has one, else the vehicle's default (the quad-plane's:
"vehicle"). The draw comes from a
generator seeded by the reset seed (SeedSequence([seed, WIND_STREAM])), so an episode seed fixes its wind as
it fixes everything else; without a seed it comes from the wrapper's own generator.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from ftcgym.models.wind import random_mean_wind

WIND_STREAM = 6006          # separates the wind draw from the env's own stream for the same seed


class RandomMeanWind(gym.Wrapper):
    """Draw the mean wind (speed uniform in `speed_range`, direction uniform) at each reset."""

    def __init__(self, env: gym.Env, speed_range=(0.0, 9.0), turbulence="light"):
        super().__init__(env)
        low, high = (float(v) for v in speed_range)
        if not (0.0 <= low <= high):
            raise ValueError(f"speed_range: need 0 <= low <= high, got {speed_range!r}")
        self.speed_range, self.turbulence = (low, high), turbulence
        self.airspeed = _configured_airspeed(env)
        self.mean_wind = None
        self._rng = np.random.default_rng()

    def reset(self, *, seed=None, options=None):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), WIND_STREAM])) if seed is not None else self._rng
        self.mean_wind = random_mean_wind(rng, self.speed_range)
        wind = {"mean": self.mean_wind, "turbulence": self.turbulence}
        if self.airspeed is not None:
            wind["airspeed"] = self.airspeed
        obs, info = self.env.reset(seed=seed, options={**(options or {}), "wind": wind})
        return obs, {**info, "mean_wind": list(self.mean_wind)}


def _configured_airspeed(env: gym.Env):
    """The `airspeed` of the env's own `wind`: as gym.make was given it (None: the vehicle's default), else (an
    env made otherwise, or a wrapper whose spec gymnasium could not copy) its configured wind's setting."""
    if env.spec is not None:
        return (env.spec.kwargs.get("wind") or {}).get("airspeed")
    flight = env.unwrapped
    flight = getattr(flight, "plane", flight)          # QuadPlaneAutopilot-v0 flies a QuadPlane-v0
    wind = getattr(flight, "wind", None)
    return getattr(wind, "airspeed_setting", None)


def random_mean_wind_wrapper(env: gym.Env) -> gym.Env:
    """`env` with a mean wind of 0-9 m/s from a random direction and light turbulence per episode."""
    return RandomMeanWind(env)
