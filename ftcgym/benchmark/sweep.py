"""Parameter sweeps: parameter sets crossed with scenarios and seeds, flown on either backend.

    ftcgym sweep CONFIG.yaml [--backend local|ray] [--out DIR] [--resume] [--sets NAME...] [--episodes N]

A config (YAML; `fig11` names the built-in reproduction of 000 Fig. 11):

    name: my-sweep
    scenarios: {quad-rotor-loss-hover: 13, quad-no-fault-long: 7}   # name: episodes (null: its own)
    policies: [nominal]                  # optional, default: each scenario's own
    seeds: [0]                           # base seeds; every set flies the same episodes
    env_kwargs: {}                       # merged into every scenario's gym.make kwargs
    base: {detector: loe_kalman}         # a parameter set every set starts from
    parameter_sets:                      # a list of sets ...
      - {name: table-ii}
      - {name: Q x4, detector_kwargs: {Q: 0.008}}
    grid:                                # ... and/or the product of these values (field.key: [values])
      detector_kwargs.k_threshold: [0.2, 0.3]

A parameter set's fields: `name`, `detector`, `detector_kwargs`, `env_kwargs`, `vehicle_overrides`
(merged into env_kwargs' vehicle_overrides) and `policies`. Outputs in DIR: episodes.jsonl (rows as they
finish), failures.jsonl, sweep_config.json, results.json, sets.csv, report.md and the plots of sweep_report.
"""
from __future__ import annotations

import dataclasses
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ftcgym.benchmark.backends import Callbacks, EpisodesFailed, Job, run_jobs
from ftcgym.benchmark.journal import CONFIG_FILE, EpisodeJournal
from ftcgym.benchmark.outputs import OutputFolder, atomic_write_text
from ftcgym.benchmark.runner import episode_seed, make_env
from ftcgym.benchmark.scenarios import Scenario, get_scenario

BUILTIN_DIR = Path(__file__).parent / "sweeps"
CONFIG_FIELDS = ("name", "description", "scenarios", "policies", "seeds", "env_kwargs", "base",
                 "parameter_sets", "grid")
SET_FIELDS = ("name", "detector", "detector_kwargs", "env_kwargs", "vehicle_overrides", "policies")
DICT_SET_FIELDS = ("detector_kwargs", "env_kwargs", "vehicle_overrides")


@dataclass(frozen=True)
class ParameterSet:
    """What one set changes: the detector and its arguments, env kwargs, vehicle parameters, policies."""

    name: str
    detector: str | None = None
    detector_kwargs: dict = field(default_factory=dict)
    env_kwargs: dict = field(default_factory=dict)
    vehicle_overrides: dict = field(default_factory=dict)
    policies: tuple[str, ...] | None = None

    def apply(self, scenario: Scenario) -> Scenario:
        """`scenario` with this set's parameters; a different detector drops the scenario's detector kwargs."""
        same_detector = self.detector in (None, scenario.detector)
        env_kwargs = {**scenario.env_kwargs, **self.env_kwargs}
        if self.vehicle_overrides:
            env_kwargs["vehicle_overrides"] = {**env_kwargs.get("vehicle_overrides", {}), **self.vehicle_overrides}
        return dataclasses.replace(
            scenario, env_kwargs=env_kwargs, detector=self.detector or scenario.detector,
            detector_kwargs={**(scenario.detector_kwargs if same_detector else {}), **self.detector_kwargs})


@dataclass(frozen=True)
class SweepConfig:
    name: str
    scenarios: tuple[tuple[str, int | None], ...]  # (scenario name, episodes or None for its own)
    parameter_sets: tuple[ParameterSet, ...]
    seeds: tuple[int, ...] = (0,)
    policies: tuple[str, ...] | None = None
    env_kwargs: dict = field(default_factory=dict)
    description: str = ""

    def to_json(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))  # tuples as lists, as it reads back

    def select(self, set_names=None, episodes: int | None = None, env_kwargs: dict | None = None) -> SweepConfig:
        """A reduced or adjusted copy: only the named sets, `episodes` per scenario, more env kwargs."""
        sets = self.parameter_sets
        if set_names:
            known = {s.name: s for s in sets}
            unknown = [name for name in set_names if name not in known]
            if unknown:
                raise ValueError(f"--sets: unknown {unknown}; the config's sets: {list(known)}")
            sets = tuple(known[name] for name in set_names)
        scenarios = tuple((name, episodes or count) for name, count in self.scenarios)
        return dataclasses.replace(self, parameter_sets=sets, scenarios=scenarios,
                                   env_kwargs={**self.env_kwargs, **(env_kwargs or {})})


# ---- reading a config ----

def load_config(source: str) -> SweepConfig:
    """A config from a YAML file, or a built-in one by name (`ftcgym/benchmark/sweeps/<name>.yaml`)."""
    path = Path(source)
    if not path.exists():
        path = BUILTIN_DIR / f"{source}.yaml"
        if not path.exists():
            builtins = sorted(p.stem for p in BUILTIN_DIR.glob("*.yaml"))
            raise ValueError(f"config: no file {source!r} and no built-in sweep of that name; built-in: {builtins}")
    return parse_config(read_yaml(path), where=path.name)


def read_yaml(path: Path):
    """The YAML document in `path`; ValueError naming the file and the line for text that is not YAML."""
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ValueError(f"{path}: not valid YAML{where}: {getattr(error, 'problem', None) or error}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None


def parse_config(data, where: str = "config") -> SweepConfig:
    """Check a config mapping field by field; errors name the field and what it accepts."""
    _require(isinstance(data, dict), where, "must be a mapping of " + ", ".join(CONFIG_FIELDS))
    _no_unknown(data, CONFIG_FIELDS, where)
    base = _parse_set({"name": "base", **data.get("base", {})}, f"{where}: base") if "base" in data else None
    sets = [_parse_set(entry, f"{where}: parameter_sets[{i}]") for i, entry in
            enumerate(_list(data.get("parameter_sets", []), f"{where}: parameter_sets"))]
    sets += _grid_sets(data.get("grid", {}), f"{where}: grid")
    _require(bool(sets), where, "needs parameter_sets or grid (at least one parameter set)")
    names = [s.name for s in sets]
    slashed = [name for name in names if "/" in name]  # "/" separates the parts of an episode's key
    _require(not slashed, f"{where}: parameter_sets", f"names must not contain '/': {slashed}")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    _require(not duplicates, f"{where}: parameter_sets", f"names must be unique, repeated: {duplicates}")
    return SweepConfig(
        name=str(data.get("name", Path(where).stem)),
        description=str(data.get("description", "")).strip(),
        scenarios=_parse_scenarios(data.get("scenarios"), f"{where}: scenarios"),
        parameter_sets=tuple(_merge_sets(base, s) for s in sets) if base else tuple(sets),
        seeds=tuple(_int(seed, f"{where}: seeds") for seed in _list(data.get("seeds", [0]), f"{where}: seeds")),
        policies=_policies(data.get("policies"), f"{where}: policies"),
        env_kwargs=_dict(data.get("env_kwargs", {}), f"{where}: env_kwargs"),
    )


def _parse_scenarios(value, where: str) -> tuple[tuple[str, int | None], ...]:
    _require(isinstance(value, (dict, list)) and value, where,
             "must be a non-empty mapping {scenario name: episodes or null} or a list of names")
    pairs = value.items() if isinstance(value, dict) else ((name, None) for name in value)
    parsed = []
    for name, episodes in pairs:
        try:
            get_scenario(name)
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
        parsed.append((name, None if episodes is None else _int(episodes, f"{where}.{name}", minimum=1)))
    return tuple(parsed)


def _parse_set(entry, where: str) -> ParameterSet:
    _require(isinstance(entry, dict), where, f"must be a mapping with fields {list(SET_FIELDS)}")
    _no_unknown(entry, SET_FIELDS, where)
    _require(isinstance(entry.get("name"), str) and entry["name"], f"{where}.name", "must be a non-empty string")
    detector = entry.get("detector")
    if detector is not None:
        from ftcgym.fdd import DETECTORS
        try:
            DETECTORS.load(detector)
        except ValueError as error:
            raise ValueError(f"{where}.detector: {error}") from None
    return ParameterSet(name=entry["name"], detector=detector,
                        policies=_policies(entry.get("policies"), f"{where}.policies"),
                        **{key: _dict(entry.get(key, {}), f"{where}.{key}") for key in DICT_SET_FIELDS})


def _grid_sets(grid, where: str) -> list[ParameterSet]:
    """One set per combination of the grid's values; keys are `field.key` with field one of DICT_SET_FIELDS."""
    grid = _dict(grid, where)
    axes = []
    for key, values in grid.items():
        kind, _, name = key.partition(".")
        _require(kind in DICT_SET_FIELDS and name, f"{where}.{key}",
                 f"keys are FIELD.NAME with FIELD one of {list(DICT_SET_FIELDS)}, e.g. detector_kwargs.Q")
        _require(isinstance(values, list) and values, f"{where}.{key}", "must be a non-empty list of values")
        axes.append([(kind, name, value) for value in values])
    if not axes:  # the product of no axes is one empty combination, not no set
        return []
    sets = []
    for combination in itertools.product(*axes):
        fields: dict[str, dict] = {kind: {} for kind in DICT_SET_FIELDS}
        for kind, name, value in combination:
            fields[kind][name] = value
        label = " ".join(f"{name}={value}" for _, name, value in combination)
        sets.append(ParameterSet(name=label, **fields))
    return sets


def _merge_sets(base: ParameterSet, over: ParameterSet) -> ParameterSet:
    """`over` on top of `base`: dict fields merge key by key, the others are replaced when given."""
    return ParameterSet(name=over.name, detector=over.detector or base.detector,
                        policies=over.policies or base.policies,
                        **{key: {**getattr(base, key), **getattr(over, key)} for key in DICT_SET_FIELDS})


def _policies(value, where: str) -> tuple[str, ...] | None:
    if value is None:
        return None
    from ftcgym.agents import POLICIES
    names = tuple(_list(value, where))
    for name in names:
        try:
            POLICIES.load(name)
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
    return names


def _require(condition: bool, where: str, message: str) -> None:
    if not condition:
        raise ValueError(f"{where}: {message}")


def _no_unknown(mapping: dict, accepted, where: str) -> None:
    unknown = [key for key in mapping if key not in accepted]
    _require(not unknown, where, f"unknown field(s) {unknown}; accepted: {list(accepted)}")


def _list(value, where: str) -> list:
    _require(isinstance(value, list), where, f"must be a list, got {value!r}")
    return value


def _dict(value, where: str) -> dict:
    _require(isinstance(value, dict), where, f"must be a mapping, got {value!r}")
    return value


def _int(value, where: str, minimum: int | None = None) -> int:
    ok = isinstance(value, int) and not isinstance(value, bool) and (minimum is None or value >= minimum)
    _require(ok, where, f"must be an integer{f' >= {minimum}' if minimum is not None else ''}, got {value!r}")
    return value


# ---- jobs ----

def sweep_jobs(config: SweepConfig) -> list[Job]:
    """Every (set, scenario, policy, seed, episode) in that nested order; keys name all five."""
    jobs = []
    for parameter_set in config.parameter_sets:
        for name, episodes in config.scenarios:
            scenario = parameter_set.apply(get_scenario(name))
            for policy in parameter_set.policies or config.policies or scenario.policies:
                for seed in config.seeds:
                    jobs += [Job(f"{parameter_set.name}/{name}/{policy}/{seed}/{index}", scenario, policy,
                                 episode_seed(seed, index), config.env_kwargs or None)
                             for index in range(episodes or scenario.episodes)]
    return jobs


def check_parameter_sets(config: SweepConfig) -> None:
    """Build each set's env on the first scenario, and each scenario with the first set, so a misspelt
    parameter fails now rather than mid-sweep (every pair would cost sets x scenarios env builds)."""
    first_set, first_scenario = config.parameter_sets[0], config.scenarios[0][0]
    pairs = [(s, first_scenario) for s in config.parameter_sets] + [(first_set, n) for n, _ in config.scenarios[1:]]
    for parameter_set, name in pairs:
        try:
            make_env(parameter_set.apply(get_scenario(name)), config.env_kwargs).close()
        except (TypeError, ValueError) as error:
            raise ValueError(f"parameter set {parameter_set.name!r} on {name}: {error}") from None


# ---- running ----

def run_sweep(config: SweepConfig, out_dir, backend: str = "local", workers: int = 1, resume: bool = False,
              progress: bool = True, **backend_options) -> list[dict]:
    """Fly the sweep's unfinished episodes, journaling each row; return every row (set name added), job order.
    Holds `out_dir`'s lock throughout (`outputs.OutputFolder`): FolderInUse if another run holds it.

    Raises EpisodesFailed, after recording it, when episodes failed on every attempt: the finished ones
    stay in the journal and `resume` runs only what is missing.
    """
    with OutputFolder(out_dir):  # taken before the folder is looked at, so two fresh sweeps cannot both claim it
        return _run_sweep(config, EpisodeJournal(out_dir), backend, workers, resume, progress, backend_options)


def _run_sweep(config: SweepConfig, journal: EpisodeJournal, backend: str, workers: int, resume: bool,
               progress: bool, backend_options: dict) -> list[dict]:
    _claim_out_dir(journal, config, resume)
    jobs = sweep_jobs(config)
    finished = journal.finished_rows() if resume else {}
    todo = [job for job in jobs if job.key not in finished]
    if todo:
        check_parameter_sets(config)
    callbacks = Callbacks(finished=lambda job, row: _record(journal, finished, job, row),
                          retried=lambda job, attempt, error: journal.record_failure(job.key, attempt, error, False))
    try:
        run_jobs(todo, backend, min(workers, max(len(todo), 1)), callbacks=callbacks, keep_trajectory=False,
                 progress=progress, **backend_options)
    except EpisodesFailed as failure:
        for key, error in failure.failures.items():
            journal.record_failure(key, -1, error, True)
        raise
    return [{"parameter_set": job.key.split("/")[0], **finished[job.key]} for job in jobs]


def _record(journal: EpisodeJournal, finished: dict, job: Job, row: dict) -> None:
    journal.record_row(job.key, row)
    finished[job.key] = {k: v for k, v in row.items() if k != "trajectory"}


def _claim_out_dir(journal: EpisodeJournal, config: SweepConfig, resume: bool) -> None:
    """Write the config to the output folder; refuse to mix two sweeps' rows in one folder."""
    path = journal.out_dir / CONFIG_FILE
    if journal.exists() and not resume:
        raise ValueError(f"{journal.out_dir} already holds a sweep's episodes: pass --resume to finish it, "
                         "or choose another --out")
    if resume and path.exists():
        stored = json.loads(path.read_text())
        changed = [key for key, value in config.to_json().items() if stored.get(key) != value]
        if changed:
            raise ValueError(f"--resume: {journal.out_dir} holds a sweep with other {changed}; "
                             "resume with the same config and options, or choose another --out")
    atomic_write_text(path, json.dumps(config.to_json(), indent=2) + "\n")
