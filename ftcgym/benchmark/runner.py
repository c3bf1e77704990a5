"""Fly policies through scenarios, record each episode and score it (docs/concepts.md, 'Benchmark metrics').

`run_episode` flies one episode and returns its row of `EPISODE_FIELDS` plus a compact trajectory
under "trajectory" (for plots, never written to CSV or JSON). `run_benchmark` runs many episodes,
in worker processes or as Ray tasks when asked (`backends`), and returns the rows in a fixed order. Episode seeds
depend only on
the base seed and the episode index, so every policy flies the same episodes and a seed reproduces
the numbers.
"""
from __future__ import annotations

import copy
import os
import pickle
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from ftcgym.agents import make_policy, policy_view, thrust_axis_reference
from ftcgym.benchmark import metrics
from ftcgym.benchmark.backends import Job, run_jobs
from ftcgym.benchmark.scenarios import Scenario, get_scenario
from ftcgym.fdd import DetectorWrapper, published_detector, wrap_with_detector
from ftcgym.fdd.metrics import detection_delay, is_false_alarm

TRAJECTORY_MAX_HZ = 50.0
# Full-rate window kept around a fault onset, for the event plot: long enough after it to show a recovery (the
# 2 s recovered window starts ~0.6-1.5 s after a rotor loss) or a crash (~1 s after it, fault-unaware).
EVENT_BEFORE_S, EVENT_AFTER_S = 0.5, 3.0


def episode_seed(seed: int, index: int) -> int:
    """The env seed of episode `index` of a run seeded with `seed`."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


@dataclass
class EpisodeLog:
    """What one episode recorded, one row per agent step (the reset state first)."""

    time: np.ndarray                   # (N,) s
    position: np.ndarray               # (N, 3) NED m, truth
    reference_position: np.ndarray     # (N, 3) NED m, the task's setpoint
    attitude: np.ndarray               # (N, 4) FRD->NED quaternion x, y, z, w, truth
    body_rates: np.ndarray             # (N, 3) rad/s, truth
    rotor_speed: np.ndarray            # (N, 4) rad/s, truth
    thrust_axis_reference: np.ndarray  # (N, 3) NED unit vectors, from the policy
    detector_outputs: dict             # field -> (N, k) array of the scored detector's observation outputs
    fault: dict | None                 # info["fault"] at the first onset, None if no fault began
    detector: str | None
    alarm_time: float | None           # first alarm of `detector`
    isolated: object                   # first target `detector` isolated at or after its alarm
    crashed: bool
    airspeed: np.ndarray | None = None       # (N,) m/s, truth (quad-plane)
    skew: np.ndarray | None = None           # (N,) rad, truth (quad-plane)
    airspeed_used: np.ndarray | None = None  # (N,) m/s, what the autopilot scheduled on (QuadPlaneAutopilot-v0)
    phase: np.ndarray | None = None          # (N,) mission phase names (QuadPlaneAutopilot-v0)
    cruise_airspeed: float | None = None


class _Recorder:
    """Collects per-step truth and latches the first fault onset and the first alarm."""

    def __init__(self, detector: str | None):
        self.detector = detector
        self.rows: dict[str, list] = {name: [] for name in (
            "time", "position", "reference_position", "attitude", "body_rates", "rotor_speed",
            "thrust_axis_reference")}
        self.detector_outputs: dict[str, list] = {}
        self.quadplane: dict[str, list] = {}
        self.cruise_airspeed = None
        self.fault = None
        self.alarm_time = None
        self.isolated = None
        self.detector_seen = False

    def record(self, info: dict, axis_reference: np.ndarray, obs: dict | None = None) -> None:
        truth = info["truth"]
        for name, value in (("time", info["time"]), ("position", truth["position"]),
                            ("reference_position", info["reference"]["position"]),
                            ("attitude", truth["attitude"]), ("body_rates", truth["body_rates"]),
                            ("rotor_speed", truth["rotor_speed"]),
                            ("thrust_axis_reference", axis_reference)):
            self.rows[name].append(np.array(value, dtype=float))
        if "skew" in truth:
            self.quadplane.setdefault("airspeed", []).append(truth["airspeed"])
            self.quadplane.setdefault("skew", []).append(truth["skew"])
        mission = info.get("mission")
        if mission is not None:
            self.quadplane.setdefault("airspeed_used", []).append(mission["airspeed_used"])
            self.quadplane.setdefault("phase", []).append(mission["phase"])
            self.cruise_airspeed = mission["cruise_airspeed"]
        if self.fault is None and info["fault"]["onset_time"] is not None:
            self.fault = dict(info["fault"])
        if self.detector is not None:
            self._latch_alarm(info)
            prefix = f"fdd/{self.detector}/"
            for key, value in (obs or {}).items():
                if key.startswith(prefix):
                    self.detector_outputs.setdefault(key[len(prefix):], []).append(np.array(value, dtype=float))

    def _latch_alarm(self, info: dict) -> None:
        entry = info.get("fdd", {}).get(self.detector)
        if entry is None:
            return
        self.detector_seen = True
        if self.alarm_time is None:
            alarm_time = entry.get("alarm_time")
            self.alarm_time = info["time"] if alarm_time is None and entry.get("alarm") else alarm_time
        if self.alarm_time is not None and self.isolated is None:
            self.isolated = entry.get("isolated")

    def finish(self, final_info: dict) -> EpisodeLog:
        if self.detector is not None and not self.detector_seen:
            raise ValueError(f"detector {self.detector!r} never appeared in info['fdd']: "
                             "wrap the env with it (Scenario.wrappers or env kwargs)")
        return EpisodeLog(**{name: np.array(values) for name, values in self.rows.items()},
                          detector_outputs={k: np.array(v) for k, v in self.detector_outputs.items()},
                          fault=self.fault, detector=self.detector, alarm_time=self.alarm_time,
                          isolated=self.isolated, crashed=bool(final_info["crashed"]),
                          cruise_airspeed=self.cruise_airspeed,
                          **{name: np.array(values) for name, values in self.quadplane.items()})


def roll_out(env: gym.Env, policy, seed: int, detector: str | None = None, on_step=None,
             until: float | None = None) -> EpisodeLog:
    """Fly one episode of `policy` in `env` from `env.reset(seed=seed)` and record it; `on_step(obs, info)`,
    if given, sees every recorded step too (the reset first, the final step last). `until` (s), if given, ends
    the flight early, at the first step at or past that time."""
    obs, info = env.reset(seed=seed)
    policy.reset(obs, policy_view(info, policy))
    recorder = _Recorder(detector)
    while True:
        action = policy.act(obs, policy_view(info, policy))
        recorder.record(info, thrust_axis_reference(policy), obs)
        if on_step is not None:
            on_step(obs, info)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated or (until is not None and info["time"] >= until):
            break
    recorder.record(info, thrust_axis_reference(policy), obs)
    if on_step is not None:
        on_step(obs, info)
    return recorder.finish(info)


def score_episode(log: EpisodeLog) -> dict:
    """The metric fields of an episode row (EPISODE_FIELDS less scenario, policy and seed)."""
    fault = log.fault or {}
    onset = fault.get("onset_time")
    altitude = -log.position[:, 2]
    scores = {
        "fault_kind": fault.get("kind"),
        "fault_target": fault.get("target"),
        "fault_onset": onset,
        **_detection_fields(log, onset, metrics.isolation_target(fault.get("kind"), fault.get("target"))),
        "recovery_time": None,
        "recovered": None,
        "crashed": log.crashed,
        "altitude_loss": None,
        "position_rmse": metrics.position_rmse(log.position, log.reference_position),
        "airspeed_error_rmse": None,  # the quadrotor has no airspeed source to get wrong
        "flight_time": float(log.time[-1]),
        **dict.fromkeys(metrics.RETURN_FIELDS),
        **dict.fromkeys(metrics.QUADPLANE_FIELDS),
    }
    if log.skew is not None:
        scores.update(_quadplane_scores(log, onset))
    elif onset is not None:
        # The rotor-loss criterion (docs/concepts.md, 'Benchmark metrics') serves every quadrotor fault.
        axis_error = metrics.thrust_axis_error(log.attitude, log.thrust_axis_reference)
        recovered = metrics.hover_recovered(altitude, -log.reference_position[:, 2], axis_error)
        scores["recovery_time"] = metrics.recovery_time(log.time, recovered, onset)
        scores["recovered"] = scores["recovery_time"] is not None and not log.crashed
        scores["altitude_loss"] = metrics.altitude_loss(log.time, altitude, onset)
        scores.update(metrics.return_fields(log.time, log.position, log.reference_position, onset, log.crashed))
    return scores


def _quadplane_scores(log: EpisodeLog, onset) -> dict:
    """Mission fields; with the autopilot's airspeed, its error and the airspeed-fault recovery
    (docs/concepts.md, 'Benchmark metrics')."""
    altitude = -log.position[:, 2]
    roll, pitch = metrics.roll_pitch(log.attitude)
    scores = {**metrics.flight_phase_times(log.time, log.skew, altitude > 0.5),
              "max_attitude_deg": float(np.degrees(np.max(np.maximum(np.abs(roll), np.abs(pitch)))))}
    if onset is not None:
        window = metrics.upset(log.time, altitude, roll, pitch, onset)
        scores["upset_attitude_deg"], scores["upset_altitude_loss"] = window if window else (None, None)
    if log.airspeed_used is None:
        return scores
    airborne = altitude > 0.5
    cruise = log.phase == "cruise"
    scores["airspeed_error_rmse"] = metrics.rms((log.airspeed_used - log.airspeed)[airborne])
    scores["cruise_airspeed_rmse"] = metrics.rms(log.airspeed[cruise] - log.cruise_airspeed)
    scores["mission_complete"] = bool(log.phase[-1] == "landed" and not log.crashed)
    if onset is not None:
        recovered = metrics.airspeed_recovered(log.airspeed_used, log.airspeed, log.attitude)
        scores["recovery_time"] = metrics.recovery_time(log.time, recovered, onset)
        scores["recovered"] = scores["recovery_time"] is not None and not log.crashed
    return scores


def _detection_fields(log: EpisodeLog, onset, target) -> dict:
    """Alarm, delay, isolation and false-alarm fields; all None when no detector is scored."""
    if log.detector is None:
        return dict.fromkeys(("alarm_time", "detection_delay", "isolated_target",
                              "isolation_correct", "false_alarm"))
    has_target = onset is not None and target is not None
    try:
        return {
            "alarm_time": log.alarm_time,
            "detection_delay": detection_delay(log.alarm_time, onset),
            "isolated_target": log.isolated,
            "isolation_correct": _native(log.isolated) == _native(target) if has_target else None,
            "false_alarm": is_false_alarm(log.alarm_time, onset),
        }
    except ValueError as error:                     # a NaN alarm time: say whose
        raise ValueError(f"detector {log.detector!r}: status()'s {error}") from None


def trajectory(log: EpisodeLog, max_hz: float = TRAJECTORY_MAX_HZ) -> dict[str, np.ndarray]:
    """The log's time, position, reference position, attitude and rotor speeds at <= `max_hz`."""
    step = float(np.median(np.diff(log.time))) if len(log.time) > 1 else 1.0
    stride = max(1, int(np.ceil(1.0 / (max_hz * step) - 1e-9)))
    keep = np.unique(np.append(np.arange(0, len(log.time), stride), len(log.time) - 1))
    out = {name: getattr(log, name)[keep]
           for name in ("time", "position", "reference_position", "attitude", "rotor_speed")}
    out["event"] = event_window(log)
    return out


def event_window(log: EpisodeLog, before: float = EVENT_BEFORE_S, after: float = EVENT_AFTER_S) -> dict | None:
    """Full-rate time history around the fault onset (as 000 Figs. 8-9): rotor speeds, attitude and the
    scored detector's outputs, and on the quad-plane the true airspeed and the one the autopilot used; None
    without a fault."""
    onset = (log.fault or {}).get("onset_time")
    if onset is None:
        return None
    keep = (log.time >= onset - before) & (log.time <= onset + after)
    window = {"time": log.time[keep], "rotor_speed": log.rotor_speed[keep], "attitude": log.attitude[keep],
              "body_rates": log.body_rates[keep],
              "altitude": -log.position[keep, 2], "onset": onset, "alarm_time": log.alarm_time,
              "detector": log.detector}
    window["outputs"] = {name: values[keep] for name, values in log.detector_outputs.items()}
    for name in ("airspeed", "airspeed_used"):
        if getattr(log, name) is not None:
            window[name] = getattr(log, name)[keep]
    return window


def make_env(scenario: Scenario, env_overrides: dict | None = None) -> gym.Env:
    """The scenario's env, its kwargs updated (top-level keys) by `env_overrides`, wrapped with the scenario's
    fault wrappers, its detector, then its further wrappers."""
    return make_scored_env(scenario, env_overrides)[0]


def make_scored_env(scenario: Scenario, env_overrides: dict | None = None) -> tuple[gym.Env, str | None]:
    """`make_env`'s env and the `info["fdd"]` key the benchmark scores: that of the scenario's own detector (its
    `name`), whatever detectors the scenario's `wrappers` add around it; None without one."""
    kwargs = copy.deepcopy({**scenario.env_kwargs, **(env_overrides or {})})
    env = gym.make(scenario.env_id, **kwargs)
    for wrap in scenario.fault_wrappers:
        env = wrap(env)
    scored = None
    if scenario.detector is not None:
        env = wrap_with_detector(scenario.detector, env, **scenario.detector_kwargs)
        scored = published_detector(env, scenario.detector)
    for wrap in scenario.wrappers:
        env = wrap(env)
    return env, scored


def check_setup(scenario: Scenario, env_overrides: dict | None = None, policies=()) -> None:
    """Build the scenario's env and detector, and each of `policies` on that env, and fly each policy's first
    step: a bad env or detector argument, or a policy that does not fly the env (lacks `act`, or acts with a wrong
    shape or a NaN), is one ValueError naming the scenario before any episode flies (instead of the same failure
    in every episode)."""
    try:
        env = make_env(scenario, env_overrides)
    except (ValueError, TypeError) as error:
        raise ValueError(f"scenario {scenario.name!r}: {error}") from error
    try:
        env.reset(seed=0)                  # the env, and its detectors' first outputs and status, before any policy
        for policy in policies:
            built = make_policy(policy, env)
            _check_detector(built, policy, env)
            _first_step(env, built, policy)
    except (ValueError, TypeError) as error:
        raise ValueError(f"scenario {scenario.name!r}: {error}") from error
    finally:
        env.close()


def _first_step(env, policy, name: str) -> None:
    """The policy's reset and first step, its failure (whatever it raises) one ValueError naming it."""
    try:
        roll_out(env, policy, seed=0, until=0.0)
    except (ValueError, TypeError) as error:
        raise ValueError(f"policy {name!r}: {error}") from error
    except Exception as error:  # noqa: BLE001 - the policy's own bug (an IndexError, torch's RuntimeError)
        raise ValueError(f"policy {name!r}: its first step raised {type(error).__name__}: {error}") from error


def _check_detector(policy, name: str, env) -> None:
    """A policy that names a detector in `detector` reads its `info["fdd"]` status: the env must be wrapped with
    it. An oracle (`uses_true_onset`) is given the true fault instead and is exempt."""
    needed = getattr(policy, "detector", None)
    if not isinstance(needed, str) or getattr(policy, "uses_true_onset", False):
        return
    wrapped = []
    while isinstance(env, gym.Wrapper):
        if isinstance(env, DetectorWrapper):
            wrapped.append(env.detector.name)
        env = env.env
    if needed not in wrapped:
        raise ValueError(f"policy {name!r} reads the {needed!r} detector, which this scenario's env is not wrapped "
                         f"with ({', '.join(wrapped) or 'no detector'}); give --detector {needed} or a scenario "
                         f"that has it")


def run_episode(scenario: Scenario | str, policy_name: str, seed: int,
                env_overrides: dict | None = None) -> dict:
    """One episode: its row of EPISODE_FIELDS (JSON-ready values) plus "trajectory" (arrays). `policy_name`
    is any name `ftcgym.agents.make_policy` takes; the row carries it as given."""
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    env, detector = make_scored_env(scenario, env_overrides)
    try:
        log = roll_out(env, make_policy(policy_name, env), seed, detector)
    finally:
        env.close()
    values = {"scenario": scenario.name, "policy": policy_name, "seed": int(seed), **score_episode(log)}
    row = {name: _native(values[name]) for name in metrics.EPISODE_FIELDS}
    row["trajectory"] = trajectory(log)
    return row


def run_benchmark(scenarios, policies=None, episodes: int | None = None, seed: int = 0,
                  workers: int | None = 1, env_overrides: dict | None = None,
                  progress: bool = True, backend: str = "local", **backend_options) -> list[dict]:
    """Run every (scenario, policy, episode) and return the episode rows in that nested order.

    `scenarios` are Scenario objects or names; `policies` and `episodes` default to each scenario's
    own. `workers` > 1 runs episodes in that many processes (None: one per CPU); 1 runs in-process.
    `backend` "ray" runs them as Ray tasks instead; `backend_options` go to `backends.run_jobs`
    (ray_address, chunk, retries, callbacks).
    """
    scenarios = [get_scenario(s) if isinstance(s, str) else s for s in scenarios]
    _no_repeats([scenario.name for scenario in scenarios], "scenarios")
    _no_repeats(policies or (), "policies")
    for scenario in scenarios:
        check_setup(scenario, env_overrides, policies or scenario.policies)
    jobs = [Job(f"{scenario.name}/{policy}/{index}", scenario, policy, episode_seed(seed, index), env_overrides)
            for scenario in scenarios
            for policy in (policies or scenario.policies)
            for index in range(episodes or scenario.episodes)]
    processes = pool_size(workers, len(jobs))
    if processes > 1 or backend != "local":
        for scenario in scenarios:
            _check_picklable(scenario)
    return run_jobs(jobs, backend, processes, progress=progress, **backend_options)


def _check_picklable(scenario: Scenario) -> None:
    """Episodes in other processes get the scenario pickled: a lambda or a local function among its wrappers would
    fail every episode; say so once, before any flies."""
    try:
        pickle.dumps(scenario)
    except (pickle.PicklingError, AttributeError, TypeError) as error:
        raise ValueError(f"scenario {scenario.name!r}: it cannot go to worker processes ({error}); its wrappers and "
                         f"fault_wrappers must be module-level functions or classes, or run it with workers=1"
                         ) from None


def pool_size(workers: int | None, episodes: int) -> int:
    """The processes a run of `episodes` episodes uses when `workers` are asked for (None: one per CPU): no more
    than there are episodes."""
    return min(workers or os.cpu_count() or 1, max(episodes, 1))


def _no_repeats(names, what: str) -> None:
    """ValueError naming the first name given twice: its episodes would fly twice, with the same seeds, and count
    twice in the summary."""
    seen = set()
    for name in names:
        if name in seen:
            raise ValueError(f"{what}: {name!r} is given twice; give each once")
        seen.add(name)


def _native(value):
    """numpy scalars and arrays as plain Python values, so rows serialise to JSON and compare simply."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_native(item) for item in value]
    return value
