"""`ftcgym sweep`: parameter sets x scenarios x seeds, per-set results and plots (`ftcgym.benchmark.sweep`)."""
from __future__ import annotations


def add_parser(subparsers) -> None:
    from ftcgym.benchmark import sweep
    parser = subparsers.add_parser(
        "sweep", help="parameter sweep: parameter sets x scenarios x seeds, per-set results and plots",
        description="Fly every parameter set of a sweep config (YAML, or the built-in fig11: 000 Fig. 11) over "
                    "its scenarios and seeds, on worker processes or Ray; rows are journaled as they finish, "
                    "so --resume continues an interrupted sweep.")
    sweep.add_arguments(parser)
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark import sweep
    return sweep.main(args, argv)
