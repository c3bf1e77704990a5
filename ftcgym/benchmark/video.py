"""Film one benchmark episode around its fault (`ftcgym video`, docs/howto/video.md).

The episode is flown twice from the same seed. The first flight is the benchmark's own (`roll_out`, then
`score_episode`): it gives the fault onset, the detector's alarm and the recovery that the overlay shows, the same
numbers as the episode's row of `ftcgym bench`. The second flies the same steps with `render_mode="rgb_array"`,
drawing a frame only at the steps that fall on a video frame, and stops at the end of the window; every step
of it is checked against the first flight (a policy or detector that does not repeat itself from the seed is
reported as `FilmedEpisode.diverged_at`).

Frames are taken at `fps * slowmo` per simulated second, so the video runs `slowmo` times slower than the flight
(1: real time) and lasts `slowmo` x the window. The window runs from `before` s before the fault's onset to
`after` s after it, within the episode; the whole episode without a fault. Each frame is the step nearest its
time (sample and hold at the agent rate: frames repeat a step when they come faster than the agent steps).

Writing needs imageio and imageio-ffmpeg (the `video` extra); the overlay is drawn with Pillow (installed with
matplotlib) in matplotlib's DejaVu Sans Mono.
"""
from __future__ import annotations

import importlib
import math
import os
from dataclasses import dataclass, field

import numpy as np

from ftcgym.agents import make_policy
from ftcgym.benchmark.runner import make_env, make_scored_env, roll_out, score_episode
from ftcgym.benchmark.scenarios import Scenario, get_scenario
from ftcgym.benchmark.style import ROTORS, fault_title

BEFORE_S, AFTER_S = 1.0, 3.0     # default window around the fault onset
FPS = 30
SIZE = (640, 480)               # pixels, width x height
MISSING_EXTRA = ("writing a video needs imageio and imageio-ffmpeg: pip install -c constraints.txt -e '.[video]' in "
                 "the ftcgym clone")

WHITE, DIM = (255, 255, 255), (150, 150, 150)
RED, ORANGE, GREEN = (255, 90, 80), (255, 180, 60), (110, 230, 120)


class MissingVideoExtra(ImportError):
    """imageio or imageio-ffmpeg is not installed (the `video` extra)."""


def video_modules():
    """imageio's v2 API, after checking that imageio and its ffmpeg plug-in are installed; else MissingVideoExtra
    with the one line that names the extra."""
    try:
        imageio = importlib.import_module("imageio.v2")
        importlib.import_module("imageio_ffmpeg")
    except ImportError:
        raise MissingVideoExtra(MISSING_EXTRA) from None
    return imageio


def film_window(onset: float | None, flight_time: float, before: float = BEFORE_S,
                after: float = AFTER_S) -> tuple[float, float]:
    """(start, end) of the simulated time filmed: `before` s before the onset to `after` s after it, within
    [0, flight_time]; the whole flight without an onset."""
    if onset is None:
        return 0.0, float(flight_time)
    return max(0.0, onset - before), min(float(flight_time), onset + after)


def frame_times(start: float, end: float, fps: float, slowmo: float = 1.0) -> np.ndarray:
    """Simulated time of each frame: [start, end) at `fps * slowmo` frames per simulated second, so that the
    frames, shown at `fps`, last (end - start) x slowmo (at least one frame)."""
    rate = fps * slowmo
    count = max(1, int(round((end - start) * rate)))
    return start + np.arange(count) / rate


@dataclass(frozen=True)
class FlightEvents:
    """What the overlay tells: the scored episode's fault, alarm and recovery (times in s of simulated time)."""

    scenario: str
    policy: str
    seed: int
    fault_kind: str | None = None
    fault_target: object = None
    onset: float | None = None
    detector: str | None = None
    alarm_time: float | None = None
    isolated: object = None
    recovery_time: float | None = None
    crashed: bool = False
    end_time: float = 0.0

    @classmethod
    def from_score(cls, scenario: str, policy: str, seed: int, score: dict, detector: str | None,
                   end_time: float) -> FlightEvents:
        """From `score_episode`'s fields."""
        return cls(scenario, policy, int(seed), score["fault_kind"], score["fault_target"], score["fault_onset"],
                   detector, score["alarm_time"], score["isolated_target"], score["recovery_time"],
                   bool(score["crashed"]), float(end_time))


def speed_label(slowmo: float) -> str:
    if math.isclose(slowmo, 1.0):
        return "real time"
    return f"{slowmo:g}x slow motion" if slowmo > 1.0 else f"{1.0 / slowmo:g}x fast forward"


def overlay_lines(t: float, events: FlightEvents, slowmo: float = 1.0, altitude: float | None = None,
                  airspeed: float | None = None) -> list[tuple[str, tuple]]:
    """The overlay at simulated time `t`, as (text, RGB) lines: the episode, the clock (and the true altitude
    and airspeed when given), then the fault, the alarm and the recovery, each dim until its time has come."""
    lines = [(f"{events.scenario}  {events.policy}  seed {events.seed}", WHITE),
             (f"t = {t:7.3f} s   {speed_label(slowmo)}", WHITE)]
    if altitude is not None and airspeed is not None:
        lines.append((f"altitude {altitude:6.2f} m   airspeed {airspeed:5.2f} m/s", WHITE))
    onset = events.onset
    if onset is None:
        lines.append(("fault      none", DIM))
    else:
        text = f"fault      {fault_text(events.fault_kind, events.fault_target)} at {onset:.3f} s"
        lines.append((text, RED if t >= onset else DIM))
    if events.detector is not None:
        alarm = events.alarm_time
        if alarm is None or t < alarm:
            lines.append((f"alarm      {events.detector}: none", DIM))
        else:
            delay = "" if onset is None else f" ({alarm - onset:+.3f} s)"
            isolated = "" if events.isolated is None else f", isolated {_target(events.isolated)}"
            lines.append((f"alarm      {events.detector} at {alarm:.3f} s{delay}{isolated}", ORANGE))
    if onset is not None:
        recovery = events.recovery_time
        if recovery is not None and t >= recovery:
            lines.append((f"recovered  at {recovery:.3f} s ({recovery - onset:+.3f} s)", GREEN))
        elif recovery is None and t >= events.end_time - 1e-9:
            lines.append(("recovered  no", DIM))
        else:
            lines.append(("recovered  not yet", DIM))
    if events.crashed and t >= events.end_time - 1e-9:
        lines.append((f"CRASHED    at {events.end_time:.3f} s", RED))
    return lines


def fault_text(kind: str, target) -> str:
    """The fault in the figures' words: 'Rotor r4 lost', 'Pitot blockage (reads zero)' (`style.fault_title`)."""
    return fault_title(kind, target)


def _target(target) -> str:
    """A detector's isolated target in the figures' words: rotor index 3 reads 'r4'."""
    targets = target if isinstance(target, (list, tuple)) else [target]
    return "+".join(ROTORS[t] if isinstance(t, int) and 0 <= t < len(ROTORS) else str(t) for t in targets)


LEGEND = (("rotors:", WHITE), ("spinning", (38, 166, 64)), ("weak", (255, 140, 0)), ("lost", (230, 20, 20)),
          ("stopped", (140, 140, 140)))


class Overlay:
    """Draws overlay lines and the rotor-colour legend on RGB frames (Pillow, DejaVu Sans Mono)."""

    def __init__(self, height: int):
        from matplotlib import font_manager
        from PIL import ImageFont
        self._size = max(9, height // 30)
        path = font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans Mono"))
        self.font = ImageFont.truetype(path, self._size)

    def draw(self, frame: np.ndarray, lines: list[tuple[str, tuple]]) -> np.ndarray:
        from PIL import Image, ImageDraw
        image = Image.fromarray(frame).convert("RGBA")
        shade = Image.new("RGBA", image.size, (0, 0, 0, 0))
        pen = ImageDraw.Draw(shade)
        step, pad = int(self._size * 1.3), self._size // 2
        width = max(pen.textlength(text, font=self.font) for text, _ in lines) + 2 * pad
        pen.rectangle((0, 0, width, pad + step * len(lines) + pad // 2), fill=(0, 0, 0, 150))
        legend_top = image.size[1] - step - pad
        pen.rectangle((0, legend_top - pad // 2, image.size[0], image.size[1]), fill=(0, 0, 0, 120))
        image = Image.alpha_composite(image, shade)
        pen = ImageDraw.Draw(image)
        for row, (text, color) in enumerate(lines):
            pen.text((pad, pad + row * step), text, fill=color, font=self.font)
        x = pad
        for text, color in LEGEND:
            if color != WHITE:
                pen.rectangle((x, legend_top + 2, x + self._size - 2, legend_top + self._size), fill=color)
                x += self._size + 2
            pen.text((x, legend_top), text, fill=WHITE, font=self.font)
            x += pen.textlength(text, font=self.font) + self._size
        return np.asarray(image.convert("RGB"))


@dataclass
class FilmedEpisode:
    """What `film_episode` wrote: `frames` at `fps` of simulated [start, end], and the scored episode."""

    path: str
    frames: int
    fps: float
    slowmo: float
    start: float
    end: float
    events: FlightEvents
    score: dict = field(repr=False)
    diverged_at: float | None = None     # first simulated time the filmed flight left the scored one, if ever

    @property
    def duration(self) -> float:
        """Seconds of video."""
        return self.frames / self.fps


def film_episode(scenario: Scenario | str, policy_name: str, seed: int, out: str, *, before: float = BEFORE_S,
                 after: float = AFTER_S, fps: float = FPS, slowmo: float = 1.0, size: tuple = SIZE,
                 env_overrides: dict | None = None) -> FilmedEpisode:
    """Fly episode `seed` of `policy_name` in `scenario` and write the video of its window to `out` (module
    docstring). Raises MissingVideoExtra without imageio and imageio-ffmpeg, before anything flies."""
    imageio = video_modules()
    if not (fps > 0 and slowmo > 0 and before >= 0 and after >= 0):
        raise ValueError(f"video: fps and slowmo must be > 0 and before, after >= 0; got fps={fps}, "
                         f"slowmo={slowmo}, before={before}, after={after}")
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    env_overrides = dict(env_overrides or {})
    env, detector = make_scored_env(scenario, env_overrides)
    try:
        log = roll_out(env, make_policy(policy_name, env), seed, detector)
    finally:
        env.close()
    score = score_episode(log)
    flight_time = float(log.time[-1])
    events = FlightEvents.from_score(scenario.name, policy_name, seed, score, detector, flight_time)
    start, end = film_window(score["fault_onset"], flight_time, before, after)
    times = frame_times(start, end, fps, slowmo)
    half_step = 0.5 * (float(np.median(np.diff(log.time))) if len(log.time) > 1 else 0.0)
    overlay = Overlay(size[1])

    env = make_env(scenario, {**env_overrides, "render_mode": "rgb_array", "render_size": tuple(size)})
    state = {"step": 0, "frame": 0, "diverged_at": None, "image": None, "lines": []}

    def on_step(obs, info) -> None:
        index, t = state["step"], info["time"]
        state["step"] += 1
        if state["diverged_at"] is None and (index >= len(log.time) or
                                             not np.array_equal(info["truth"]["position"], log.position[index])):
            state["diverged_at"] = t
        image = lines = None
        while state["frame"] < len(times) and times[state["frame"]] <= t + half_step + 1e-9:
            if image is None:
                image = env.render()
                truth = info["truth"]
                lines = overlay_lines(t, events, slowmo, -float(truth["position"][2]), float(truth["airspeed"]))
            writer.append_data(overlay.draw(image, lines))
            state["frame"] += 1
        if image is not None:
            state["image"], state["lines"] = image, lines

    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    writer = imageio.get_writer(out, format="FFMPEG", mode="I", fps=fps, codec="libx264", pixelformat="yuv420p",
                                quality=7, macro_block_size=2, ffmpeg_log_level="error")
    try:
        try:
            roll_out(env, make_policy(policy_name, env), seed, detector, on_step=on_step, until=end)
        finally:
            env.close()
        while state["frame"] < len(times):   # none left unless the filmed flight ended early (it diverged)
            writer.append_data(overlay.draw(state["image"], state["lines"]))
            state["frame"] += 1
    finally:
        writer.close()
    return FilmedEpisode(out, len(times), fps, slowmo, start, end, events, score, state["diverged_at"])
