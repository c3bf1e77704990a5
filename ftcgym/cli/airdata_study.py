"""`ftcgym airdata-study`: every airdata_ekf criterion's alarm and the airspeed error on a scenario
(`ftcgym.benchmark.airdata_study`)."""
from __future__ import annotations


def add_parser(subparsers) -> None:
    from ftcgym.benchmark import airdata_study as study
    parser = subparsers.add_parser(
        "airdata-study", help="every airdata_ekf criterion's alarm and the airspeed error on a scenario",
        description="Fly a scenario scored on airdata_ekf and report the Table 2 and CUSUM pitot alarms, the "
                    "innovation (GNSS, pusher RPM) alarms and the EKF airspeed error after detection.")
    study.add_study_arguments(parser)
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark import airdata_study as study
    return study.main_study(args)
