"""Imitation pre-training: the task env's shadow expert and DAgger (`ftcgym.training.imitation`)."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

import ftcgym  # noqa: F401
from ftcgym.cli import main
from ftcgym.task_envs.rotor_loss_recovery import N_FEATURES, RotorLossRecoveryEnv
from ftcgym.training.config import load_config
from ftcgym.training.imitation import DaggerSettings

pytest.importorskip("stable_baselines3")

FAST_TASK = {"onset": [0.5, 1.0], "horizon_seconds": 1.0, "action_repeat": 2, "vehicle": "bebop2"}


def _fly(env, seed, choose):
    """One episode; `choose(obs, info)` gives the action. Returns (observations, expert labels, last info)."""
    obs, info = env.reset(seed=seed)
    observations, labels = [], []
    while True:
        observations.append(obs)
        labels.append(info["expert_action"])
        obs, _, terminated, truncated, info = env.step(choose(obs, info))
        if terminated or truncated:
            return np.array(observations), np.array(labels), info


@pytest.mark.parametrize("failed_rotor", [0, 3])
def test_the_shadow_expert_flies_the_spin_recovery(failed_rotor):
    env = RotorLossRecoveryEnv(expert=True, **FAST_TASK, failed_rotor=failed_rotor)
    features, labels, info = _fly(env, failed_rotor, lambda obs, info: info["expert_action"])
    assert not info["crashed"] and abs(info["position_error"][2]) < 0.3      # held altitude for 1 s
    # its guidance: the commanded axis (body frame) leans from the vertical (R^T up = -R^T e_z) as the position
    # loop brings the drifting vehicle back, by about the bebop2's 30 deg at most (the cap is on the horizontal
    # acceleration, so a little more while less than the weight is asked); the thrust near the weight once the
    # spin holds altitude
    axis, up = features[:, 17:20], -features[:, 3:6]
    tilt = np.degrees(np.arccos(np.clip(np.sum(axis * up, axis=1), -1, 1)))
    assert np.allclose(np.linalg.norm(axis, axis=1), 1.0, atol=1e-5) and tilt[0] < 5 and 20 < tilt.max() < 35
    assert abs(np.median(features[len(features) // 2:, 20])) < 0.3
    assert labels.shape[1] == 4 and np.all(np.abs(labels) <= 1)
    # it idles the isolated (failed) rotor: command 0, action -1; labels and actions are in the canonical
    # order (tasks.rotor_order), where a lost r3 / r4 sits at r1's / r2's place
    np.testing.assert_array_equal(labels[:, failed_rotor % 2], -1.0)
    assert "expert_action" not in RotorLossRecoveryEnv(**FAST_TASK).reset(seed=0)[1]
    env.close()


def test_dagger_settings_reject_unknown_keys():
    with pytest.raises(ValueError, match="unknown keys"):
        DaggerSettings.from_config({"iterations": 2, "epoch": 3})
    with pytest.raises(ValueError, match="method"):
        DaggerSettings.from_config({"method": "bc"})
    with pytest.raises(ValueError, match="pretrain.loss"):
        DaggerSettings.from_config({"loss": "huber"})
    with pytest.raises(ValueError, match="final_epochs >= 0"):
        DaggerSettings.from_config({"final_epochs": -1})


def test_saturated_loss_ignores_a_mean_beyond_the_bound_its_label_sits_at():
    torch = pytest.importorskip("torch")
    from ftcgym.training.imitation import _action_loss
    labels = torch.tensor([[1.0, -1.0, 0.3, 1.0]])
    mean = torch.tensor([[1.5, -3.0, 0.5, 0.5]])
    bound = torch.ones(4)
    # beyond +1 and -1 at saturated labels: no error; interior 0.2; short of the bound 0.5
    assert float(_action_loss(mean, labels, "saturated", bound)) == pytest.approx((0.2 ** 2 + 0.5 ** 2) / 4)
    assert float(_action_loss(mean, labels, "mse", bound)) == pytest.approx((0.25 + 4.0 + 0.04 + 0.25) / 4)
    assert float(_action_loss(mean, labels, "l1", bound)) == pytest.approx((0.5 + 2.0 + 0.2 + 0.5) / 4)


def test_annealed_fit_ends_below_a_constant_rate_and_restores_the_rate():
    torch = pytest.importorskip("torch")
    from stable_baselines3 import PPO

    from ftcgym.training.imitation import _fit_actor
    env = RotorLossRecoveryEnv(**FAST_TASK)
    rng = np.random.default_rng(0)
    observations = rng.uniform(-1, 1, (2048, N_FEATURES)).astype(np.float32)
    labels = 0.9 * np.tanh(2.0 * observations[:, :4] + observations[:, 4:8])
    losses = {}
    for anneal in (False, True):
        model = PPO("MlpPolicy", env, policy_kwargs={"net_arch": [32, 32]}, seed=0, device="cpu")
        optimizer = torch.optim.Adam(model.policy.parameters(), lr=1e-2)
        settings = DaggerSettings(batch_size=64, learning_rate=1e-2)
        _fit_actor(model, optimizer, observations, labels, settings, np.random.default_rng(1), epochs=10)
        losses[anneal] = _fit_actor(model, optimizer, observations, labels, settings, np.random.default_rng(2),
                                    epochs=10, anneal=anneal)["action_mse"]
        assert optimizer.param_groups[0]["lr"] == 1e-2      # the value fit after it runs at the set rate
    # 10 more passes after the same 10 at 1e-2 (Adam's noise floor on this fit: 4.6e-4): annealed, 3.7e-4
    assert losses[True] < 0.9 * losses[False]
    # another loss reports itself beside the squared error, which stays comparable across losses
    fit = _fit_actor(model, optimizer, observations, labels, DaggerSettings(batch_size=64, loss="l1"), rng, epochs=1)
    assert set(fit) == {"action_mse", "action_loss"}
    assert 0.0 < fit["action_loss"] ** 2 <= fit["action_mse"]   # (mean |e|)^2 <= mean e^2 (Jensen), per batch
    env.close()


def test_dagger_pretraining_imitates_the_expert(tmp_path, capsys):
    document = yaml.safe_load(Path(load_config("rotor-loss-recovery").source).read_text())
    body = document["rotor-loss-recovery"]
    body["env_kwargs"].update(FAST_TASK)
    body["eval"] = None
    body["pretrain"].update(iterations=2, steps_per_iteration=1000, epochs=20, final_epochs=10)
    body["PPO"].update(n_envs=1, policy_kwargs={"net_arch": [64, 64]})
    path = tmp_path / "dagger.yaml"
    path.write_text(yaml.safe_dump(document))
    out = tmp_path / "run"
    assert main(["train", "--config", str(path), "--total-steps", "0", "--out", str(out), "--no-progress"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert (out / "pretrained" / "model.zip").is_file() and (out / "pretrained" / "vecnormalize.pkl").is_file()
    assert manifest["steps"] == 0 and [i["iteration"] for i in manifest["pretrain"]["iterations"]] == [0, 1]
    assert manifest["pretrain"]["iterations"][0]["beta"] == 1.0
    last = manifest["pretrain"]["iterations"][-1]   # the annealed final fit lowers the training loss further
    assert last["final_fit"]["epochs"] == 10 and last["final_fit"]["action_mse"] < last["action_mse"]
    printed = capsys.readouterr().out
    assert "action_loss" in last and "action_loss" in last["final_fit"]     # the config fits the absolute error
    assert ("2 DAgger iterations, 2000 samples" in printed and f"action mse {last['action_mse']:.4f} "
            f"({last['action_loss']:.4f} by the fitted loss), final fit action mse "
            f"{last['final_fit']['action_mse']:.4f} ({last['final_fit']['action_loss']:.4f} by the fitted loss)"
            in printed)

    from stable_baselines3 import PPO

    from ftcgym.training.policy import load_normalizer
    normalizer = load_normalizer(out / "vecnormalize.pkl")
    trained = PPO.load(out / "model.zip")
    untrained = PPO("MlpPolicy", RotorLossRecoveryEnv(**FAST_TASK), policy_kwargs={"net_arch": [64, 64]}, seed=1)
    # On fresh expert-flown episodes, the pre-trained policy's actions are far closer to the expert's.
    env = RotorLossRecoveryEnv(expert=True, **FAST_TASK)
    observations, labels, _ = _fly(env, 123, lambda obs, info: info["expert_action"])
    errors = [np.mean((np.clip(model.predict(normalizer.normalize_obs(observations), deterministic=True)[0], -1, 1)
                       - labels) ** 2) for model in (trained, untrained)]
    assert errors[0] < 0.1 and errors[0] < errors[1] / 3
    env.close()


def test_fine_tuning_starts_from_a_saved_model(tmp_path):
    from stable_baselines3 import PPO

    from ftcgym.training.policy import load_normalizer
    from ftcgym.training.shipped import shipped_path
    from ftcgym.training.train import train

    shipped = shipped_path("learned-spin")
    config = load_config("rotor-loss-recovery", n_envs=1, total_steps=64)
    config.env_kwargs = {**config.env_kwargs, **FAST_TASK}
    config.eval = None
    config.hyperparams.update(n_steps=64, batch_size=64, n_epochs=1, learning_rate=1e-6)
    manifest = train(config, tmp_path / "tuned", progress=False, init_from=shipped)
    assert manifest["init_from"] == str(shipped) and "pretrain" not in manifest
    features = np.random.default_rng(1).uniform(-1, 1, (16, N_FEATURES)).astype(np.float32)
    def act(folder):
        observation = load_normalizer(folder / "vecnormalize.pkl").normalize_obs(features)
        return PPO.load(folder / "model.zip").predict(observation, deterministic=True)[0]
    actions = [act(folder) for folder in (shipped, tmp_path / "tuned")]
    # one tiny PPO update (lr 1e-6) away from the shipped policy; its observation statistics carried over
    assert np.max(np.abs(actions[0] - actions[1])) < 0.05
    config.policy_kwargs = {"net_arch": [32, 32]}
    with pytest.raises(ValueError, match="init_from"):
        train(config, tmp_path / "mismatch", progress=False, init_from=shipped)


def test_dagger_continues_from_a_saved_model(tmp_path):
    from stable_baselines3 import PPO

    from ftcgym.training.config import plan_line
    from ftcgym.training.policy import load_normalizer
    from ftcgym.training.shipped import shipped_path
    from ftcgym.training.train import train

    shipped = shipped_path("learned-spin")
    config = load_config("rotor-loss-recovery", n_envs=1, total_steps=0)
    config.env_kwargs = {**config.env_kwargs, **FAST_TASK}
    config.eval = None
    config.pretrain = {**config.pretrain, "iterations": 1, "steps_per_iteration": 300, "beta": 0.0, "epochs": 1,
                       "learning_rate": 1e-6, "continue_from_init": True}
    assert "DAgger 1 iteration x 300 steps" in plan_line(config, "OUT", init_from=shipped)
    with pytest.raises(ValueError, match="continue_from_init.*--init-from"):
        train(config, tmp_path / "nothing", progress=False)
    manifest = train(config, tmp_path / "continued", progress=False, init_from=shipped)
    assert manifest["init_from"] == str(shipped)
    assert manifest["pretrain"]["iterations"][0]["samples"] == 300       # the learner flew 300 labelled steps
    # its fit started from the shipped policy: the labels' error is the shipped policy's (MSE 0.010 on these
    # 300 steps), not an untrained network's (0.90 by the same run without --init-from)
    assert manifest["pretrain"]["iterations"][0]["action_mse"] < 0.03
    features = np.random.default_rng(1).uniform(-1, 1, (16, N_FEATURES)).astype(np.float32)
    def act(folder):
        observation = load_normalizer(folder / "vecnormalize.pkl").normalize_obs(features)
        return PPO.load(folder / "model.zip").predict(observation, deterministic=True)[0]
    assert np.max(np.abs(act(shipped) - act(tmp_path / "continued"))) < 0.05
