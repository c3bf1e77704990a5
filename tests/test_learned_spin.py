"""The shipped `learned-spin` policy: it loads through the benchmark's policy registry, acts
deterministically, carries its manifest, and recovers from a propeller loss on a benchmark episode."""
import json

import numpy as np
import pytest

import ftcgym  # noqa: F401
from ftcgym.task_envs.rotor_loss_recovery import N_FEATURES
from ftcgym.training.shipped import shipped_path

pytest.importorskip("stable_baselines3")


def _env():
    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    return make_env(get_scenario("quad-rotor-loss-hover"))


def test_shipped_model_has_its_manifest():
    folder = shipped_path("learned-spin")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["command"].startswith("ftcgym train --config rotor-loss-recovery")
    assert manifest["config"]["env_id"] == "ftcgym/RotorLossRecovery-v0"
    assert manifest["wall_time_s"] > 0 and len(manifest["git_commit"]) >= 40 and "seed" in manifest
    assert manifest["pretrain"]["iterations"][-1]["samples"] > 100_000
    assert sum(p.stat().st_size for p in folder.iterdir()) < 2_000_000      # small enough to ship


def test_learned_spin_loads_and_acts_deterministically():
    from ftcgym.agents import make_policy
    env = _env()
    first, second = make_policy("learned-spin", env), make_policy("learned-spin", env)
    features = np.random.default_rng(0).uniform(-1, 1, (8, N_FEATURES)).astype(np.float32)
    actions = np.array([first.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [second.predict(f) for f in features])
    np.testing.assert_array_equal(actions, [first.predict(f) for f in features])
    assert len({tuple(a) for a in actions}) == len(actions)                # it reads its input
    env.close()


def test_learned_spin_recovers_from_a_propeller_loss():
    from ftcgym.agents import make_policy
    from ftcgym.benchmark.runner import roll_out, score_episode
    env = _env()
    scores = score_episode(roll_out(env, make_policy("learned-spin", env), 7, "loe_kalman"))
    env.close()
    assert scores["isolation_correct"] and not scores["crashed"]
    assert scores["recovered"] and scores["recovery_time"] - scores["fault_onset"] < 1.5
    assert scores["altitude_loss"] < 1.5


@pytest.mark.parametrize("policy, scenario, flies", [("learned-spin", "qp-mission", "ftcgym/Quadrotor-v0"),
                                                      ("learned-airspeed", "quad-rotor-loss-hover",
                                                       "ftcgym/QuadPlaneAutopilot-v0")])
def test_shipped_model_on_the_wrong_vehicle_says_which_it_flies(policy, scenario, flies):
    from ftcgym.agents import make_policy
    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    env = make_env(get_scenario(scenario))
    with pytest.raises(ValueError, match=f"flies {flies}, not"):
        make_policy(policy, env)
    env.close()


def test_a_model_of_an_earlier_feature_layout_is_refused_with_what_to_do():
    from types import SimpleNamespace

    from ftcgym.training.policy import LearnedPolicy
    env = _env()
    old = SimpleNamespace(observation_space=SimpleNamespace(shape=(37,)))
    with pytest.raises(ValueError, match=rf"takes \(37,\) observations; recovery_features gives \({N_FEATURES},\).*"
                                         r"must be retrained"):
        LearnedPolicy(old, env=env)
    env.close()
