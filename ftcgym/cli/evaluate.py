"""`ftcgym evaluate`: the benchmark's summary table for a model saved by `ftcgym train`."""
from __future__ import annotations

import time

from .common import add_env_and_detector_arguments, non_negative_int, positive_int, scenario


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="run the benchmark on a trained model",
        description="Fly a model saved by `ftcgym train` (its folder or .zip) through a benchmark scenario "
                    "as a policy, deterministic actions, and print the summary table of `ftcgym bench`, the "
                    "policy named as the benchmark names its task's: learned-spin, learned-airspeed.")
    parser.add_argument("model", metavar="MODEL", help="the training output folder or a model .zip in it")
    parser.add_argument("--scenario", type=scenario, metavar="NAME",
                        help="benchmark scenario (default: the model's task's: quad-rotor-loss-hover for "
                             "rotor-loss-recovery, qp-pitot-incipient for airspeed-source)")
    parser.add_argument("--episodes", type=positive_int, metavar="N",
                        help="episodes (default: the scenario's own)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="base seed (default: 0)")
    add_env_and_detector_arguments(parser, "score")
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark.report import format_table
    from ftcgym.benchmark.results import with_detector
    from ftcgym.benchmark.scenarios import get_scenario
    from ftcgym.training.evaluate import default_scenario, evaluate_model

    started = time.perf_counter()
    chosen = args.scenario if args.scenario is not None else get_scenario(default_scenario(args.model))
    scenario = with_detector(chosen, args.detector, args.detector_kwargs)
    summary, episodes = evaluate_model(args.model, scenario, args.episodes, args.seed, args.env_kwargs)
    print(format_table(summary))
    print(f"\n{len(episodes)} episodes in {time.perf_counter() - started:.1f} s")
    return 0
