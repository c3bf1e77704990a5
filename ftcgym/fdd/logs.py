"""Flight logs for offline replay: PX4 ULogs (RflyMAD) and ftcgym's own recordings on one uniform time grid.

A `FlightLog` holds sensor readings keyed like the env's observation (`gyro` rad/s and `accel` m/s^2
specific force in body FRD, `rotor_speed` rad/s, optionally `attitude` x y z w, `position` and `velocity`
NED), so a detector reads a logged sample exactly as it reads a live observation.

PX4 logs carry no rotor speeds, only the PWM sent to the ESCs. `read_ulog` makes speeds from it, as 001
Sec. 7.4 did for a prototype without RPM feedback:
- a linear map, PWM min -> idle speed, PWM max -> full speed (1000 and 2000 us in these logs; 900 us is
  disarmed: stopped). An open-loop ESC sets a voltage ~ duty cycle and a loaded motor turns at a speed ~
  voltage, from an idle speed once armed: the form of our env's ESC model (omega_min + u (omega_max -
  omega_min)); 000's Bebop idles at 1/4 of its top speed (Sec. IV-A). Idle = 15% of full speed is what the
  fault-free hover of the RflyMAD HIL logs says: there the fit a_z = G_az sum(omega^2) + bias has no bias
  (no thrust, no specific force) and its slope equals the hover ratio a_z / sum(omega^2); at idle 0 the
  slope is only half of it. The full speed only scales omega^2, which the identified gains absorb.
- the PWM held between logged samples (zero-order hold), as the ESC holds the last pulse width; unlike
  interpolation it never uses a command logged after the instant (SIL logs keep it at only 10 Hz).
- a dead time and the motor's first-order lag (see `read_ulog`).
IMU samples are interpolated linearly onto the grid (they sample continuous signals).
"""
from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import signal

FTCGYM_ROTOR_ORDER = "ftcgym / 000 Fig. 2: 0 front-left, 1 front-right, 2 rear-right, 3 rear-left"
PX4_QUAD_X_ORDER = "PX4 quad X outputs: 0 front-right, 1 rear-left, 2 front-left, 3 rear-right"
#: actuator order -> the ftcgym rotor index of each of its outputs (docs/concepts.md, "Rotor numbering")
FTCGYM_INDEX = {FTCGYM_ROTOR_ORDER: (0, 1, 2, 3), PX4_QUAD_X_ORDER: (1, 3, 0, 2)}

PWM_RANGE = (1000.0, 2000.0)       # us, idle..full in the RflyMAD logs (armed outputs span exactly 1000-2000)
MAX_ROTOR_SPEED = 1000.0           # rad/s at full PWM: ~9500 rpm, a 450-class quad's 10" prop (scale only)
IDLE_ROTOR_SPEED = 150.0           # rad/s at PWM min, armed: 15% of full speed (module docstring)
MOTOR_TIME_CONSTANT = 0.01         # s, see read_ulog
ACTUATOR_DELAY = 0.024             # s, see read_ulog
ULOG_TOPICS = ("sensor_combined", "actuator_outputs", "vehicle_attitude", "vehicle_local_position",
               "rfly_ctrl_lxl")


@dataclass
class FlightLog:
    """Sensor readings of one flight on a uniform time grid, plus what the log knows of its fault.

    time:            (N,) s from the log's start, uniform rate
    readings:        key -> (N, ...) array, keys as the env's observation
    actuator_order:  which rotor each column of `rotor_speed` (and each detector target) is
    fault_time:      s from the log's start (ground truth), None if none is known
    fault_target:    0-based rotor index in `actuator_order`, None if none is known
    source:          the file it was read from
    commands:        (N, m) action sent before each sample (NaN where none, e.g. at reset), or None
    metadata:        other facts of the recording (vehicle, fault kind and magnitude, how speeds were made)
    """

    time: np.ndarray
    readings: dict
    actuator_order: str
    fault_time: float | None = None
    fault_target: int | None = None
    source: str = ""
    commands: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.time[1] - self.time[0])

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.time)

    def samples(self):
        """(time, readings, command) per sample, as a detector's `update` takes them."""
        for i, t in enumerate(self.time):
            readings = {key: value[i] for key, value in self.readings.items()}
            command = None if self.commands is None or np.isnan(self.commands[i]).all() else self.commands[i]
            yield float(t), readings, command


# ----------------------------------------------------------------------------------------- PX4 ULog

def read_ulog(path, rate_hz: float = 250.0, pwm_range=PWM_RANGE, max_rotor_speed: float = MAX_ROTOR_SPEED,
              idle_rotor_speed: float = IDLE_ROTOR_SPEED, motor_time_constant: float = MOTOR_TIME_CONSTANT,
              actuator_delay: float = ACTUATOR_DELAY, n_rotors: int = 4) -> FlightLog:
    """A PX4 ULog resampled to `rate_hz`, with rotor speeds made from the PWM outputs (module docstring).

    Rotor outputs 0-3 follow PX4's quad X numbering (MOT_ORDERING 0, as in RflyMAD). The speed lags the
    PWM by `actuator_delay` s, then by a first-order lag of `motor_time_constant` s. Both were identified
    on the fault-free flight of the RflyMAD HIL logs (PWM at ~225 Hz): the roll and pitch rows of
    `replay.identify_effectiveness` explain most (R^2 0.77) for a lag plus dead time of ~33 ms, nearly all
    dead time (tau 5-10 ms with 24-28 ms delay; a 30 ms lag alone reaches R^2 0.37): the simulator's loop
    (USB, MAVLink) adds to the motor. The SIL logs' 10 Hz PWM cannot resolve this; they get the same values.
    """
    from pyulog import ULog

    ulog = ULog(str(path), list(ULOG_TOPICS))
    topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    start = ulog.start_timestamp
    missing = [name for name in ULOG_TOPICS[:2] if name not in topics]
    if missing:
        raise ValueError(f"{path}: no {' or '.join(missing)} topic to make the readings from")
    imu, outputs = topics["sensor_combined"], topics["actuator_outputs"]
    # one stamp for gyro and accelerometer: accelerometer_timestamp_relative is 0 in the RflyMAD logs
    t_imu, t_out = _seconds(imu, start), _seconds(outputs, start)
    time = uniform_grid(max(t_imu[0], t_out[0]), min(t_imu[-1], t_out[-1]), rate_hz)

    pwm = hold(t_out + actuator_delay, _columns(outputs, "output", n_rotors), time)
    speed_command = pwm_to_rotor_speed(pwm, pwm_range, max_rotor_speed, idle_rotor_speed)
    readings = {
        "gyro": interpolate(t_imu, _columns(imu, "gyro_rad", 3), time),
        "accel": interpolate(t_imu, _columns(imu, "accelerometer_m_s2", 3), time),
        "rotor_speed": first_order_lag(speed_command, 1.0 / rate_hz, motor_time_constant),
    }
    readings.update(_navigation(topics, start, time))
    fault_time, fault_target, effectiveness = _rfly_fault(topics.get("rfly_ctrl_lxl"), start, n_rotors)
    metadata = {"pwm_range": list(pwm_range), "max_rotor_speed": max_rotor_speed,
                "idle_rotor_speed": idle_rotor_speed, "motor_time_constant": motor_time_constant,
                "actuator_delay": actuator_delay, "actuator_rate_hz": _median_rate(t_out),
                "fault_effectiveness": effectiveness, "hardware": ulog.msg_info_dict.get("ver_hw", "")}
    return FlightLog(time, readings, PX4_QUAD_X_ORDER, fault_time, fault_target, str(path), None, metadata)


def uniform_grid(start: float, end: float, rate_hz: float) -> np.ndarray:
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz: must be a finite number > 0, got {rate_hz!r}")
    return start + np.arange(int(np.floor((end - start) * rate_hz)) + 1) / rate_hz


def interpolate(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column onto `grid` (ends held)."""
    return np.column_stack([np.interp(grid, t, column) for column in values.T])


def hold(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Zero-order hold: at each grid time the latest sample logged at or before it (the first before any)."""
    index = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    return values[index]


def pwm_to_rotor_speed(pwm, pwm_range=PWM_RANGE, max_rotor_speed: float = MAX_ROTOR_SPEED,
                       idle_rotor_speed: float = IDLE_ROTOR_SPEED) -> np.ndarray:
    """omega = idle + (max - idle) (pwm - pwm_min) / (pwm_max - pwm_min), clipped at max; 0 below pwm_min (disarmed)."""
    low, high = pwm_range
    pwm = np.asarray(pwm, dtype=float)
    throttle = np.clip((pwm - low) / (high - low), 0.0, 1.0)
    return np.where(pwm < low, 0.0, idle_rotor_speed + (max_rotor_speed - idle_rotor_speed) * throttle)


def first_order_lag(command: np.ndarray, dt: float, time_constant: float) -> np.ndarray:
    """omega' = (command - omega) / tau, exact for a command held over each step, started at rest at command[0]."""
    if time_constant <= 0:
        return np.array(command, dtype=float)
    decay = np.exp(-dt / time_constant)
    b, a = [1.0 - decay], [1.0, -decay]
    command = np.asarray(command, dtype=float)
    initial = signal.lfilter_zi(b, a)[:, None] * command[0]
    return signal.lfilter(b, a, command, axis=0, zi=initial)[0]


def _seconds(data: dict, start: int) -> np.ndarray:
    # int64 first: a few topics carry stamps from before the log's start, which wrap around in uint64.
    return (data["timestamp"].astype(np.int64) - np.int64(start)) * 1e-6


def _median_rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t)))


def _columns(data: dict, name: str, n: int) -> np.ndarray:
    return np.column_stack([data[f"{name}[{i}]"] for i in range(n)]).astype(float)


def _navigation(topics: dict, start: int, grid: np.ndarray) -> dict:
    """Attitude (PX4 stores w x y z; ours is scalar-last) and NED position/velocity, where logged."""
    out = {}
    if "vehicle_attitude" in topics:
        att = topics["vehicle_attitude"]
        q = _continuous_sign(_columns(att, "q", 4)[:, [1, 2, 3, 0]])
        q = interpolate(_seconds(att, start), q, grid)
        out["attitude"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    if "vehicle_local_position" in topics:
        pos = topics["vehicle_local_position"]
        t = _seconds(pos, start)
        out["position"] = interpolate(t, np.column_stack([pos[k] for k in ("x", "y", "z")]).astype(float), grid)
        out["velocity"] = interpolate(t, np.column_stack([pos[k] for k in ("vx", "vy", "vz")]).astype(float), grid)
    return out


def _continuous_sign(q: np.ndarray) -> np.ndarray:
    """q and -q are one rotation: flip signs so consecutive quaternions agree (safe to interpolate)."""
    flips = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
    return q * np.concatenate(([1.0], flips))[:, None]


def _rfly_fault(data: dict | None, start: int, n_rotors: int):
    """RflyMAD ground truth: the first `rfly_ctrl_lxl` sample with mode 1 gives the motors' effectiveness.

    Before that the topic holds zeros, which are not a fault. Returns (time, 0-based motor, effectiveness).
    """
    if data is None or not np.any(data["mode"] == 1):
        return None, None, None
    first = int(np.argmax(data["mode"] == 1))
    effectiveness = _columns(data, "controls", n_rotors)[first]
    faulty = np.flatnonzero(effectiveness < 1.0)
    if faulty.size == 0:
        return None, None, None
    target = int(faulty[0])
    return float(_seconds(data, start)[first]), target, float(effectiveness[target])


# ----------------------------------------------------------------------------------------- ftcgym recordings

def read_npz(path) -> FlightLog:
    """A recording written by `RecordingWrapper` (NPZ): arrays `time`, `commands`, `reading/<key>`, `metadata`."""
    with np.load(path, allow_pickle=False) as data:
        readings = {name.split("/", 1)[1]: data[name] for name in data.files if name.startswith("reading/")}
        metadata = json.loads(str(data["metadata"]))
        commands = data["commands"] if "commands" in data.files else None
        return _recorded_log(data["time"], readings, commands, metadata, path)


def read_csv(path) -> FlightLog:
    """A recording written by `RecordingWrapper` (CSV): `# metadata <json>` line, header `time,gyro[0],...`."""
    with open(path, newline="") as file:
        first = file.readline()
        if not first.startswith("# metadata "):
            raise ValueError(f"{path}: not an ftcgym recording (no '# metadata' line)")
        metadata = json.loads(first[len("# metadata "):])
        rows = list(csv.reader(file))
    header, table = rows[0], np.array(rows[1:], dtype=float).reshape(-1, len(rows[0]))
    columns = {}
    for i, name in enumerate(header):
        key = name.split("[", 1)[0]
        columns.setdefault(key, []).append(table[:, i])
    arrays = {key: np.column_stack(cols) for key, cols in columns.items()}
    time, commands = arrays.pop("time")[:, 0], arrays.pop("command", None)
    return _recorded_log(time, arrays, commands, metadata, path)


def _recorded_log(time, readings, commands, metadata: dict, path) -> FlightLog:
    return FlightLog(np.asarray(time, dtype=float), dict(readings), metadata.get("actuator_order", FTCGYM_ROTOR_ORDER),
                     metadata.get("fault_time"), metadata.get("fault_target"), str(path), commands, metadata)


def read_log(path, rate_hz: float = 250.0) -> FlightLog:
    """Any supported log by its extension: .ulg (resampled to `rate_hz`), .npz, .csv (as recorded)."""
    suffix = Path(path).suffix.lower()
    readers = {".ulg": lambda: read_ulog(path, rate_hz), ".npz": lambda: read_npz(path), ".csv": lambda: read_csv(path)}
    if suffix not in readers:
        raise ValueError(f"{path}: unknown log type {suffix!r}; accepted: .ulg, .npz, .csv")
    return readers[suffix]()
