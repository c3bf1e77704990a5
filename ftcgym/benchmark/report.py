"""Benchmark outputs (docs/concepts.md, "Benchmark metrics"): results.json, episodes.csv, report.md, PNG plots, and
the summary table printed to stdout.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # a bare Figure renders with Agg: no pyplot, no global backend

from ftcgym.benchmark.metrics import EPISODE_FIELDS, SUMMARY_FIELDS
from ftcgym.benchmark.outputs import OutputFolder

# Short column labels for the tables; results.json and the CSV keep the full field names.
COLUMN_LABELS = {
    "scenario": "scenario", "policy": "policy", "episodes": "n",
    "detection_delay_median": "delay med (s)", "detection_delay_p95": "delay p95 (s)",
    "missed_detection_rate": "missed", "false_alarms_per_hour": "FA/h",
    "isolation_accuracy": "isolation", "recovery_latency_median": "recovery med (s)",
    "recovery_latency_p95": "recovery p95 (s)", "success_rate": "success", "crash_rate": "crash",
}
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
    "no crash in a fault-free episode. Medians and 95th percentiles interpolate linearly; '-' marks "
    "a figure that does not apply."
)


def format_value(value) -> str:
    """A table cell: 3 significant digits for floats, '-' for None."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def format_table(summary: list[dict]) -> str:
    """The summary as a plain text table, text left-aligned and numbers right-aligned."""
    header = [COLUMN_LABELS[field] for field in SUMMARY_FIELDS]
    cells = [[format_value(row[field]) for field in SUMMARY_FIELDS] for row in summary]
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
    """Write results.json, episodes.csv, the plots and report.md of a run's `results` document
    (`results.results_document`); `episodes` are the rows with their trajectories, for the plots.
    The files are staged and published whole (`outputs.OutputFolder`): the folder then holds this run's
    files and none of its previous run's."""
    with OutputFolder(out_dir) as folder:
        paths = write_files(folder.staged, results, episodes)
        folder.publish()
    return [folder.path / path.name for path in paths]


def write_files(place, results: dict, episodes: list[dict]) -> list[Path]:
    """The report's files, each written at `place(name)`; returns their paths, report.md's plots last."""
    paths = [write_json(place("results.json"), results), write_csv(place("episodes.csv"), results["episodes"])]
    plots = []
    for name in dict.fromkeys(episode["scenario"] for episode in episodes):
        of_scenario = _of_scenario(episodes, name)
        plots.append(plot_scenario(place(f"{name}.png"), name, of_scenario))
        event = next((e for e in of_scenario if e["trajectory"].get("event")), None)
        if event is not None:
            plots.append(plot_event(place(f"{name}-event.png"), event))
        if any(e["fault_onset"] is not None for e in of_scenario):
            plots.append(plot_latencies(place(f"{name}-latency.png"), name, of_scenario))
    paths.append(write_markdown(place("report.md"), results["summary"], results["config"], plots))
    return paths + plots


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


def write_markdown(path: Path, summary: list[dict], config: dict, plots: list[Path]) -> Path:
    scenario_lines = [f"- `{s['name']}` ({s['env_id']}, policies {', '.join(s['policies'])}, "
                      f"{s['episodes']} episodes): {s['description']}" for s in config["scenarios"]]
    plot_lines = [f"![{plot.stem}]({plot.name})" for plot in plots]
    text = "\n\n".join([
        "# ftcgym benchmark",
        f"`{config['command']}` (ftcgym {config['ftcgym_version']}, seed {config['seed']}, "
        f"{config['workers']} workers, {config['wall_time_s']:.0f} s wall time). Environment "
        "overrides: " + (f"`{json.dumps(config['env_overrides'])}`" if config["env_overrides"] else "none") + ".",
        "## Scenarios", "\n".join(scenario_lines),
        "## Summary", markdown_table(summary), DEFINITIONS,
        "## Plots", "Altitude and horizontal path of every episode (dotted lines mark fault onsets, "
        "dashed black lines the reference); for scenarios with faults, histograms of the detection delay "
        "and the recovery latency, and the time history of one episode around the fault.",
        "\n\n".join(plot_lines),
    ])
    path.write_text(text + "\n")
    return path


def plot_scenario(path: Path, scenario: str, episodes: list[dict]) -> Path:
    """Altitude vs time and the horizontal path (north up, east right) of each episode, by policy."""
    figure = Figure(figsize=(11, 4), layout="constrained")
    altitude_axes, path_axes = figure.subplots(1, 2, width_ratios=(3, 2))
    reference = episodes[0]["trajectory"]
    altitude_axes.plot(reference["time"], -reference["reference_position"][:, 2], "k--", lw=1)
    path_axes.plot(reference["reference_position"][:, 1], reference["reference_position"][:, 0], "k--", lw=1)
    policies = dict.fromkeys(episode["policy"] for episode in episodes)
    colors = {policy: f"C{i % 10}" for i, policy in enumerate(policies)}
    for episode in episodes:
        color, trajectory = colors[episode["policy"]], episode["trajectory"]
        altitude_axes.plot(trajectory["time"], -trajectory["position"][:, 2], color=color, lw=1, alpha=0.8)
        path_axes.plot(trajectory["position"][:, 1], trajectory["position"][:, 0], color=color, lw=1, alpha=0.8)
        if episode["fault_onset"] is not None:
            altitude_axes.axvline(episode["fault_onset"], color=color, ls=":", lw=1)
    for policy, color in colors.items():
        altitude_axes.plot([], [], color=color, label=policy)
    altitude_axes.set(title=scenario, xlabel="time (s)", ylabel="altitude (m)")
    altitude_axes.legend(loc="best", fontsize="small")
    path_axes.set(title="horizontal path", xlabel="east (m)", ylabel="north (m)")
    path_axes.set_aspect("equal", adjustable="datalim")
    figure.savefig(path, dpi=100)
    return path


def plot_latencies(path: Path, scenario: str, episodes: list[dict]) -> Path:
    """Histograms of the detection delay and the recovery latency (recovery time - onset), by policy."""
    figure = Figure(figsize=(10, 3.2), layout="constrained")
    delay_axes, recovery_axes = figure.subplots(1, 2)
    policies = dict.fromkeys(episode["policy"] for episode in episodes)
    for i, policy in enumerate(policies):
        n_faults, delays, latencies = latency_samples(episodes, policy)
        for axes, values in ((delay_axes, delays), (recovery_axes, latencies)):
            if values:
                axes.hist(values, bins=20, color=f"C{i % 10}", alpha=0.6,
                          label=f"{policy} (n={len(values)}/{n_faults})")
    delay_axes.set(title=f"{scenario}: detection delay", xlabel="alarm - onset (s)", ylabel="episodes")
    recovery_axes.set(title="recovery latency", xlabel="recovery time - onset (s)")
    for axes in (delay_axes, recovery_axes):
        if axes.has_data():
            axes.legend(fontsize="small")
    figure.savefig(path, dpi=100)
    return path


def latency_samples(episodes: list[dict], policy: str) -> tuple[int, list[float], list[float]]:
    """(fault episodes, detection delays, recovery latencies) of `policy`; undetected or unrecovered
    episodes add no sample."""
    mine = [e for e in episodes if e["policy"] == policy and e["fault_onset"] is not None]
    delays = [e["detection_delay"] for e in mine if e["detection_delay"] is not None]
    latencies = [e["recovery_time"] - e["fault_onset"] for e in mine if e["recovery_time"] is not None]
    return len(mine), delays, latencies


def plot_event(path: Path, episode: dict) -> Path:
    """Time history around the fault of one episode, as 000 Figs. 5, 8 and 9: altitude, attitude,
    rotor speeds and each detector output, with the onset (dotted) and the alarm (dashed) marked."""
    from scipy.spatial.transform import Rotation
    event = episode["trajectory"]["event"]
    outputs = event["outputs"]
    roll_pitch = Rotation.from_quat(event["attitude"]).as_euler("ZYX", degrees=True)[:, :0:-1]
    panels = [("altitude (m)", event["altitude"]), ("roll, pitch (deg)", roll_pitch),
              ("yaw rate (deg/s)", np.rad2deg(event["body_rates"][:, 2])),
              ("rotor speed (rad/s)", event["rotor_speed"])]
    panels += [(f"{event['detector']}: {name}", values) for name, values in outputs.items()]
    figure = Figure(figsize=(8, 1.7 * len(panels)), layout="constrained")
    axes = figure.subplots(len(panels), 1, sharex=True)
    for ax, (label, values) in zip(axes, panels):
        ax.plot(event["time"], values, lw=1)
        ax.set_ylabel(label, fontsize="small")
        ax.axvline(event["onset"], color="k", ls=":", lw=1)
        if event["alarm_time"] is not None:
            ax.axvline(event["alarm_time"], color="r", ls="--", lw=1)
    if values.ndim > 1 and values.shape[1] == 4:
        axes[-1].legend([f"rotor {i}" for i in range(4)], fontsize="x-small", ncol=4, loc="best")
    axes[0].set_title(f"{episode['scenario']} / {episode['policy']}: fault {episode['fault_kind']} "
                      f"on {episode['fault_target']} (dotted), alarm (dashed)")
    axes[-1].set_xlabel("time (s)")
    figure.savefig(path, dpi=100)
    return path


def _of_scenario(episodes: list[dict], name: str) -> list[dict]:
    return [episode for episode in episodes if episode["scenario"] == name]
