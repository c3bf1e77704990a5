"""`ftcgym thresholds`: false-detection probability (001 eq. 40-41) and proposed thresholds for the airdata_ekf
criteria, from fault-free flights (`ftcgym.benchmark.airdata_study`, `ftcgym.fdd.false_alarm`)."""
from __future__ import annotations


def add_parser(subparsers) -> None:
    from ftcgym.benchmark import airdata_study as study
    parser = subparsers.add_parser(
        "thresholds", help="false-detection probability (001 eq. 40-41) and proposed thresholds",
        description="From fault-free airdata_ekf signals (flown, or --load), print each criterion's false-"
                    "detection probability per flight hour (001 eq. 40-41), the autocorrelation check of 001 "
                    "Fig. 4 and the threshold that meets --target.")
    study.add_threshold_arguments(parser)
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark import airdata_study as study
    return study.main_thresholds(args)
