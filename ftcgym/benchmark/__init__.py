"""The detection-to-recovery benchmark (docs/concepts.md, 'Benchmark metrics').

- `scenarios`: the scenario catalogue (`Scenario`, `SCENARIOS`, `register`, `get_scenario`)
- `runner`: flies episodes and scores them (`run_episode`, `run_benchmark`)
- `metrics`: per-episode metrics and the per-scenario summary (`summarize`)
- `report`: results.json, episodes.csv, report.md, plots, the summary table
"""
from ftcgym.benchmark.metrics import EPISODE_FIELDS, SUMMARY_FIELDS, summarize
from ftcgym.benchmark.scenarios import SCENARIOS, Scenario, default_scenarios, get_scenario, register

__all__ = ["EPISODE_FIELDS", "SUMMARY_FIELDS", "SCENARIOS", "Scenario", "default_scenarios",
           "get_scenario", "register", "summarize"]
