"""Training configs: one YAML file per task, in the style of RL Zoo hyperparameter files.

    <task>:
      env_id: ftcgym/RotorLossRecovery-v0   # any registered id
      env_kwargs: {...}                     # gym.make keywords (the task's randomisation)
      wrappers: [loe_kalman]                # detectors to wrap env_id with (ftcgym.fdd.DETECTORS)
      default_algo: PPO
      checkpoint_freq: 100000               # env steps
      torch_threads: 1                      # torch.set_num_threads for the updates
      vec_env: auto                         # subproc (process per env), dummy (in this process), parallel, auto
      eval: {scenario: quad-rotor-loss-hover, episodes: 4, freq: 50000, env_kwargs: {}}
      pretrain: {method: dagger, env_kwargs: {expert: true}, ...}   # imitation first (imitation.DaggerSettings)
      PPO:                                  # one section per algorithm
        n_envs: 2
        n_timesteps: !!float 3e6
        policy: MlpPolicy
        normalize: {norm_obs: true, norm_reward: true}   # VecNormalize keywords; false: none
        policy_kwargs: {net_arch: [128, 128], activation_fn: relu}   # activation by name (ACTIVATIONS)
        n_steps: 1024                       # every other key goes to the algorithm's constructor
      SAC: {...}
      quick:                                # `--quick`: merged over the keys above (a run of about a minute)
        pretrain: {iterations: 3, steps_per_iteration: 4000}
        PPO: {n_envs: 1, n_timesteps: 2048, n_steps: 1024}

`load_config(name_or_path)` takes a path or the name of a built-in file in `ftcgym/training/configs`;
`load_config(..., quick=True)` merges the file's `quick` section over the rest first (`merge`: mappings key by
key, anything else replaced), then applies the command-line overrides. `rl_steps(config)` is the number of RL
steps a run takes: SB3 collects whole rollouts, so `total_steps` is rounded up to a multiple of one.
"""
from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field
from pathlib import Path

import gymnasium as gym

from ftcgym.benchmark.sweep import read_yaml
from ftcgym.models.checks import no_unknown

CONFIG_DIR = Path(__file__).with_name("configs")
ALGOS = ("PPO", "SAC")
#: `vec_env`: SB3's SubprocVecEnv ("subproc", one process per env), DummyVecEnv ("dummy", the envs stepped in turn
#: in the learner's process), `ftcgym.training.vec_env.ParallelVecEnv` ("parallel", the envs on every core through
#: shared memory), or "auto": subproc for more than one env. A step through a process pipe costs about 100 us on
#: a 2-core machine, so subproc pays only where an env step costs much more (docs/performance.md).
VEC_ENVS = ("auto", "subproc", "dummy", "parallel")
SECTION_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "policy_kwargs")
#: `policy_kwargs.activation_fn` by name (RL Zoo writes the class, `nn.ReLU`; YAML keeps to plain data).
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU", "silu": "SiLU"}


@dataclass
class TrainConfig:
    """A resolved training run: the task's settings and the chosen algorithm's section."""

    task: str
    env_id: str
    algo: str
    n_envs: int
    total_steps: int
    seed: int = 0
    policy: str = "MlpPolicy"
    env_kwargs: dict = field(default_factory=dict)
    wrappers: list = field(default_factory=list)
    normalize: dict | None = field(default_factory=lambda: {"norm_obs": True, "norm_reward": True})
    policy_kwargs: dict = field(default_factory=dict)
    hyperparams: dict = field(default_factory=dict)   # the algorithm's constructor keywords
    checkpoint_freq: int = 100_000
    eval: dict | None = None
    torch_threads: int = 1
    vec_env: str = "auto"          # VEC_ENVS
    pretrain: dict | None = None   # imitation pre-training (`imitation.dagger`); env_kwargs added for it
    source: str = ""
    quick: bool = False            # the file's `quick` section was merged in (`--quick`)

    def as_dict(self) -> dict:
        return asdict(self)


def builtin_tasks() -> list[str]:
    """Names of the built-in configs."""
    return sorted(path.stem for path in CONFIG_DIR.glob("*.yaml"))


def config_path(name_or_path: str) -> Path:
    """The YAML file of a built-in task name or a path."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ValueError(f"config: no file {name_or_path!r}")
        return path
    builtin = CONFIG_DIR / f"{name_or_path}.yaml"
    if not builtin.is_file():
        raise ValueError(f"config: {name_or_path!r} is neither a file nor a built-in task; "
                         f"built-in: {', '.join(builtin_tasks())}")
    return builtin


def merge(base: dict, overrides: dict) -> dict:
    """`base` with `overrides` merged in: mappings key by key (recursively), any other value replaced."""
    merged = copy.deepcopy(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


#: the keys of a task's body and what each must be (`_check_body`)
BODY_KEYS = {"env_id": str, "env_kwargs": dict, "wrappers": list, "default_algo": str, "checkpoint_freq": int,
             "torch_threads": int, "vec_env": str, "eval": dict, "pretrain": dict, "seed": int,
             **{algo: dict for algo in ALGOS}, "quick": dict}
_KINDS = {str: "text", dict: "a mapping", list: "a list", int: "a whole number"}


def _check_body(body: dict, where: str, overrides: bool = False) -> None:
    """ValueError naming the first key of a task's body (or of its `quick` overrides) that is unknown or of the
    wrong kind (a `None` value stands for the key's default), the first algorithm section key of the wrong kind,
    or a missing env_id."""
    no_unknown(body, BODY_KEYS, f"{where}: key")
    if "env_id" not in body and not overrides:
        raise ValueError(f"{where}: env_id is missing (the registered id to train on, e.g. "
                         f"ftcgym/RotorLossRecovery-v0)")
    for key, value in body.items():
        kind = BODY_KEYS[key]
        wrong = not isinstance(value, kind) or (kind is int and isinstance(value, bool))
        if value is not None and wrong:
            raise ValueError(f"{where}: {key}: expected {_KINDS[kind]}, got {value!r}")
    if not all(isinstance(name, str) for name in body.get("wrappers") or []):
        raise ValueError(f"{where}: wrappers: expected a list of detector names, got {body['wrappers']!r}")
    for key in ("checkpoint_freq", "torch_threads"):
        if body.get(key) is not None and body[key] < 1:
            raise ValueError(f"{where}: {key}: must be >= 1, got {body[key]!r}")
    for algo in ALGOS:
        for key, value in (body.get(algo) or {}).items():
            _check_section_value(f"{where}: {algo}.{key}", key, value)
    if body.get("quick") is not None:
        _check_body(body["quick"], f"{where}: quick", overrides=True)


def _check_env_id(env_id: str, where: str) -> None:
    """ValueError unless `env_id` is a registered Gymnasium id (ftcgym's are registered by importing it)."""
    import ftcgym  # noqa: F401  (registers the ftcgym/ ids)
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        raise ValueError(f"{where}: env_id: {error}") from None


def _check_section_value(where: str, key: str, value) -> None:
    """The section keys ftcgym reads itself (SECTION_KEYS) must be of their kind; the rest go to SB3."""
    if key in ("n_envs", "n_timesteps"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value or value < 0 or \
                value != int(value):
            raise ValueError(f"{where}: expected a whole number >= 0, got {value!r}")
    elif key == "policy" and not isinstance(value, str):
        raise ValueError(f"{where}: expected a policy name such as MlpPolicy, got {value!r}")
    elif key == "policy_kwargs" and not isinstance(value, dict):
        raise ValueError(f"{where}: expected a mapping of policy keywords, got {value!r}")
    elif key == "normalize" and not isinstance(value, (bool, dict)):
        raise ValueError(f"{where}: expected true, false or a mapping of VecNormalize keywords, got {value!r}")
    elif key == "normalize" and isinstance(value, dict):
        for flag in ("norm_obs", "norm_reward"):
            if flag in value and not isinstance(value[flag], bool):
                raise ValueError(f"{where}.{flag}: expected true or false, got {value[flag]!r}")


def load_config(name_or_path: str, algo: str | None = None, n_envs: int | None = None,
                total_steps: int | None = None, seed: int | None = None, pretrain_iterations: int | None = None,
                quick: bool = False) -> TrainConfig:
    """The run described by a config file (or built-in task name), with command-line overrides. `quick`: the
    file's `quick` section merged over it first; `pretrain_iterations`: the DAgger iterations (0: none)."""
    path = config_path(name_or_path)
    document = read_yaml(path)
    if not isinstance(document, dict) or len(document) != 1:
        raise ValueError(f"config {path}: expected one top-level key, the task name")
    (task, body), = document.items()
    if not isinstance(body, dict):
        raise ValueError(f"config {path}: the task {task!r} must map keys to settings")
    _check_body(body, f"config {path}")
    _check_env_id(body["env_id"], f"config {path}")
    body = copy.deepcopy(body)
    overrides = body.pop("quick", None)
    if quick:
        if not isinstance(overrides, dict):
            raise ValueError(f"config {path}: no `quick` section (the overrides of --quick)")
        body = merge(body, overrides)
    algo = (algo or body.get("default_algo") or "PPO").upper()
    if algo not in ALGOS:
        raise ValueError(f"algo: {algo!r}; accepted: {list(ALGOS)}")
    if not isinstance(body.get(algo), dict):
        raise ValueError(f"config {path}: no {algo} section; sections: {[a for a in ALGOS if body.get(a)]}")
    if "n_timesteps" not in body[algo] and total_steps is None:
        raise ValueError(f"config {path}: {algo}.n_timesteps is missing (the env steps to train for)")
    section = dict(body[algo])
    normalize = section.pop("normalize", True)
    normalize = {"norm_obs": True, "norm_reward": True} if normalize is True else (normalize or None)
    config = TrainConfig(
        task=task, env_id=body["env_id"], algo=algo,
        n_envs=int(n_envs or section.pop("n_envs", 1)),
        total_steps=int(section.pop("n_timesteps") if total_steps is None else total_steps),
        seed=int(body.get("seed", 0) if seed is None else seed), policy=section.pop("policy", "MlpPolicy"),
        env_kwargs=body.get("env_kwargs") or {}, wrappers=list(body.get("wrappers") or []),
        normalize=normalize, policy_kwargs=section.pop("policy_kwargs", None) or {},
        checkpoint_freq=int(body.get("checkpoint_freq", 100_000)), eval=body.get("eval"),
        torch_threads=int(body.get("torch_threads", 1)), vec_env=body.get("vec_env", "auto"),
        pretrain=body.get("pretrain"), source=str(path), quick=bool(quick))
    if config.vec_env not in VEC_ENVS:
        raise ValueError(f"config {path}: vec_env: {config.vec_env!r}; accepted: {list(VEC_ENVS)}")
    section.pop("n_envs", None)
    section.pop("n_timesteps", None)
    config.hyperparams = section
    if pretrain_iterations is not None:
        if pretrain_iterations < 0:
            raise ValueError(f"pretrain iterations must be >= 0, got {pretrain_iterations}")
        if pretrain_iterations == 0:
            config.pretrain = None
        elif not config.pretrain:
            raise ValueError(f"config {path}: no `pretrain` section, so no DAgger iterations to set")
        else:
            config.pretrain = {**config.pretrain, "iterations": int(pretrain_iterations)}
    activation = config.policy_kwargs.get("activation_fn", "tanh")
    if activation not in ACTIVATIONS:
        raise ValueError(f"policy_kwargs.activation_fn: {activation!r}; accepted: {list(ACTIVATIONS)}")
    least = 0 if config.pretrain else 1      # a pre-trained policy may ship without RL fine-tuning
    if config.n_envs < 1 or config.total_steps < least:
        raise ValueError(f"n_envs must be >= 1 and total steps >= {least}, "
                         f"got {config.n_envs} and {config.total_steps}")
    return config


def rollout_steps(config: TrainConfig) -> int | None:
    """Env steps (all envs together) SB3 collects between two checks of the step budget: PPO's rollout,
    n_steps x n_envs; SAC's train_freq x n_envs (None when train_freq counts episodes)."""
    if config.algo == "PPO":
        return int(config.hyperparams.get("n_steps", 2048)) * config.n_envs
    frequency = config.hyperparams.get("train_freq", 1)
    if isinstance(frequency, (list, tuple)):
        if len(frequency) != 2 or str(frequency[1]) != "step":
            return None
        frequency = frequency[0]
    return int(frequency) * config.n_envs


def rl_steps(config: TrainConfig) -> int:
    """The RL steps a run of `config` takes: `total_steps` rounded up to whole rollouts (`rollout_steps`),
    as SB3's `learn` stops only between them."""
    unit = rollout_steps(config)
    if config.total_steps <= 0 or not unit:
        return max(config.total_steps, 0)
    return -(-config.total_steps // unit) * unit


def runs_pretraining(config: TrainConfig, init_from=None) -> bool:
    """Whether a run starts with the config's imitation pre-training (PPO only). From a saved model
    (`init_from`) only when the `pretrain` section says `continue_from_init: true` (continued imitation);
    otherwise such a run is fine-tuning by RL alone."""
    if not config.pretrain or config.algo != "PPO":
        return False
    return init_from is None or bool(config.pretrain.get("continue_from_init", False))


def dagger_plan(config: TrainConfig) -> tuple[int, int]:
    """(iterations, env steps per iteration) of the config's DAgger: `steps_per_iteration` rounded down to
    whole steps of all envs, as `imitation.dagger` flies it."""
    from ftcgym.training.imitation import DaggerSettings
    section = {k: v for k, v in (config.pretrain or {}).items() if k != "env_kwargs"}
    settings = DaggerSettings.from_config(section)
    return settings.iterations, max(settings.steps_per_iteration // config.n_envs, 1) * config.n_envs


def plan_line(config: TrainConfig, out, init_from=None) -> str:
    """One line saying what `ftcgym train` will run: task, algorithm, envs, RL steps (and their rounding),
    the DAgger iterations, the seed and the output folder."""
    steps = rl_steps(config)
    rl = f"{steps} RL steps"
    if steps != config.total_steps:
        envs = f"{config.n_envs} env{'s' if config.n_envs > 1 else ''}"
        unit = (f"n_steps {config.hyperparams.get('n_steps', 2048)} x {envs}" if config.algo == "PPO"
                else f"train_freq x {envs}")
        rl += f" ({config.total_steps} asked, rounded up to whole rollouts of {unit} = {rollout_steps(config)})"
    if runs_pretraining(config, init_from):
        iterations, per_iteration = dagger_plan(config)
        dagger = f"DAgger {iterations} iteration{'s' if iterations > 1 else ''} x {per_iteration} steps, then "
    elif config.pretrain:
        dagger = f"no DAgger ({'--init-from' if init_from is not None else config.algo}), "
    else:
        dagger = ""
    quick = " (--quick)" if config.quick else ""
    start = f" from {init_from}" if init_from is not None else ""
    envs = f"{config.n_envs} env{'s' if config.n_envs > 1 else ''}"
    return (f"ftcgym train: {config.task}{quick}, {config.algo}, {envs}, seed {config.seed}: {dagger}{rl}{start}; "
            f"writing to {out}")
