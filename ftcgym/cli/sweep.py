"""`ftcgym sweep`: parameter sets x scenarios x seeds, per-set results and plots (`ftcgym.benchmark.sweep`)."""
from __future__ import annotations

import argparse
import os
import shlex
import time

from ftcgym.benchmark.backends import EpisodesFailed, add_backend_arguments

from .common import json_object, positive_int


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "sweep", help="parameter sweep: parameter sets x scenarios x seeds, per-set results and plots",
        description="Fly every parameter set of a sweep config (YAML, or the built-in fig11: Fig. 11 of Strack van "
                    "Schijndel et al. 2023) over "
                    "its scenarios and seeds, on worker processes or Ray; rows are journaled as they finish, "
                    "so --resume continues an interrupted sweep.")
    parser.add_argument("config", metavar="CONFIG",
                        help="sweep config YAML, or a built-in name (fig11: Fig. 11 of Strack van Schijndel et al. "
                             "2023, 19 sets x 33 flights)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: sweep_out/<config name>)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the sweep in --out, skipping the episodes it already finished")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="W",
                        help="worker processes or local Ray CPUs (default: one per CPU)")
    parser.add_argument("--sets", nargs="+", metavar="NAME", help="run only these parameter sets")
    parser.add_argument("--episodes", type=positive_int, metavar="N",
                        help="episodes per scenario (default: the config's)")
    parser.add_argument("--env-kwargs", type=json_object, default=None, metavar="JSON",
                        help="JSON object merged into every scenario's gym.make kwargs")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="show a progress bar (default: on)")
    add_backend_arguments(parser)
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark.outputs import OutputFolder
    from ftcgym.benchmark.sweep import load_config

    config = load_config(args.config).select(args.sets, args.episodes, args.env_kwargs)
    out = args.out or os.path.join("sweep_out", config.name)
    with OutputFolder(out):  # held from the check of what the folder holds to the last report file
        return sweep(args, argv, config, out)


def sweep(args, argv: list[str], config, out: str) -> int:
    """Run (or resume) the sweep into `out`, write its report and print the per-set table."""
    from ftcgym.benchmark.journal import EpisodeJournal
    from ftcgym.benchmark.sweep import run_sweep
    from ftcgym.benchmark.sweep_report import write_sweep_report

    try:
        started = time.perf_counter()
        rows = run_sweep(config, out, args.backend, args.workers or os.cpu_count() or 1, args.resume,
                         progress=args.progress, ray_address=args.ray_address, chunk=args.chunk,
                         retries=args.retries)
    except EpisodesFailed as error:
        raise SystemExit(f"ftcgym sweep: {error}\nFinished episodes are kept in {out}; "
                         f"rerun with --resume.") from None
    wall = time.perf_counter() - started
    journal = EpisodeJournal(out)
    record = {"command": shlex.join(["ftcgym", *argv]), "backend": args.backend, "workers": args.workers,
              "wall_time_s": wall, "failed_attempts": len(journal.failures())}
    table = write_sweep_report(out, config, rows, record)
    print(table)
    print(f"\n{len(rows)} episodes ({len(config.parameter_sets)} sets) in {wall:.1f} s; "
          f"{record['failed_attempts']} failed attempt(s) in failures.jsonl; wrote results to {out}")
    return 0
