"""`ftcgym airdata-study`: every airdata_ekf criterion's alarm and the airspeed error on a scenario
(`ftcgym.benchmark.airdata_study`)."""
from __future__ import annotations

import json

from .common import json_object, non_negative_int, policy_name, positive_int, scenario_name


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "airdata-study", help="every airdata_ekf criterion's alarm and the airspeed error on a scenario",
        description="Fly a scenario scored on airdata_ekf and report the Table 2 and CUSUM pitot alarms, the "
                    "innovation (GNSS, pusher RPM) alarms and the EKF airspeed error after detection.")
    parser.add_argument("--scenario", required=True, metavar="NAME", type=scenario_name,
                        help="an airdata_ekf scenario")
    add_study_options(parser, episodes=10)
    parser.add_argument("--out", metavar="FILE", help="write episodes and summary as JSON")
    parser.set_defaults(run=run)


def add_study_options(parser, episodes: int) -> None:
    """The options `airdata-study` and `thresholds` share."""
    parser.add_argument("--episodes", type=positive_int, default=episodes, metavar="N",
                        help=f"episodes to fly (default: {episodes})")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="run seed, as ftcgym bench --seed")
    parser.add_argument("--policy", default="oracle-airspeed", metavar="NAME", type=policy_name,
                        help="policy flying the episodes (default: oracle-airspeed, which does not react to the "
                             "pitot, as in Larocque 2023's offline injection)")
    parser.add_argument("--env-kwargs", type=json_object, default=None, metavar="JSON",
                        help="merged into the scenario's env kwargs")
    parser.add_argument("--detector-kwargs", type=json_object, default=None, metavar="JSON",
                        help='merged into the scenario\'s airdata_ekf kwargs, e.g. \'{"error_seed": 2}\'')
    parser.add_argument("--workers", type=positive_int, default=1, metavar="W",
                        help="episodes flown in parallel processes (default 1)")


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark.airdata_study import ALARMS, study, summary
    config = {"scenario": args.scenario, "episodes": args.episodes, "seed": args.seed, "policy": args.policy,
              "env_kwargs": args.env_kwargs, "detector_kwargs": args.detector_kwargs}
    done = []

    def progress(index, row):
        delays = {name: row[f"delay_{name}"] for name in ALARMS}
        print(f"episode {index} seed {row['seed']}: delays {delays}, false "
              f"{[n for n in ALARMS if row[f'false_alarm_{n}']]}, airborne {row['airborne_time']:.0f} s", flush=True)
        done.append(row)
        _write(args.out, done, config)          # after every episode: a long run stopped early keeps its rows

    results = study(args.scenario, args.episodes, args.seed, args.policy, args.env_kwargs, progress=progress,
                    workers=args.workers, detector_kwargs=args.detector_kwargs)
    print(json.dumps(summary(results), indent=1))
    return 0


def _write(path, results, config) -> None:
    """Replace `path` whole (`atomic_write_text`): a run stopped mid-write keeps the last complete file."""
    from ftcgym.benchmark.airdata_study import summary
    from ftcgym.benchmark.outputs import atomic_write_text

    if path:
        atomic_write_text(path, json.dumps({"summary": summary(results), "episodes": results, "config": config},
                                           indent=1))
