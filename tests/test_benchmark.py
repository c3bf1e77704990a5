"""Benchmark metrics on synthetic trajectories, the episode runner on a fake env, and `ftcgym bench`
end to end on the real quadrotor."""
import csv
import json

import numpy as np
import pytest

from ftcgym.benchmark import metrics
from ftcgym.benchmark.outputs import OutputFolder
from ftcgym.benchmark.report import format_table, format_value, latency_samples, markdown_table, plot_latencies
from ftcgym.benchmark.runner import episode_seed, roll_out, run_benchmark, score_episode
from ftcgym.benchmark.scenarios import get_scenario
from ftcgym.cli import main

# The results.json field names of docs/concepts.md, spelled out so a rename shows up here.
DESIGN_EPISODE_FIELDS = [
    "scenario", "policy", "seed", "fault_kind", "fault_target", "fault_onset", "alarm_time",
    "detection_delay", "isolated_target", "isolation_correct", "false_alarm", "recovery_time",
    "recovered", "crashed", "altitude_loss", "position_rmse", "airspeed_error_rmse", "flight_time",
]
# ftcgym's additions after them: the position-return fields (quadrotor faults), the quad-plane mission fields (null
# for the quadrotor).
RETURN_FIELDS = ["return_time_0_5m", "return_time_0_2m", "max_position_error", "final_position_error"]
QUADPLANE_FIELDS = ["mission_complete", "time_quad_mode", "time_transition", "time_forward_flight",
                    "cruise_airspeed_rmse", "max_attitude_deg", "upset_attitude_deg", "upset_altitude_loss"]
DESIGN_SUMMARY_FIELDS = [
    "scenario", "policy", "episodes", "detection_delay_median", "detection_delay_p95",
    "missed_detection_rate", "false_alarms_per_hour", "isolation_accuracy",
    "recovery_latency_median", "recovery_latency_p95", "success_rate", "crash_rate",
    "return_time_0_5m_median", "return_time_0_2m_median", "max_position_error_median",
    "final_position_error_median", "altitude_loss_median",
]
TIME = np.round(np.arange(0.0, 10.0 + 1e-9, 0.1), 10)


def between(start, stop):
    return (start - 1e-9 <= TIME) & (stop - 1e-9 > TIME)


# ---- per-episode metrics ----

def test_recovery_time_is_start_of_a_2s_recovered_window():
    assert metrics.recovery_time(TIME, between(3.2, 5.7), onset=2.0) == pytest.approx(3.2)


def test_recovery_time_skips_a_short_stretch():
    recovered = between(3.0, 4.5) | between(5.0, 11.0)  # 1.5 s, a dip, then for good
    assert metrics.recovery_time(TIME, recovered, onset=2.0) == pytest.approx(5.0)


def test_recovery_time_counts_from_onset_and_can_be_none():
    assert metrics.recovery_time(TIME, np.ones_like(TIME, bool), onset=2.0) == pytest.approx(2.0)
    assert metrics.recovery_time(TIME, between(0.0, 8.5), onset=7.0) is None   # 1.5 s left after onset
    assert metrics.recovery_time(TIME, np.zeros_like(TIME, bool), onset=2.0) is None


def test_thrust_axis_of_a_rolled_vehicle_tilts_right():
    roll = np.radians(20.0)
    attitude = np.array([[0, 0, 0, 1], [np.sin(roll / 2), 0, 0, np.cos(roll / 2)]])
    np.testing.assert_allclose(metrics.thrust_axis(attitude), [[0, 0, -1], [0, np.sin(roll), -np.cos(roll)]],
                               atol=1e-12)
    error = metrics.thrust_axis_error(attitude, np.array([[0, 0, -1], [0, 0, -2.0]]))
    np.testing.assert_allclose(np.degrees(error), [0.0, 20.0])


def test_hover_recovered_thresholds():
    recovered = metrics.hover_recovered(altitude=[5.4, 5.6, 5.0, 4.6],
                                        altitude_reference=[5.0] * 4,
                                        axis_error=np.radians([9.0, 0.0, 11.0, 0.0]))
    assert recovered.tolist() == [True, False, False, True]


def test_altitude_loss_from_onset_to_lowest_point():
    altitude = np.where(TIME < 2.0, 5.0, 5.0 - np.minimum(TIME - 2.0, 1.2) + np.maximum(TIME - 6.0, 0))
    assert metrics.altitude_loss(TIME, altitude, onset=2.0) == pytest.approx(1.2)
    assert metrics.altitude_loss(TIME, np.linspace(1, 5, TIME.size), onset=2.0) == 0.0
    assert metrics.altitude_loss(TIME, altitude, onset=11.0) is None


def test_upset_looks_only_at_the_window_after_onset():
    """A 60 deg roll and a 3 m sink 4 s after onset count; a 90 deg bank and a landing 12 s after do not."""
    t = np.arange(0.0, 30.0, 0.1)
    roll = np.radians(np.select([(t > 24) & (t < 26), (t > 5) & (t < 7), t < 1], [90.0, 60.0, 70.0], 10.0))
    pitch = np.radians(np.full_like(t, 5.0))
    altitude = 30.0 - 3.0 * ((t > 6) & (t < 12)) - 25.0 * (t > 14)
    attitude, loss = metrics.upset(t, altitude, roll, pitch, onset=2.0, window=10.0)
    assert attitude == pytest.approx(60.0) and loss == pytest.approx(3.0)
    assert metrics.upset(t, altitude, roll, np.radians(np.full_like(t, 75.0)), onset=2.0)[0] == pytest.approx(75.0)
    assert metrics.upset(t, altitude, roll, pitch, onset=31.0) is None


def test_position_rmse():
    position = np.array([[3.0, 4.0, -5.0], [0.0, 0.0, -5.0]])
    reference = np.array([[0.0, 0.0, -5.0], [0.0, 0.0, -5.0]])
    assert metrics.position_rmse(position, reference) == pytest.approx(np.sqrt(25 / 2))


# ---- position return (hand-made error histories, onset at 2 s, samples every 0.1 s to 10 s) ----

def error_history(*stretches, base=1.0):
    """An error of `base` m, with (start, stop, value) stretches laid over it."""
    error = np.full(TIME.shape, base)
    for start, stop, value in stretches:
        error[between(start, stop)] = value
    return error


def test_return_time_of_a_flight_that_returns_and_stays():
    error = error_history((0.0, 2.5, 0.0), (2.5, 3.0, 0.8), (3.0, 4.0, 0.3), (4.0, 11.0, 0.1))
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.5) == pytest.approx(1.0)   # in at 3.0 s
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.2) == pytest.approx(2.0)   # in at 4.0 s


def test_return_time_is_the_last_entry_into_the_band():
    error = error_history((0.0, 2.0, 0.0), (3.0, 4.0, 0.1), (5.0, 11.0, 0.1))   # in, out at 4-5 s, back in
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.5) == pytest.approx(3.0)


def test_return_time_is_zero_when_the_band_is_never_left_after_onset():
    error = error_history((0.0, 1.0, 2.0), base=0.1)   # outside before onset only
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.5) == 0.0


def test_return_time_is_none_for_a_flight_that_never_returns_or_ends_outside():
    assert metrics.return_time(TIME, error_history(), onset=2.0, radius=0.5) is None
    leaves = error_history((3.0, 9.0, 0.1))    # back in at 3 s, out again for the last second
    assert metrics.return_time(TIME, leaves, onset=2.0, radius=0.5) is None


def test_return_time_of_a_flight_that_enters_on_its_last_sample():
    error = error_history((10.0, 11.0, 0.1))
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.5) == pytest.approx(8.0)


def test_a_crash_has_no_return_time_even_inside_the_band():
    error = error_history((3.0, 11.0, 0.1))
    assert metrics.return_time(TIME, error, onset=2.0, radius=0.5, crashed=True) is None
    fields = metrics.return_fields(TIME, np.column_stack([error, 0 * TIME, 0 * TIME]), np.zeros((TIME.size, 3)),
                                   onset=2.0, crashed=True)
    assert fields["return_time_0_5m"] is None and fields["return_time_0_2m"] is None
    assert fields["max_position_error"] == pytest.approx(1.0) and fields["final_position_error"] == pytest.approx(0.1)


def test_position_errors_after_onset_and_over_the_last_2_s():
    north = error_history((0.0, 2.0, 5.0), (3.0, 4.0, 2.0), (4.0, 8.0, 0.3), (8.0, 11.0, 0.0))
    east = np.where(between(9.0, 11.0), 0.4, 0.0)        # the last 2 s (8.0-10.0 s): on target, then 0.4 m east
    position = np.column_stack([north, east, np.full(TIME.shape, -5.0)])
    reference = np.tile([0.0, 0.0, -5.0], (TIME.size, 1))
    fields = metrics.return_fields(TIME, position, reference, onset=2.0, crashed=False)
    assert fields["max_position_error"] == pytest.approx(2.0)         # the 5 m before onset does not count
    assert fields["final_position_error"] == pytest.approx(np.sqrt(11 / 21 * 0.16))   # 11 of 21 samples 0.4 m
    assert fields["return_time_0_5m"] == pytest.approx(2.0) and fields["return_time_0_2m"] is None


def test_no_sample_after_onset_gives_no_return_fields():
    assert metrics.return_time(TIME, error_history(base=0.0), onset=11.0, radius=0.5) is None
    assert metrics.max_position_error(TIME, error_history(), onset=11.0) is None


# ---- summary ----

def episode(**fields):
    row = dict.fromkeys(DESIGN_EPISODE_FIELDS)
    row.update(scenario="s", policy="p", crashed=False, flight_time=10.0)
    row.update(fields)
    return row


def test_summary_of_fault_episodes_with_a_detector():
    rows = [
        episode(fault_onset=2.0, fault_target=1, alarm_time=2.1, detection_delay=0.1, isolated_target=1,
                false_alarm=False, recovery_time=4.0, recovered=True),
        episode(fault_onset=3.0, fault_target=3, alarm_time=3.3, detection_delay=0.3, isolated_target=2,
                false_alarm=False, recovery_time=4.5, recovered=True),
        episode(fault_onset=4.0, fault_target=0, false_alarm=False, recovered=False, crashed=True),
        episode(fault_onset=2.0, fault_target=0, alarm_time=1.0, isolated_target=0, false_alarm=True,
                recovery_time=5.0, recovered=False),   # recovered window but crashed later
    ]
    [summary] = metrics.summarize(rows)
    assert list(summary) == DESIGN_SUMMARY_FIELDS
    expected = {
        "episodes": 4,
        "detection_delay_median": 0.2, "detection_delay_p95": 0.1 + 0.95 * 0.2,
        "missed_detection_rate": 0.5,
        "false_alarms_per_hour": 3600.0 / (2 + 3 + 4 + 2),   # exposure: fault-free time before onsets
        "isolation_accuracy": 0.5,                           # over the two detected faults
        "recovery_latency_median": 1.75, "recovery_latency_p95": 1.5 + 0.95 * 0.5,
        "success_rate": 0.5, "crash_rate": 0.25,
        **dict.fromkeys(DESIGN_SUMMARY_FIELDS[12:]),           # no position-return fields in these rows
    }
    assert summary == pytest.approx({"scenario": "s", "policy": "p", **expected})


def test_summary_of_fault_free_episodes_without_a_detector():
    rows = [episode(policy="a"), episode(policy="b", crashed=True), episode(policy="a", crashed=True)]
    summary = metrics.summarize(rows)
    assert [(row["policy"], row["episodes"], row["success_rate"], row["crash_rate"]) for row in summary] == [
        ("a", 2, 0.5, 0.5), ("b", 1, 0.0, 1.0)]
    assert all(summary[0][field] is None for field in DESIGN_SUMMARY_FIELDS[3:10] + DESIGN_SUMMARY_FIELDS[12:])


def returned(time_0_5m, time_0_2m=None, **fields):
    return episode(**{"fault_onset": 2.0, "return_time_0_5m": time_0_5m, "return_time_0_2m": time_0_2m,
                      "max_position_error": 1.0, "final_position_error": 0.1, "altitude_loss": 0.2, **fields})


def test_return_medians_count_a_flight_that_never_returned_as_inf():
    rows = [returned(1.0, 2.0), returned(3.0), returned(None, max_position_error=5.0, altitude_loss=4.0, crashed=True),
            episode()]                               # fault-free: no return fields, not counted
    [summary] = metrics.summarize(rows)
    assert summary["return_time_0_5m_median"] == pytest.approx(3.0)       # of 1, 3, inf
    assert summary["return_time_0_2m_median"] is None                      # of 2, inf, inf: inf
    assert summary["max_position_error_median"] == pytest.approx(1.0)     # of 1, 1, 5
    assert summary["final_position_error_median"] == pytest.approx(0.1)
    assert summary["altitude_loss_median"] == pytest.approx(0.2)
    [even] = metrics.summarize([returned(1.0), returned(None)])
    assert even["return_time_0_5m_median"] is None                         # the mean of 1 and inf
    [finite] = metrics.summarize([returned(1.0), returned(2.0)])
    assert finite["return_time_0_5m_median"] == pytest.approx(1.5)


def test_quad_plane_faults_do_not_count_as_never_returned():
    rows = [episode(fault_onset=45.0, recovered=True, recovery_time=46.0)]   # no position-return fields
    [summary] = metrics.summarize(rows)
    assert summary["return_time_0_5m_median"] is None and summary["max_position_error_median"] is None


def test_latency_plot_takes_detected_and_recovered_fault_episodes(tmp_path):
    rows = [episode(policy="a", fault_onset=2.0, detection_delay=0.05, recovery_time=2.9, recovered=True),
            episode(policy="a", fault_onset=3.0, detection_delay=0.07, recovery_time=None, recovered=False),
            episode(policy="a", fault_onset=4.0, detection_delay=None, recovery_time=None, recovered=False),
            # recovered, then crashed: not recovered, as the summary counts it
            episode(policy="a", fault_onset=1.0, detection_delay=0.04, recovery_time=2.0, recovered=False,
                    crashed=True),
            episode(policy="a"),                                   # fault-free: not counted
            episode(policy="b", fault_onset=2.5, detection_delay=0.06, recovery_time=3.1, recovered=True)]
    n, delays, latencies = latency_samples(rows, "a")
    assert (n, delays) == (4, [0.05, 0.07, 0.04]) and latencies == pytest.approx([0.9])
    [summary] = metrics.summarize([row for row in rows if row["policy"] == "a"])
    assert summary["recovery_latency_median"] == pytest.approx(0.9)          # the figure's sample, the table's
    assert latency_samples(rows, "b")[2] == pytest.approx([0.6])
    assert plot_latencies(tmp_path / "s-latency.png", "s", rows).stat().st_size > 0


def test_table_cells():
    assert [format_value(v) for v in (None, 0.123456, 327.27, 4, "quad")] == ["-", "0.123", "327", "4", "quad"]
    row = {field: None for field in DESIGN_SUMMARY_FIELDS} | {"scenario": "s", "policy": "p"}
    table = format_table([row])
    assert table.splitlines()[2].split() == ["s", "p"] + ["-"] * 10
    assert "return 0.5 m med (s)" in table and "p95" not in table and "final error" not in table
    markdown = markdown_table([row])
    assert markdown.splitlines()[0].count("|") == len(DESIGN_SUMMARY_FIELDS) + 1   # report.md: every column


# ---- the runner on a fake env: what a policy sees, and what gets scored ----

class FakeHoverEnv:
    """Hovers at 5 m, sinks at 1 m/s after a rotor-1 loss at t = 2 s, back on target from t = 3 s."""

    dt, onset = 0.1, 2.0

    def reset(self, seed=None):
        self.t = 0.0
        return {}, self._info()

    def step(self, action):
        self.t = round(self.t + self.dt, 10)
        return {}, 0.0, False, self.t >= 6.0, self._info()

    def _info(self):
        faulty = self.t >= self.onset
        altitude = 5.0 - (self.t - self.onset) if faulty and self.t < 3.0 else 5.0
        fault = {"active": faulty, "kind": "rotor_loss" if faulty else None, "target": 1 if faulty else None,
                 "onset_time": self.onset if faulty else None, "magnitude": 1.0 if faulty else None}
        alarm = self.t >= 2.3
        return {
            "time": self.t, "fault": fault, "faults": [{"kind": "rotor_loss", "target": 1, "time": self.onset}],
            "truth": {"position": np.array([0.0, 0.0, -altitude]), "attitude": np.array([0.0, 0, 0, 1]),
                      "body_rates": np.zeros(3),
                      "rotor_speed": np.full(4, 500.0)},
            "reference": {"position": np.array([0.0, 0.0, -5.0]), "velocity": np.zeros(3), "yaw": 0.0},
            "crashed": False, "termination": None,
            "fdd": {"fake": {"alarm": alarm, "alarm_time": 2.3 if alarm else None, "isolated": 1 if alarm else None}},
        }


class RecordingPolicy:
    def __init__(self, oracle=False):
        self.uses_true_onset = oracle
        self.seen = []

    def reset(self, obs, info):
        self.seen.append(info)

    def act(self, obs, info):
        self.seen.append(info)
        return np.zeros(4)


def test_policies_never_see_the_truth_and_only_an_oracle_sees_the_onset():
    for oracle in (False, True):
        policy = RecordingPolicy(oracle)
        roll_out(FakeHoverEnv(), policy, seed=0)
        assert not any({"truth", "fault", "faults"} & set(info) for info in policy.seen)
        assert all(("oracle_onset_time" in info) is oracle for info in policy.seen)
    assert policy.seen[-1]["oracle_onset_time"] == 2.0


def test_fake_episode_scores():
    scores = score_episode(roll_out(FakeHoverEnv(), RecordingPolicy(), seed=0, detector="fake"))
    assert scores == pytest.approx({
        "fault_kind": "rotor_loss", "fault_target": 1, "fault_onset": 2.0, "alarm_time": 2.3,
        "detection_delay": 0.3, "isolated_target": 1, "isolation_correct": True, "false_alarm": False,
        "recovery_time": 3.0, "recovered": True, "crashed": False, "altitude_loss": 0.9,
        "position_rmse": np.sqrt(2.85 / 61), "airspeed_error_rmse": None, "flight_time": 6.0,
        # 0.9 m below at 2.9 s, on target from 3.0 s; the last 2 s (4-6 s) on target
        "return_time_0_5m": 1.0, "return_time_0_2m": 1.0, "max_position_error": 0.9, "final_position_error": 0.0,
        **dict.fromkeys(QUADPLANE_FIELDS),
    })


def test_a_missing_detector_is_an_error():
    with pytest.raises(ValueError, match="never appeared"):
        roll_out(FakeHoverEnv(), RecordingPolicy(), seed=0, detector="other")


def test_unknown_scenario_lists_the_registered_ones():
    with pytest.raises(ValueError, match="quad-hover"):
        get_scenario("no-such-scenario")


# ---- the real quadrotor ----

def test_episode_seeds_depend_on_seed_and_index_only():
    assert episode_seed(0, 1) == episode_seed(0, 1)
    assert len({episode_seed(0, 0), episode_seed(0, 1), episode_seed(1, 0)}) == 3


def test_workers_do_not_change_results_or_their_order():
    def run(workers):
        rows = run_benchmark(["quad-hover"], episodes=2, seed=3, workers=workers, progress=False,
                             env_overrides={"max_episode_seconds": 0.3})
        return [{k: v for k, v in row.items() if k != "trajectory"} for row in rows]

    in_process = run(1)
    assert [row["seed"] for row in in_process] == [episode_seed(3, 0), episode_seed(3, 1)]
    assert run(2) == in_process


def test_bench_cli_end_to_end(tmp_path, capsys):
    with OutputFolder(tmp_path) as earlier:   # an earlier run's files, one a plot this run does not make
        for name in ("results.json", "quad-plane-cruise.png"):
            earlier.staged(name).write_text("earlier")
        earlier.publish()
    assert main(["bench", "--scenario", "quad-hover", "--episodes", "1", "--workers", "4",
                 "--env-kwargs", '{"max_episode_seconds": 2}', "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    assert set(results) == {"summary", "episodes", "config"}
    assert results["config"]["workers"] == 1         # one episode flies in one process, whatever was asked
    assert "--workers 4" in results["config"]["command"]
    assert [list(row) for row in results["episodes"]] == [DESIGN_EPISODE_FIELDS + RETURN_FIELDS + QUADPLANE_FIELDS]
    assert [list(row) for row in results["summary"]] == [DESIGN_SUMMARY_FIELDS]
    [row] = results["episodes"]
    assert row["flight_time"] == pytest.approx(2.0) and row["crashed"] is False
    assert row["position_rmse"] < 0.5   # the nominal controller holds a 2 s hover
    assert all(row[field] is None for field in RETURN_FIELDS)   # no fault
    with (tmp_path / "episodes.csv").open() as file:
        assert len(list(csv.DictReader(file))) == 1
    assert (tmp_path / "quad-hover.png").stat().st_size > 0
    assert (tmp_path / "quad-hover.pdf").read_bytes()[:4] == b"%PDF"   # the vector copy beside the PNG
    report = (tmp_path / "report.md").read_text()
    assert "quad-hover.png" in report and "PDF" in report and "1 process," in report
    assert "quad-hover" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([   # this run's files only, published whole
        ".ftcgym.lock", ".ftcgym-files.json", "results.json", "episodes.csv", "report.md", "quad-hover.png",
        "quad-hover.pdf"])


def test_a_pitot_blockage_is_isolated_by_naming_the_pitot():
    assert metrics.isolation_target("pitot_blockage", "zero") == "pitot"
    assert metrics.isolation_target("pitot_blockage", None) == "pitot"
    assert metrics.isolation_target("rotor_loss", 2) == 2


def test_summary_counts_a_pitot_alarm_naming_the_pitot_as_isolated():
    rows = [episode(fault_kind="pitot_blockage", fault_target="zero", fault_onset=45.0, alarm_time=45.1,
                    detection_delay=0.1, isolated_target="pitot", false_alarm=False, recovered=True,
                    recovery_time=45.1)]
    [summary] = metrics.summarize(rows)
    assert summary["isolation_accuracy"] == 1.0


def test_the_goto_scenarios_fly_the_anchor_set_up_outside_the_defaults():
    from ftcgym.benchmark.scenarios import SCENARIOS, default_scenarios
    names = ["quad-rotor-loss-goto", "quad-rotor-loss-goto-mueller", "quad-rotor-loss-goto-wind",
             "quad-rotor-loss-goto-wind-mueller"]
    assert not set(names) & {scenario.name for scenario in default_scenarios()}
    for name in names:
        kwargs = SCENARIOS[name].env_kwargs
        assert kwargs["task"]["name"] == "goto" and kwargs["faults"] == [
            {"kind": "rotor_loss", "target": "random", "time": 2.5}]
        assert kwargs.get("vehicle", "bebop2") == ("mueller2014" if name.endswith("mueller") else "bebop2")
        calm = "wind" not in name.split("goto")[1]
        assert (kwargs["wind"]["turbulence"] == "none") is calm
        assert (set(kwargs.get("sensors", {}).values()) == {0.0}) is calm
