"""Nominal controller acceptance: hover accuracy, the square task, and that a rotor loss matters."""
import numpy as np
import pytest
from conftest import LIGHT_WIND, fly, make_env


def _rms(truth, ref, skip_s=1.0, hz=500):
    e = (truth - ref)[int(skip_s * hz):]
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))


def test_hover_without_wind_under_5_cm():
    truth, ref, info = fly(make_env(max_episode_seconds=30), seed=11)
    assert not info["crashed"] and info["time"] == 30.0
    assert _rms(truth, ref) < 0.05


def test_hover_in_light_turbulence_with_mean_wind_under_30_cm():
    truth, ref, info = fly(make_env(max_episode_seconds=30, wind=LIGHT_WIND), seed=12)
    assert not info["crashed"]
    assert _rms(truth, ref) < 0.30


@pytest.mark.parametrize("seed", range(10))
def test_square_task_without_crash(seed):
    """004 Sec. 5.1 square (8 m, 8 m altitude, speed excitation) in light turbulence: one lap and a half."""
    truth, ref, info = fly(make_env(task="square", max_episode_seconds=45, wind=LIGHT_WIND), seed=100 + seed)
    assert not info["crashed"] and info["time"] == 45.0
    assert _rms(truth, ref) < 1.0
    assert np.ptp(truth[:, 0]) > 7.0 and np.ptp(truth[:, 1]) > 7.0  # it really flew the square


def test_rotor_loss_crashes_the_nominal_controller():
    """The fault matters: without recovery a propeller loss ends in a crash in at least 9 of 10 seeds."""
    crashes = 0
    for seed in range(10):
        _, _, info = fly(make_env(faults="random:rotor_loss", max_episode_seconds=10, wind=LIGHT_WIND), seed=200 + seed)
        crashes += info["crashed"]
    assert crashes >= 9


@pytest.mark.parametrize("vehicle, payload", [("mueller2014", 0.5), ("bebop2", 0.3)])
def test_the_integral_trims_out_a_payload_the_rotors_can_lift(vehicle, payload):
    """Ho et al.'s payload (Mueller's 0.5 kg doubled at 2-4 s) and 80% more on the Bebop 2: back within 10 cm of
    the set-point 12 s after the payload is on. A 2 m/s^2 vertical integral limit left them 3.9 m and 2.9 m low
    (seed 13)."""
    faults = [{"kind": "payload", "time": 2.0, "magnitude": payload, "duration": 2.0}]
    truth, ref, info = fly(make_env(vehicle=vehicle, faults=faults, max_episode_seconds=16), seed=13)
    assert not info["crashed"] and info["time"] == 16.0
    assert np.abs(truth[-500:, 2] - ref[-500:, 2]).max() < 0.10     # the last second
