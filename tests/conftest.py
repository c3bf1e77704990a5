"""Shared helpers: make the quadrotor env and fly it with a policy."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401  (registers the env ids)
from ftcgym.agents import make_policy

LIGHT_WIND = {"mean": [1.0, -1.0, 0.0], "turbulence": "light"}


def make_env(**kwargs):
    return gym.make("ftcgym/Quadrotor-v0", **kwargs)


def fly(env, seed: int, policy: str = "nominal"):
    """One episode with a benchmark policy; returns (truth positions, reference positions, last info)."""
    obs, info = env.reset(seed=seed)
    pol = make_policy(policy, env)
    pol.reset(obs, info)
    truth, ref = [], []
    while True:
        obs, _, terminated, truncated, info = env.step(pol.act(obs, info))
        truth.append(info["truth"]["position"])
        ref.append(info["reference"]["position"])
        if terminated or truncated:
            return np.array(truth), np.array(ref), info


def hover_command(params, omega=None) -> float:
    omega = params.hover_omega if omega is None else omega
    return (omega - params.omega_min) / (params.omega_max - params.omega_min)


@pytest.fixture
def quiet_sensors():
    """Sensor settings without noise, bias or vibration, for crisp physics checks."""
    return {k: 0.0 for k in ("gyro_noise", "accel_noise", "gyro_bias", "accel_bias", "gyro_vibration",
                             "accel_vibration", "rotor_speed_noise", "attitude_noise", "position_noise",
                             "velocity_noise")}
