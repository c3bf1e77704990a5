"""Sweeps: config checks, per-episode journal and --resume, and 000 Fig. 11 end to end at a reduced size."""
from __future__ import annotations

import json

import pytest

from ftcgym.benchmark.journal import EpisodeJournal
from ftcgym.benchmark.outputs import OutputFolder
from ftcgym.benchmark.sweep import check_parameter_sets, load_config, parse_config, run_sweep, sweep_jobs
from ftcgym.benchmark.sweep_report import summarize_sets, write_sweep_report
from ftcgym.cli import main

SMALL = {
    "name": "small",
    "scenarios": {"quad-rotor-loss-hover": 2, "quad-no-fault-long": 1},
    "policies": ["nominal"],
    "seeds": [0, 1],
    "base": {"detector": "loe_kalman"},
    "parameter_sets": [{"name": "table-II"}],
    "grid": {"detector_kwargs.k_threshold": [0.2, 0.3], "detector_kwargs.Q": [0.001]},
}
CALLS: list[int] = []


def fake_episode(scenario, policy, seed, env_overrides):
    """A row whose detection delay grows with k_threshold; fault-free scenarios alarm on odd seeds."""
    CALLS.append(seed)
    faulty = "rotor-loss" in scenario.name
    delay = 0.05 + 0.1 * scenario.detector_kwargs.get("k_threshold", 0.25) if faulty else None
    return {"scenario": scenario.name, "policy": policy, "seed": seed, "fault_onset": 3.0 if faulty else None,
            "detection_delay": delay, "false_alarm": not faulty and seed % 2 == 1, "trajectory": {"t": [0.0]}}


# ---- configs ----

def test_a_config_crosses_sets_scenarios_policies_and_seeds():
    config = parse_config(SMALL)
    assert [s.name for s in config.parameter_sets] == ["table-II", "k_threshold=0.2 Q=0.001",
                                                       "k_threshold=0.3 Q=0.001"]
    assert all(s.detector == "loe_kalman" for s in config.parameter_sets)   # from base
    jobs = sweep_jobs(config)
    assert len(jobs) == 3 * (2 + 1) * 2                     # sets x episodes of both scenarios x seeds
    assert len({job.key for job in jobs}) == len(jobs)
    assert jobs[-1].key == "k_threshold=0.3 Q=0.001/quad-no-fault-long/nominal/1/0"
    assert jobs[-1].scenario.detector_kwargs == {"k_threshold": 0.3, "Q": 0.001}
    # every set flies the same episodes: seeds depend on the base seed and index only
    assert [job.seed for job in jobs[:6]] == [job.seed for job in jobs[6:12]]


def test_vehicle_overrides_merge_into_the_scenarios_env_kwargs():
    config = parse_config({**SMALL, "parameter_sets": [{"name": "heavy", "vehicle_overrides": {"mass": 0.6}}],
                           "grid": {}})
    job = sweep_jobs(config)[0]
    assert job.scenario.env_kwargs["vehicle_overrides"] == {"mass": 0.6}
    assert job.scenario.env_kwargs["faults"] == "random:rotor_loss"   # the scenario's own kwargs stay


@pytest.mark.parametrize("change, message", [
    ({"colour": "red"}, r"config: unknown field\(s\) \['colour'\]; accepted: \['name'"),
    ({"parameter_sets": [{"name": "a", "detector_kwrags": {}}]},
     r"parameter_sets\[0\]: unknown field\(s\) \['detector_kwrags'\]; accepted: \['name', 'detector'"),
    ({"parameter_sets": [{"detector": "loe_kalman"}]}, r"parameter_sets\[0\].name: must be a non-empty string"),
    ({"parameter_sets": [{"name": "a", "detector": "psychic"}]},
     r"\.detector: detector: unknown name 'psychic'; .*accepted: \["),
    ({"grid": {"Q": [1]}}, r"grid.Q: keys are FIELD.NAME with FIELD one of \['detector_kwargs'"),
    ({"grid": {"detector_kwargs.Q": 0.1}}, r"grid.detector_kwargs.Q: must be a non-empty list"),
    ({"scenarios": {"quad-nowhere": 3}}, r"scenarios: scenario: unknown name 'quad-nowhere' "
                                        r"\(did you mean 'quad-hover'\?\); .*accepted: \['quad-hover'"),
    ({"scenarios": {"quad-hover": 0}}, r"scenarios.quad-hover: must be an integer >= 1, got 0"),
    ({"seeds": 3}, r"seeds: must be a list, got 3"),
    ({"policies": ["autopilot-x"]},
     r"policies: policy: unknown name 'autopilot-x' \(did you mean 'autopilot'\?\); .*accepted:"),
    ({"parameter_sets": [{"name": "a"}, {"name": "a"}], "grid": {}}, r"names must be unique, repeated: \['a'\]"),
    ({"parameter_sets": [{"name": "G/2"}]}, r"names must not contain '/': \['G/2'\]"),
])
def test_bad_configs_name_the_field_and_what_it_accepts(change, message):
    with pytest.raises(ValueError, match=message):
        parse_config({**SMALL, **change})


def test_an_unknown_detector_parameter_fails_before_any_flight():
    config = parse_config({**SMALL, "parameter_sets": [{"name": "typo", "detector_kwargs": {"k_thres": 0.3}}],
                           "grid": {}})
    with pytest.raises(ValueError, match="parameter set 'typo' on quad-rotor-loss-hover: .*k_thres"):
        check_parameter_sets(config)


def test_the_builtin_fig11_config_is_000s_study_at_full_size():
    config = load_config("fig11")
    assert len(config.parameter_sets) == 19
    assert sum(episodes for _, episodes in config.scenarios) == 33            # 26 rotor losses + 7 fault-free
    assert len(sweep_jobs(config)) == 19 * 33
    check_parameter_sets(config)                                                # every set builds its detector


# ---- journal and resume ----

def test_rows_are_journaled_and_resume_runs_only_the_missing_episodes(tmp_path):
    config = parse_config(SMALL)
    CALLS.clear()
    full = run_sweep(config, tmp_path, episode=fake_episode, progress=False)
    assert len(CALLS) == len(full) == 18
    journal = EpisodeJournal(tmp_path)
    assert len(journal.finished_rows()) == 18

    # An interrupted sweep: 7 rows written, the 8th cut mid-line by the crash.
    lines = journal.rows_path.read_text().splitlines(keepends=True)
    journal.rows_path.write_text("".join(lines[:7]) + lines[7][:25])
    CALLS.clear()
    resumed = run_sweep(config, tmp_path, resume=True, episode=fake_episode, progress=False)
    assert len(CALLS) == 11                              # the 7 finished episodes were not flown again
    assert resumed == full
    CALLS.clear()
    assert run_sweep(config, tmp_path, resume=True, episode=fake_episode, progress=False) == full
    assert CALLS == []


def test_an_existing_sweep_is_not_overwritten_or_resumed_with_another_config(tmp_path):
    config = parse_config(SMALL)
    run_sweep(config, tmp_path, episode=fake_episode, progress=False)
    with pytest.raises(ValueError, match="already holds a sweep's episodes: pass --resume"):
        run_sweep(config, tmp_path, episode=fake_episode, progress=False)
    with pytest.raises(ValueError, match=r"--resume: .* holds a sweep with other \['seeds'\]"):
        run_sweep(parse_config({**SMALL, "seeds": [0]}), tmp_path, resume=True, episode=fake_episode,
                  progress=False)


def test_a_journal_key_recorded_twice_with_different_rows_is_an_error(tmp_path):
    journal = EpisodeJournal(tmp_path)
    journal.record_row("a/s/p/0/0", {"x": 1.0, "y": float("nan")})
    journal.record_row("a/s/p/0/0", {"y": float("nan"), "x": 1.0})   # the same row again: kept once
    assert list(journal.finished_rows()) == ["a/s/p/0/0"]
    journal.record_row("a/s/p/0/0", {"x": 2.0, "y": None})
    with pytest.raises(ValueError, match=r"episodes.jsonl:3: episode 'a/s/p/0/0' is recorded twice with different"):
        journal.finished_rows()


def test_a_sweep_replaces_the_folders_previous_run_and_owns_its_journal(tmp_path):
    with OutputFolder(tmp_path) as bench:   # an earlier bench run in the folder
        for name in ("results.json", "quad-hover.png"):
            bench.staged(name).write_text("bench")
        bench.publish()
    config = parse_config(SMALL)
    rows = run_sweep(config, tmp_path, episode=fake_episode, progress=False)
    write_sweep_report(tmp_path, config, rows, {"command": "ftcgym sweep", "backend": "local", "wall_time_s": 1.0})
    report = ["detection_delay.png", "detection_delay.pdf", "detections.png", "detections.pdf", "episodes.jsonl",
              "report.md", "results.json", "sets.csv", "sweep_config.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([".ftcgym.lock", ".ftcgym-files.json", *report])
    assert json.loads((tmp_path / ".ftcgym-files.json").read_text()) == sorted([*report, "failures.jsonl"])
    with OutputFolder(tmp_path), pytest.raises(ValueError, match="already holds"):   # nested in one process
        run_sweep(config, tmp_path, episode=fake_episode, progress=False)


def test_set_summary_counts_missed_detections_and_false_alarms():
    rows = [{"parameter_set": "a", "fault_onset": 3.0, "detection_delay": 0.04, "false_alarm": False},
            {"parameter_set": "a", "fault_onset": 3.0, "detection_delay": 0.08, "false_alarm": False},
            {"parameter_set": "a", "fault_onset": 3.0, "detection_delay": None, "false_alarm": True},
            {"parameter_set": "a", "fault_onset": None, "detection_delay": None, "false_alarm": True},
            {"parameter_set": "b", "fault_onset": None, "detection_delay": None, "false_alarm": False}]
    a, b = summarize_sets(rows, ["a", "b"])
    assert (a["flights"], a["fault_flights"], a["detected"], a["missed"], a["false_alarms"]) == (4, 3, 2, 1, 2)
    assert a["delay_median_ms"] == pytest.approx(60.0) and a["delay_max_ms"] == pytest.approx(80.0)
    assert (b["fault_flights"], b["missed"], b["false_alarms"], b["delay_median_ms"]) == (0, 0, 0, None)


# ---- 000 Fig. 11, reduced: 2 sets x 3 flights of 6 s (the full size is 19 sets x 33 flights) ----

def test_fig11_sweep_end_to_end_at_a_reduced_size(tmp_path, capsys):
    out = tmp_path / "fig11"
    assert main(["sweep", "fig11", "--sets", "table-II", "k_thres=0.5", "--episodes", "1", "--workers", "2",
                 "--env-kwargs", '{"max_episode_seconds": 6}', "--out", str(out), "--no-progress"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert len(results["episodes"]) == 2 * 3
    table_ii, k_half = results["summary"]
    assert (table_ii["parameter_set"], table_ii["flights"]) == ("table-II", 3)
    # Seed 0's hover flight loses a rotor at ~5 s: Table II detects it in 000's 28-132 ms range, and raising
    # k_thres to 0.5 (P(k < 0.5) passes 0.9 sooner) detects it no later; the fault-free flight raises no alarm.
    assert table_ii["detected"] >= 1 and table_ii["missed"] == 0 and table_ii["false_alarms"] == 0
    assert 28 <= table_ii["delay_median_ms"] <= 132
    assert k_half["delay_median_ms"] <= table_ii["delay_median_ms"]
    for name in ("detection_delay.png", "detections.png", "sets.csv", "report.md", "episodes.jsonl"):
        assert (out / name).stat().st_size > 0
    assert "k_thres=0.5" in capsys.readouterr().out
