"""Benchmark outputs (docs/concepts.md, "Benchmark metrics"): results.json, episodes.csv, report.md, the figures
(each a PNG and a PDF beside it, in the look of `style`), and the summary table printed to stdout.
"""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # a bare Figure renders with Agg: no pyplot, no global backend
from matplotlib.lines import Line2D

from ftcgym.benchmark import style
from ftcgym.benchmark.metrics import EPISODE_FIELDS, SUMMARY_FIELDS
from ftcgym.benchmark.outputs import OutputFolder

#: policies that fly on as if nothing happened: the event figure sets a recovering policy beside one of them
FAULT_UNAWARE = ("nominal", "pitot-only", "autopilot")
BOX_MIN = 5   # a latency row draws a box from this many episodes on, a median tick below

# Short column labels for the tables; results.json and the CSV keep the full field names.
COLUMN_LABELS = {
    "scenario": "scenario", "policy": "policy", "episodes": "n",
    "detection_delay_median": "delay med (s)", "detection_delay_p95": "delay p95 (s)",
    "missed_detection_rate": "missed", "false_alarms_per_hour": "FA/h",
    "isolation_accuracy": "isolation", "recovery_latency_median": "recovery med (s)",
    "recovery_latency_p95": "recovery p95 (s)", "success_rate": "success", "crash_rate": "crash",
    "return_time_0_5m_median": "return 0.5 m med (s)", "return_time_0_2m_median": "return 0.2 m med (s)",
    "max_position_error_median": "max error med (m)", "final_position_error_median": "final error med (m)",
    "altitude_loss_median": "altitude loss med (m)",
}
#: the columns of the table printed to the terminal (report.md has every SUMMARY_FIELDS column)
TERMINAL_FIELDS = tuple(field for field in SUMMARY_FIELDS if field not in (
    "detection_delay_p95", "recovery_latency_p95", "max_position_error_median", "final_position_error_median",
    "altitude_loss_median"))
DEFINITIONS = (
    "Definitions (docs/concepts.md, Benchmark metrics): detection delay = alarm time - fault onset, over "
    "detected faults; "
    "missed = fraction of fault episodes whose alarm never came at or after onset; a false alarm is "
    "an alarm before onset or in a fault-free episode, FA/h counts them per hour of fault-free flight "
    "(before onset, or the whole episode); isolation = fraction of detected faults attributed to the "
    "right target. Recovery time is the start of the first window after onset in which the vehicle "
    "stays recovered for 2 s; for a rotor loss, recovered means altitude within 0.5 m of its target "
    "and the thrust axis within 10 deg of the controller's reference. Recovery latency = recovery "
    "time - onset, over recovered episodes. Success = recovered (and not crashed) after a fault, or "
    "no crash in a fault-free episode. Position return (quadrotor faults; the error is the 3-D distance "
    "between the true position and the task's set-point at each agent step): return 0.5 m (0.2 m) = seconds from "
    "onset to the last entry into the 0.5 m (0.2 m) band, after which the error stays inside it to the episode's "
    "end; none if the episode crashed or ended outside the band, counted as +inf in the median (shown '-' when "
    "the median is inf). Max error = the largest error after onset; final error = RMS error over the episode's "
    "last 2 s; altitude loss = altitude at onset minus the lowest altitude after it. Medians and 95th "
    "percentiles interpolate linearly; '-' marks a figure that does not apply."
)


def format_value(value) -> str:
    """A table cell: 3 significant digits for floats, '-' for None."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def format_table(summary: list[dict], fields: tuple[str, ...] = TERMINAL_FIELDS) -> str:
    """The summary's `fields` (default: the terminal's) as a plain text table, text left-aligned and numbers
    right-aligned."""
    header = [COLUMN_LABELS[field] for field in fields]
    cells = [[format_value(row[field]) for field in fields] for row in summary]
    widths = [max(len(column) for column in columns) for columns in zip(header, *cells)]
    text_columns = 2  # scenario and policy

    def line(values):
        return "  ".join(value.ljust(width) if i < text_columns else value.rjust(width)
                         for i, (value, width) in enumerate(zip(values, widths))).rstrip()

    return "\n".join([line(header), line(["-" * width for width in widths]), *map(line, cells)])


def markdown_table(summary: list[dict]) -> str:
    header = [COLUMN_LABELS[field] for field in SUMMARY_FIELDS]
    rows = [[format_value(row[field]) for field in SUMMARY_FIELDS] for row in summary]
    return "\n".join("| " + " | ".join(cells) + " |"
                     for cells in [header, ["---"] * len(header), *rows])


def write_report(out_dir, results: dict, episodes: list[dict]) -> list[Path]:
    """Write results.json, episodes.csv, the figures and report.md of a run's `results` document
    (`results.results_document`); `episodes` are the rows with their trajectories, for the figures.
    The files are staged and published whole (`outputs.OutputFolder`): the folder then holds this run's
    files and none of its previous run's."""
    with OutputFolder(out_dir) as folder:
        paths = write_files(folder.staged, results, episodes)
        folder.publish()
    return [folder.path / path.name for path in paths]


def write_files(place, results: dict, episodes: list[dict]) -> list[Path]:
    """The report's files, each written at `place(name)`; returns their paths: results.json, episodes.csv,
    report.md, its figures (PNG) and their vector copies (`style.VECTOR_FORMAT`)."""
    paths = [write_json(place("results.json"), results), write_csv(place("episodes.csv"), results["episodes"])]
    plots = []
    for name in dict.fromkeys(episode["scenario"] for episode in episodes):
        of_scenario, stem = _of_scenario(episodes, name), file_stem(name)
        plots.append(plot_scenario(place(f"{stem}.png"), name, of_scenario))
        shown = event_episodes(of_scenario)
        if shown:
            plots.append(plot_event(place(f"{stem}-event.png"), shown, fault_rate(results["config"], name)))
        if any(e["fault_onset"] is not None for e in of_scenario):
            plots.append(plot_latencies(place(f"{stem}-latency.png"), name, of_scenario))
    paths.append(write_markdown(place("report.md"), results["summary"], results["config"], plots))
    return paths + plots + [plot.with_suffix(f".{style.VECTOR_FORMAT}") for plot in plots]


def file_stem(scenario: str) -> str:
    """A scenario's name as a file name: a MODULE:ATTR reference's ':' (a URL scheme to a Markdown viewer, and no
    file name on Windows) and anything but letters, digits, '.', '_' and '-' become '_'."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", scenario)


def write_json(path: Path, results: dict) -> Path:
    path.write_text(json.dumps(results, indent=2) + "\n")
    return path


def write_csv(path: Path, rows: list[dict]) -> Path:
    """One line per episode; None becomes an empty cell."""
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=EPISODE_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def write_markdown(path: Path, summary: list[dict], config: dict, plots: list[Path]) -> Path:
    scenario_lines = [f"- `{s['name']}` ({s['env_id']}, policies {', '.join(s['policies'])}, "
                      f"{s['episodes']} episodes, detector {s['detector'] or 'none'}): {s['description']}"
                      for s in config["scenarios"]]
    plot_lines = [f"![{plot.stem}]({plot.name})" for plot in plots]
    vector = style.VECTOR_FORMAT.upper()
    text = "\n\n".join([
        "# ftcgym benchmark",
        f"`{config['command']}` (ftcgym {config['ftcgym_version']}, seed {config['seed']}, "
        f"{_count(config['workers'], 'process', 'processes')}, {config['wall_time_s']:.0f} s wall time). Environment "
        "overrides: " + (f"`{json.dumps(config['env_overrides'])}`" if config["env_overrides"] else "none") + ".",
        "## Scenarios", "\n".join(scenario_lines),
        "## Summary", markdown_table(summary), DEFINITIONS,
        "## Plots", "Altitude and horizontal path of every episode (dotted lines mark fault onsets, "
        "dashed black lines the reference, crosses crashes); for scenarios with faults, the detection delay and "
        f"the recovery latency of every episode by policy (a box of the quartiles from {BOX_MIN} episodes on, a "
        "median tick below), and the time history around the fault of a fault-unaware flight beside the "
        "best-recovering policy's flight of the same episode. "
        f"Each PNG has a {vector} beside it (same name, .{style.VECTOR_FORMAT}) for papers.",
        "\n\n".join(plot_lines),
    ])
    path.write_text(text + "\n")
    return path


def plot_scenario(path: Path, scenario: str, episodes: list[dict]) -> Path:
    """Altitude vs time and the horizontal path (north up, east right) of each episode, by policy; fault onsets
    dotted, crashes crossed; each policy its colour and dashes (`style.policy_lines`). Writes the PNG at `path`
    and its vector copy beside it; returns `path`."""
    policies = style.policy_lines(episode["policy"] for episode in episodes)
    with style.paper():
        figure = Figure(figsize=style.size(2, 2.7), layout="constrained")
        altitude_axes, path_axes = figure.subplots(1, 2, width_ratios=(3, 2))
        reference = max((e["trajectory"] for e in episodes), key=lambda trajectory: trajectory["time"][-1])
        altitude_axes.plot(reference["time"], -reference["reference_position"][:, 2], color=style.REFERENCE_COLOR,
                           ls="--", lw=0.8, zorder=3)
        path_axes.plot(reference["reference_position"][:, 1], reference["reference_position"][:, 0],
                       color=style.REFERENCE_COLOR, ls="--", lw=0.8, zorder=3)
        for onset in sorted({e["fault_onset"] for e in episodes if e["fault_onset"] is not None}):
            altitude_axes.axvline(onset, color=style.GREY, ls=":", lw=0.8, zorder=1)
        for episode in episodes:
            line, trajectory = policies[episode["policy"]], episode["trajectory"]
            color, north, east, altitude = line["color"], *(trajectory["position"] * (1, 1, -1)).T
            altitude_axes.plot(trajectory["time"], altitude, lw=0.9, alpha=0.8, **line)
            path_axes.plot(east, north, lw=0.9, alpha=0.8, **line)
            if episode["crashed"]:
                altitude_axes.plot(trajectory["time"][-1], altitude[-1], "x", color=color, ms=5, mew=1.2)
                path_axes.plot(east[-1], north[-1], "x", color=color, ms=5, mew=1.2)
        handles = [Line2D([], [], label=policy, **line) for policy, line in policies.items()]
        handles.append(Line2D([], [], color=style.REFERENCE_COLOR, ls="--", lw=0.8, label="reference"))
        if any(e["fault_onset"] is not None for e in episodes):
            handles.append(Line2D([], [], color=style.GREY, ls=":", lw=0.8, label="fault onset"))
        if any(e["crashed"] for e in episodes):
            handles.append(Line2D([], [], color=style.GREY, ls="", marker="x", mew=1.2, label="crash"))
        figure.legend(handles=handles, loc="outside upper center", ncol=min(len(handles), 7))
        altitude_axes.set(title=scenario, xlabel=style.label("time"), ylabel=style.label("altitude"))
        path_axes.set(title="Horizontal path", xlabel=style.label("east"), ylabel=style.label("north"))
        path_axes.set_aspect("equal", adjustable="datalim")
        style.save(figure, path)
    return path


def plot_latencies(path: Path, scenario: str, episodes: list[dict]) -> Path:
    """Detection delay and recovery latency (recovery time - onset) of every fault episode, one row per policy:
    each episode a dot, over a box of the quartiles (whiskers 1.5 IQR; a median tick under BOX_MIN episodes), and
    at the right how many of the policy's fault episodes gave a value. Writes the PNG at `path` and its vector
    copy beside it; returns `path`."""
    policies = style.policy_colors(episode["policy"] for episode in episodes)
    samples = {policy: latency_samples(episodes, policy) for policy in policies}
    delays = [value for _, values, _ in samples.values() for value in values]
    delay_scale, delay_unit = (1000.0, "ms") if not delays or max(delays) < 2.0 else (1.0, "s")
    with style.paper():
        figure = Figure(figsize=style.size(2, 0.9 + 0.32 * len(policies)), layout="constrained")
        delay_axes, recovery_axes = figure.subplots(1, 2, sharey=True)
        rows = np.arange(len(policies))[::-1]   # the first policy on top
        for axes, index, scale, counted in ((delay_axes, 1, delay_scale, "alarmed"),
                                            (recovery_axes, 2, 1.0, "recovered")):
            for row, (policy, color) in zip(rows, policies.items()):
                n_faults, values = samples[policy][0], scale * np.asarray(samples[policy][index], dtype=float)
                _strip(axes, row, values, color)
                text = f"{len(values)}/{n_faults} {counted}"
                axes.annotate(text, (1.0, row), xycoords=("axes fraction", "data"), xytext=(3, 0),
                              textcoords="offset points", va="center", ha="left", fontsize=6.5, color=style.GREY,
                              annotation_clip=False)
            axes.grid(axis="y", visible=False)
        delay_axes.set_yticks(rows, list(policies))
        delay_axes.set_ylim(-0.6, len(policies) - 0.4)
        delay_axes.set(title=f"{scenario}: detection delay", xlabel=f"Alarm time − fault onset ({delay_unit})")
        recovery_axes.set(title="Recovery latency", xlabel="Recovery time − fault onset (s)")
        recovery_axes.tick_params(axis="y", left=False)
        for axes in (delay_axes, recovery_axes):
            if not axes.has_data():
                axes.set_xlim(0.0, 1.0)
        style.save(figure, path)
    return path


def _strip(axes, row: float, values: np.ndarray, color: str) -> None:
    """One policy's row: each value a dot jittered across the row (deterministically) over a box of the quartiles
    (whiskers 1.5 IQR), or with fewer than BOX_MIN values a tick at the median."""
    if values.size == 0:
        return
    if values.size < BOX_MIN:
        axes.plot([np.median(values)] * 2, [row - 0.28, row + 0.28], color=color, lw=1.4)
    else:
        axes.boxplot(values, positions=[row], orientation="horizontal", widths=0.55, whis=1.5, showfliers=False,
                     patch_artist=True, manage_ticks=False,
                     boxprops={"facecolor": "none", "edgecolor": color, "linewidth": 0.8},
                     medianprops={"color": color, "linewidth": 1.4},
                     whiskerprops={"color": color, "linewidth": 0.8}, capprops={"color": color, "linewidth": 0.8})
    jitter = np.random.default_rng(0).uniform(-0.2, 0.2, values.size)
    axes.scatter(values, row + jitter, s=9, color=color, alpha=0.75, edgecolors="none", zorder=3)


def latency_samples(episodes: list[dict], policy: str) -> tuple[int, list[float], list[float]]:
    """(fault episodes, detection delays, recovery latencies) of `policy`; undetected or unrecovered
    episodes add no sample. Recovered as the summary counts it (`recovered`: one that recovered and then crashed
    did not), so the figure and the table give the same count and median."""
    mine = [e for e in episodes if e["policy"] == policy and e["fault_onset"] is not None]
    delays = [e["detection_delay"] for e in mine if e["detection_delay"] is not None]
    latencies = [e["recovery_time"] - e["fault_onset"] for e in mine if e["recovered"]]
    return len(mine), delays, latencies


def event_episodes(episodes: list[dict]) -> list[dict]:
    """The flights the event figure shows, left to right: a fault-unaware policy's (FAULT_UNAWARE) and the
    best-recovering other policy's, on the same episode (seed); one of them when the other is missing.

    The best-recovering policy recovered the largest share of its fault episodes, a flyable one before an oracle
    (an oracle switches at the true onset: an upper bound) as long as it recovered any; ties go to the lower
    median recovery latency, then to the policy flown first. Its episode is the first it recovered in, preferring
    one the fault-unaware policy did not recover and one flown by that policy too.
    """
    flights = [e for e in episodes if e["trajectory"].get("event") is not None]
    if not flights:
        return []
    policies = list(dict.fromkeys(e["policy"] for e in flights))
    unaware = next((policy for policy in policies if policy in FAULT_UNAWARE), None)
    baseline = {e["seed"]: e for e in flights if e["policy"] == unaware}

    def rank(policy):
        mine = [e for e in flights if e["policy"] == policy]
        latencies = [e["recovery_time"] - e["fault_onset"] for e in mine if e["recovered"]]
        share = len(latencies) / len(mine)
        return (share == 0, policy.startswith("oracle"), -share,
                float(np.median(latencies)) if latencies else np.inf, policies.index(policy))

    others = sorted((policy for policy in policies if policy != unaware), key=rank)
    if not others:
        return [next((e for e in flights if e["recovered"]), flights[0])]
    best = [e for e in flights if e["policy"] == others[0]]
    shown = min(best, key=lambda e: (not e["recovered"], bool((baseline.get(e["seed"]) or {}).get("recovered")),
                                     e["seed"] not in baseline, best.index(e)))
    return [e for e in (baseline.get(shown["seed"]), shown) if e is not None]


def fault_rate(config: dict, scenario: str) -> float | None:
    """The `rate` of the scenario's first fault spec in `config` (an incipient fault), None without one."""
    for entry in config.get("scenarios", []):
        faults = entry.get("env_kwargs", {}).get("faults") if entry.get("name") == scenario else None
        if isinstance(faults, list):
            return next((f.get("rate") for f in faults if isinstance(f, dict) and f.get("kind")), None)
    return None


def event_panels(event: dict) -> list[tuple[style.Signal, list[tuple[np.ndarray, dict]]]]:
    """The event figure's rows for one flight: (Signal, [(values (N,) or (N, k), line options)]) each. The vehicle's
    altitude, roll and pitch (unwrapped), the yaw rate (quadrotor) or the airspeeds (quad-plane: true, used by the
    autopilot and the detector's estimate), the rotor speeds, then each detector output."""
    from scipy.spatial.transform import Rotation
    roll_pitch = style.unwrap_deg(Rotation.from_quat(event["attitude"]).as_euler("ZYX", degrees=True)[:, :0:-1])
    outputs = dict(event["outputs"])
    panels = [(style.signal("altitude"), [(event["altitude"], {})]),
              (style.signal("attitude"), [(roll_pitch, {})])]
    if "airspeed" in event:
        lines = [(event["airspeed"], {"color": style.BLACK, "label": "true", "lw": 0.8})]
        if "airspeed_used" in event:
            lines.append((event["airspeed_used"], {"color": style.ORANGE, "label": "used by the autopilot"}))
        signal = style.signal("airspeed")
        if event["detector"] == "airdata_ekf" and "airspeed" in outputs:
            lines.append((outputs.pop("airspeed")[:, 0], {"color": style.BLUE, "ls": "--", "label": "EKF estimate"}))
        panels.append((signal, lines))
        panels.append((style.signal("hover_rotor_speed"), [(event["rotor_speed"], {})]))
    else:
        panels.append((style.signal("yaw_rate"), [(np.rad2deg(event["body_rates"][:, 2]), {})]))
        panels.append((style.signal("rotor_speed"), [(event["rotor_speed"], {})]))
    panels += [(style.signal(name, event["detector"]), [(values, {})]) for name, values in outputs.items()]
    return panels


def plot_event(path: Path, episodes: list[dict], rate: float | None = None) -> Path:
    """The time history around the fault onset of `episodes` (`event_episodes`: a fault-unaware flight and a
    recovering one of the same episode), side by side, as 000 Figs. 5, 8 and 9: altitude, roll and pitch, yaw
    rate or airspeeds, rotor speeds and each detector output, against the time since onset; the alarm (dashed),
    the start of the recovered window (dash-dot) and a crash (cross) marked. `rate`: an incipient fault's, for the
    title. Writes the PNG at `path` and its vector copy beside it; returns `path`."""
    if isinstance(episodes, dict):
        episodes = [episodes]
    colors = style.policy_colors(e["policy"] for e in episodes)
    columns = [(episode, event_panels(episode["trajectory"]["event"])) for episode in episodes]
    n_rows = len(columns[0][1])
    first = episodes[0]
    onset = first["trajectory"]["event"]["onset"]
    with style.paper():
        # two columns wide even for one episode: the legends right of the panels and the title need the width
        figure = Figure(figsize=style.size(2, 0.55 + 0.95 * n_rows),
                        layout="constrained")
        grid = np.asarray(figure.subplots(n_rows, len(columns), sharex=True, sharey="row", squeeze=False))
        for column, (episode, panels) in enumerate(columns):
            event = episode["trajectory"]["event"]
            t = event["time"] - event["onset"]
            for row, (signal, lines) in enumerate(panels):
                axes = grid[row, column]
                for values, options in lines:
                    _event_lines(axes, t, values, signal, {"color": style.BLACK, **options})
                _event_marks(axes, episode, event)
                if column == 0:
                    axes.set_ylabel(style.wrap(signal.label))
                if signal.levels:
                    axes.set_yticks(range(len(signal.levels)), signal.levels)
                if column == len(columns) - 1 and axes.get_legend_handles_labels()[0]:
                    axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
            if episode["crashed"]:
                grid[0, column].plot(t[-1], event["altitude"][-1], "x", color=style.BLACK, ms=6, mew=1.4)
            grid[0, column].set_title(_event_column_title(episode), color=colors[episode["policy"]])
            grid[-1, column].set_xlabel(style.label("time_since_onset"))
        times = [e["trajectory"]["event"]["time"] - e["trajectory"]["event"]["onset"] for e in episodes]
        grid[0, 0].set_xlim(min(t[0] for t in times), max(t[-1] for t in times))
        detector = first["trajectory"]["event"]["detector"]
        handles = [Line2D([], [], color=style.ONSET_COLOR, ls=":", label="fault onset"),
                   Line2D([], [], color=style.ALARM_COLOR, ls="--", label=f"alarm ({detector})"),
                   Line2D([], [], color=style.RECOVERY_COLOR, ls="-.", label="recovered (start of the 2 s window)"),
                   Line2D([], [], color=style.BLACK, ls="", marker="x", mew=1.4, label="crash")]
        handles = [handle for handle, shown in zip(handles, (True, detector is not None, any(
            e["recovery_time"] is not None for e in episodes), any(e["crashed"] for e in episodes))) if shown]
        figure.suptitle(f"{style.fault_title(first['fault_kind'], first['fault_target'], rate)} at t = {onset:.2f} s "
                        f"({first['scenario']}" + (", same episode)" if len(episodes) > 1 else ")"))
        figure.legend(handles=handles, loc="outside lower center", ncol=len(handles))
        figure.align_ylabels(grid[:, 0])
        style.save(figure, path)
    return path


def _event_lines(axes, t: np.ndarray, values: np.ndarray, signal: style.Signal, options: dict) -> None:
    """One signal's line(s): a vector signal one line per component, coloured and named by component."""
    values = np.asarray(values, dtype=float)
    if values.ndim == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.ndim == 1:
        axes.plot(t, values, **options)
        return
    names = signal.components if len(signal.components) == values.shape[1] else [
        f"{i + 1}" for i in range(values.shape[1])]
    for i, name in enumerate(names):
        axes.plot(t, values[:, i], **{**options, "color": style.COMPONENT_COLORS[i % len(style.COMPONENT_COLORS)],
                                      "label": name})


def _event_marks(axes, episode: dict, event: dict) -> None:
    axes.axvline(0.0, color=style.ONSET_COLOR, ls=":", lw=0.8)
    if event["alarm_time"] is not None:
        axes.axvline(event["alarm_time"] - event["onset"], color=style.ALARM_COLOR, ls="--", lw=0.8)
    if episode["recovery_time"] is not None and episode["recovery_time"] <= event["time"][-1]:
        axes.axvline(episode["recovery_time"] - event["onset"], color=style.RECOVERY_COLOR, ls="-.", lw=0.9)


def _event_column_title(episode: dict) -> str:
    onset, parts = episode["fault_onset"], []
    if episode["alarm_time"] is not None and onset is not None:
        delay = episode["alarm_time"] - onset
        parts.append(f"alarm {delay * 1000:+.0f} ms" if abs(delay) < 1 else f"alarm {delay:+.2f} s")
    if episode["crashed"]:
        parts.append(f"crash {episode['flight_time'] - onset:+.2f} s")
    elif episode["recovery_time"] is not None:
        parts.append(f"recovered {episode['recovery_time'] - onset:+.2f} s")
    else:
        parts.append("not recovered")
    return f"{episode['policy']}\n" + ", ".join(parts)


def _of_scenario(episodes: list[dict], name: str) -> list[dict]:
    return [episode for episode in episodes if episode["scenario"] == name]
