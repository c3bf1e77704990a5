"""`reset(options=...)`: faults, wind and vehicle overrides for one episode, validated as the make-time kwargs;
the next reset without options flies the make-time configuration again."""
import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401

ROTOR_LOSS = [{"kind": "rotor_loss", "target": 1, "time": 0.1}]


def fly(env, seconds, seed=3, options=None):
    obs, info = env.reset(seed=seed, options=options)
    hover = np.full(env.action_space.shape, 0.5, dtype=np.float32)
    observations = [obs]
    while info["time"] < seconds - 1e-9:
        obs, _, _, _, info = env.step(hover)
        observations.append(obs)
    return observations, info


def test_quadrotor_flies_the_fault_of_the_options_then_its_own_configuration_again():
    env = gym.make("ftcgym/Quadrotor-v0", max_episode_seconds=2.0)
    _, info = fly(env, 0.2, options={"faults": ROTOR_LOSS})
    assert info["fault"]["active"] and info["fault"]["kind"] == "rotor_loss" and info["fault"]["target"] == 1
    assert info["truth"]["rotor_effectiveness"].tolist() == [1.0, 0.0, 1.0, 1.0]
    plain, info = fly(env, 0.2)
    assert not info["fault"]["active"] and info["faults"] == []
    assert info["truth"]["rotor_effectiveness"].tolist() == [1.0, 1.0, 1.0, 1.0]
    fresh, _ = fly(gym.make("ftcgym/Quadrotor-v0", max_episode_seconds=2.0), 0.2)
    assert all(np.array_equal(a[key], b[key]) for a, b in zip(plain, fresh) for key in a)   # bit-identical
    env.close()


def test_options_replace_the_make_time_faults_wind_and_vehicle_for_one_episode():
    env = gym.make("ftcgym/Quadrotor-v0", faults=ROTOR_LOSS, wind={"mean": [1.0, 0.0, 0.0]})
    _, info = env.reset(seed=0, options={"faults": [], "wind": {"mean": [0.0, 2.0, 0.0]},
                                         "vehicle_overrides": {"mass": 0.5}})
    assert info["faults"] == [] and info["truth"]["wind"].tolist() == [0.0, 2.0, 0.0]
    assert info["truth"]["mass"] == 0.5
    _, info = env.reset(seed=0)
    assert info["faults"][0]["kind"] == "rotor_loss" and info["truth"]["wind"].tolist() == [1.0, 0.0, 0.0]
    assert info["truth"]["mass"] == pytest.approx(0.374)
    env.close()


def test_quadplane_flies_the_fault_of_the_options_then_its_own_configuration_again():
    env = gym.make("ftcgym/QuadPlane-v0", max_episode_seconds=2.0)
    observations, info = fly(env, 0.5, options={"faults": [{"kind": "gnss", "time": 0.2}],
                                                "wind": {"mean": [3.0, 0.0, 0.0]},
                                                "vehicle_overrides": {"mass": 7.0}})
    assert info["fault"]["active"] and info["fault"]["kind"] == "gnss"
    assert np.all(observations[-1]["gnss_velocity"] == 0.0)           # the GNSS reads zero after the onset
    assert info["truth"]["wind"].tolist() == [3.0, 0.0, 0.0] and info["truth"]["mass"] == 7.0
    observations, info = fly(env, 0.5)
    assert not info["fault"]["active"] and info["faults"] == []
    assert np.all(observations[-1]["gnss_velocity"] != 0.0)           # noisy readings: no dropout
    assert info["truth"]["wind"].tolist() == [0.0, 0.0, 0.0] and info["truth"]["mass"] == 6.5
    env.close()


def test_the_autopilot_env_passes_options_to_its_quadplane():
    env = gym.make("ftcgym/QuadPlaneAutopilot-v0")
    _, info = env.reset(seed=1, options={"faults": [{"kind": "pitot_blockage", "time": 30.0}]})
    assert info["faults"][0]["kind"] == "pitot_blockage"
    _, info = env.reset(seed=1)
    assert info["faults"] == []
    env.close()


@pytest.mark.parametrize("env_id", ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0"])
@pytest.mark.parametrize("options, message", [
    ({"fault": []},
     r"reset options key: unknown \['fault'\] \(did you mean 'faults'\?\); "
     r"accepted: \['faults', 'vehicle_overrides', 'wind'\]"),
    ({"faults": [{"kind": "loe", "target": 9}]}, r"reset options: faults\[0\].target: 9 is not accepted for loe"),
    ({"wind": {"speed": 3}}, r"reset options: wind config key: unknown \['speed'\]"),
    ({"vehicle_overrides": {"mas": 1.0}},
     r"reset options: vehicle_overrides field: unknown \['mas'\] \(did you mean 'mass'\?\)"),
])
def test_bad_options_are_rejected_as_the_make_time_kwargs_are(env_id, options, message):
    env = gym.make(env_id)
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options=options)
    env.close()


def test_overrides_that_widen_the_observation_space_belong_to_gym_make():
    env = gym.make("ftcgym/Quadrotor-v0")
    message = r"widen the bounds of observation 'rotor_speed'.*pass these overrides to gym.make"
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options={"vehicle_overrides": {"omega_max": 2000.0}})
    env.close()


def test_a_refused_reset_leaves_the_episode_as_it_was():
    env = gym.make("ftcgym/Quadrotor-v0", wind={"mean": [1.0, 0.0, 0.0], "turbulence": "light"})
    env.reset(seed=3)
    twin = gym.make("ftcgym/Quadrotor-v0", wind={"mean": [1.0, 0.0, 0.0], "turbulence": "light"})
    twin.reset(seed=3)
    with pytest.raises(ValueError, match=r"reset options: faults\[0\].target"):
        env.reset(options={"wind": {"mean": [5.0, 0.0, 0.0]}, "faults": [{"kind": "loe", "target": 9}]})
    action = np.full(4, 0.55, dtype=np.float32)
    for _ in range(50):                     # the episode goes on in its own wind, as the twin's does
        obs, *_ = env.step(action)
        twin_obs, *_ = twin.step(action)
    assert all(np.array_equal(obs[key], twin_obs[key]) for key in obs)
    env.close()
    twin.close()


@pytest.mark.parametrize("env_id", ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0", "ftcgym/RotorLossRecovery-v0"])
def test_an_env_whose_first_reset_was_refused_steps_after_a_good_one(env_id):
    """Gymnasium's passive env checker (off for ftcgym's ids) broke every later step after a refused first reset."""
    env = gym.make(env_id)
    with pytest.raises(ValueError):
        env.reset(seed=0, options={"wind": {"mean": [0.0, float("nan"), 0.0]}})
    env.reset(seed=0)
    obs, reward, *_ = env.step(env.action_space.sample())
    assert np.isfinite(reward) and env.observation_space.contains(obs)
    env.close()
