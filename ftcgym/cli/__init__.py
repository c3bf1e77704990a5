"""The `ftcgym` command line: one module per subcommand, each with `add_parser(subparsers)` (which sets
`run(args, argv) -> exit status` as the parser's default) and nothing simulator-heavy imported before it runs.

    ftcgym bench [--scenario NAME...] [--policy NAME...] [--detector NAME] [--detector-kwargs JSON]
                 [--episodes N] [--seed S] [--workers W] [--env-kwargs JSON] [--out DIR] [--list]
                 [--backend local|ray] [--ray-address ADDR] [--chunk N] [--retries N]
    ftcgym sweep CONFIG [--out DIR] [--resume] [--sets NAME...] [--episodes N] [--workers W] [--backend ...]
    ftcgym replay LOG --detector NAME [--json] [--rate HZ]
    ftcgym airdata-study --scenario NAME [--episodes N] [--seed S] [--policy P] [--out FILE] ...
    ftcgym thresholds [--scenario NAME] [--target P] [--save F.npz | --load F.npz] ...
    ftcgym perf [--steps N] [--seed S] [--json]
    ftcgym trim [--vehicle NAME] [--vehicle-overrides JSON] [--airspeeds V...]
    ftcgym train --config FILE_OR_TASK [--algo PPO|SAC] [--n-envs N] [--total-steps N] [--seed S] [--out DIR]
                 [--init-from MODEL] [--no-progress]
    ftcgym evaluate MODEL [--scenario NAME] [--episodes N] [--seed S] [--env-kwargs JSON]

A policy, detector or scenario NAME is a built-in name, a name an installed package registers (entry-point
groups `ftcgym.policies`, `ftcgym.detectors`, `ftcgym.scenarios`) or MODULE:ATTR; `ftcgym bench --list`
lists the names. `ftcgym COMMAND --help` describes each command.
"""
from __future__ import annotations

import argparse
import sys

from . import airdata_study, bench, evaluate, perf, replay, sweep, thresholds, train, trim
from .common import package_version

COMMANDS = (bench, sweep, replay, airdata_study, thresholds, perf, trim, train, evaluate)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    from ftcgym.benchmark.outputs import FolderInUse  # a small module: no simulator loads here
    try:
        return args.run(args, argv) or 0
    except FolderInUse as error:  # a usage error, as argparse's: status 2, one line
        print(f"ftcgym {args.command}: {error}", file=sys.stderr)
        return 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ftcgym", description="Fault-tolerant flight control testbed.",
                                     epilog="NAME arguments also take MODULE:ATTR or an installed plug-in's name.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(subparsers)
    return parser


if __name__ == "__main__":
    sys.exit(main())
