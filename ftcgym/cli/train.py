"""`ftcgym train`: train a recovery policy with Stable-Baselines3 (`ftcgym.training`); SB3 and torch are
imported only when it runs."""
from __future__ import annotations

import argparse
import os
import shlex
import sys

from .common import non_negative_int, positive_int


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "train", help="train a recovery policy with Stable-Baselines3",
        description="Train a policy from a task config (YAML in the style of RL Zoo hyperparameter files). "
                    "Writes the model, its VecNormalize statistics, checkpoints, evaluations and a manifest "
                    "to --out.")
    parser.add_argument("--config", required=True, metavar="FILE_OR_TASK",
                        help="a YAML config file or a built-in task (ftcgym/training/configs: rotor-loss-recovery, "
                             "airspeed-source, airspeed-source-finetune)")
    parser.add_argument("--algo", type=str.upper, choices=("PPO", "SAC"),
                        help="algorithm (default: the config's default_algo)")
    parser.add_argument("--n-envs", type=positive_int, metavar="N", help="parallel envs (default: the config's)")
    parser.add_argument("--total-steps", type=non_negative_int, metavar="N",
                        help="env steps to train for after any pre-training (default: the config's n_timesteps; "
                             "rounded up to whole rollouts, n_steps x n_envs for PPO; 0 with a `pretrain` section: "
                             "imitation only)")
    parser.add_argument("--pretrain-iterations", type=non_negative_int, metavar="N",
                        help="DAgger iterations of the config's `pretrain` section (0: no pre-training)")
    parser.add_argument("--quick", action="store_true",
                        help="a run of about a minute to try the pipeline: the config's `quick` section merged over "
                             "it (few DAgger iterations and samples, few RL steps, one env); the other options "
                             "still apply on top (default --out: train_out/<task>-<algo>-seed<S>-quick)")
    parser.add_argument("--seed", type=non_negative_int, metavar="S", help="seed (default: the config's, else 0)")
    parser.add_argument("--out", metavar="DIR", help="output directory (default: train_out/<task>-<algo>-seed<S>)")
    parser.add_argument("--init-from", metavar="MODEL",
                        help="start from a saved model (a training output folder or .zip, e.g. a shipped policy's "
                             "folder) instead of the config's pre-training: fine-tuning")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="show progress bars, with ETAs, over the DAgger steps and the RL steps (default: on)")
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    """Say what will run, in one line, before anything slow loads; train; Ctrl-C saves the model so far,
    says where in one line on stderr and exits with status 130."""
    try:
        return _run(args, argv)
    except KeyboardInterrupt as interrupt:
        manifest = getattr(interrupt, "manifest", None)      # a TrainingInterrupted: the model so far was saved
        if manifest is not None:
            print(f"ftcgym train: interrupted {manifest['interrupted']}; saved the model so far "
                  f"({manifest['steps']} RL steps) to {interrupt.out}", file=sys.stderr)
        else:
            print("ftcgym train: interrupted before training started; nothing saved", file=sys.stderr)
        return 130


def _run(args, argv: list[str]) -> int:
    from ftcgym.training.config import load_config, plan_line
    config = load_config(args.config, args.algo, args.n_envs, args.total_steps, args.seed, args.pretrain_iterations,
                         args.quick)
    out = args.out or os.path.join("train_out", f"{config.task}-{config.algo}-seed{config.seed}"
                                                f"{'-quick' if config.quick else ''}")
    print(plan_line(config, out, args.init_from), flush=True)
    from ftcgym.training.imitation import fit_summary
    from ftcgym.training.train import train

    manifest = train(config, out, progress=args.progress, command=shlex.join(["ftcgym", *argv]),
                     init_from=args.init_from)
    if "pretrain" in manifest:
        last = manifest["pretrain"]["iterations"][-1]
        final = f", final fit {fit_summary(last['final_fit'])}" if "final_fit" in last else ""
        print(f"imitation pre-training: {len(manifest['pretrain']['iterations'])} DAgger iterations, "
              f"{last['samples']} samples in {manifest['pretrain']['wall_time_s']:.1f} s, "
              f"{fit_summary(last)}{final}")
    written = ", ".join(name for name in ("model.zip", "vecnormalize.pkl", "manifest.json")
                        if os.path.exists(os.path.join(out, name)))
    print(f"{manifest['steps']} steps in {manifest['wall_time_s']:.1f} s ({manifest['steps_per_s'] or 0:.0f} steps/s, "
          f"{config.n_envs} env{'s' if config.n_envs != 1 else ''}); wrote {written} to {out}")
    return 0
