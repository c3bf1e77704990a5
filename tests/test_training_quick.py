"""`ftcgym train` for a first try: `--quick` (each config's `quick` section), `--pretrain-iterations`, the plan
line printed first, `--total-steps` rounded up to whole rollouts (and recorded), progress bars, DAgger
checkpoints and Ctrl-C (the model so far published, one line, status 130), and the benchmark names
`ftcgym evaluate` gives a trained policy. Runs of a few hundred steps only."""
import json
from pathlib import Path

import pytest
import yaml

import ftcgym  # noqa: F401
from ftcgym.cli import main
from ftcgym.training.config import builtin_tasks, load_config, merge, plan_line, rl_steps, rollout_steps

pytest.importorskip("stable_baselines3")

FAST_TASK = {"onset": [0.5, 1.0], "horizon_seconds": 1.0, "action_repeat": 2, "vehicle": "bebop2",
             "task": ["hover"]}
SHORT_EVAL = {"max_episode_seconds": 3.0, "faults": [{"kind": "rotor_loss", "target": 1, "time": 1.0}]}


def _config(tmp_path, pretrain: dict | None = None, steps: int = 256) -> Path:
    """The built-in rotor-loss-recovery config shrunk to seconds: short episodes, a small network, 256-step
    rollouts, no evaluation; DAgger with `pretrain` (updates to its section), none without."""
    document = yaml.safe_load(Path(load_config("rotor-loss-recovery").source).read_text())
    body = document["rotor-loss-recovery"]
    body["env_kwargs"].update(FAST_TASK)
    body["eval"] = None
    body["checkpoint_freq"] = 10_000
    if pretrain is None:
        body.pop("pretrain")
    else:
        body["pretrain"].update(pretrain)
    body["PPO"].update(n_envs=1, n_timesteps=steps, n_steps=256, batch_size=64, n_epochs=1,
                       policy_kwargs={"net_arch": [32, 32]})
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def test_every_builtin_config_has_a_quick_section_that_shrinks_the_run():
    for task in builtin_tasks():
        full, quick = load_config(task), load_config(task, quick=True)
        assert quick.quick and not full.quick and quick.task == full.task and quick.env_id == full.env_id
        assert rl_steps(quick) <= 2048 < rl_steps(full) and quick.n_envs == 1
        assert quick.eval is None or quick.eval["episodes"] == 1
        if quick.pretrain:
            assert quick.pretrain["iterations"] * quick.pretrain["steps_per_iteration"] <= 20_000
        for algo in ("PPO", "SAC"):
            assert load_config(task, algo=algo, quick=True).total_steps <= 2048


def test_the_quick_rotor_loss_run_and_overrides_on_top_of_it():
    quick = load_config("rotor-loss-recovery", quick=True)
    assert (quick.pretrain["iterations"], quick.pretrain["steps_per_iteration"]) == (4, 5000)
    assert quick.pretrain["epochs"] == 6 and quick.pretrain["env_kwargs"] == {"expert": True}   # merged, not replaced
    assert (quick.n_envs, quick.total_steps, quick.hyperparams["n_steps"], rl_steps(quick)) == (1, 2048, 1024, 2048)
    assert quick.env_kwargs["task"] == ["hover"] and quick.env_kwargs["vehicle"] == ["bebop2", "mueller2014"]
    assert quick.eval == {"scenario": "quad-rotor-loss-hover", "episodes": 1, "freq": 2048, "env_kwargs": {}}
    assert quick.as_dict()["quick"] is True
    # the command line's options apply on top of the quick section
    tuned = load_config("rotor-loss-recovery", n_envs=2, total_steps=100, pretrain_iterations=1, quick=True)
    assert (tuned.n_envs, tuned.total_steps, tuned.pretrain["iterations"]) == (2, 100, 1)
    assert load_config("rotor-loss-recovery", pretrain_iterations=0).pretrain is None
    assert load_config("rotor-loss-recovery", pretrain_iterations=3).pretrain["iterations"] == 3
    with pytest.raises(ValueError, match="total steps >= 1"):     # no DAgger and no RL: nothing to train
        load_config("rotor-loss-recovery", pretrain_iterations=0, total_steps=0)
    with pytest.raises(ValueError, match="no `pretrain` section"):
        load_config("airspeed-source", pretrain_iterations=2)
    assert merge({"a": {"b": 1, "c": [1, 2]}, "d": 1}, {"a": {"c": [3]}, "d": None}) == {"a": {"b": 1, "c": [3]},
                                                                                       "d": None}


def test_a_config_without_a_quick_section_says_so(tmp_path):
    document = yaml.safe_load(Path(load_config("airspeed-source").source).read_text())
    document["airspeed-source"].pop("quick")
    path = tmp_path / "slow.yaml"
    path.write_text(yaml.safe_dump(document))
    assert not load_config(str(path)).quick
    with pytest.raises(ValueError, match="no `quick` section"):
        load_config(str(path), quick=True)


def test_total_steps_round_up_to_whole_rollouts_and_the_plan_line_says_so():
    full = load_config("rotor-loss-recovery")                       # PPO, n_steps 2048 x 2 envs
    assert rollout_steps(full) == 4096 and rl_steps(full) == 303_104
    asked = load_config("rotor-loss-recovery", total_steps=2048)
    assert rl_steps(asked) == 4096
    line = plan_line(asked, "OUT")
    assert line.startswith("ftcgym train: rotor-loss-recovery, PPO, 2 envs, seed 0: DAgger 20 iterations x 25000 "
                           "steps, then 4096 RL steps (2048 asked, rounded up to whole rollouts of n_steps 2048 x "
                           "2 envs = 4096)") and line.endswith("writing to OUT")
    assert rl_steps(load_config("rotor-loss-recovery", total_steps=8192)) == 8192
    assert rl_steps(load_config("rotor-loss-recovery", total_steps=0)) == 0
    sac = load_config("rotor-loss-recovery", algo="SAC", n_envs=3, total_steps=1000)
    assert rl_steps(sac) == 1002 and "no DAgger (SAC)" in plan_line(sac, "OUT")
    sac.hyperparams["train_freq"] = [2, "episode"]                   # unknown in advance: as asked
    assert rollout_steps(sac) is None and rl_steps(sac) == 1000
    assert "no DAgger (--init-from)" in plan_line(load_config("rotor-loss-recovery"), "OUT", init_from="m")
    quick = plan_line(load_config("rotor-loss-recovery", quick=True, pretrain_iterations=1), "OUT")
    assert "(--quick)" in quick and "DAgger 1 iteration x 5000 steps, then 2048 RL steps;" in quick


def test_a_short_run_records_the_steps_asked_and_taken_and_shows_a_bar(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--config", str(_config(tmp_path)), "--total-steps", "300", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    first = captured.out.splitlines()[0]
    assert first.startswith("ftcgym train: rotor-loss-recovery, PPO, 1 env, seed 0: 512 RL steps (300 asked, "
                            "rounded up to whole rollouts of n_steps 256 x 1 env = 256)")
    assert "RL: 100%" in captured.err and "512/512" in captured.err   # tqdm: a total (and an ETA while running)
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["requested_steps"], manifest["rl_steps"], manifest["steps"]) == (300, 512, 512)
    assert manifest["total_steps"] == 300 and manifest["interrupted"] is None and manifest["quick"] is False


def _no_traceback(captured) -> None:
    assert "Traceback" not in captured.out + captured.err and "KeyboardInterrupt" not in captured.out + captured.err


def test_ctrl_c_in_dagger_saves_the_policy_so_far(tmp_path, capsys, monkeypatch):
    from ftcgym.training import imitation
    from ftcgym.training.policy import LearnedPolicy

    fly, calls = imitation._fly, []

    def interrupted_on_the_second_iteration(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return fly(*args, **kwargs)
    monkeypatch.setattr(imitation, "_fly", interrupted_on_the_second_iteration)
    out = tmp_path / "run"
    config = _config(tmp_path, {"iterations": 3, "steps_per_iteration": 300, "epochs": 2})
    assert main(["train", "--config", str(config), "--out", str(out), "--no-progress"]) == 130
    captured = capsys.readouterr()
    _no_traceback(captured)
    assert captured.err.splitlines() == [f"ftcgym train: interrupted in DAgger iteration 2 of 3; saved the model so "
                                         f"far (0 RL steps) to {out}"]
    assert captured.out.splitlines()[0].startswith("ftcgym train: rotor-loss-recovery, PPO, 1 env, seed 0: DAgger 3 "
                                                   "iterations x 300 steps, then 256 RL steps")
    # iteration 1's checkpoint and the model so far, published with a manifest that says it was interrupted
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["dagger_1.zip", "dagger_1_vecnormalize.pkl"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["interrupted"] == "in DAgger iteration 2 of 3" and manifest["steps"] == 0
    assert [i["iteration"] for i in manifest["pretrain"]["iterations"]] == [0]
    from ftcgym.benchmark.runner import make_env
    from ftcgym.benchmark.scenarios import get_scenario
    env = make_env(get_scenario("quad-rotor-loss-hover"), SHORT_EVAL)
    for model in (out, out / "checkpoints" / "dagger_1.zip"):
        policy = LearnedPolicy.load(model, env)
        assert policy.normalizer is not None and policy.normalizer.obs_rms.count > 290   # iteration 1's statistics
    env.close()
    assert main(["evaluate", str(out), "--episodes", "1", "--env-kwargs", json.dumps(SHORT_EVAL)]) == 0
    assert capsys.readouterr().out.splitlines()[2].split()[:3] == ["quad-rotor-loss-hover", "learned-spin", "1"]


def test_ctrl_c_in_rl_saves_the_model_so_far(tmp_path, capsys, monkeypatch):
    from stable_baselines3 import PPO

    def interrupted(self, *args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(PPO, "train", interrupted)        # after the first rollout, in the first update
    out = tmp_path / "run"
    assert main(["train", "--config", str(_config(tmp_path, steps=1024)), "--out", str(out)]) == 130
    captured = capsys.readouterr()
    _no_traceback(captured)
    assert captured.err.splitlines()[-1] == (f"ftcgym train: interrupted at RL step 256 of 1024; saved the model so "
                                             f"far (256 RL steps) to {out}")
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["steps"], manifest["rl_steps"], manifest["interrupted"]) == (256, 1024, "at RL step 256 of 1024")
    assert PPO.load(out / "model.zip").num_timesteps == 256 and (out / "vecnormalize.pkl").is_file()


def test_ctrl_c_before_training_saves_nothing(tmp_path, capsys, monkeypatch):
    from ftcgym.training import train as training

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(training, "build_vec_env", interrupted)
    out = tmp_path / "run"
    assert main(["train", "--config", str(_config(tmp_path)), "--out", str(out), "--no-progress"]) == 130
    captured = capsys.readouterr()
    _no_traceback(captured)
    assert captured.err == "ftcgym train: interrupted before training started; nothing saved\n"
    assert not (out / "model.zip").exists()


def test_evaluate_names_each_task_as_the_benchmark_does():
    from ftcgym.task_envs.airspeed_source import ENV_ID as AIRSPEED_ENV_ID
    from ftcgym.training.evaluate import default_scenario
    from ftcgym.training.policy import TASK_ENV_ID, policy_name
    from ftcgym.training.shipped import SHIPPED, shipped_path

    assert (policy_name(TASK_ENV_ID), policy_name(AIRSPEED_ENV_ID), policy_name("Other-v0")) == (
        "learned-spin", "learned-airspeed", "learned")
    for name, task in SHIPPED.items():             # the benchmark's names of the shipped policies
        assert policy_name(load_config(task).env_id) == name
    assert default_scenario(shipped_path("learned-spin")) == "quad-rotor-loss-hover"
    assert default_scenario(shipped_path("learned-airspeed")) == "qp-pitot-incipient"


def test_tensorboard_logs_when_installed(tmp_path):
    pytest.importorskip("tensorboard")
    out = tmp_path / "run"
    config = _config(tmp_path, {"iterations": 1, "steps_per_iteration": 200, "epochs": 1})
    assert main(["train", "--config", str(config), "--out", str(out), "--no-progress"]) == 0
    assert list((out / "tb").glob("events.out.tfevents.*"))
