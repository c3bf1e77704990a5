"""`ftcgym video`: film one benchmark episode around its fault (`ftcgym.benchmark.video`)."""
from __future__ import annotations

import argparse
import os
import sys
import time

from .common import add_env_and_detector_arguments, non_negative_int, policy_name, positive_int, scenario

SUFFIXES = (".mp4", ".mkv", ".mov")


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "video", help="film one benchmark episode around its fault",
        description="Fly one episode of a benchmark scenario and write a video of it: from --before s before the "
                    "fault's onset to --after s after it (the whole episode without a fault), headless, with an "
                    "overlay of the time, the fault, the detector's alarm and the recovery. Needs the video extra "
                    "(pip install -c constraints.txt -e '.[video]' in the ftcgym clone).")
    parser.add_argument("--scenario", required=True, type=scenario, metavar="NAME",
                        help="benchmark scenario (see `ftcgym bench --list`), or MODULE:ATTR")
    parser.add_argument("--policy", type=policy_name, metavar="NAME",
                        help="policy to fly (default: the scenario's first), or MODULE:ATTR")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="the episode's seed, as in the seed column of `ftcgym bench`'s episodes.csv (default: 0)")
    parser.add_argument("--out", required=True, type=video_path, metavar="FILE",
                        help=f"video file to write ({', '.join(SUFFIXES)})")
    parser.add_argument("--slowmo", type=positive_float, default=1.0, metavar="K",
                        help="play K times slower than the flight (default: 1, real time; below 1: faster)")
    parser.add_argument("--before", type=non_negative_float, default=1.0, metavar="S",
                        help="seconds of flight filmed before the fault's onset (default: 1)")
    parser.add_argument("--after", type=non_negative_float, default=3.0, metavar="S",
                        help="seconds of flight filmed after the fault's onset (default: 3)")
    parser.add_argument("--fps", type=positive_int, default=30, metavar="N", help="video frame rate (default: 30)")
    parser.add_argument("--size", type=frame_size, default=(640, 480), metavar="WxH",
                        help="frame size in pixels, even numbers (default: 640x480)")
    add_env_and_detector_arguments(parser, "show")
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.benchmark.results import with_detector
    from ftcgym.benchmark.video import MissingVideoExtra, film_episode, speed_label

    started = time.perf_counter()
    scenario = with_detector(args.scenario, args.detector, args.detector_kwargs)
    policy = args.policy or scenario.policies[0]
    try:
        film = film_episode(scenario, policy, args.seed, args.out, before=args.before, after=args.after,
                            fps=args.fps, slowmo=args.slowmo, size=args.size, env_overrides=args.env_kwargs)
    except MissingVideoExtra as error:
        print(f"ftcgym video: {error}", file=sys.stderr)
        return 2
    events = film.events
    print(f"wrote {film.path}: {film.frames} frames at {film.fps:g} fps, {film.duration:.2f} s of video of "
          f"t = {film.start:.2f}-{film.end:.2f} s of {scenario.name} / {policy} / seed {args.seed} "
          f"({speed_label(film.slowmo)})")
    print("; ".join(_summary(events)))
    if film.diverged_at is not None:
        print(f"ftcgym video: warning: the filmed flight left the scored one at t = {film.diverged_at:.3f} s (the "
              f"policy or detector does not repeat itself from the seed); the overlay shows the scored flight's "
              f"events", file=sys.stderr)
    print(f"in {time.perf_counter() - started:.1f} s")
    return 0


def _summary(events) -> list[str]:
    from ftcgym.benchmark.video import fault_text
    parts = ["no fault" if events.onset is None else
             f"fault {fault_text(events.fault_kind, events.fault_target)} at {events.onset:.3f} s"]
    if events.detector is not None:
        parts.append(f"alarm {events.detector} at {events.alarm_time:.3f} s" if events.alarm_time is not None
                     else f"no alarm from {events.detector}")
    if events.onset is not None:
        parts.append(f"recovered at {events.recovery_time:.3f} s" if events.recovery_time is not None
                     else "not recovered")
    if events.crashed:
        parts.append(f"crashed at {events.end_time:.3f} s")
    return parts


def video_path(text: str) -> str:
    if os.path.splitext(text)[1].lower() not in SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text!r}: a video file ending in {', '.join(SUFFIXES)}")
    return text


def positive_float(text: str) -> float:
    return _float(text, lambda v: v > 0, "a number > 0")


def non_negative_float(text: str) -> float:
    return _float(text, lambda v: v >= 0, "a number >= 0")


def _float(text: str, accept, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value == value and value != float("inf") and accept(value)):
        raise argparse.ArgumentTypeError(f"{text!r}: expected {what}")
    return value


def frame_size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, even numbers of pixels from 16 to 4096 (the H.264 encoder's 4:2:0 needs even sides)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        width = height = -1
    if not all(16 <= v <= 4096 and v % 2 == 0 for v in (width, height)):
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT, even numbers of pixels in [16, 4096], "
                                         f"e.g. 640x480")
    return width, height
