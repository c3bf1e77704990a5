"""A wrapper that gives every quad-plane episode its own mean wind, for fault-free hours in varied wind.

The env's `wind` kwarg is one fixed mean; `qp-no-fault-long` (issue 6) wants many flights in different winds
to count false alarms. `RandomMeanWind` replaces the quad-plane's wind model before each reset with a mean of
uniform speed in `speed_range` m/s from a uniform direction (horizontal), with the given turbulence. The draw
comes from a generator seeded by the reset seed (SeedSequence([seed, WIND_STREAM])), so an episode seed
fixes its wind as it fixes everything else; without a seed it comes from the env's own np_random.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from ftcgym.envs.wind import DrydenWind

WIND_STREAM = 6006          # separates the wind draw from the env's own stream for the same seed


class RandomMeanWind(gym.Wrapper):
    """Draw the mean wind (speed uniform in `speed_range`, direction uniform) at each reset."""

    def __init__(self, env: gym.Env, speed_range=(0.0, 9.0), turbulence="light"):
        super().__init__(env)
        low, high = (float(v) for v in speed_range)
        if not (0.0 <= low <= high):
            raise ValueError(f"speed_range: need 0 <= low <= high, got {speed_range!r}")
        self.speed_range, self.turbulence = (low, high), turbulence
        self.mean_wind = None

    def reset(self, *, seed=None, options=None):
        plane = getattr(self.env.unwrapped, "plane", self.env.unwrapped)   # QuadPlaneAutopilot-v0 holds one
        rng = (np.random.default_rng(np.random.SeedSequence([int(seed), WIND_STREAM])) if seed is not None
               else plane.np_random)
        speed, direction = rng.uniform(*self.speed_range), rng.uniform(0.0, 2.0 * np.pi)
        self.mean_wind = [float(speed * np.cos(direction)), float(speed * np.sin(direction)), 0.0]
        plane.wind = DrydenWind.from_config({"mean": self.mean_wind, "turbulence": self.turbulence}, plane.dt)
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, "mean_wind": list(self.mean_wind)}


def random_mean_wind(env: gym.Env) -> gym.Env:
    """`env` with a mean wind of 0-9 m/s from a random direction and light turbulence per episode."""
    return RandomMeanWind(env)
