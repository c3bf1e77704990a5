"""One look for every benchmark figure (`report`, `sweep_report`, `iv_study`): paper rcParams, figure sizes
for one- and two-column papers, a fixed colour per policy, labels in words with units for every signal the
figures draw, angle unwrapping, integer ticks on count axes, and `save` (PNG plus a PDF beside it).

Use as
    with style.paper():
        figure = Figure(figsize=style.size(2, 3.0), layout="constrained")
        ...
        style.save(figure, path)          # path.png and path.pdf

Colours are the Okabe-Ito colour-blind-safe palette: a policy keeps its colour in every figure (the fault-unaware
`nominal` and `pitot-only` vermillion, the detector-driven recoveries blue, the oracles green, the learned policies
purple); a policy outside the table takes the first colour its figure does not use yet.
"""
from __future__ import annotations

import contextlib
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: inches: one column and the full width of a two-column paper (IEEE: 3.5 and 7.16 in)
COLUMN_WIDTH, PAGE_WIDTH = 3.5, 7.16
PNG_DPI = 200
VECTOR_FORMAT = "pdf"   # written beside every PNG

RC = {
    "font.size": 8.0, "axes.titlesize": 8.5, "axes.labelsize": 8.0, "xtick.labelsize": 7.0,
    "ytick.labelsize": 7.0, "legend.fontsize": 7.0, "figure.titlesize": 9.0,
    "legend.frameon": False, "legend.handlelength": 1.6, "legend.borderaxespad": 0.3,
    "axes.linewidth": 0.6, "lines.linewidth": 1.0, "lines.markersize": 4.0,
    "xtick.major.width": 0.6, "ytick.major.width": 0.6, "xtick.major.size": 2.5, "ytick.major.size": 2.5,
    "axes.spines.top": False, "axes.spines.right": False,
    "axes.grid": True, "grid.linewidth": 0.4, "grid.alpha": 0.35,
    "axes.titlelocation": "left", "axes.titleweight": "normal",
    "figure.constrained_layout.h_pad": 0.03, "figure.constrained_layout.w_pad": 0.03,
    "pdf.fonttype": 42, "ps.fonttype": 42,   # TrueType in the PDF: text stays text (journals ask for it)
    "svg.fonttype": "none",
    "savefig.dpi": PNG_DPI,
}

# Okabe & Ito (2008), "Color universal design".
BLACK, ORANGE, SKY_BLUE, GREEN, YELLOW, BLUE, VERMILLION, PURPLE, GREY = (
    "#000000", "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7", "#7F7F7F")
POLICY_COLORS = {
    "nominal": VERMILLION, "pitot-only": VERMILLION, "autopilot": VERMILLION,
    "ftc-spin": BLUE, "airspeed-switch": BLUE,
    "oracle-spin": GREEN, "oracle-airspeed": GREEN,
    "learned-spin": PURPLE, "learned-airspeed": PURPLE,
    "synthetic-only": ORANGE,
}
SPARE_COLORS = (ORANGE, SKY_BLUE, BLUE, GREEN, PURPLE, VERMILLION, YELLOW, BLACK, GREY)
#: colours of the components of a vector signal (rotors r1..r4, north/east/down, ...)
COMPONENT_COLORS = (BLUE, ORANGE, GREEN, PURPLE, SKY_BLUE, VERMILLION)
ONSET_COLOR, ALARM_COLOR, RECOVERY_COLOR, REFERENCE_COLOR = BLACK, BLACK, GREEN, BLACK


@contextlib.contextmanager
def paper():
    """rcParams for the figures made (and saved) inside the block."""
    import matplotlib
    with matplotlib.rc_context(RC):
        yield


def size(columns: int = 2, height: float = 2.4) -> tuple[float, float]:
    """(width, height) in inches of a figure one (`columns`=1) or two columns wide."""
    return (COLUMN_WIDTH if columns == 1 else PAGE_WIDTH, height)


def policy_colors(policies) -> dict[str, str]:
    """A colour per policy: its own (POLICY_COLORS), or for a policy outside the table the first spare colour
    no other policy in `policies` uses."""
    policies = list(dict.fromkeys(policies))
    colors = {policy: POLICY_COLORS[policy] for policy in policies if policy in POLICY_COLORS}
    spare = [color for color in SPARE_COLORS if color not in colors.values()] or list(SPARE_COLORS)
    for policy in policies:
        if policy not in colors:
            colors[policy] = spare.pop(0) if spare else GREY
    return {policy: colors[policy] for policy in policies}


#: line styles of the policies in a plot, in order: where two policies fly the same path, the dashes of the later
#: one show the earlier one's line under it (the grey dotted line is the fault onset's)
POLICY_DASHES = ("-", (0, (5, 2.5)), (0, (1.2, 1.8)), (0, (7, 2, 1.5, 2)), (0, (3, 3)))


def policy_lines(policies) -> dict[str, dict]:
    """Matplotlib line keywords per policy: its colour (`policy_colors`) and a line style of POLICY_DASHES."""
    colors = policy_colors(policies)
    return {policy: {"color": color, "ls": POLICY_DASHES[i % len(POLICY_DASHES)]}
            for i, (policy, color) in enumerate(colors.items())}


@dataclass(frozen=True)
class Signal:
    """A plotted quantity: `name` in words, `unit` (None: dimensionless, shown without one), the legend names of
    its components (vector signals), and `levels`, the names of an integer-coded signal's values."""

    name: str
    unit: str | None = None
    components: tuple[str, ...] = ()
    levels: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.name} ({self.unit})" if self.unit else self.name


ROTORS = ("r1", "r2", "r3", "r4")   # fault target i is rotor r(i+1) (docs/concepts.md, 'Rotor numbering')
NED = ("north", "east", "down")
#: what the vehicle logs and the figures draw
VEHICLE_SIGNALS = {
    "time": Signal("Time", "s"),
    "time_since_onset": Signal("Time since fault onset", "s"),
    "altitude": Signal("Altitude", "m"),
    "north": Signal("North", "m"),
    "east": Signal("East", "m"),
    "attitude": Signal("Roll and pitch", "deg", ("roll", "pitch")),
    "yaw_rate": Signal("Yaw rate", "deg/s"),
    "rotor_speed": Signal("Rotor speed", "rad/s", ROTORS),
    "hover_rotor_speed": Signal("Hover-rotor speed", "rad/s", ROTORS),
    "airspeed": Signal("Airspeed", "m/s", ("true", "used by the autopilot")),
    "detection_delay": Signal("Detection delay", "ms"),
    "recovery_latency": Signal("Recovery latency", "s"),
    "flights": Signal("Flights"),
}
#: (detector, output field) -> Signal, for every built-in detector's `output_fields`
DETECTOR_SIGNALS = {
    ("loe_kalman", "k_hat"): Signal("Estimated rotor effectiveness", None, ROTORS),
    ("loe_kalman", "k_var"): Signal("Effectiveness estimate variance", None, ROTORS),
    ("loe_kalman", "p_fail"): Signal("Rotor failure probability", None, ROTORS),
    ("loe_cusum", "cusum"): Signal("Thrust-loss CUSUM statistic", None, ROTORS),
    ("loe_cusum", "speed_cusum"): Signal("Motor spin-up CUSUM statistic", None, ROTORS),
    ("loe_cusum", "residual"): Signal("Acceleration residual", "rad/s^2, m/s^2", ("p-dot", "q-dot", "a-z")),
    ("aekf", "loe"): Signal("Estimated loss of effectiveness", None, ROTORS),
    ("aekf", "loe_std"): Signal("Loss-of-effectiveness std. dev.", None, ROTORS),
    ("aekf", "innovation"): Signal("Normalised innovation statistic"),
    ("iv_change", "J"): Signal("IV cost", None, ("x axis", "y axis")),
    ("iv_change", "residual"): Signal("Sensor-to-sensor residual", "m/s²", ("x axis", "y axis")),
    ("iv_change", "c_hat"): Signal("IV estimate of drag per mass", "1/s"),
    ("iv_change", "cusum"): Signal("CUSUM statistic", "s"),
    ("iv_change", "wind_cusum"): Signal("Wind-test CUSUM statistic", None),
    ("airdata_ekf", "airspeed"): Signal("EKF airspeed", "m/s", ("EKF estimate",)),
    ("airdata_ekf", "wind"): Signal("EKF wind estimate", "m/s", NED),
    ("airdata_ekf", "pitot_residual"): Signal("Pitot residual (pitot − EKF)", "m/s"),
    ("propulsion_bayes", "p_fault_detect"): Signal("Fault probability", None,
                                                   ("propeller icing", "viscous friction", "static friction")),
    ("propulsion_bayes", "p_isolate"): Signal("Isolation probability", None,
                                              ("no fault", "propeller icing", "viscous friction", "static friction")),
    ("propulsion_bayes", "estimate"): Signal("Fault-state estimates", None, ("θ₁", "cᵥ", "I₀ (A)")),
    ("propulsion_bayes", "airspeed_request"): Signal("Airspeed request", "m/s"),
    ("propulsion_bayes", "phase"): Signal("Detector phase", None, (),
                                          ("waiting", "calibrating", "detecting", "isolating", "isolated")),
}


def signal(name: str, detector: str | None = None) -> Signal:
    """The Signal of a vehicle signal `name`, or of `detector`'s output `name`. A name neither table knows (a
    plug-in detector's output) gets its words: underscores become spaces, no unit."""
    known = DETECTOR_SIGNALS.get((detector, name)) if detector else VEHICLE_SIGNALS.get(name)
    return known or Signal(name.replace("_", " ").strip().capitalize() or "Output")


def label(name: str, detector: str | None = None) -> str:
    """Axis label in words with the unit, e.g. 'Rotor failure probability' or 'EKF wind estimate (m/s)'."""
    return signal(name, detector).label


FAULTS = {"rotor_loss": "Rotor {target} lost", "loe": "Loss of effectiveness of rotor {target}",
          "payload": "Payload added", "sensor_bias": "Sensor {target} biased", "sensor_stuck": "Sensor {target} stuck",
          "sensor_dropout": "Sensor {target} reads zero", "gnss": "GNSS velocity reads zero",
          "pusher_rpm_sensor": "Pusher speed sensor reads zero", "skew_sensor": "Skew sensor stuck",
          "propeller_icing": "Propeller icing", "viscous_friction": "Pusher viscous friction",
          "static_friction": "Pusher static friction"}
PITOT_BLOCKAGE = {"zero": "Pitot blockage (reads zero)", "stuck": "Pitot blockage (reading stuck)",
                  "incipient": "Incipient pitot blockage (reading drifts down)"}


def fault_title(kind: str | None, target=None, rate: float | None = None) -> str:
    """A fault in words: 'Rotor r3 lost', 'Pitot blockage (reads zero)'."""
    if kind is None:
        return "No fault"
    if kind == "pitot_blockage":
        return PITOT_BLOCKAGE["incipient" if rate else (target or "zero")]
    if kind in ("rotor_loss", "loe"):
        targets = target if isinstance(target, (list, tuple)) else [target]
        target = ", ".join(ROTORS[t] if isinstance(t, int) and 0 <= t < len(ROTORS) else str(t) for t in targets)
    text = FAULTS.get(kind, kind.replace("_", " ").capitalize() + (" on {target}" if target is not None else ""))
    return text.format(target=target)


def wrap(text: str, width: int = 16) -> str:
    """`text` broken into lines of at most `width` characters (a y label beside a short panel)."""
    return textwrap.fill(text, width, break_long_words=False)


def unwrap_deg(angles_deg: np.ndarray) -> np.ndarray:
    """Angles (deg, along axis 0) without the 360 deg jumps where they wrap at +-180 deg."""
    return np.rad2deg(np.unwrap(np.deg2rad(np.asarray(angles_deg, dtype=float)), axis=0))


def integer_ticks(axis) -> None:
    """Ticks at whole numbers only on `axis` (an Axes' xaxis or yaxis): for counts."""
    from matplotlib.ticker import MaxNLocator
    axis.set_major_locator(MaxNLocator(integer=True))


def save(figure, path: Path) -> list[Path]:
    """`figure` at `path` (PNG, PNG_DPI) and as VECTOR_FORMAT beside it; both paths."""
    path = Path(path)
    vector = path.with_suffix(f".{VECTOR_FORMAT}")
    figure.savefig(path, dpi=PNG_DPI)
    figure.savefig(vector, metadata={"CreationDate": None} if VECTOR_FORMAT == "pdf" else None)
    return [path, vector]
