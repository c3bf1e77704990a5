"""`ftcgym bench`: fly policies through benchmark scenarios and report detection and recovery metrics."""
from __future__ import annotations

import os
import shlex
import time

from ftcgym.benchmark.backends import add_backend_arguments

from .common import detector_name, json_object, non_negative_int, package_version, policy_name, positive_int, scenario


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench", help="run the fault-tolerance benchmark",
        description="Fly policies through benchmark scenarios and report detection and recovery metrics. "
                    "Without --scenario, runs the default scenarios. Writes results.json, episodes.csv, "
                    "report.md and plots to --out.")
    parser.add_argument("--scenario", nargs="+", action="extend", metavar="NAME", type=scenario,
                        help="scenarios to run (default: the default set; see --list), or MODULE:ATTR; repeating "
                             "the option adds to the list")
    parser.add_argument("--policy", nargs="+", action="extend", metavar="NAME", type=policy_name,
                        help="policies to fly in every scenario (default: each scenario's own), or MODULE:ATTR of "
                             "a class or factory called with the env; repeating the option adds to the list")
    parser.add_argument("--detector", metavar="NAME", type=detector_name,
                        help="detector to wrap every scenario's env with and score (default: each scenario's own), "
                             "or MODULE:ATTR of a Detector class or of a factory f(env, **kwargs)")
    parser.add_argument("--detector-kwargs", type=json_object, default={}, metavar="JSON",
                        help='JSON object of detector arguments, e.g. \'{"G_scale": 1.2}\' for loe_kalman')
    parser.add_argument("--episodes", type=positive_int, metavar="N",
                        help="episodes per scenario and policy (default: each scenario's own)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S", help="base seed (default: 0)")
    parser.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1, metavar="W",
                        help="worker processes; 1 runs in-process (default: one per CPU)")
    parser.add_argument("--env-kwargs", type=json_object, default={}, metavar="JSON",
                        help="JSON object merged (top-level keys) into every scenario's gym.make kwargs")
    parser.add_argument("--out", default="bench_out", metavar="DIR", help="output directory (default: bench_out)")
    parser.add_argument("--list", action="store_true", help="list scenarios, policies and detectors, then exit")
    add_backend_arguments(parser)
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    if args.list:
        print(listing())
        return 0
    from ftcgym.benchmark.outputs import OutputFolder
    from ftcgym.benchmark.results import with_detector
    from ftcgym.benchmark.scenarios import default_scenarios

    scenarios = [with_detector(s, args.detector, args.detector_kwargs) for s in args.scenario or default_scenarios()]
    with OutputFolder(args.out):  # before flying: a second run into the folder stops now, not at the end
        return bench(args, argv, scenarios)


def bench(args, argv: list[str], scenarios) -> int:
    """Fly `scenarios`, write the report to args.out and print the summary table."""
    from ftcgym.benchmark.report import format_table, write_report
    from ftcgym.benchmark.results import results_document, run_config
    from ftcgym.benchmark.runner import pool_size, run_benchmark

    started = time.perf_counter()
    episodes = run_benchmark(scenarios, args.policy, args.episodes, args.seed, args.workers, args.env_kwargs,
                             backend=args.backend, ray_address=args.ray_address, chunk=args.chunk,
                             retries=args.retries)
    # the processes that flew (a Ray cluster joined by address has its own size: the number asked for is kept)
    workers = args.workers if args.ray_address else pool_size(args.workers, len(episodes))
    config = run_config(shlex.join(["ftcgym", *argv]), package_version(), scenarios, seed=args.seed,
                        episodes=args.episodes, policies=args.policy, workers=workers, backend=args.backend,
                        env_overrides=args.env_kwargs, wall_time_s=time.perf_counter() - started)
    results = results_document(episodes, config)
    paths = write_report(args.out, results, episodes)
    print(format_table(results["summary"]))
    print(f"\n{len(episodes)} episodes in {config['wall_time_s']:.1f} s; "
          f"wrote {', '.join(path.name for path in paths)} to {args.out}")
    return 0


def listing() -> str:
    """The scenarios (default ones starred), policies and detectors, each with its one-line description."""
    from ftcgym.agents import POLICIES
    from ftcgym.benchmark.scenarios import PLUG_INS, SCENARIOS, get_scenario, scenario_names
    from ftcgym.fdd import DETECTORS

    scenarios = scenario_names()
    width = max(map(len, [*scenarios, *POLICIES, *DETECTORS]))
    lines = ["scenarios (* = run by default; or MODULE:ATTR):"]
    for name in scenarios:
        scenario = SCENARIOS.get(name)
        if scenario is None:              # an installed plug-in: its own description, if it loads
            try:
                scenario = get_scenario(name)
            except (ValueError, TypeError):
                lines += [f"  {name:<{width}}   {PLUG_INS.describe(name)}"]
                continue
        lines += [f"  {name:<{width}} {'*' if scenario.default else ' '} {scenario.description}".rstrip()]
    for title, registry in (("policies", POLICIES), ("detectors", DETECTORS)):
        lines += [f"{title} (or MODULE:ATTR):"]
        lines += [f"  {name:<{width}}   {registry.describe(name)}".rstrip() for name in registry]
    return "\n".join(lines)
