"""A model saved by `ftcgym train` (model.zip, vecnormalize.pkl, manifest.json) and `SavedModelPolicy`, the
base of the benchmark policies that fly one (`policy.LearnedPolicy`, `airspeed_task.LearnedAirspeedPolicy`)."""
from __future__ import annotations

import functools
import json
import pickle
import re
import zipfile
from pathlib import Path

import numpy as np
from gymnasium import spaces

MODEL_FILE, NORMALIZER_FILE, MANIFEST_FILE = "model.zip", "vecnormalize.pkl", "manifest.json"


def model_files(path) -> tuple[Path, Path, Path]:
    """(model, VecNormalize statistics, manifest) of a training output folder or its model .zip."""
    path = Path(path)
    folder, model = (path, path / MODEL_FILE) if path.is_dir() else (path.parent, path)
    if not model.is_file():
        raise FileNotFoundError(f"model: no file {model}")
    stem = model.name[:-len(".zip")] if model.name.endswith(".zip") else model.name
    checkpoint = re.fullmatch(r"(.+)_(\d+)_steps", stem)    # CheckpointCallback's names
    normalizer = folder / (NORMALIZER_FILE if stem == "model" else
                           f"{checkpoint[1]}_vecnormalize_{checkpoint[2]}_steps.pkl" if checkpoint else
                           f"{stem}_{NORMALIZER_FILE}")
    manifest = next((f / MANIFEST_FILE for f in (folder, folder.parent) if (f / MANIFEST_FILE).is_file()),
                    folder / MANIFEST_FILE)
    return model, normalizer, manifest


def load_normalizer(path):
    """The pickled VecNormalize saved beside a model (statistics only: no env attached, not updating)."""
    with open(path, "rb") as file:
        normalizer = pickle.load(file)
    normalizer.training = False
    return normalizer


class SavedModelPolicy:
    """Loading and deterministic prediction shared by the learned benchmark policies. Subclasses take
    (model, normalizer, env_id, task_kwargs, env, **kwargs) and set `DEFAULT_ENV_ID`."""

    DEFAULT_ENV_ID: str = ""

    @classmethod
    def load(cls, path, env=None, **kwargs):
        """The model saved by `ftcgym train` at `path` (the output folder or its .zip) for `env`; `kwargs`
        go to the constructor. The files are read once per process while they stay as they are
        (`_loaded_files`): a benchmark makes a policy per episode, and loading a model costs about a second."""
        files = model_files(path)
        config, model, normalizer = _loaded_files(*map(str, files), _stamp(files))
        return cls(model, normalizer, config.get("env_id", cls.DEFAULT_ENV_ID), config.get("env_kwargs"), env,
                   **kwargs)

    def predict(self, observation) -> np.ndarray:
        """The model's deterministic action for one (unnormalised) observation."""
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        return deterministic_action(self.model, observation)


def deterministic_action(model, observation) -> np.ndarray:
    """`model.predict(observation, deterministic=True)`'s action for one observation, without the checks and
    conversions SB3 makes around the network on every call (a third of its cost for the shipped policies): the
    same modules on the same tensor, so the same bits (`tests/test_training.py`). That path is taken where the
    observation and action spaces are both Box; anything else goes through `model.predict`."""
    import torch as th  # the `train` extra, as the model itself

    policy = model.policy
    space = policy.observation_space
    if (not isinstance(space, spaces.Box) or not isinstance(policy.action_space, spaces.Box)
            or np.shape(observation) != space.shape):
        action, _ = model.predict(observation, deterministic=True)
        return np.asarray(action)
    if policy.training:                      # as SB3's predict, which sets it on every call
        policy.set_training_mode(False)
    with th.no_grad():
        actions = policy._predict(th.as_tensor(np.asarray(observation)).reshape(1, *space.shape), deterministic=True)
    actions = actions.cpu().numpy().reshape(policy.action_space.shape)
    if policy.squash_output:
        return policy.unscale_action(actions)
    return np.clip(actions, policy.action_space.low, policy.action_space.high)


def read_manifest(path) -> dict:
    """The manifest a training run wrote at `path` ({} where there is none): a JSON object whose `config`, if
    any, is one too; anything else is a ValueError naming the file."""
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        manifest = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not a training manifest (JSON: {error})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("config", {}), dict):
        raise ValueError(f"{path}: not a training manifest (expected a JSON object with a 'config' object)")
    return manifest


@functools.lru_cache(maxsize=8)
def _loaded_files(model_path: str, normalizer_path: str, manifest_path: str, stamp: tuple) -> tuple:
    """(config, model, normalizer) of a saved model's files; `stamp` (`_stamp`) keys a file changed on disk anew.
    The model and normalizer are shared by the policies made from them: they only predict (the normalizer does
    not update, `load_normalizer`)."""
    from ftcgym.training.train import algorithm_class
    config = read_manifest(manifest_path).get("config", {})
    try:
        model = algorithm_class(config.get("algo") or _algo_of(Path(model_path))).load(model_path, device="cpu")
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:   # what a damaged archive raises
        raise ValueError(f"{model_path}: not a model saved by ftcgym train or SB3 ({type(error).__name__}: "
                         f"{error})") from None
    normalizer = load_normalizer(normalizer_path) if Path(normalizer_path).is_file() else None
    return config, model, normalizer


def _stamp(files) -> tuple:
    """(modification time ns, size) of each of `files` that exists, None for one that does not."""
    stats = [path.stat() if path.is_file() else None for path in files]
    return tuple(None if st is None else (st.st_mtime_ns, st.st_size) for st in stats)


def _algo_of(model_path: Path) -> str:
    """The algorithm of a model saved without a manifest, from the zip's stored class name."""
    with zipfile.ZipFile(model_path) as archive:
        data = json.loads(archive.read("data"))
    text = json.dumps(data.get("policy_class", ""))
    return "SAC" if "sac" in text.lower() else "PPO"
