"""Stable-Baselines3 training and evaluation of recovery policies on the task envs of `ftcgym.task_envs`.

- `config`: task configs in the style of RL Zoo hyperparameter files (`load_config`)
- `train`: `train.train(config, out)`: vectorised envs, VecNormalize, checkpoints, evaluation, manifest
- `policy`: `LearnedPolicy`, a saved model behind the benchmark's policy interface
- `evaluate`: `evaluate_model`, the benchmark on a saved model

Stable-Baselines3 and torch (the `train` extra) are imported only by `train`, `policy`, `evaluate`
and `callbacks`.
"""


def __getattr__(name):
    """`LearnedPolicy`, `load_config`, `evaluate_model` on first use (SB3 and torch load lazily). The
    training entry point is `ftcgym.training.train.train` (the submodule's name would shadow it here)."""
    from importlib import import_module
    homes = {"LearnedPolicy": "policy", "load_config": "config", "TrainConfig": "config",
             "evaluate_model": "evaluate"}
    if name not in homes:
        raise AttributeError(f"module 'ftcgym.training' has no attribute {name!r}")
    return getattr(import_module(f"ftcgym.training.{homes[name]}"), name)


__all__ = ["LearnedPolicy", "TrainConfig", "evaluate_model", "load_config"]
