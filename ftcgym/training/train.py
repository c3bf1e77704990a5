"""`train(config, out)`: one Stable-Baselines3 run of a task config.

Builds `n_envs` copies of the config's env (the config's `vec_env`: by default SubprocVecEnv for more than
one, DummyVecEnv for one; or ParallelVecEnv; each in a Monitor), VecNormalize, the algorithm, and callbacks:
checkpoints (with VecNormalize statistics), the benchmark-metric evaluation, a progress bar. TensorBoard logs go
to OUT/tb when tensorboard is installed.
Writes to OUT:

    model.zip, vecnormalize.pkl     the final model and its observation/reward normalisation
    manifest.json                   command, config, seed, steps, wall time, git commit, versions (and the
                                    imitation pre-training's per-iteration statistics when the config has one)
    checkpoints/                    model_<steps>_steps.zip, model_vecnormalize_<steps>_steps.pkl; with
                                    pre-training, dagger_<i>.zip, dagger_<i>_vecnormalize.pkl after iteration i
    pretrained/model.zip, pretrained/vecnormalize.pkl   after imitation pre-training, before RL
    best/model.zip, best/vecnormalize.pkl, evaluations.jsonl   when the config has an `eval` section
    logs/progress.csv               training curves (SB3's logger)
    tb/                             TensorBoard event files (when tensorboard is installed)

RL runs `config.rl_steps(config)` steps (the requested ones rounded up to whole rollouts); tqdm bars with a
total and an ETA cover the DAgger's labelled steps and the RL steps. Ctrl-C publishes the model so far
(`TrainingInterrupted`).
"""
from __future__ import annotations

import contextlib
import functools
import importlib.util
import inspect
import json
import platform
import signal
import subprocess
import threading
import time
from pathlib import Path

import gymnasium as gym

from ftcgym.benchmark.outputs import OutputFolder
from ftcgym.models.checks import no_unknown
from ftcgym.training.config import ACTIVATIONS, TrainConfig, dagger_plan, rl_steps, runs_pretraining
from ftcgym.training.policy import MANIFEST_FILE, MODEL_FILE, NORMALIZER_FILE

#: what a run writes in OUT as it trains (the final files are staged and published at the end)
IN_PLACE = ("checkpoints", "pretrained", "best", "evaluations.jsonl", "logs", "tb")


#: the constructor keywords `_train` sets itself (the config's policy, the vector env, the seed, ...)
SET_BY_TRAIN = {"self", "policy", "env", "seed", "policy_kwargs", "device", "verbose"}


def check_hyperparams(config: TrainConfig) -> None:
    """The algorithm section's other keys must be keywords of the SB3 algorithm's constructor (a misspelt one is
    a ValueError with the closest name), before any env is built."""
    accepted = {name for name in inspect.signature(algorithm_class(config.algo).__init__).parameters
                if not name.startswith("_")} - SET_BY_TRAIN
    no_unknown(config.hyperparams, accepted, f"config {config.source}: {config.algo} keyword")


def algorithm_class(name: str):
    """The SB3 class of an algorithm name (PPO, SAC)."""
    import stable_baselines3
    try:
        return {"PPO": stable_baselines3.PPO, "SAC": stable_baselines3.SAC}[name.upper()]
    except KeyError:
        raise ValueError(f"algo: {name!r}; accepted: ['PPO', 'SAC']") from None


def make_env(env_id: str, env_kwargs: dict, wrappers: list) -> gym.Env:
    """One training env: `gym.make(env_id, **env_kwargs)` wrapped with the named detectors and a Monitor.
    Module-level (with `import ftcgym` at the top of the package), so SubprocVecEnv workers can build it."""
    from stable_baselines3.common.monitor import Monitor

    import ftcgym  # noqa: F401  (registers the ids in a worker process)
    from ftcgym.fdd import wrap_with_detector

    env = gym.make(env_id, **env_kwargs)
    for name in wrappers:
        env = wrap_with_detector(name, env)
    return Monitor(env)


def build_vec_env(config: TrainConfig, extra_kwargs: dict | None = None, normalize: bool = True):
    """The config's vectorised (and, if asked, normalised) training env, seeded with config.seed."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    from .vec_env import ParallelVecEnv

    factory = functools.partial(make_env, config.env_id, {**config.env_kwargs, **(extra_kwargs or {})},
                                config.wrappers)
    named = {"subproc": SubprocVecEnv, "dummy": DummyVecEnv, "parallel": ParallelVecEnv}
    vec_cls = named.get(config.vec_env) or (SubprocVecEnv if config.n_envs > 1 else DummyVecEnv)   # "auto"
    venv = vec_cls([factory] * config.n_envs)
    venv.seed(config.seed)
    if config.normalize and normalize:
        gamma = config.hyperparams.get("gamma", 0.99)
        venv = VecNormalize(venv, gamma=gamma, **config.normalize)
    return venv


class TrainingInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C (KeyboardInterrupt) after its model existed: the model so far, its statistics
    and a manifest with `"interrupted"` were published to `out` before this was raised."""

    def __init__(self, out: Path, manifest: dict):
        super().__init__(f"interrupted {manifest['interrupted']}; the model so far is in {out}")
        self.out, self.manifest = Path(out), manifest


def train(config: TrainConfig, out: str | Path, progress: bool = True, command: str | None = None,
          verbose: int = 0, init_from: str | Path | None = None) -> dict:
    """Run `config`, write the outputs listed in the module docstring to `out`; returns the manifest.
    `init_from`: a saved model (folder or .zip, e.g. a shipped policy) whose weights and observation
    statistics start the run instead of the config's pre-training (fine-tuning), or before it where the
    `pretrain` section says `continue_from_init: true` (continued DAgger; `config.runs_pretraining`). Holds
    `out`'s lock from the start (`outputs.OutputFolder`: FolderInUse if another run holds it); the model, its
    statistics and the manifest are staged and published together at the end. RL runs `config.rl_steps(config)`
    steps: the requested `total_steps` rounded up to whole rollouts.

    A KeyboardInterrupt (Ctrl-C) during the pre-training or RL publishes the model so far the same way, its
    manifest marked `"interrupted"`, and raises `TrainingInterrupted`; one before the model is built leaves
    the folder as it was."""
    if (config.pretrain or {}).get("continue_from_init") and init_from is None:
        raise ValueError("pretrain.continue_from_init: DAgger continues from a saved model; give one (--init-from)")
    check_hyperparams(config)
    with OutputFolder(out) as folder:
        return _train(config, folder, progress, command, verbose, init_from)


def _train(config: TrainConfig, folder: OutputFolder, progress: bool, command: str | None, verbose: int,
           init_from: str | Path | None) -> dict:
    import torch
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback

    from ftcgym.training.callbacks import BenchmarkEvalCallback, TqdmProgressCallback

    # Small MLPs update fastest on one thread; more threads contend with the env workers (and, on a
    # shared 2-core machine, slowed PPO's update by ~10x).
    torch.set_num_threads(config.torch_threads)
    out = folder.path
    steps = rl_steps(config)
    venv = build_vec_env(config)
    try:
        tensorboard = importlib.util.find_spec("tensorboard") is not None
        if not tensorboard and (progress or verbose):
            print("ftcgym train: tensorboard is not installed, so no TensorBoard logs (pip install tensorboard)")
        try:
            model = algorithm_class(config.algo)(
                config.policy, venv, seed=config.seed, policy_kwargs=policy_kwargs(config) or None, device="cpu",
                verbose=verbose, **config.hyperparams)
        except (TypeError, ValueError, AssertionError) as error:   # what SB3 and torch say of a bad setting
            raise ValueError(f"config {config.source}: the {config.algo} section (or its policy_kwargs) does not "
                             f"build a model: {type(error).__name__}: {error}") from error
    except BaseException:
        close_quietly(venv)
        raise
    # Our own logger: training curves always land in OUT/logs/progress.csv (and OUT/tb with tensorboard);
    # SB3's default would open an empty SB3-<date> folder in /tmp for every run.
    model.set_logger(configure_logger(str(out / "logs"), ["csv"] + (["stdout"] if verbose else []),
                                      str(out / "tb") if tensorboard else None))
    callbacks = [CheckpointCallback(max(config.checkpoint_freq // config.n_envs, 1), str(out / "checkpoints"),
                                    name_prefix="model", save_vecnormalize=bool(config.normalize))]
    if config.eval:
        callbacks.append(BenchmarkEvalCallback(
            int(config.eval.get("freq", 50_000)), config.eval.get("scenario", "quad-rotor-loss-hover"),
            int(config.eval.get("episodes", 4)), int(config.eval.get("seed", 1000)),
            config.eval.get("env_kwargs"), config.env_id, config.env_kwargs, out / "best",
            out / "evaluations.jsonl", verbose=1 if progress or verbose else 0))
    bar = TqdmProgressCallback(steps) if progress else None   # tqdm: a total and an ETA over the RL steps
    if bar is not None:
        callbacks.append(bar)
    started = time.perf_counter()
    pretraining: list[dict] | None = None
    pretrain_time = 0.0
    interrupted = None
    try:
        if init_from is not None:
            _initialise(model, venv, init_from, config)
        if config.pretrain and config.algo != "PPO":
            print(f"ftcgym train: the config's imitation pre-training fits PPO's actor-critic; "
                  f"skipped for {config.algo}")
        elif runs_pretraining(config, init_from):
            pretraining = []
            try:
                _pretrain(config, model, venv, out, pretraining, progress=progress, verbose=bool(verbose),
                          tensorboard=tensorboard)
            except KeyboardInterrupt:
                interrupted = f"in DAgger iteration {len(pretraining) + 1} of {dagger_plan(config)[0]}"
                raise
        pretrain_time = time.perf_counter() - started
        if steps > 0:
            try:
                model.learn(steps, callback=CallbackList(callbacks))
            except KeyboardInterrupt:
                interrupted = f"at RL step {model.num_timesteps} of {steps}"
                raise
    except KeyboardInterrupt:
        if interrupted is None:          # between the phases
            interrupted = f"at RL step {model.num_timesteps} of {steps}"
        if bar is not None:
            bar.close()
        if pretraining is not None and not pretrain_time:
            pretrain_time = time.perf_counter() - started
    with _sigint_ignored():              # a second Ctrl-C must not leave a half-written model
        wall_time = time.perf_counter() - started
        model.save(folder.staged(MODEL_FILE))
        if config.normalize:
            venv.save(str(folder.staged(NORMALIZER_FILE)))
        close_quietly(venv)
        manifest = _manifest(config, model, wall_time, command, rl_time=wall_time - pretrain_time)
        manifest["init_from"] = str(init_from) if init_from is not None else None
        manifest["interrupted"] = interrupted
        if pretraining is not None:
            manifest["pretrain"] = {"wall_time_s": pretrain_time, "iterations": pretraining}
        folder.staged(MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
        folder.publish(also=tuple(name for name in IN_PLACE if (out / name).exists()))
    if interrupted is not None:
        raise TrainingInterrupted(out, manifest)
    return manifest


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored inside the block (in the main thread; elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def close_quietly(venv) -> None:
    """Close a VecEnv; after a Ctrl-C its worker processes may already have quit (SB3's workers end on
    KeyboardInterrupt), so a broken pipe ends them by force instead of raising."""
    try:
        venv.close()
    except (OSError, EOFError):
        inner = venv
        while hasattr(inner, "venv"):
            inner = inner.venv
        for process in getattr(inner, "processes", []):
            process.terminate()


def policy_kwargs(config: TrainConfig) -> dict:
    """The config's policy_kwargs for SB3, `activation_fn` turned from its name into the torch class."""
    import torch

    kwargs = dict(config.policy_kwargs)
    if "activation_fn" in kwargs:
        kwargs["activation_fn"] = getattr(torch.nn, ACTIVATIONS[kwargs["activation_fn"]])
    return kwargs


def _initialise(model, venv, path, config: TrainConfig) -> None:
    """Start from the weights and VecNormalize statistics saved at `path` (same algorithm and network);
    the Gaussian policy's log std is reset to the config's `policy_kwargs.log_std_init` when it sets one."""
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    from ftcgym.training.policy import load_normalizer, model_files

    model_path, normalizer_path, _ = model_files(path)
    saved = algorithm_class(config.algo).load(model_path, device="cpu")
    try:
        model.policy.load_state_dict(saved.policy.state_dict())
    except RuntimeError as error:
        raise ValueError(f"init_from: {model_path} does not fit the config's {config.algo} network ({error})") from None
    if isinstance(venv, VecNormalize) and normalizer_path.is_file():
        venv.obs_rms = load_normalizer(normalizer_path).obs_rms
    log_std = (config.policy_kwargs or {}).get("log_std_init")
    if log_std is not None and hasattr(model.policy, "log_std"):
        with torch.no_grad():
            model.policy.log_std.fill_(log_std)


def _pretrain(config: TrainConfig, model, venv, out: Path, history: list, progress: bool, verbose: bool,
              tensorboard: bool = False) -> None:
    """Imitation pre-training (`imitation.dagger`) on its own copy of the envs with the section's
    env_kwargs (the expert's labels); fills the run's VecNormalize observation statistics, appends each
    iteration's statistics to `history` and checkpoints the policy so far after each
    (OUT/checkpoints/dagger_<i>.zip and dagger_<i>_vecnormalize.pkl), then saves the pre-trained model to
    OUT/pretrained (model.zip, vecnormalize.pkl) before any RL. `progress`: a tqdm bar over the labelled
    steps of all iterations (a total and an ETA), the iterations' lines printed above it. `tensorboard`: each
    iteration's statistics also go to OUT/tb as dagger/* against the labelled samples so far."""
    from stable_baselines3.common.vec_env import VecNormalize
    from tqdm import tqdm

    from ftcgym.training.imitation import DaggerSettings, dagger

    section = dict(config.pretrain)
    extra = section.pop("env_kwargs", None) or {}
    settings = DaggerSettings.from_config(section)
    iterations, per_iteration = dagger_plan(config)
    normalizer = venv if isinstance(venv, VecNormalize) else None
    checkpoints = out / "checkpoints"

    logger = configure_logger(str(out / "logs"), [], str(out / "tb")) if tensorboard else None

    def checkpoint(stats: dict) -> None:
        history.append(stats)
        if logger is not None:
            for key in ("action_mse", "beta", "crash_rate", "mean_return"):
                if stats[key] is not None:
                    logger.record(f"dagger/{key}", stats[key])
            logger.dump(step=stats["samples"])
        checkpoints.mkdir(parents=True, exist_ok=True)
        name = f"dagger_{stats['iteration'] + 1}"
        model.save(checkpoints / f"{name}.zip")
        if normalizer is not None:
            normalizer.save(str(checkpoints / f"{name}_{NORMALIZER_FILE}"))

    bar = tqdm(total=iterations * per_iteration, unit="step", desc="DAgger", dynamic_ncols=True) if progress else None
    log = bar.write if bar is not None else print if verbose else (lambda *_: None)
    expert_venv = build_vec_env(config, extra, normalize=False)
    try:
        dagger(model, expert_venv, settings, normalizer, seed=config.seed, log=log, progress=bar,
               on_iteration=checkpoint)
    finally:
        if bar is not None:
            bar.close()
        if logger is not None:
            logger.close()
        close_quietly(expert_venv)
    folder = out / "pretrained"
    folder.mkdir(parents=True, exist_ok=True)
    model.save(folder / MODEL_FILE)
    if normalizer is not None:
        normalizer.save(str(folder / NORMALIZER_FILE))


def configure_logger(folder: str, formats: list[str], tensorboard_folder: str | None):
    """An SB3 logger writing `formats` to `folder` and, when given, TensorBoard event files to its own folder."""
    from stable_baselines3.common.logger import KVWriter, Logger, TensorBoardOutputFormat, make_output_format

    writers: list[KVWriter] = [make_output_format(f, folder) for f in formats]
    if tensorboard_folder is not None:
        writers.append(TensorBoardOutputFormat(tensorboard_folder))
    return Logger(folder, writers)


def _manifest(config: TrainConfig, model, wall_time: float, command: str | None, rl_time: float) -> dict:
    from importlib import metadata

    def version(name):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None
    return {
        "command": command,
        "task": config.task,
        "config": config.as_dict(),
        "seed": config.seed,
        "algo": config.algo,
        "n_envs": config.n_envs,
        "total_steps": config.total_steps,
        "requested_steps": config.total_steps,      # RL steps asked for (the config's or --total-steps)
        "rl_steps": rl_steps(config),               # ... rounded up to whole rollouts: what a full run takes
        "steps": int(model.num_timesteps),          # ... and what this run took
        "quick": config.quick,
        "wall_time_s": wall_time,
        "steps_per_s": model.num_timesteps / rl_time if rl_time > 0 else None,   # RL steps over RL time
        "git_commit": git_commit(),
        "ftcgym_version": version("ftcgym"),
        "versions": {name: version(name) for name in ("stable-baselines3", "torch", "gymnasium", "pybullet")},
        "python": platform.python_version(),
        "files": {"model": MODEL_FILE, "vecnormalize": NORMALIZER_FILE if config.normalize else None},
    }


def git_commit() -> str | None:
    """The checkout's HEAD commit, with "-dirty" if tracked files differ; None outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("-dirty" if dirty else "")
