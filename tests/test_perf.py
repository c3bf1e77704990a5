"""`ftcgym perf`: every registered detector is timed on a flight of its own vehicle; the report's fields."""
import json
import math

from ftcgym.cli import main
from ftcgym.cli.perf import DETECTOR_BUDGET_US, detector_costs, detector_step_costs
from ftcgym.fdd import DETECTORS


def test_every_detector_gets_a_finite_cost_per_update():
    costs = detector_costs(steps=60, seed=0, repeats=1)
    assert set(costs) == set(DETECTORS)
    assert all(math.isfinite(us) and 0.0 < us < 1e5 for us in costs.values())


def test_step_cost_is_the_update_and_what_the_wrapper_reads():
    costs = detector_step_costs(steps=60, seed=0, repeats=1)
    assert set(costs) == set(DETECTORS)
    for cost in costs.values():
        assert set(cost) == {"update_us", "step_us"}
        assert all(math.isfinite(us) and 0.0 < us < 1e5 for us in cost.values())


def test_perf_json_names_its_fields(capsys):
    """The fields of `ftcgym perf --json` (not the numbers): what docs and scripts quote."""
    assert main(["perf", "--steps", "30", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report) == {"machine", "env", "vector", "bare_pybullet_physics_steps_per_s", "detector_us_per_update",
                           "detector_us_per_step", "detector_budget_us"}
    assert set(report["machine"]) == {"cpu", "cores", "load_average", "python", "numpy", "pybullet", "gymnasium",
                                      "numba"}
    assert [row["agent_hz"] for row in report["vector"]] == [500.0, 50.0]
    for row in report["vector"]:
        assert set(row["steps_per_s"]) == {"one", "sync", "async", "parallel", "independent"}
        assert all(rate > 0 for rate in row["steps_per_s"].values())
        assert set(row["ratio_to_one_env"]) == {"sync", "async", "parallel", "independent"}
    assert report["detector_budget_us"] == DETECTOR_BUDGET_US == 18.0
    assert set(report["detector_us_per_update"]) == set(report["detector_us_per_step"]) == set(DETECTORS)
    assert {row["case"] for row in report["env"]} >= {"Quadrotor random, 500/500 Hz", "QuadPlane autopilot, 500/100 Hz",
                                                      "Quadrotor random + loe_kalman, 500/500 Hz"}
    for row in report["env"]:
        assert set(row) == {"case", "steps_per_s", "physics_steps_per_s", "sim_s_per_wall_s", "resets", "reset_ms",
                            "wall_s", "peak_rss_mib", "rss_growth_mib", "step_only_physics_steps_per_s",
                            "step_only_sim_s_per_wall_s", "bare_loop_share", "pybullet_share"}


def test_perf_table_shows_each_detector_against_the_budget(capsys):
    assert main(["perf", "--steps", "30"]) == 0
    out = capsys.readouterr().out
    assert "budget 18 us per update" in out
    lines = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("  ") and line.split()}
    for name in DETECTORS:
        row = lines[name]
        assert len(row) == 4 and row[3] in ("under", "OVER")
        float(row[1]), float(row[2])
