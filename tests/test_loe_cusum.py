"""loe_cusum: the CUSUM on 000's angular-acceleration residual with the motor-speed confirmation."""
import numpy as np
import pytest
from conftest import LIGHT_WIND, make_env

from ftcgym.agents import make_policy
from ftcgym.agents.catalogue import rotor_loss_detector
from ftcgym.fdd import DETECTORS, LoeCusumDetector, loe_cusum_wrapper, wrap_with_detector
from ftcgym.fdd.loe_kalman import SIGNS_000
from ftcgym.models.constants import GRAVITY
from ftcgym.models.quadrotor import BEBOP2

DT = 1 / 500
G = tuple(BEBOP2.effectiveness_G.tolist())
B = np.diag(G) @ SIGNS_000
OMEGA = float(np.sqrt(GRAVITY / (G[2] * 4)))          # hover: B[2] omega^2 (1, 1, 1, 1) = -g


def _detector(**kw):
    return LoeCusumDetector(DT, G=G, motor_time_constant=BEBOP2.motor_time_constant, omega_min=BEBOP2.omega_min,
                            omega_max=BEBOP2.omega_max, **kw)


def _synthetic_flight(det, lost=None, onset=200, samples=400, rng=None, noise=(0.0, 0.0, 0.0)):
    """Hover readings; from sample `onset` rotor `lost` gives no thrust (000 eq. 12 with k = 0) and its unloaded
    motor spins up toward 1.3 times the command with a 10 ms lag (as the simulator's bebop2). Returns the first
    alarm's sample index, or None."""
    command = np.full(4, OMEGA / BEBOP2.omega_max)
    omega, rates = np.full(4, OMEGA), np.zeros(3)
    gain_unloaded = 1 - np.exp(-DT / 0.01)
    for k in range(samples):
        k_eff = np.ones(4)
        if lost is not None and k >= onset:
            k_eff[lost] = 0.0
            omega[lost] += gain_unloaded * (1.3 * OMEGA - omega[lost])
        p_dot, q_dot, a_z = B @ (k_eff * omega ** 2)
        rates = rates + DT * np.array([p_dot, q_dot, 0.0])
        readings = {"gyro": rates.copy(), "accel": np.array([0.0, 0.0, a_z]), "rotor_speed": omega.copy()}
        if rng is not None:
            readings = {key: value + rng.normal(0.0, sigma, value.shape)
                        for (key, value), sigma in zip(readings.items(), noise)}
        det.update(readings, k * DT, command)
        if det.status()["alarm"]:
            return k
    return None


@pytest.mark.parametrize("rotor", range(4))
def test_alarm_within_a_few_samples_of_a_synthetic_loss_and_isolates_it(rotor):
    det = _detector()
    k = _synthetic_flight(det, lost=rotor)
    assert k is not None and 200 <= k <= 200 + 8          # within 16 ms at 500 Hz
    assert det.status()["isolated"] == rotor


def test_speed_test_holds_an_angular_alarm_the_motor_does_not_confirm():
    """A thrust loss whose motor stays on its command (no unloading) passes the CUSUM but not the speed test."""
    det = _detector()
    det.update({"gyro": np.zeros(3), "accel": np.array([0.0, 0.0, -GRAVITY]), "rotor_speed": np.full(4, OMEGA)}, 0.0,
               np.full(4, OMEGA / BEBOP2.omega_max))
    rates, command = np.zeros(3), np.full(4, OMEGA / BEBOP2.omega_max)
    for k in range(1, 100):
        p_dot, q_dot, a_z = B @ (np.array([0.0, 1, 1, 1]) * OMEGA ** 2)
        rates = rates + DT * np.array([p_dot, q_dot, 0.0])
        det.update({"gyro": rates.copy(), "accel": np.array([0.0, 0.0, a_z]), "rotor_speed": np.full(4, OMEGA)},
                   k * DT, command)
    assert det.cusum[0] > det.settings.threshold and not det.status()["alarm"]
    assert _synthetic_flight(_detector(speed_test=False), lost=0) is not None


def test_no_alarm_on_sensor_noise_alone():
    """60 s at 500 Hz of the default sensor noise (gyro 0.005 rad/s, accel 0.05 m/s^2, rotor speed 1 rad/s) at
    10 times its level, seeded: the angular CUSUM alone (speed test off) stays far below its threshold."""
    det = _detector(speed_test=False)
    rng = np.random.default_rng(37)
    assert _synthetic_flight(det, samples=30_000, rng=rng, noise=(0.05, 0.5, 10.0)) is None
    assert det.armed and max(det.cusum) < 0.1 * det.settings.threshold


@pytest.mark.parametrize("key, index", [("gyro", 0), ("accel", 2), ("rotor_speed", 3)])  # the elements it reads
def test_nan_reading_is_rejected_naming_it(key, index):
    readings = {"gyro": np.zeros(3), "accel": np.zeros(3), "rotor_speed": np.ones(4)}
    readings[key][index] = np.nan
    with pytest.raises(ValueError, match=key):
        _detector().update(readings, 0.0)
    with pytest.raises(ValueError, match="command"):
        _detector().update({"gyro": np.zeros(3), "accel": np.zeros(3), "rotor_speed": np.ones(4)}, 0.0,
                           np.array([np.nan, 0, 0, 0]))


def test_unknown_setting_is_named():
    with pytest.raises(ValueError, match="threshhold"):
        _detector(threshhold=3.0)


def test_registered_and_spin_policies_read_it():
    assert "loe_cusum" in DETECTORS.names()
    env = wrap_with_detector("loe_cusum", make_env(wind=LIGHT_WIND))
    assert rotor_loss_detector(env) == "loe_cusum" and make_policy("ftc-spin", env).detector == "loe_cusum"
    assert rotor_loss_detector(make_env()) == "loe_kalman"
    env.close()


@pytest.mark.parametrize("seed, rotor", [(31, 0), (32, 3)])
def test_rotor_loss_is_detected_and_isolated_in_flight(seed, rotor):
    """The flights of test_loe_kalman's 000-bounds test: isolated, within 30 ms."""
    env = loe_cusum_wrapper(make_env(faults=[{"kind": "rotor_loss", "target": rotor, "time": 3.0}], task="hover",
                                     wind=LIGHT_WIND, max_episode_seconds=3.3))
    obs, info = env.reset(seed=seed)
    assert env.observation_space.contains(obs)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs, info))
        if term or trunc:
            break
    status = info["fdd"]["loe_cusum"]
    assert status["alarm"] and status["isolated"] == rotor
    assert 0.0 < status["alarm_time"] - 3.0 <= 0.030
    assert not any(isinstance(v, np.generic) for v in status.values())
    env.close()
