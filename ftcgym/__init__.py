"""ftcgym: Gymnasium environments, fault detectors and a benchmark for fault-tolerant flight control."""
import hashlib
import os
import shutil
from functools import partial
from pathlib import Path

from gymnasium.envs.registration import register, registry
from numba.core import config as _numba_config

__version__ = "0.1.0"
_KEPT_CACHES = 4
#: where the compiled functions and everything they can import live (the layers below task_envs, README 'Layout')
_COMPILED_LAYERS = ("", "models/", "envs/", "fdd/", "agents/")


def _compiled_cache_dir() -> Path | None:
    """Where numba keeps the package's compiled functions: a folder named by a fingerprint of the source files of
    the layers that hold them (path, time stamp, size), under NUMBA_CACHE_DIR or the user's cache folder. numba
    checks a cached function against its own file only, so a kernel that calls one from another module would
    outlive an edit of that module; with the fingerprint an edit there starts a fresh cache. The newest few
    folders are kept. None where the folder cannot be made (numba then caches beside the sources, as by
    default)."""
    package = Path(__file__).parent
    stamp = hashlib.sha1()
    for path in sorted(path for folder in _COMPILED_LAYERS for path in package.glob(f"{folder}*.py")):
        info = path.stat()
        stamp.update(f"{path.relative_to(package)}:{info.st_mtime_ns}:{info.st_size};".encode())
    root = Path(os.environ.get("NUMBA_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"),
                                                               "ftcgym", "numba"))
    folder = root / f"ftcgym-{stamp.hexdigest()[:16]}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    older = sorted(root.glob("ftcgym-*"), key=lambda p: p.stat().st_mtime, reverse=True)[_KEPT_CACHES:]
    for stale in older:
        if stale != folder:
            shutil.rmtree(stale, ignore_errors=True)
    return folder


# before any module defines a compiled function (numba reads the setting when it sets up a function's cache)
_CACHE = _compiled_cache_dir()
if _CACHE is not None:
    _numba_config.CACHE_DIR = str(_CACHE)

_ENVS = {
    "ftcgym/Quadrotor-v0": "ftcgym.envs.quadrotor:QuadrotorEnv",
    "ftcgym/QuadPlane-v0": "ftcgym.envs.quadplane:QuadPlaneEnv",
    "ftcgym/QuadPlaneAutopilot-v0": "ftcgym.task_envs.autopilot:QuadPlaneAutopilotEnv",
    "ftcgym/RotorLossRecovery-v0": "ftcgym.task_envs.rotor_loss_recovery:RotorLossRecoveryEnv",
    "ftcgym/AirspeedSource-v0": "ftcgym.task_envs.airspeed_source:AirspeedSourceEnv",
}


def _parallel(env_id: str, **kwargs):
    """The vector entry point of the envs above (`ftcgym.vector.make_parallel`, imported when first used)."""
    from .vector import make_parallel
    return make_parallel(env_id, **kwargs)


# Without Gymnasium's passive env checker: its first reset marks itself done before the env runs, so a reset the
# env refuses (a NaN in `options`, which a user then corrects) left every later step() raising TypeError inside
# the checker (gymnasium 1.4). The suite runs gymnasium's and SB3's check_env on every id instead.
for _id, _entry in _ENVS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry, vector_entry_point=partial(_parallel, _id), disable_env_checker=True)
