"""Trained policies shipped with ftcgym: one folder per task, each holding what
`ftcgym train` wrote (`model.zip`, `vecnormalize.pkl`, `manifest.json` with the training command, seed,
steps, wall time and commit). The benchmark policies `learned-spin` and `learned-airspeed` load them."""
from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
# benchmark policy name -> training task (the folder here)
SHIPPED = {"learned-spin": "rotor-loss-recovery", "learned-airspeed": "airspeed-source"}


def shipped_path(policy: str) -> Path:
    """The folder of a shipped policy; FileNotFoundError naming what is shipped if it is missing."""
    if policy not in SHIPPED:
        raise ValueError(f"policy: {policy!r} is not a shipped learned policy; accepted: {list(SHIPPED)}")
    folder = HERE / SHIPPED[policy]
    if not (folder / "model.zip").is_file():
        shipped = [name for name, task in SHIPPED.items() if (HERE / task / "model.zip").is_file()]
        raise FileNotFoundError(f"policy: {policy!r} has no trained model in {folder}; shipped: {shipped}")
    return folder


def load_shipped(policy: str, env):
    """The shipped model of `policy` as a benchmark policy for `env` (needs the `train` extra)."""
    try:
        from ftcgym.training.policy import load_policy
    except ImportError as error:
        raise ImportError(f"policy {policy!r} needs stable-baselines3 and torch: pip install -c constraints.txt "
                          f"-e '.[train]' in the ftcgym clone ({error})") from error
    return load_policy(shipped_path(policy), env)


def learned_spin(env):
    """The benchmark policy `learned-spin` (catalogue entry of `ftcgym.agents.POLICIES`)."""
    return load_shipped("learned-spin", env)


def learned_airspeed(env):
    """The benchmark policy `learned-airspeed` (catalogue entry of `ftcgym.agents.POLICIES`)."""
    return load_shipped("learned-airspeed", env)
