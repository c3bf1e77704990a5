"""`ftcgym thresholds`: false-detection probability (Larocque 2023 eq. 40-41) and proposed thresholds for the
airdata_ekf criteria, from fault-free flights (`ftcgym.benchmark.airdata_study`, `ftcgym.fdd.false_alarm`)."""
from __future__ import annotations

import json

from ftcgym.fdd.false_alarm import TAILS

from .airdata_study import add_study_options
from .common import scenario_name


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "thresholds", help="false-detection probability (Larocque 2023 eq. 40-41) and proposed thresholds",
        description="From fault-free airdata_ekf signals (flown, or --load), print each criterion's false-"
                    "detection probability per flight hour (Larocque 2023 eq. 40-41), the autocorrelation check of "
                    "Larocque 2023 Fig. 4 and the threshold that meets --target.")
    parser.add_argument("--scenario", default="qp-no-fault-long", metavar="NAME", type=scenario_name,
                        help="fault-free airdata_ekf scenario to fly (default: qp-no-fault-long)")
    add_study_options(parser, episodes=4)
    parser.add_argument("--target", type=float, default=1e-3, metavar="P",
                        help="false detection probability per flight hour (default 1e-3: Larocque 2023's 0.1%%)")
    parser.add_argument("--tail", default="auto", choices=TAILS, help="tail model (default auto)")
    parser.add_argument("--save", metavar="NPZ", help="save the fault-free signals flown")
    parser.add_argument("--load", metavar="NPZ", help="use saved signals instead of flying")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark.airdata_study import (
        EKF_HZ,
        load_segments,
        save_segments,
        study,
        threshold_table,
        traces_to_segments,
    )

    if args.load:
        segments = load_segments(args.load)
    else:
        results = study(args.scenario, args.episodes, args.seed, args.policy, args.env_kwargs, record=True,
                        workers=args.workers, detector_kwargs=args.detector_kwargs)
        if any(r["fault_onset"] is not None for r in results):
            raise ValueError(f"scenario {args.scenario!r} has faults: thresholds need fault-free flights")
        segments = traces_to_segments([r["trace"] for r in results])
        if args.save:
            save_segments(args.save, segments)
    rows = threshold_table(segments, args.target, tail=args.tail)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"fault-free samples: {rows[0]['samples'] if rows else 0} at {EKF_HZ:g} Hz ({rows[0]['hours']:.2f} h); "
          f"target {args.target:g} false detections per flight hour (Larocque 2023 eq. 40-41)")
    head = ("criterion", "Z", "T s", "n", "p_single", "p_seq", "p_flight/h (eq. 41)", "runs/h seen", "rho1",
            "max|rho|", "indep", "proposed Z", "method")
    print(" | ".join(head))
    for r in rows:
        print(" | ".join([r["criterion"], f"{r['threshold']:g}", f"{r['hold_time']:g}", str(r["samples_in_sequence"]),
                          f"{r['p_single']:.3g}", f"{r['p_seq']:.3g}", f"{r['p_flight_hour']:.3g}",
                          f"{r['run_rate_per_hour']:.3g}", f"{r['rho_lag1']:.2f}", f"{r['max_abs_rho']:.2f}",
                          "yes" if r["independent"] else "no",
                          "-" if r["proposed_threshold"] is None else f"{r['proposed_threshold']:.3g}", r["method"]]))
    return 0
