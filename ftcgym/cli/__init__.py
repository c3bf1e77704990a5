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
    ftcgym train --config FILE_OR_TASK [--quick] [--algo PPO|SAC] [--n-envs N] [--total-steps N]
                 [--pretrain-iterations N] [--seed S] [--out DIR] [--init-from MODEL] [--no-progress]
    ftcgym evaluate MODEL [--scenario NAME] [--episodes N] [--seed S] [--env-kwargs JSON]
    ftcgym video --scenario NAME [--policy NAME] [--seed S] --out FILE.mp4 [--slowmo K] [--before S] [--after S]
                 [--fps N] [--size WxH] [--env-kwargs JSON] [--detector NAME] [--detector-kwargs JSON]

A policy, detector or scenario NAME is a built-in name, a name an installed package registers (entry-point
groups `ftcgym.policies`, `ftcgym.detectors`, `ftcgym.scenarios`) or MODULE:ATTR; `ftcgym bench --list`
lists the names. `ftcgym COMMAND --help` describes each command.
"""
from __future__ import annotations

import argparse
import os
import sys
import zipfile

import yaml

from . import airdata_study, bench, evaluate, perf, replay, sweep, thresholds, train, trim, video
from .common import package_version

COMMANDS = (bench, sweep, replay, airdata_study, thresholds, perf, trim, train, evaluate, video)
#: errors from what the user passed: a value out of range, an unreadable or malformed file, an unwritable folder
USER_ERRORS = (ValueError, OSError, yaml.YAMLError, zipfile.BadZipFile)


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand. What a user got wrong (a bad value, file or folder; a folder in use) ends in one
    line on stderr and status 2, as argparse's usage errors do; episodes that failed end in their list and
    status 1; Ctrl-C in one line and status 130. FTCGYM_TRACEBACK=1 shows the traceback instead."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    from ftcgym.benchmark.backends import EpisodesFailed
    from ftcgym.benchmark.outputs import FolderInUse  # small modules: no simulator loads here
    try:
        return args.run(args, argv) or 0
    except KeyboardInterrupt:   # Ctrl-C: one line, as for an error (`train` says what it saved itself)
        if os.environ.get("FTCGYM_TRACEBACK"):
            raise
        print(f"ftcgym {args.command}: interrupted", file=sys.stderr)
        return 130              # 128 + SIGINT, as a shell reports it
    except BrokenPipeError:     # the reader went away (`| head`): nothing to report; Python's docs' recipe
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141              # 128 + SIGPIPE, as a shell reports it
    except (FolderInUse, EpisodesFailed, *USER_ERRORS) as error:
        if os.environ.get("FTCGYM_TRACEBACK"):
            raise
        if isinstance(error, EpisodesFailed):      # its list of failed episodes, one per line
            print(f"ftcgym {args.command}: {error}", file=sys.stderr)
            return 1
        print(f"ftcgym {args.command}: {' '.join(str(error).split())}", file=sys.stderr)
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
