"""`ftcgym replay`: a fault detector run over a recorded flight log (`ftcgym.fdd.replay`)."""
from __future__ import annotations

import argparse
import math


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "replay", help="run a fault detector over a recorded flight log",
        description="Run a detector over every sample of a flight log (PX4 ULog .ulg, or an ftcgym recording "
                    ".npz/.csv) and print its alarms: times from the log's start, targets in its actuator order.")
    parser.add_argument("log", metavar="LOG", help="the flight log")
    parser.add_argument("--detector", required=True, metavar="NAME",
                        help="detector to run: loe_kalman or aekf (the others exit 2 saying why they cannot)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.add_argument("--rate", type=positive_rate, default=250.0, metavar="HZ",
                        help="rate a ULog is resampled to (default: 250); recordings keep their own")
    parser.add_argument("--identify", type=time_window, default=None, metavar="START:END",
                        help="window (s from the log's start) to identify the detector's model on, instead of the "
                             "automatic one (the first 5 s of steady flight from 3 s after take-off)")
    parser.add_argument("--vehicle", default=None, metavar="NAME",
                        help="aekf only: a built-in vehicle (bebop2, mueller2014) whose mass, inertia and arm its "
                             "model keeps, the thrust scaled to the log (default: all identified from the log)")
    parser.set_defaults(run=run)


MAX_RATE = 10_000.0   # Hz: above any IMU a PX4 log holds; a higher rate only resamples into a huge array


def positive_rate(text: str) -> float:
    """A rate in (0, MAX_RATE] Hz."""
    try:
        rate = float(text)
    except ValueError:
        rate = math.nan
    if not (math.isfinite(rate) and 0 < rate <= MAX_RATE):
        raise argparse.ArgumentTypeError(f"expected a number of Hz in (0, {MAX_RATE:g}], got {text!r}")
    return rate


def time_window(text: str) -> tuple[float, float]:
    """START:END, seconds from the log's start: two finite numbers, 0 <= START < END."""
    parts = text.split(":")
    try:
        start, end = (float(part) for part in parts) if len(parts) == 2 else (math.nan, math.nan)
    except ValueError:
        start = end = math.nan
    if not (math.isfinite(start) and math.isfinite(end) and 0 <= start < end):
        raise argparse.ArgumentTypeError(f"expected START:END in seconds from the log's start, 0 <= START < END, "
                                         f"got {text!r}")
    return start, end


def run(args, argv: list[str]) -> int:
    from ftcgym.fdd.replay import main  # imported here: only replay needs pyulog
    return main(args)
