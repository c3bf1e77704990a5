"""Measurements of the airdata_ekf detectors: every criterion's alarm on the same flights,
the airspeed error after a sensor fault, and threshold proposals from fault-free residual statistics.

    ftcgym airdata-study --scenario NAME [--episodes N] [--seed S] [--policy P] [--env-kwargs JSON]
                         [--detector-kwargs JSON] [--workers W] [--out F]
    ftcgym thresholds [--scenario NAME] [--episodes N] [--seed S] [--detector-kwargs JSON] [--workers W]
                      [--target RATE] [--save F.npz | --load F.npz]

`ftcgym bench` scores one alarm per detector (the first); these commands read the detector's status instead,
so one flight gives the Table 2 and the CUSUM pitot alarm times and each innovation detector's. Episodes are
seeded as `ftcgym bench` seeds them (`runner.episode_seed`) and flown by `oracle-airspeed` by default: the
autopilot then flies the same whatever the detector says, so the criteria compete on identical residuals.
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from ftcgym.benchmark.backends import Callbacks, Job, run_jobs
from ftcgym.benchmark.runner import episode_seed, make_env, roll_out
from ftcgym.benchmark.scenarios import get_scenario
from ftcgym.fdd import false_alarm
from ftcgym.fdd.airdata_ekf import EKF_HZ, INNOVATION_DETECTORS, InnovationTest
from ftcgym.fdd.pitot_detection import (
    CUSUM_DEFAULT,
    RAMP_DEFAULT,
    RAMP_MIN_AIRSPEED,
    TABLE_2_DERIVATIVE,
    TABLE_2_NORM,
    RampGlr,
    ResidualCusum,
)

DETECTOR = "airdata_ekf"
FORWARD_SKEW = math.radians(80.0)       # 001 Table 5: forward flight above 80 deg skew
BIAS_WINDOW = 10.0                       # s before onset over which the signed EKF airspeed error is averaged
ALARMS = ("table2", "cusum", "ramp", "gnss", "pusher_rpm")


def fly(scenario_name: str, seed: int, policy_name: str = "oracle-airspeed", env_overrides: dict | None = None,
        record: bool = False, detector_kwargs: dict | None = None) -> dict:
    """One episode: each criterion's alarm time and delay, the EKF airspeed error, and (with `record`) the
    detector's per-EKF-step detection signals under "trace". `detector_kwargs` override the scenario's."""
    from ftcgym.agents import make_policy

    scenario = get_scenario(scenario_name)
    if scenario.detector != DETECTOR:
        raise ValueError(f"scenario {scenario_name!r} is not scored on {DETECTOR!r}")
    scenario = dataclasses.replace(scenario, detector_kwargs={**scenario.detector_kwargs, **(detector_kwargs or {}),
                                                               "record": record})
    env = make_env(scenario, env_overrides)
    rows, seen = [], {}

    def keep(obs, info):
        rows.append(_sample(obs, info))
        seen.setdefault("reset", info)
        seen["last"] = info
    try:
        log = roll_out(env, make_policy(policy_name, env), seed, DETECTOR, on_step=keep)
        trace = env.get_wrapper_attr("detector").trace if record else None
    finally:
        env.close()
    mean_wind, info = seen["reset"].get("mean_wind"), seen["last"]
    onset = log.fault["onset_time"] if log.fault is not None else None
    result = _score(np.array(rows), info, onset)
    result.update(seed=int(seed), scenario=scenario_name, policy=policy_name, mean_wind=mean_wind)
    if record:
        result["trace"] = trace
    return result


def _sample(obs: dict, info: dict) -> list[float]:
    truth = info["truth"]
    return [info["time"], float(obs[f"fdd/{DETECTOR}/airspeed"][0]), truth["airspeed"], truth["skew"],
            -truth["position"][2]]


def _alarm_times(status: dict) -> dict:
    return {"table2": status["alarm_time_table2"], "cusum": status["alarm_time_cusum"],
            "ramp": status["alarm_time_ramp"],
            **{sensor: status["innovation_alarms"].get(sensor) for sensor in ("gnss", "pusher_rpm")}}


def _score(samples: np.ndarray, info: dict, onset) -> dict:
    time, ekf, true, skew, altitude = samples.T
    status = info["fdd"][DETECTOR]
    alarms = _alarm_times(status)
    airborne = altitude > 0.5
    error = np.abs(ekf - true)
    out = {"fault_kind": info["fault"]["kind"] if onset is not None else None, "fault_onset": onset,
           "flight_time": float(time[-1]), "airborne_time": float(np.sum(np.diff(time, append=time[-1]) * airborne)),
           "crashed": bool(info["crashed"]), "table2_criterion": status["table2_criterion"],
           "ekf_started": status["start_time"],
           "pusher_rpm_criterion": status.get("innovation_criteria", {}).get("pusher_rpm"),
           "pusher_rpm_unconfirmed": status.get("innovation_unconfirmed", {}).get("pusher_rpm")}
    for name, t in alarms.items():
        out[f"alarm_time_{name}"] = t
        out[f"delay_{name}"] = None if (t is None or onset is None or t < onset) else t - onset
        out[f"false_alarm_{name}"] = t is not None and (onset is None or t < onset)
    monitored = airborne & (time >= (status["start_time"] or math.inf))
    before = monitored & (time < (onset if onset is not None else math.inf))
    out["airspeed_rmse_before_onset"] = _rms(error[before])
    if onset is not None:
        # signed: an EKF reading b low raises r = pitot - EKF by b, so a falling pitot reaches -Z_norm b / rate s later
        recent = before & (time >= onset - BIAS_WINDOW)
        out["airspeed_bias_before_onset"] = float(np.mean(ekf[recent] - true[recent])) if recent.any() else None
    sensor_alarm = min([t for t in (alarms["gnss"], alarms["pusher_rpm"]) if t is not None], default=None)
    if sensor_alarm is not None:
        after = monitored & (time >= sensor_alarm)
        out["airspeed_error_max_after_detection"] = float(error[after].max()) if after.any() else None
        forward = after & (skew > FORWARD_SKEW)
        out["airspeed_error_max_after_detection_forward"] = float(error[forward].max()) if forward.any() else None
        out["airspeed_rmse_after_detection"] = _rms(error[after])
    if onset is not None:
        out["airspeed_error_max_onset_to_detection"] = _max(error[monitored & (time >= onset)
                                                                  & (time < (sensor_alarm or math.inf))])
    return out


def _rms(values: np.ndarray):
    return float(np.sqrt(np.mean(values ** 2))) if values.size else None


def _max(values: np.ndarray):
    return float(values.max()) if values.size else None


def study(scenario_name: str, episodes: int, seed: int, policy_name: str = "oracle-airspeed",
          env_overrides: dict | None = None, record: bool = False, progress=None, workers: int = 1,
          detector_kwargs: dict | None = None) -> list[dict]:
    """`episodes` episodes seeded as `ftcgym bench --seed seed` seeds them, in episode order; `workers` > 1 flies
    them in that many processes (`backends.run_jobs`); `progress(index, row)` sees each as it finishes;
    `detector_kwargs` override the scenario's (e.g. {"error_seed": 2, "vertical_wind": "fixed"})."""
    if not isinstance(detector_kwargs or {}, dict):
        raise ValueError(f"detector_kwargs: need a JSON object of airdata_ekf kwargs, got {detector_kwargs!r}")
    scenario = get_scenario(scenario_name)
    scenario = dataclasses.replace(scenario, detector_kwargs={**scenario.detector_kwargs, **(detector_kwargs or {})})
    jobs = [Job(f"{scenario_name}/{policy_name}/{index}", scenario, policy_name, episode_seed(seed, index),
                env_overrides) for index in range(episodes)]
    order = {job.key: index for index, job in enumerate(jobs)}
    callbacks = Callbacks(finished=lambda job, row: progress(order[job.key], row)) if progress else None
    episode = functools.partial(_fly_job, record=True) if record else _fly_job
    return run_jobs(jobs, "local", max(1, min(workers, episodes)), callbacks=callbacks, episode=episode,
                    progress=False)


def _fly_job(scenario, policy_name: str, seed: int, env_overrides, record: bool = False) -> dict:
    """`fly` with `run_jobs`' episode signature (module level: it is pickled to the workers)."""
    return fly(scenario.name, seed, policy_name, env_overrides, record, scenario.detector_kwargs)


def summary(results: list[dict]) -> dict:
    """Median / max delays, detections and false alarms per criterion, flight hours, the EKF's mean signed airspeed
    error over the 10 s before onset."""
    out = {"episodes": len(results), "flight_hours": sum(r["airborne_time"] for r in results) / 3600.0,
           "crashes": sum(r["crashed"] for r in results),
           "pusher_rpm_unconfirmed": sum(r.get("pusher_rpm_unconfirmed") is not None for r in results)}
    for name in ALARMS:
        delays = [r[f"delay_{name}"] for r in results if r[f"delay_{name}"] is not None]
        out[name] = {"detected": len(delays), "false_alarms": sum(r[f"false_alarm_{name}"] for r in results),
                     "delay_median": float(np.median(delays)) if delays else None,
                     "delay_max": float(np.max(delays)) if delays else None}
    errors = [r.get("airspeed_error_max_after_detection") for r in results]
    errors = [e for e in errors if e is not None]
    out["airspeed_error_max_after_detection"] = max(errors) if errors else None
    forward = [r.get("airspeed_error_max_after_detection_forward") for r in results]
    forward = [e for e in forward if e is not None]
    out["airspeed_error_max_after_detection_forward"] = max(forward) if forward else None
    biases = [r["airspeed_bias_before_onset"] for r in results if r.get("airspeed_bias_before_onset") is not None]
    out["airspeed_bias_before_onset_mean"] = float(np.mean(biases)) if biases else None
    return out


# ---- thresholds (001 eq. 40-41, Fig. 4) ----

def criteria(cusum=CUSUM_DEFAULT, innovation_detectors=INNOVATION_DETECTORS, ramp=RAMP_DEFAULT) -> list[tuple]:
    """(name, trace signal, threshold, hold time, sign) of every criterion the detector runs; sign +1 / -1: a
    one-sided criterion, whose statistics are those of max(sign * s, 0)."""
    out = [("pitot norm", "pitot_residual", TABLE_2_NORM[0], TABLE_2_NORM[1], 0),
           ("pitot derivative", "pitot_residual_derivative", TABLE_2_DERIVATIVE[0], TABLE_2_DERIVATIVE[1], 0),
           ("pitot cusum", "cusum", cusum[1], 0.0, 0),
           ("pitot ramp", "ramp", ramp[0], 0.0, 1)]
    for sensor, spec in innovation_detectors.items():
        spec = InnovationTest.of(spec)
        for c in spec.channels:
            out.append((f"{sensor}[{c}] norm", f"{sensor}_{c}_innovation", *spec.norm[:2], spec.sign))
            out.append((f"{sensor}[{c}] derivative", f"{sensor}_{c}_innovation_derivative", *spec.derivative[:2], 0))
        if spec.pitot_confirmation is not None:
            _, _, residual, hold = spec.pitot_confirmation
            out.append((f"{sensor} pitot confirmation", f"{sensor}_pitot_confirmation", residual, hold, 1))
        if spec.current_check is not None:
            _, threshold, hold = spec.current_check
            out.append((f"{sensor} current check", f"{sensor}_current_excess", threshold, hold, 1))
    return out


def traces_to_segments(traces: list[list[dict]]) -> dict[str, list[np.ndarray]]:
    """signal -> one array per flight, from the detectors' `trace`s."""
    signals = {key for trace in traces for row in trace[:1] for key in row if key != "time"}
    return {key: [np.array([row[key] for row in trace], dtype=float) for trace in traces if trace]
            for key in sorted(signals)}


def cusum_segments(raw_segments: list[np.ndarray], cusum=CUSUM_DEFAULT, sample_hz: float = EKF_HZ) -> list[np.ndarray]:
    """The CUSUM statistic g of `ResidualCusum(*cusum)` over each flight's raw pitot residual (armed
    throughout), so saved flights can be re-scored with the current (or any) CUSUM parameters."""
    return [_statistic(ResidualCusum(sample_hz, *cusum), raw, sample_hz) for raw in raw_segments]


def ramp_segments(raw_segments: list[np.ndarray], forward_airspeeds: list[np.ndarray], ramp=RAMP_DEFAULT,
                  min_airspeed: float = RAMP_MIN_AIRSPEED, sample_hz: float = EKF_HZ) -> list[np.ndarray]:
    """The ramp GLR's z of `RampGlr(*ramp)` over each flight's raw pitot residual, armed where the EKF's forward
    airspeed is at least `min_airspeed` (as the detector arms it)."""
    return [_statistic(RampGlr(sample_hz, *ramp), raw, sample_hz, forward >= min_airspeed)
            for raw, forward in zip(raw_segments, forward_airspeeds)]


def _statistic(test, raw: np.ndarray, sample_hz: float, armed=None) -> np.ndarray:
    out = np.empty(len(raw))
    for k, r in enumerate(raw):
        test.update(r, k / sample_hz, True if armed is None else bool(armed[k]))
        out[k] = test.statistic
    return out


def threshold_table(segments: dict[str, list[np.ndarray]], target_per_hour: float = 1e-3,
                    sample_hz: float = EKF_HZ, tail: str = "auto") -> list[dict]:
    """`false_alarm.criterion_report` for each criterion of `criteria()` on the fault-free `segments`; the
    CUSUM and ramp rows are recomputed from the raw residual with the current CUSUM_DEFAULT and RAMP_DEFAULT
    where it was recorded (the ramp row needs the forward airspeed that arms it)."""
    if "pitot_residual_raw" in segments:
        raw = segments["pitot_residual_raw"]
        segments = {**segments, "cusum": cusum_segments(raw, sample_hz=sample_hz)}
        if "forward_airspeed" in segments:
            segments["ramp"] = ramp_segments(raw, segments["forward_airspeed"], sample_hz=sample_hz)
    rows = []
    for name, signal, threshold, hold, sign in criteria():
        if signal not in segments:
            continue
        parts = segments[signal] if sign == 0 else [np.maximum(sign * s, 0.0) for s in segments[signal]]
        report = false_alarm.criterion_report(parts, threshold, hold, sample_hz, target_per_hour, tail,
                                              max_lag=max(false_alarm.sequence_length(hold, sample_hz), 25))
        rows.append({"criterion": name, **report})
    return rows


def save_segments(path: str, segments: dict[str, list[np.ndarray]]) -> None:
    np.savez_compressed(path, **{f"{key}__{i}": s for key, parts in segments.items() for i, s in enumerate(parts)})


def load_segments(path: str) -> dict[str, list[np.ndarray]]:
    data = np.load(path)
    out: dict[str, list] = {}
    for name in sorted(data.files, key=lambda n: (n.rsplit("__", 1)[0], int(n.rsplit("__", 1)[1]))):
        out.setdefault(name.rsplit("__", 1)[0], []).append(data[name])
    return out
