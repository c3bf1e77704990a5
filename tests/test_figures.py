"""The benchmark's figures (benchmark/style.py, report.py, sweep_report.py): labels in words with units for every
signal they draw, unwrapped angles, the flights the event figure shows, whole-number count axes, vector copies."""
import inspect
import pkgutil
from importlib import import_module

import numpy as np
import pytest

import ftcgym.fdd
from ftcgym.benchmark import style
from ftcgym.benchmark.report import event_episodes, event_panels, fault_rate, plot_event, plot_latencies
from ftcgym.benchmark.sweep_report import detections_figure, plot_delays


def detector_classes():
    """Every detector class of ftcgym.fdd: a `name` and the `output_fields` its outputs are published under."""
    found = {}
    for module in pkgutil.iter_modules(ftcgym.fdd.__path__):
        for _, cls in inspect.getmembers(import_module(f"ftcgym.fdd.{module.name}"), inspect.isclass):
            if isinstance(getattr(cls, "output_fields", None), dict) and isinstance(getattr(cls, "name", None), str):
                found[cls.name] = cls
    return found


def assert_in_words(text: str):
    assert text and "_" not in text and ":" not in text, text


def test_every_detector_output_has_a_label_in_words_and_a_name_per_component():
    classes = detector_classes()
    assert set(classes) >= {"loe_kalman", "aekf", "iv_change", "airdata_ekf", "propulsion_bayes"}
    for name, cls in classes.items():
        for field, (_, _, shape) in cls.output_fields.items():
            assert (name, field) in style.DETECTOR_SIGNALS, f"{name}.{field} has no label in style.DETECTOR_SIGNALS"
            signal = style.signal(field, name)
            assert_in_words(signal.label)
            for component in signal.components:
                assert_in_words(component)
            if shape[0] > 1:
                assert len(signal.components) == shape[0], f"{name}.{field}: one legend name per component"


def test_vehicle_signals_and_unknown_outputs_read_as_words():
    for name in style.VEHICLE_SIGNALS:
        assert_in_words(style.label(name))
    assert style.label("altitude") == "Altitude (m)" and style.label("wind", "airdata_ekf") == "EKF wind estimate (m/s)"
    assert style.signal("wind", "airdata_ekf").components == ("north", "east", "down")
    assert style.label("my_plugin_score", "plugin") == "My plugin score"   # a plug-in's output: its words, no unit


def test_coded_detector_outputs_name_their_levels_as_the_detector_does():
    from ftcgym.fdd.propulsion_bayes import MODES, PHASES
    assert style.signal("phase", "propulsion_bayes").levels == PHASES
    assert len(style.signal("p_isolate", "propulsion_bayes").components) == len(MODES)


@pytest.mark.parametrize(("kind", "target", "rate", "title"), [
    ("pitot_blockage", "zero", None, "Pitot blockage (reads zero)"),
    ("pitot_blockage", "zero", 2.5, "Incipient pitot blockage (reading drifts down)"),
    ("rotor_loss", 2, None, "Rotor r3 lost"),
    ("loe", [0, 2], None, "Loss of effectiveness of rotor r1, r3"),
    ("gnss", None, None, "GNSS velocity reads zero"),
    ("new_kind", None, None, "New kind"),
])
def test_faults_in_words(kind, target, rate, title):
    assert style.fault_title(kind, target, rate) == title


def test_fault_rate_comes_from_the_scenarios_fault_spec():
    config = {"scenarios": [{"name": "a", "env_kwargs": {"faults": [{"kind": "pitot_blockage", "rate": 2.5}]}},
                            {"name": "b", "env_kwargs": {"faults": "random:rotor_loss"}}]}
    assert (fault_rate(config, "a"), fault_rate(config, "b"), fault_rate(config, "c")) == (2.5, None, None)


def test_angles_unwrap_across_180_deg():
    roll = np.array([170.0, 179.0, -179.0, -170.0, 175.0])   # through +180, then back
    assert style.unwrap_deg(roll) == pytest.approx([170.0, 179.0, 181.0, 190.0, 175.0])
    both = style.unwrap_deg(np.column_stack([roll, -roll]))  # along time, per column
    assert both[:, 0] == pytest.approx([170.0, 179.0, 181.0, 190.0, 175.0])
    assert both[:, 1] == pytest.approx([-170.0, -179.0, -181.0, -190.0, -175.0])


def test_every_policy_keeps_its_colour_and_others_get_unused_ones():
    colors = style.policy_colors(["nominal", "ftc-spin", "mine", "theirs"])
    assert colors["nominal"] == style.POLICY_COLORS["nominal"] and colors["ftc-spin"] == style.POLICY_COLORS["ftc-spin"]
    assert len(set(colors.values())) == 4
    assert style.policy_colors(["ftc-spin"])["ftc-spin"] == colors["ftc-spin"]


def test_policies_that_fly_the_same_path_differ_in_dashes_as_well():
    lines = style.policy_lines(["pitot-only", "oracle-airspeed", "pitot-only", "mine"])
    assert list(lines) == ["pitot-only", "oracle-airspeed", "mine"]
    assert lines["pitot-only"] == {"color": style.POLICY_COLORS["pitot-only"], "ls": "-"}
    assert len({str(line["ls"]) for line in lines.values()}) == 3


# ---- which flights the event figure shows ----

def row(policy, seed, recovered, recovery_time=None, crashed=False, onset=2.0):
    event = {"time": np.linspace(onset - 0.5, onset + 3.0, 8)}
    return {"scenario": "s", "policy": policy, "seed": seed, "fault_kind": "rotor_loss", "fault_target": 1,
            "fault_onset": onset, "alarm_time": onset + 0.05, "recovered": recovered,
            "recovery_time": recovery_time if recovery_time is not None else (onset + 1.0 if recovered else None),
            "crashed": crashed, "flight_time": onset + 1.0 if crashed else 10.0, "trajectory": {"event": event}}


def picked(rows):
    return [(e["policy"], e["seed"]) for e in event_episodes(rows)]


def test_the_event_figure_sets_a_recovering_flight_beside_the_fault_unaware_one():
    rows = [row("nominal", 1, False, crashed=True), row("nominal", 2, False, crashed=True),
            row("ftc-spin", 1, False, crashed=True), row("ftc-spin", 2, True),
            row("oracle-spin", 1, True), row("oracle-spin", 2, True)]
    # ftc-spin recovered once, the oracle twice: a flyable policy that recovered goes before the upper bound
    assert picked(rows) == [("nominal", 2), ("ftc-spin", 2)]


def test_the_best_recovering_policy_recovers_most_then_soonest():
    rows = [row("nominal", 1, False, crashed=True), row("nominal", 2, False, crashed=True),
            row("slow", 1, True, recovery_time=3.5), row("slow", 2, True, recovery_time=3.6),
            row("fast", 1, False), row("fast", 2, True, recovery_time=2.5),
            row("sure", 1, True, recovery_time=3.9), row("sure", 2, True, recovery_time=3.8)]
    assert picked(rows) == [("nominal", 1), ("slow", 1)]      # slow and sure both 2/2: slow's median is lower
    assert picked([r for r in rows if r["policy"] != "slow"]) == [("nominal", 1), ("sure", 1)]   # 2/2 > 1/2


def test_the_event_figure_prefers_an_episode_the_unaware_policy_did_not_survive():
    rows = [row("pitot-only", 1, True), row("pitot-only", 2, False),
            row("airspeed-switch", 1, True), row("airspeed-switch", 2, True)]
    assert picked(rows) == [("pitot-only", 2), ("airspeed-switch", 2)]


def test_the_event_figure_without_recovery_or_baseline():
    nobody = [row("nominal", 1, False, crashed=True), row("ftc-spin", 1, False, crashed=True)]
    assert picked(nobody) == [("nominal", 1), ("ftc-spin", 1)]   # still the comparison, none recovered
    assert picked([row("oracle-spin", 1, False), row("oracle-spin", 2, True)]) == [("oracle-spin", 2)]
    assert picked([row("airspeed-switch", 3, True), row("oracle-airspeed", 3, True)]) == [("airspeed-switch", 3)]
    assert event_episodes([{**row("nominal", 1, False), "trajectory": {"event": None}}]) == []


# ---- drawing ----

def event_of(policy, seed, recovered, crashed, detector, outputs, **extra):
    n = 60
    t = np.linspace(4.5, 4.5 + (1.5 if crashed else 3.5), n)
    angle = np.linspace(0.0, 3.0 * np.pi, n)   # a tumble: roll through +-180 deg
    attitude = np.column_stack([np.sin(angle / 2), np.zeros(n), np.zeros(n), np.cos(angle / 2)])
    event = {"time": t, "onset": 5.0, "alarm_time": 5.05, "detector": detector, "altitude": np.linspace(5, 0, n),
             "attitude": attitude, "body_rates": np.zeros((n, 3)), "rotor_speed": np.full((n, 4), 700.0),
             "outputs": {name: np.ones((n, k)) for name, k in outputs.items()}, **extra}
    return {**row(policy, seed, recovered, crashed=crashed, onset=5.0), "trajectory": {"event": event}}


def test_event_panels_label_every_row_in_words_and_unwrap_the_roll():
    quad = event_of("nominal", 1, False, True, "loe_kalman", {"k_hat": 4, "k_var": 4, "p_fail": 4})
    panels = event_panels(quad["trajectory"]["event"])
    for signal, _ in panels:
        assert_in_words(signal.label)
    assert [s.label for s, _ in panels][:4] == ["Altitude (m)", "Roll and pitch (deg)", "Yaw rate (deg/s)",
                                                 "Rotor speed (rad/s)"]
    roll = panels[1][1][0][0][:, 0]
    assert np.all(np.diff(roll) > 0) and roll[-1] == pytest.approx(540.0)   # 1.5 turns, no jump back
    n = 60
    plane = event_of("pitot-only", 1, False, False, "airdata_ekf", {"airspeed": 1, "wind": 3, "pitot_residual": 1},
                     airspeed=np.full(n, 18.0), airspeed_used=np.zeros(n))
    panels = event_panels(plane["trajectory"]["event"])
    labels = [s.label for s, _ in panels]
    assert labels == ["Altitude (m)", "Roll and pitch (deg)", "Airspeed (m/s)", "Hover-rotor speed (rad/s)",
                      "EKF wind estimate (m/s)", "Pitot residual (pitot − EKF) (m/s)"]
    assert [options["label"] for _, options in panels[2][1]] == ["true", "used by the autopilot", "EKF estimate"]


def test_event_and_latency_figures_write_png_and_pdf(tmp_path):
    outputs = {"k_hat": 4, "k_var": 4, "p_fail": 4}
    shown = [event_of("nominal", 1, False, True, "loe_kalman", outputs),
             event_of("ftc-spin", 1, True, False, "loe_kalman", outputs)]
    path = plot_event(tmp_path / "s-event.png", shown)
    assert path.read_bytes()[:4] == b"\x89PNG" and path.with_suffix(".pdf").read_bytes()[:4] == b"%PDF"
    rows = [{**e, "detection_delay": 0.05} for e in shown]
    path = plot_latencies(tmp_path / "s-latency.png", "s", rows)
    assert path.with_suffix(".pdf").read_bytes()[:4] == b"%PDF"


def test_count_axes_tick_whole_numbers_only():
    summary = [{"parameter_set": name, "fault_flights": 3, "flights": 4, "missed": missed, "false_alarms": 0}
               for name, missed in (("a", 0), ("b", 1))]   # y from 0 to 1.5: a default axis would tick 0.5
    figure = detections_figure(summary, "t")
    ticks = figure.axes[0].get_yticks()
    assert len(ticks) >= 2 and np.all(ticks == np.round(ticks))


def test_sweep_delay_plot_writes_png_and_pdf(tmp_path):
    rows = [{"parameter_set": "a", "detection_delay": d} for d in (0.04, 0.05, 0.09)]
    path = plot_delays(tmp_path / "detection_delay.png", rows, ["a", "b"], "t")
    assert path.stat().st_size > 0 and path.with_suffix(".pdf").read_bytes()[:4] == b"%PDF"
