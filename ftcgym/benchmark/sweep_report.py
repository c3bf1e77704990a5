"""A sweep's outputs: per-set summary (results.json, sets.csv, report.md) and the plots of 000 Fig. 11:
detection-delay box plots per parameter set (detection_delay.png), missed detections and false alarms per
set (detections.png); each PNG with a PDF beside it, in the look of `style`.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # a bare Figure renders with Agg: no pyplot, no global backend
from matplotlib.lines import Line2D

from ftcgym.benchmark import style
from ftcgym.benchmark.journal import CONFIG_FILE, FAILURES_FILE, ROWS_FILE
from ftcgym.benchmark.outputs import OutputFolder

SET_FIELDS = ("parameter_set", "flights", "fault_flights", "detected", "missed", "false_alarms",
              "delay_median_ms", "delay_q1_ms", "delay_q3_ms", "delay_max_ms")


def summarize_sets(rows: list[dict], set_names) -> list[dict]:
    """Per parameter set: flights, faults detected and missed, flights with a false alarm, delay quartiles (ms).

    A missed detection is a fault flight without an alarm at or after onset; a false alarm, an alarm before
    onset or in a fault-free flight (docs/concepts.md, 'Benchmark metrics'), so a flight that alarmed early
    counts as both.
    """
    return [_summarize_set(name, [row for row in rows if row["parameter_set"] == name]) for name in set_names]


def _summarize_set(name: str, rows: list[dict]) -> dict:
    faulty = [row for row in rows if row["fault_onset"] is not None]
    delays_ms = 1000.0 * np.array([row["detection_delay"] for row in faulty if row["detection_delay"] is not None])
    quartiles = np.percentile(delays_ms, [50, 25, 75, 100]).tolist() if delays_ms.size else [None] * 4
    return dict(zip(SET_FIELDS, (name, len(rows), len(faulty), int(delays_ms.size), len(faulty) - delays_ms.size,
                                 sum(bool(row["false_alarm"]) for row in rows), *quartiles)))


def write_sweep_report(out_dir, config, rows: list[dict], run: dict) -> str:
    """Write results.json, sets.csv, the two plots and report.md; return the summary as a text table.
    They are staged and published whole (`outputs.OutputFolder`); the journal and sweep_config.json, written
    as the sweep ran, count as this run's files too."""
    with OutputFolder(out_dir) as folder:
        table = write_sweep_files(folder.staged, config, rows, run)
        folder.publish(also=(ROWS_FILE, FAILURES_FILE, CONFIG_FILE))
    return table


def write_sweep_files(place, config, rows: list[dict], run: dict) -> str:
    """The report's files, each written at `place(name)`; returns the summary as a text table."""
    names = [s.name for s in config.parameter_sets]
    summary = summarize_sets(rows, names)
    results = {"summary": summary, "episodes": rows, "config": {**config.to_json(), "run": run}}
    place("results.json").write_text(json.dumps(results, indent=1) + "\n")
    with place("sets.csv").open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=SET_FIELDS)
        writer.writeheader()
        writer.writerows(summary)
    plot_delays(place("detection_delay.png"), rows, names, config.name)
    plot_detections(place("detections.png"), summary, config.name)
    table = format_sets(summary)
    place("report.md").write_text(
        f"# Sweep {config.name}\n\n{config.description}\n\nCommand: `{run['command']}` ({run['backend']} backend, "
        f"{run['wall_time_s']:.0f} s)\n\n```\n{table}\n```\n\n![detection delay](detection_delay.png)\n\n"
        f"![missed detections and false alarms](detections.png)\n\nEach PNG has a "
        f"{style.VECTOR_FORMAT.upper()} beside it (same name, .{style.VECTOR_FORMAT}) for papers.\n")
    return table


def format_sets(summary: list[dict]) -> str:
    header = ["set", "flights", "faults", "detected", "missed", "false al.", "delay med ms", "q1", "q3", "max"]
    cells = [[str(row[f]) if not isinstance(row[f], float) else f"{row[f]:.0f}" for f in SET_FIELDS] for row in summary]
    cells = [[cell if cell != "None" else "-" for cell in line] for line in cells]
    widths = [max(len(c) for c in column) for column in zip(header, *cells)]
    return "\n".join("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
                     for line in [header, *cells])


def plot_delays(path: Path, rows: list[dict], names: list[str], title: str) -> Path:
    """000 Fig. 11: one box of detection delays (ms) per set; outliers beyond 1.5 IQR as crosses, with a key."""
    delays = [[1000.0 * row["detection_delay"] for row in rows
               if row["parameter_set"] == name and row["detection_delay"] is not None] for name in names]
    with style.paper():
        figure = Figure(figsize=style.size(1 if len(names) <= 6 else 2, 2.8), layout="constrained")
        axes = figure.add_subplot()
        axes.boxplot([d if d else [np.nan] for d in delays], tick_labels=names, whis=1.5,
                     boxprops={"linewidth": 0.8}, medianprops={"color": style.BLUE, "linewidth": 1.2},
                     flierprops={"marker": "+", "markeredgecolor": style.VERMILLION, "markersize": 4})
        axes.set_ylabel(style.label("detection_delay"))
        axes.set_title(f"{title}: detection delay per parameter set")
        key = [Line2D([], [], color=style.BLUE, lw=1.2, label="median"),
               Line2D([], [], color=style.BLACK, lw=0.8, label="quartiles; whiskers within 1.5 IQR"),
               Line2D([], [], ls="", marker="+", markeredgecolor=style.VERMILLION, label="beyond the whiskers")]
        figure.legend(handles=key, loc="outside upper right", ncol=3, fontsize="small")
        for label in axes.get_xticklabels():
            label.set(rotation=60, ha="right")
        axes.grid(axis="x", visible=False)
        style.save(figure, path)
    return path


def plot_detections(path: Path, summary: list[dict], title: str) -> Path:
    """Missed detections and false alarms (flights) per set, side by side; a PNG at `path`, a PDF beside it."""
    with style.paper():
        style.save(detections_figure(summary, title), path)
    return path


def detections_figure(summary: list[dict], title: str) -> Figure:
    """The figure of `plot_detections`: whole-number ticks on its count axis."""
    x = np.arange(len(summary))
    figure = Figure(figsize=style.size(1 if len(summary) <= 6 else 2, 2.6), layout="constrained")
    axes = figure.add_subplot()
    bars = ((-0.2, "missed", "missed detections", style.VERMILLION),
            (0.2, "false_alarms", "flights with a false alarm", style.SKY_BLUE))
    for offset, key, label, color in bars:
        drawn = axes.bar(x + offset, [row[key] for row in summary], 0.4, label=label, color=color)
        # a zero is a result too: label it in the bar's colour, as an empty axis says nothing
        axes.bar_label(drawn, fontsize=6, color=color, fontweight="bold")
    axes.set_xticks(x, [row["parameter_set"] for row in summary], rotation=60, ha="right")
    axes.set_ylabel(style.label("flights"))
    faults, flights = summary[0]["fault_flights"], summary[0]["flights"]
    axes.set_title(f"{title}: {faults} fault flights, {flights - faults} fault-free, per set")
    style.integer_ticks(axes.yaxis)
    most = max([row["missed"] for row in summary] + [row["false_alarms"] for row in summary])
    axes.set_ylim(0, max(most, 1) + 0.5)  # zero counts stay on the axis instead of a symmetric empty range
    axes.grid(axis="x", visible=False)
    axes.legend(loc="upper right")
    return figure
