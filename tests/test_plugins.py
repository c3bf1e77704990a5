"""A user's own policy, detector and scenario, from a module outside the package: by MODULE:ATTR on
PYTHONPATH, and by name through the entry points of a small package that pip installs."""
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401
from ftcgym.agents import make_policy
from ftcgym.benchmark.scenarios import get_scenario
from ftcgym.fdd import DetectorWrapper, wrap_with_detector

PLUGIN = Path(__file__).parent / "plugin"
FTCGYM = Path(sys.executable).parent / "ftcgym"


def bench(out: Path, pythonpath: Path, *args: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    run = subprocess.run([str(FTCGYM), "bench", *args, "--workers", "1", "--out", str(out)], env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads((out / "results.json").read_text())


def assert_detected_and_recovered(results: dict, policy: str) -> None:
    """Rotor 2 lost at 1 s: the user's detector names it within 0.1 s and the user's policy recovers."""
    episodes = results["episodes"]
    assert [e["policy"] for e in episodes] == [policy, policy]               # the name as given
    for e in episodes:
        assert e["fault_target"] == 2 and e["isolated_target"] == 2 and e["isolation_correct"]
        assert 0.0 < e["detection_delay"] < 0.1 and not e["false_alarm"]
        assert e["recovered"] and not e["crashed"]


def test_bench_flies_and_scores_a_module_policy_and_detector_class(tmp_path):
    modules = tmp_path / "modules"                   # the user's modules, written here and put on PYTHONPATH
    shutil.copytree(PLUGIN / "ftcgym_plugin_example", modules / "ftcgym_plugin_example")
    results = bench(tmp_path / "out", modules, "--scenario", "ftcgym_plugin_example.scenario:SCENARIO",
                    "--policy", "ftcgym_plugin_example.policy:SpinOnRotorJump",
                    "--detector", "ftcgym_plugin_example.detector:RotorJumpDetector")
    assert_detected_and_recovered(results, "ftcgym_plugin_example.policy:SpinOnRotorJump")
    [scenario] = results["config"]["scenarios"]
    assert scenario["name"] == "ftcgym_plugin_example.scenario:SCENARIO"
    assert scenario["detector"] == "ftcgym_plugin_example.detector:RotorJumpDetector"
    report = (tmp_path / "out" / "report.md").read_text()     # figures named without the ':' a viewer takes for a URL
    assert (tmp_path / "out" / "ftcgym_plugin_example.scenario_SCENARIO.png").exists()
    assert "(ftcgym_plugin_example.scenario_SCENARIO.png)" in report
    assert "detector ftcgym_plugin_example.detector:RotorJumpDetector)" in report


def test_an_installed_package_plugs_in_by_entry_point(tmp_path):
    site = tmp_path / "site"
    build = tmp_path / "build"
    shutil.copytree(PLUGIN, build)
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                          "--no-build-isolation", "--target", str(site), str(build)],
                         capture_output=True, text=True, timeout=300)
    assert pip.returncode == 0, pip.stderr
    assert list(site.glob("ftcgym_plugin_example-*.dist-info/entry_points.txt"))
    results = bench(tmp_path / "out", site, "--scenario", "example-rotor-loss")   # its policy and detector too
    assert_detected_and_recovered(results, "example-spin")
    listing = subprocess.run([str(FTCGYM), "bench", "--list"], env={**os.environ, "PYTHONPATH": str(site)},
                             capture_output=True, text=True, check=True).stdout
    assert "example-spin" in listing and "rotor-jump" in listing
    [line] = [line for line in listing.splitlines() if line.strip().startswith("example-rotor-loss")]
    assert get_scenario_description(site) in line     # the plug-in scenario with its own description


def get_scenario_description(site: Path) -> str:
    run = subprocess.run([sys.executable, "-c", "from ftcgym.benchmark.scenarios import get_scenario; "
                          "print(get_scenario('example-rotor-loss').description)"],
                         env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True, text=True, check=True)
    return run.stdout.strip()


def test_the_python_api_takes_module_references(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGIN))
    env = wrap_with_detector("ftcgym_plugin_example.detector:RotorJumpDetector",
                             gym.make("ftcgym/Quadrotor-v0"), margin=100.0)
    assert env.detector.margin == 100.0 and "fdd/rotor_jump/excess" in env.observation_space.spaces
    policy = make_policy("ftcgym_plugin_example.policy:SpinOnRotorJump", env)
    assert policy.detector == "rotor_jump"
    assert get_scenario("ftcgym_plugin_example.scenario:rotor_loss_hover").detector == "rotor-jump"
    env.close()


@pytest.mark.parametrize("name, message", [
    ("no_such_module:Thing", r"policy: 'no_such_module:Thing': module 'no_such_module' could not be imported"),
    ("ftcgym.agents:NoSuchPolicy", r"module 'ftcgym.agents' has no attribute 'NoSuchPolicy'"),
    ("nomnal", r"policy: unknown name 'nomnal' \(did you mean 'nominal'\?\); tried the built-in names and the "
               r"entry points of group 'ftcgym.policies'; accepted: \['nominal', .*\] or MODULE:ATTR"),
])
def test_an_unknown_or_unimportable_policy_says_what_was_tried(name, message):
    with pytest.raises(ValueError, match=message):
        make_policy(name, gym.make("ftcgym/Quadrotor-v0"))


def test_a_class_that_takes_no_env_is_named():
    with pytest.raises(TypeError, match=r"policy 'ftcgym.fdd:DetectorWrapper': it is called with the env as its one "
                                        r"argument, and missing a required argument: 'detector'"):
        make_policy("ftcgym.fdd:DetectorWrapper", gym.make("ftcgym/Quadrotor-v0"))


def test_an_object_without_reset_and_act_is_no_policy():
    with pytest.raises(TypeError, match=r"policy 'ftcgym.models.constants:GRAVITY': a float is neither a class"):
        make_policy("ftcgym.models.constants:GRAVITY", gym.make("ftcgym/Quadrotor-v0"))
    with pytest.raises(TypeError, match=r"policy 'ftcgym.models:FaultSpec': FaultSpec has no reset or act"):
        make_policy("ftcgym.models:FaultSpec", gym.make("ftcgym/Quadrotor-v0"))


def test_the_cli_rejects_an_unknown_detector_before_flying(tmp_path):
    run = subprocess.run([str(FTCGYM), "bench", "--detector", "psychic", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "detector: unknown name 'psychic'" in run.stderr


def test_the_cli_rejects_a_policy_without_act_before_flying(tmp_path):
    (tmp_path / "half_policy.py").write_text("class NoAct:\n    def __init__(self, env):\n        pass\n\n"
                                             "    def reset(self, obs, info):\n        pass\n")
    run = subprocess.run([str(FTCGYM), "bench", "--scenario", "quad-rotor-loss-hover", "--policy", "half_policy:NoAct",
                          "--episodes", "1", "--out", str(tmp_path / "out")],
                         env={**os.environ, "PYTHONPATH": str(tmp_path)}, capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        "ftcgym bench: scenario 'quad-rotor-loss-hover': policy 'half_policy:NoAct': NoAct has no act(obs, info); a "
        "policy is a class or factory called with the env that returns an object with reset(obs, info) and "
        "act(obs, info)"]
    assert not (tmp_path / "out" / "results.json").exists()


def test_a_misspelt_scenario_names_the_built_in_it_is_closest_to():
    with pytest.raises(ValueError, match=r"scenario: unknown name 'quad-rotor-loss-hoverr' \(did you mean "
                                         r"'quad-rotor-loss-hover'\?\); .*accepted: \['quad-hover', 'quad-square', "):
        get_scenario("quad-rotor-loss-hoverr")


@pytest.mark.parametrize("source, argument, message", [
    ('raise RuntimeError("boom at import")\n', "--policy",
     "argument --policy: policy: 'user_module:X': importing module 'user_module' raised RuntimeError: boom at import "
     "(python -c 'import user_module' shows where)"),
    ("def f(:\n", "--detector", "argument --detector: detector: 'user_module:X': importing module 'user_module' "
                                "raised SyntaxError: invalid syntax"),
    ('def scenario():\n    raise KeyError("nope")\n', "--scenario",
     "argument --scenario: scenario 'user_module:scenario': its factory raised KeyError: 'nope'"),
])
def test_a_plug_in_that_fails_is_one_line_naming_it(tmp_path, source, argument, message):
    (tmp_path / "user_module.py").write_text(source)
    reference = "user_module:scenario" if argument == "--scenario" else "user_module:X"
    run = subprocess.run([str(FTCGYM), "bench", argument, reference, "--out", str(tmp_path / "out")],
                         env={**os.environ, "PYTHONPATH": str(tmp_path)}, capture_output=True, text=True)
    assert run.returncode == 2 and message in run.stderr and "Traceback" not in run.stderr


TORCH_POLICY = '''
import torch
from ftcgym.agents import make_policy


class TorchHover:
    """The nominal controller beside a torch layer that runs every step, as a learned policy's network does."""

    def __init__(self, env):
        self.inner, self.layer = make_policy("nominal", env), torch.nn.Linear(512, 512)
        with torch.no_grad():
            self.layer(torch.ones(256, 512))       # torch's thread pool starts in the process that builds it

    def reset(self, obs, info):
        self.inner.reset(obs, info)

    def act(self, obs, info):
        with torch.no_grad():
            self.layer(torch.ones(256, 512))
        return self.inner.act(obs, info)
'''


def test_a_torch_policy_flies_in_worker_processes(tmp_path):
    """The pool's workers are forked after `check_setup` built the policy; torch's threads do not survive a fork,
    and without one torch thread per worker (`backends._exit_with_parent`) the first step waited for ever."""
    pytest.importorskip("torch")
    (tmp_path / "torch_policy.py").write_text(TORCH_POLICY)
    run = subprocess.run([str(FTCGYM), "bench", "--scenario", "quad-hover", "--policy", "torch_policy:TorchHover",
                          "--episodes", "2", "--workers", "2", "--env-kwargs", '{"max_episode_seconds": 1}',
                          "--out", str(tmp_path / "out")], env={**os.environ, "PYTHONPATH": str(tmp_path)},
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    episodes = json.loads((tmp_path / "out" / "results.json").read_text())["episodes"]
    assert len(episodes) == 2 and not any(e["crashed"] for e in episodes)


def _user_detector(monkeypatch, name="rotor_jump", outputs=None):
    """The plug-in's RotorJumpDetector under another `name`, or with `outputs` replacing what it returns."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    from ftcgym_plugin_example.detector import RotorJumpDetector
    detector = RotorJumpDetector()
    detector.name = name
    if outputs is not None:
        detector.outputs = lambda: outputs
    return detector


def test_the_benchmark_scores_the_scenarios_detector_not_one_its_wrappers_add(monkeypatch):
    """`Scenario.wrappers` may add detectors (here the plug-in's, which alarms 26 ms before `loe_kalman` on this
    episode); the scenario's own `loe_kalman` stays the one scored (the runner took the outermost one's before)."""
    from ftcgym.benchmark.runner import run_episode
    from ftcgym.benchmark.scenarios import Scenario

    scenario = get_scenario("quad-rotor-loss-hover")
    base = Scenario(name="user-rotor-loss", env_id=scenario.env_id, env_kwargs=scenario.env_kwargs,
                    policies=("nominal",), detector="loe_kalman")
    extra = _user_detector(monkeypatch, name="user_jump")
    with_extra = Scenario(name="user-rotor-loss-extra", env_id=scenario.env_id, env_kwargs=scenario.env_kwargs,
                          policies=("nominal",), detector="loe_kalman",
                          wrappers=(lambda env: DetectorWrapper(env, extra),))
    plain, wrapped = (run_episode(s, "nominal", seed=3) for s in (base, with_extra))
    assert plain["alarm_time"] is not None and plain["detection_delay"] > 0.03
    assert wrapped["alarm_time"] == plain["alarm_time"]


@pytest.mark.parametrize("name, message", [
    ("", "name must be a non-empty string without '/'"),
    (None, "name must be a non-empty string without '/'"),
    ("my/det", "name must be a non-empty string without '/'"),
])
def test_a_detector_name_that_cannot_key_info_is_refused(monkeypatch, name, message):
    with pytest.raises(ValueError, match=message):
        DetectorWrapper(gym.make("ftcgym/Quadrotor-v0"), _user_detector(monkeypatch, name=name))


def test_a_second_detector_of_the_same_name_is_refused(monkeypatch):
    """Its other output fields would not clash in the observation, but its status would overwrite the first's."""
    env = wrap_with_detector("loe_kalman", gym.make("ftcgym/Quadrotor-v0"))
    with pytest.raises(ValueError, match=r"already has a detector named 'loe_kalman'; a second would overwrite"):
        DetectorWrapper(env, _user_detector(monkeypatch, name="loe_kalman"))


@pytest.mark.parametrize("outputs, message", [
    ({"excess": np.zeros(3)}, r"outputs\(\)\['excess'\] has shape \(3,\); its output_fields declare \(4,\)"),
    ({"exces": np.zeros(4)}, r"outputs\(\) gave fields \['exces'\]; its output_fields declare \['excess'\]"),
    ({"excess": np.full(4, np.nan)}, r"outputs\(\)\['excess'\] is not finite"),
])
def test_outputs_that_break_the_declared_fields_are_named_at_the_first_step(monkeypatch, outputs, message):
    env = DetectorWrapper(gym.make("ftcgym/Quadrotor-v0"), _user_detector(monkeypatch, name="wrong", outputs=outputs))
    with pytest.raises(ValueError, match=r"detector 'wrong': " + message):
        env.reset(seed=0)


@pytest.mark.parametrize("fields, message", [
    ({"policies": "nominal"}, r"policies must be a tuple of one or more policy names, got 'nominal'"),
    ({"policies": ()}, r"policies must be a tuple of one or more policy names, got \(\)"),
    ({"policies": None}, r"policies must be a tuple of one or more policy names, got None"),
    ({"episodes": 0}, r"episodes must be a whole number >= 1, got 0"),
    ({"fault_wrappers": len}, r"fault_wrappers must be a tuple of callables"),
    ({"name": ""}, r"name must be a non-empty string"),
    ({"detector": ""}, r"detector must be a non-empty string"),
    ({"env_kwargs": None}, r"env_kwargs must be a dict"),
    ({"fault_wrappers": ("not callable",)}, r"fault_wrappers must be a tuple of callables"),
])
def test_a_malformed_scenario_names_its_field(fields, message):
    from ftcgym.benchmark.scenarios import Scenario
    with pytest.raises(ValueError, match=message):
        Scenario(**{"name": "mine", "env_id": "ftcgym/Quadrotor-v0", **fields})


def test_a_numpy_episode_count_is_a_whole_number():
    from ftcgym.benchmark.scenarios import Scenario
    assert Scenario(name="mine", env_id="ftcgym/Quadrotor-v0", episodes=np.int64(3)).episodes == 3


def test_a_scenario_that_cannot_go_to_worker_processes_is_named_before_flying():
    """A lambda among the wrappers failed every episode with a PicklingError, each retried, with workers > 1."""
    from ftcgym.benchmark.runner import run_benchmark
    from ftcgym.benchmark.scenarios import Scenario
    scenario = Scenario(name="local-wrapper", env_id="ftcgym/Quadrotor-v0", env_kwargs={"max_episode_seconds": 0.1},
                        episodes=2, wrappers=(lambda env: env,))
    with pytest.raises(ValueError, match=r"scenario 'local-wrapper': it cannot go to worker processes .*module-level"):
        run_benchmark([scenario], workers=2, progress=False)
    assert len(run_benchmark([scenario], workers=1, progress=False)) == 2     # in one process it flies


def test_register_refuses_a_reference_like_or_taken_name():
    from ftcgym.benchmark.scenarios import Scenario, register
    with pytest.raises(ValueError, match=r"a registered name has no ':'"):
        register(Scenario(name="mine:hover", env_id="ftcgym/Quadrotor-v0"))
    with pytest.raises(ValueError, match=r"'quad-hover' is already registered; give yours another name"):
        register(Scenario(name="quad-hover", env_id="ftcgym/Quadrotor-v0"))


def test_a_model_without_a_manifest_is_said_to_be_taken_for_a_task_model(tmp_path):
    """A plain SB3 .zip (no `ftcgym train` manifest) fails on its observation shape; the error says why it was
    read as a rotor-loss-recovery model and where the recipe for one's own model is."""
    sb3 = pytest.importorskip("stable_baselines3")
    from ftcgym.training.policy import load_policy
    env = gym.make("ftcgym/Quadrotor-v0", observation_format="flat", max_episode_seconds=0.2)
    sb3.PPO("MlpPolicy", env, n_steps=32, batch_size=32, device="cpu").save(tmp_path / "mine.zip")
    with pytest.raises(ValueError, match=r"mine.zip has no manifest.json beside it, so it was taken for a model of "
                                         r"ftcgym/RotorLossRecovery-v0.*own-policy.md"):
        load_policy(tmp_path / "mine.zip", gym.make("ftcgym/Quadrotor-v0"))


@pytest.mark.parametrize("action, message", [
    ("np.zeros(3)", r"policy 'bad_policy:Bad': action: expected shape \(4,\)"),
    ("np.full(4, np.nan)", r"policy 'bad_policy:Bad': action"),
    ("[0.5, 0.5][3]", r"policy 'bad_policy:Bad': its first step raised IndexError: list index out of range"),
])
def test_the_cli_rejects_a_policy_that_acts_wrongly_before_flying(tmp_path, action, message):
    (tmp_path / "bad_policy.py").write_text(f"import numpy as np\n\n\nclass Bad:\n    def __init__(self, env):\n"
                                            f"        pass\n\n    def reset(self, obs, info):\n        pass\n\n"
                                            f"    def act(self, obs, info):\n        return {action}\n")
    run = subprocess.run([str(FTCGYM), "bench", "--scenario", "quad-hover", "--policy", "bad_policy:Bad",
                          "--episodes", "2", "--out", str(tmp_path / "out")],
                         env={**os.environ, "PYTHONPATH": str(tmp_path)}, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert re.search(r"ftcgym bench: scenario 'quad-hover': " + message, run.stderr), run.stderr
    assert "retry" not in run.stderr and not (tmp_path / "out" / "results.json").exists()


@pytest.mark.parametrize("status, message", [
    ({"alarm": False, "alarm_time": None}, r"status\(\) gave \['alarm', 'alarm_time'\]; it must hold"),
    ({"alarm": True, "alarm_time": 0.0, "isolated": [2]}, r"status\(\)\['isolated'\] is \[2\]; accepted: None, "
                                                           r"a rotor index \(int\) or a name \(str\)"),
    ({"alarm": True, "alarm_time": 0.0, "isolated": np.array([2])}, r"status\(\)\['isolated'\] is array"),
])
def test_a_status_the_benchmark_cannot_score_is_named_at_the_first_step(monkeypatch, status, message):
    detector = _user_detector(monkeypatch, name="odd")
    detector.status = lambda: status
    env = DetectorWrapper(gym.make("ftcgym/Quadrotor-v0"), detector)
    with pytest.raises(ValueError, match=r"detector 'odd': " + message):
        env.reset(seed=0)
    detector.status = lambda: {"alarm": True, "alarm_time": 0.0, "isolated": np.int64(2)}   # numpy ints are ints
    env.reset(seed=0)


def test_an_entry_point_named_like_a_built_in_is_left_out_with_a_warning(monkeypatch):
    from importlib import metadata

    from ftcgym.agents.catalogue import POLICIES
    from ftcgym.benchmark.scenarios import PLUG_INS
    from ftcgym.registry import PluginNameWarning

    points = {"ftcgym.policies": [metadata.EntryPoint("nominal", "mypkg:Mine", "ftcgym.policies"),
                                  metadata.EntryPoint("mine", "mypkg:Mine", "ftcgym.policies")],
              "ftcgym.scenarios": [metadata.EntryPoint("quad-hover", "mypkg:hover", "ftcgym.scenarios")]}
    monkeypatch.setattr(metadata, "entry_points", lambda group: points.get(group, []))
    with pytest.warns(PluginNameWarning, match=r"policy: the entry point 'nominal' \(mypkg:Mine\) of group "
                                               r"'ftcgym.policies' has the name of a built-in or registered policy"):
        names = POLICIES.names()
    assert names.count("nominal") == 1 and "mine" in names
    with pytest.warns(PluginNameWarning, match=r"scenario: the entry point 'quad-hover'"):
        assert "quad-hover" not in PLUG_INS.installed()


def test_a_detector_that_fails_its_first_outputs_is_named_before_any_policy(monkeypatch):
    """check_setup resets the env once before the policies: a detector's own failure is not blamed on a policy."""
    from ftcgym.benchmark.runner import check_setup
    from ftcgym.benchmark.scenarios import Scenario
    monkeypatch.syspath_prepend(str(PLUGIN))
    scenario = Scenario(name="nan-detector", env_id="ftcgym/Quadrotor-v0", detector="bad_outputs:NanFirst")
    module = type(sys)("bad_outputs")
    from ftcgym_plugin_example.detector import RotorJumpDetector

    class NanFirst(RotorJumpDetector):
        def outputs(self):
            return {"excess": np.full(4, np.nan)}

    module.NanFirst = NanFirst
    monkeypatch.setitem(sys.modules, "bad_outputs", module)
    with pytest.raises(ValueError) as info:
        check_setup(scenario, policies=("nominal",))
    assert str(info.value).startswith("scenario 'nan-detector': detector 'rotor_jump': outputs()['excess'] is not "
                                      "finite")


def test_a_nan_alarm_time_is_named_with_its_detector(monkeypatch):
    """A detector whose alarm_time turns NaN mid-episode: the scoring error says which detector."""
    from ftcgym.benchmark.runner import run_episode
    from ftcgym.benchmark.scenarios import Scenario
    monkeypatch.syspath_prepend(str(PLUGIN))
    from ftcgym_plugin_example.detector import RotorJumpDetector

    class LateNan(RotorJumpDetector):
        name = "late_nan"

        def status(self):
            return {**super().status(), "alarm": True, "alarm_time": float("nan")} if self.count else super().status()

    module = type(sys)("late_nan")
    module.LateNan = LateNan
    monkeypatch.setitem(sys.modules, "late_nan", module)
    scenario = Scenario(name="late-nan", env_id="ftcgym/Quadrotor-v0", detector="late_nan:LateNan",
                        env_kwargs={"max_episode_seconds": 0.5, "faults": [{"kind": "rotor_loss", "target": 1,
                                                                            "time": 0.1}]})
    with pytest.raises(ValueError, match=r"detector 'late_nan': status\(\)'s alarm_time must be a finite time"):
        run_episode(scenario, "nominal", seed=0)
