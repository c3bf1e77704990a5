"""`RecordingWrapper`: writes each episode's sensor readings to a file that `ftcgym replay` reads back.

Every sample a detector wrapper would see is kept: the reset observation and each step's, with
`info["time"]` and the action sent before it, so a replay feeds a detector exactly what it got online.
The fault's onset and target (`info["fault"]`) go in as metadata: the ground truth of the recording.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

from .logs import FTCGYM_ROTOR_ORDER

NOT_RECORDED = ("fdd/", "reference_")   # detector outputs and set-points are not sensor readings


class RecordingWrapper(gym.Wrapper):
    """Record sensor readings to `path` (.npz or .csv) when each episode ends (or at `close`).

    A "{episode}" in `path` is replaced by the episode's index (from 0); otherwise each episode overwrites
    the file. Read it back with `ftcgym.fdd.logs.read_npz` / `read_csv` (or `read_log`).
    """

    def __init__(self, env: gym.Env, path):
        super().__init__(env)
        self.path = str(path)
        if Path(self.path).suffix.lower() not in (".npz", ".csv"):
            raise ValueError(f"RecordingWrapper: path must end in .npz or .csv, got {self.path!r}")
        self.episode = -1
        self._samples = []

    def reset(self, *, seed=None, options=None):
        self._write()  # an episode cut short by this reset is kept too
        self.episode += 1
        obs, info = self.env.reset(seed=seed, options=options)
        self._record(obs, info, None)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._record(obs, info, action)
        if terminated or truncated:
            self._write()
        return obs, reward, terminated, truncated, info

    def close(self):
        self._write()
        super().close()

    def _record(self, obs: dict, info: dict, action) -> None:
        readings = {key: np.array(value, dtype=np.float64) for key, value in obs.items()
                    if not key.startswith(NOT_RECORDED)}
        command = None if action is None else np.array(action, dtype=np.float64).ravel()
        self._samples.append((float(info["time"]), readings, command))
        self._last_info = info

    def _write(self) -> Path | None:
        """Write the samples recorded since the last reset, if any; returns the file written."""
        if not self._samples:
            return None
        samples, self._samples = self._samples, []
        path = Path(self.path.replace("{episode}", str(self.episode)))
        time = np.array([t for t, _, _ in samples])
        readings = {key: np.stack([r[key] for _, r, _ in samples]) for key in samples[0][1]}
        commands = _command_array(samples)
        metadata = {**self._fault_metadata(self._last_info), **self._vehicle_metadata(),
                    "actuator_order": FTCGYM_ROTOR_ORDER, "episode": self.episode}
        if path.suffix.lower() == ".npz":
            _write_npz(path, time, readings, commands, metadata)
        else:
            _write_csv(path, time, readings, commands, metadata)
        return path

    @staticmethod
    def _fault_metadata(info: dict) -> dict:
        """Ground truth from the last info: the fault that had begun by then (none if it had not)."""
        fault = info.get("fault") or {}
        if not fault.get("active"):
            return {"fault_time": None, "fault_target": None}
        return {"fault_time": fault["onset_time"], "fault_target": fault["target"], "fault_kind": fault["kind"],
                "fault_magnitude": fault["magnitude"]}

    def _vehicle_metadata(self) -> dict:
        """The vehicle's name and 000 eq. (9) gains, which a replay of our own vehicle's detector needs."""
        try:
            params = self.env.get_wrapper_attr("params")
        except AttributeError:
            return {}
        out = {"vehicle": getattr(params, "name", None)}
        if hasattr(params, "effectiveness_G"):
            out["effectiveness_G"] = np.asarray(params.effectiveness_G, dtype=float).tolist()
        return out


def _command_array(samples) -> np.ndarray:
    """(N, m) commands, NaN where none was sent (the reset sample)."""
    width = max((len(c) for _, _, c in samples if c is not None), default=0)
    commands = np.full((len(samples), width), np.nan)
    for i, (_, _, command) in enumerate(samples):
        if command is not None:
            commands[i] = command
    return commands


def _write_npz(path: Path, time, readings: dict, commands, metadata: dict) -> None:
    arrays = {f"reading/{key}": value for key, value in readings.items()}
    np.savez_compressed(path, time=time, commands=commands, metadata=np.array(json.dumps(metadata)), **arrays)


def _write_csv(path: Path, time, readings: dict, commands, metadata: dict) -> None:
    """`# metadata <json>`, then a header `time,gyro[0],...,command[0],...` and one row per sample."""
    columns = {"time": time[:, None], **{key: value.reshape(len(time), -1) for key, value in readings.items()},
               "command": commands}
    header = [name if name == "time" else f"{name}[{i}]"
              for name, block in columns.items() for i in range(block.shape[1])]
    table = np.hstack(list(columns.values()))
    with open(path, "w", newline="") as file:
        file.write("# metadata " + json.dumps(metadata) + "\n")
        writer = csv.writer(file)
        writer.writerow(header)
        writer.writerows([[repr(float(v)) for v in row] for row in table])  # repr: exact round trip
