"""The `ftcgym` command line.

    ftcgym bench [--scenario NAME...] [--policy NAME...] [--episodes N] [--seed S] [--workers W]
                 [--env-kwargs JSON] [--out DIR] [--list] [--backend local|ray] [--ray-address ADDR]
    ftcgym sweep CONFIG [--backend local|ray] [--out DIR] [--resume]   (see ftcgym/benchmark/sweep.py)
    ftcgym perf ...   (see ftcgym/perf.py)
    ftcgym train --config FILE_OR_TASK [--algo PPO|SAC] [--n-envs N] [--total-steps N] [--seed S] [--out DIR]
    ftcgym evaluate MODEL [--scenario NAME] [--episodes N] [--seed S]

`ftcgym bench` with no arguments runs the default scenarios and prints a summary table (DESIGN.md
"Benchmark").
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import time
from importlib import metadata

from ftcgym.benchmark.backends import int_at_least


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    return args.run(args, argv) or 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ftcgym", description="Fault-tolerant flight control testbed.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_bench(subparsers)
    # ---- further subcommands, one `_add_<name>(subparsers)` each (replay and train to come) ----
    _add_replay(subparsers)
    _add_perf(subparsers)
    _add_trim(subparsers)
    _add_train(subparsers)
    _add_evaluate(subparsers)
    _add_sweep(subparsers)
    _add_airdata(subparsers)
    return parser


def package_version() -> str:
    try:
        return metadata.version("ftcgym")
    except metadata.PackageNotFoundError:
        return "unknown"


# ---- bench ----

def _add_bench(subparsers) -> None:
    from ftcgym.benchmark.backends import add_backend_arguments  # light: no simulator import
    parser = subparsers.add_parser(
        "bench", help="run the fault-tolerance benchmark",
        description="Fly policies through benchmark scenarios and report detection and recovery metrics. "
                    "Without --scenario, runs the default scenarios.")
    parser.add_argument("--scenario", nargs="+", metavar="NAME", type=_scenario,
                        help="scenarios to run (default: the default set; see --list)")
    parser.add_argument("--policy", nargs="+", metavar="NAME", type=_policy_name,
                        help="policies to fly in every scenario (default: each scenario's own)")
    parser.add_argument("--episodes", type=_positive_int, metavar="N",
                        help="episodes per scenario and policy (default: each scenario's own)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="base seed (default: 0)")
    parser.add_argument("--workers", type=_positive_int, default=os.cpu_count() or 1, metavar="W",
                        help="worker processes; 1 runs in-process (default: one per CPU)")
    parser.add_argument("--env-kwargs", type=_json_object, default={}, metavar="JSON",
                        help="JSON object merged (top-level keys) into every scenario's gym.make kwargs")
    parser.add_argument("--detector", metavar="NAME", type=_detector_name,
                        help="detector to wrap every scenario's env with and score (default: each scenario's own)")
    parser.add_argument("--detector-kwargs", type=_json_object, default={}, metavar="JSON",
                        help='JSON object of detector arguments, e.g. \'{"G_scale": 1.2}\' for loe_kalman')
    parser.add_argument("--out", default="bench_out", metavar="DIR",
                        help="output directory (default: bench_out)")
    parser.add_argument("--list", action="store_true", help="list scenarios and policies, then exit")
    add_backend_arguments(parser)
    parser.set_defaults(run=_run_bench)


def _run_bench(args, argv: list[str]) -> int:
    if args.list:
        print(_listing())
        return 0
    from ftcgym.benchmark.metrics import summarize
    from ftcgym.benchmark.report import format_table, write_report
    from ftcgym.benchmark.runner import run_benchmark
    from ftcgym.benchmark.scenarios import default_scenarios

    scenarios = [_with_detector(scenario, args.detector, args.detector_kwargs)
                 for scenario in (args.scenario or default_scenarios())]
    started = time.perf_counter()
    episodes = run_benchmark(scenarios, args.policy, args.episodes, args.seed, args.workers, args.env_kwargs,
                             backend=args.backend, ray_address=args.ray_address, chunk=args.chunk,
                             retries=args.retries)
    summary = summarize(episodes)
    config = _bench_config(args, argv, scenarios, wall_time_s=time.perf_counter() - started)
    paths = write_report(args.out, summary, episodes, config)
    print(format_table(summary))
    print(f"\n{len(episodes)} episodes in {config['wall_time_s']:.1f} s; "
          f"wrote {', '.join(path.name for path in paths)} to {args.out}")
    return 0


def _with_detector(scenario, detector: str | None, detector_kwargs: dict):
    """`scenario` with the command line's detector choice and constructor arguments applied."""
    if detector is None and not detector_kwargs:
        return scenario
    name = detector or scenario.detector
    if name is None:
        raise SystemExit(f"--detector-kwargs: scenario {scenario.name!r} has no detector; name one with --detector")
    kwargs = detector_kwargs if detector and detector != scenario.detector else {**scenario.detector_kwargs,
                                                                               **detector_kwargs}
    return dataclasses.replace(scenario, detector=name, detector_kwargs=kwargs)


def _detector_name(text: str) -> str:
    from ftcgym.fdd import DETECTORS
    try:
        DETECTORS.load(text)          # a built-in, installed or MODULE:ATTR detector that imports
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def _bench_config(args, argv: list[str], scenarios, wall_time_s: float) -> dict:
    """The run's settings as written to results.json: enough to repeat it."""
    return {
        "command": shlex.join(["ftcgym", *argv]),
        "ftcgym_version": package_version(),
        "seed": args.seed,
        "episodes": args.episodes,
        "policies": args.policy,
        "workers": args.workers,
        "backend": args.backend,
        "env_overrides": args.env_kwargs,
        "scenarios": [{
            "name": scenario.name,
            "env_id": scenario.env_id,
            "env_kwargs": {**scenario.env_kwargs, **args.env_kwargs},
            "policies": list(args.policy or scenario.policies),
            "episodes": args.episodes or scenario.episodes,
            "detector": scenario.detector,
            "detector_kwargs": scenario.detector_kwargs,
            "description": scenario.description,
        } for scenario in scenarios],
        "wall_time_s": wall_time_s,
    }


def _listing() -> str:
    from ftcgym.agents import POLICIES
    from ftcgym.benchmark.scenarios import SCENARIOS
    from ftcgym.fdd import DETECTORS

    width = max(map(len, [*SCENARIOS, *POLICIES, *DETECTORS]))
    lines = ["scenarios (* = run by default):"]
    lines += [f"  {name:<{width}} {'*' if s.default else ' '} {s.description}" for name, s in SCENARIOS.items()]
    for title, registry in (("policies", POLICIES), ("detectors", DETECTORS)):
        lines += [f"{title} (or MODULE:ATTR):"]
        lines += [f"  {name:<{width}}   {registry.describe(name)}".rstrip() for name in registry]
    return "\n".join(lines)


# Argument types: argparse turns their errors into a usage message.

def _scenario(name: str):
    from ftcgym.benchmark.scenarios import get_scenario
    try:
        return get_scenario(name)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _policy_name(name: str) -> str:
    from ftcgym.agents import POLICIES
    try:
        POLICIES.load(name)           # a built-in, installed or MODULE:ATTR policy that imports
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return name


_positive_int, _non_negative_int = int_at_least(1), int_at_least(0)


def _json_object(text: str) -> dict:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"invalid JSON ({error})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object of gym.make kwargs, got {text}")
    return value


# ---- replay (ftcgym/fdd/replay.py provides main(args)) ----

def _add_replay(subparsers) -> None:
    parser = subparsers.add_parser(
        "replay", help="run a fault detector over a recorded flight log",
        description="Run a detector over every sample of a flight log (PX4 ULog .ulg, or an ftcgym recording "
                    ".npz/.csv) and print its alarms: times from the log's start, targets in its actuator order.")
    parser.add_argument("log", metavar="LOG", help="the flight log")
    parser.add_argument("--detector", required=True, metavar="NAME", help="detector to run (loe_kalman)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.add_argument("--rate", type=float, default=250.0, metavar="HZ",
                        help="rate a ULog is resampled to (default: 250); recordings keep their own")
    parser.set_defaults(run=_run_replay)


def _run_replay(args, argv: list[str]) -> int:
    from ftcgym.fdd.replay import main  # imported here: only replay needs scipy and pyulog
    return main(args)


# ---- perf (ftcgym/perf.py provides add_arguments(parser) and main(args)) ----

def _add_perf(subparsers) -> None:
    try:
        import ftcgym.perf as perf  # imported here, not at the top: only the perf command needs it
    except ModuleNotFoundError as error:
        if error.name != "ftcgym.perf":
            raise
        return  # not written yet: no perf command
    parser = subparsers.add_parser("perf", help="measure simulation speed and memory")
    perf.add_arguments(parser)
    parser.set_defaults(run=lambda args, argv: perf.main(args))


# ---- airdata-study and thresholds (ftcgym/benchmark/airdata_study.py) ----

def _add_airdata(subparsers) -> None:
    from ftcgym.benchmark import airdata_study as study   # light: the simulator loads only when flying
    parser = subparsers.add_parser(
        "airdata-study", help="every airdata_ekf criterion's alarm and the airspeed error on a scenario",
        description="Fly a scenario scored on airdata_ekf and report the Table 2 and CUSUM pitot alarms, the "
                    "innovation (GNSS, pusher RPM) alarms and the EKF airspeed error after detection.")
    study.add_study_arguments(parser)
    parser.set_defaults(run=lambda args, argv: study.main_study(args))
    parser = subparsers.add_parser(
        "thresholds", help="false-detection probability (001 eq. 40-41) and proposed thresholds",
        description="From fault-free airdata_ekf signals (flown, or --load), print each criterion's false-"
                    "detection probability per flight hour (001 eq. 40-41), the autocorrelation check of 001 "
                    "Fig. 4 and the threshold that meets --target.")
    study.add_threshold_arguments(parser)
    parser.set_defaults(run=lambda args, argv: study.main_thresholds(args))


# ---- sweep (ftcgym/benchmark/sweep.py provides add_arguments(parser) and main(args, argv)) ----

def _add_sweep(subparsers) -> None:
    from ftcgym.benchmark import sweep
    parser = subparsers.add_parser(
        "sweep", help="parameter sweep: parameter sets x scenarios x seeds, per-set results and plots",
        description="Fly every parameter set of a sweep config (YAML, or the built-in fig11: 000 Fig. 11) over "
                    "its scenarios and seeds, on worker processes or Ray; rows are journaled as they finish, "
                    "so --resume continues an interrupted sweep.")
    sweep.add_arguments(parser)
    parser.set_defaults(run=sweep.main)


# ---- trim ----

def _add_trim(subparsers) -> None:
    parser = subparsers.add_parser("trim", help="quad-plane trims over airspeed (markdown table)",
                                   description="Steady level-flight trims of a quad-plane parameter set over "
                                               "airspeed: mode, skew, angle of attack, elevator, pusher, hover "
                                               "rotors, wing lift.")
    parser.add_argument("--vehicle", default="vsqp", help="quad-plane parameter set (default vsqp)")
    parser.add_argument("--vehicle-overrides", type=_json_object, default=None, metavar="JSON",
                        help="JSON object of parameter overrides")
    parser.add_argument("--airspeeds", type=float, nargs="+", default=None, metavar="V",
                        help="airspeeds in m/s (default: hover to 24 m/s)")
    parser.set_defaults(run=_run_trim)


def _run_trim(args, argv: list[str]) -> int:
    from ftcgym.agents.quadplane_trim import default_airspeeds, format_trim_table, trim_table
    from ftcgym.models.vsqp import make_vsqp_params

    params = make_vsqp_params(args.vehicle, args.vehicle_overrides)
    print(format_trim_table(trim_table(params, args.airspeeds or default_airspeeds(params))))
    return 0


# ---- train and evaluate (ftcgym/training; Stable-Baselines3 and torch are imported only when they run) ----

def _add_train(subparsers) -> None:
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
    parser.add_argument("--n-envs", type=_positive_int, metavar="N", help="parallel envs (default: the config's)")
    parser.add_argument("--total-steps", type=_non_negative_int, metavar="N",
                        help="env steps to train for after any pre-training (default: the config's n_timesteps; "
                             "0 with a `pretrain` section: imitation only)")
    parser.add_argument("--seed", type=int, metavar="S", help="seed (default: the config's, else 0)")
    parser.add_argument("--out", metavar="DIR", help="output directory (default: train_out/<task>-<algo>-seed<S>)")
    parser.add_argument("--init-from", metavar="MODEL",
                        help="start from a saved model (a training output folder or .zip, e.g. a shipped policy's "
                             "folder) instead of the config's pre-training: fine-tuning")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="show a progress bar (default: on)")
    parser.set_defaults(run=_run_train)


def _run_train(args, argv: list[str]) -> int:
    from ftcgym.training.config import load_config
    try:
        config = load_config(args.config, args.algo, args.n_envs, args.total_steps, args.seed)
    except ValueError as error:
        raise SystemExit(f"ftcgym train: {error}") from None
    from ftcgym.training.train import train

    out = args.out or os.path.join("train_out", f"{config.task}-{config.algo}-seed{config.seed}")
    manifest = train(config, out, progress=args.progress, command=shlex.join(["ftcgym", *argv]),
                     init_from=args.init_from)
    if "pretrain" in manifest:
        last = manifest["pretrain"]["iterations"][-1]
        final = f", final fit action mse {last['final_fit']['action_mse']:.4f}" if "final_fit" in last else ""
        print(f"imitation pre-training: {len(manifest['pretrain']['iterations'])} DAgger iterations, "
              f"{last['samples']} samples in {manifest['pretrain']['wall_time_s']:.1f} s, "
              f"action mse {last['action_mse']:.4f}{final}")
    print(f"{manifest['steps']} steps in {manifest['wall_time_s']:.1f} s ({manifest['steps_per_s'] or 0:.0f} steps/s, "
          f"{config.n_envs} envs); wrote model.zip, manifest.json to {out}")
    return 0


def _add_evaluate(subparsers) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="run the benchmark on a trained model",
        description="Fly a model saved by `ftcgym train` (its folder or .zip) through a benchmark scenario "
                    "as a policy, deterministic actions, and print the summary table of `ftcgym bench`.")
    parser.add_argument("model", metavar="MODEL", help="the training output folder or a model .zip in it")
    parser.add_argument("--scenario", default="quad-rotor-loss-hover", type=_scenario, metavar="NAME",
                        help="benchmark scenario (default: quad-rotor-loss-hover)")
    parser.add_argument("--episodes", type=_positive_int, metavar="N",
                        help="episodes (default: the scenario's own)")
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="base seed (default: 0)")
    parser.add_argument("--env-kwargs", type=_json_object, default={}, metavar="JSON",
                        help="JSON object merged (top-level keys) into the scenario's gym.make kwargs")
    parser.set_defaults(run=_run_evaluate)


def _run_evaluate(args, argv: list[str]) -> int:
    from ftcgym.benchmark.report import format_table
    from ftcgym.training.evaluate import evaluate_model

    started = time.perf_counter()
    try:
        summary, episodes = evaluate_model(args.model, args.scenario, args.episodes, args.seed, args.env_kwargs)
    except FileNotFoundError as error:
        raise SystemExit(f"ftcgym evaluate: {error}") from None
    print(format_table(summary))
    print(f"\n{len(episodes)} episodes in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
