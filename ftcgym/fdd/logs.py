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
  interpolation it never uses a command logged after the instant. Where the attitude controller's commands
  (`actuator_controls_0`) are logged faster than the PWM (RflyMAD SIL logs: 20 Hz against 10 Hz), the PWM is
  made from them by PX4's own mixer (`px4_mixer`; see `motor_commands`).
- a dead time and the motor's first-order lag (see `read_ulog`).
IMU samples are interpolated linearly onto the grid (they sample continuous signals, at about the grid's rate);
attitude, position and velocity are held (`_navigation`).

Every reader refuses what it cannot replay with one `LogError` (a ValueError) naming the file and the problem:
library failures are translated where the file is read, and `check_readings` holds the rules for the arrays.
"""
from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import struct
import zipfile
import zlib
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
               "rfly_ctrl_lxl", "actuator_controls_0")
#: the controller's commands replace the logged PWM where logged this much faster (`motor_commands`)
FASTER_COMMANDS = 1.5
ULOG_MAGIC = b"ULog\x01\x12\x35"   # first 7 bytes of every ULog; a version byte and the start time follow
ULOG_HEADER_SIZE = 16
#: readings every log must have -> their columns (None: any number, one per rotor); other keys are optional
REQUIRED_READINGS = {"gyro": 3, "accel": 3, "rotor_speed": None}
#: optional readings with a fixed width: replay reads them (take-off time) where they are logged
SHAPED_READINGS = {"attitude": 4, "position": 3, "velocity": 3}
MIN_SAMPLES = 2                    # two give the sample interval, which every detector steps with
#: s, longest gap between two samples of a ULog topic: the RflyMAD logs' slowest topics (10 Hz) leave <= 0.21 s;
#: a longer one is a dropout or a damaged stamp, over which the resampling would invent (or allocate) data
MAX_ULOG_GAP = 1.0


class LogError(ValueError):
    """A flight log that cannot be replayed: missing, unreadable, truncated, empty or inconsistent.

    The message is "<file>: <what is wrong>", naming the field, the value found and what is accepted.
    """

    def __init__(self, path, problem: str):
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem

    def __reduce__(self):  # picklable (worker processes) although __init__ takes two arguments
        return type(self), (self.path, self.problem)


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
    (USB, MAVLink) adds to the motor. The SIL logs' 10-20 Hz commands cannot resolve this; they get the same values.
    """
    ulog = _parse_ulog(path, _read_bytes(path))
    topics = {d.name: _Topic(path, d.name, d.data) for d in ulog.data_list if d.multi_id == 0}
    missing = [name for name in ULOG_TOPICS[:2] if name not in topics]
    if missing:
        raise LogError(path, f"missing topic {missing[0]!r} (replay needs {' and '.join(ULOG_TOPICS[:2])}; of "
                             f"{', '.join(ULOG_TOPICS)} the log has {', '.join(sorted(topics)) or 'none'})")
    start = ulog.start_timestamp
    imu, outputs = topics["sensor_combined"], topics["actuator_outputs"]
    # one stamp for gyro and accelerometer: accelerometer_timestamp_relative is 0 in the RflyMAD logs
    t_imu, t_out = imu.seconds(start), outputs.seconds(start)
    time = uniform_grid(max(t_imu[0], t_out[0]), min(t_imu[-1], t_out[-1]), rate_hz)
    if len(time) < MIN_SAMPLES:
        raise LogError(path, f"too few samples ({len(time)} at {rate_hz:g} Hz where sensor_combined and "
                             f"actuator_outputs overlap in time; at least {MIN_SAMPLES} needed)")

    t_pwm, pwm, commands_from = motor_commands(topics, start, n_rotors, pwm_range)
    pwm = hold(t_pwm + actuator_delay, pwm, time)
    speed_command = pwm_to_rotor_speed(pwm, pwm_range, max_rotor_speed, idle_rotor_speed)
    readings = {
        "gyro": interpolate(t_imu, imu.columns("gyro_rad", 3), time),
        "accel": interpolate(t_imu, imu.columns("accelerometer_m_s2", 3), time),
        "rotor_speed": first_order_lag(speed_command, 1.0 / rate_hz, motor_time_constant),
    }
    readings.update(_navigation(topics, start, time))
    check_readings(path, time, readings, what=lambda key: f"reading {key!r}")
    fault_time, fault_target, effectiveness = _rfly_fault(topics.get("rfly_ctrl_lxl"), start, n_rotors)
    metadata = {"pwm_range": list(pwm_range), "max_rotor_speed": max_rotor_speed,
                "idle_rotor_speed": idle_rotor_speed, "motor_time_constant": motor_time_constant,
                "actuator_delay": actuator_delay, "actuator_rate_hz": _median_rate(t_pwm),
                "motor_commands": commands_from,
                "fault_effectiveness": effectiveness, "hardware": ulog.msg_info_dict.get("ver_hw", "")}
    return FlightLog(time, readings, PX4_QUAD_X_ORDER, fault_time, fault_target, str(path), None, metadata)


def motor_commands(topics: dict, start: int, n_rotors: int, pwm_range=PWM_RANGE):
    """(times (m,), PWM (m, n_rotors), the topic it came from): the motor commands replay holds.

    `actuator_outputs`, the PWM itself, unless `actuator_controls_0` (roll, pitch, yaw, thrust) is logged
    FASTER_COMMANDS (1.5) times as fast or more and the vehicle is a quadrotor: then PX4's quad X mixer makes
    the PWM from each controls sample (`px4_mixer.mix_quad_x`), pwm_min + u (pwm_max - pwm_min), while the
    latest PWM logged at or before it is armed (>= pwm_min; otherwise that PWM, disarmed). Both topics run in
    the same cycle, so a mixed sample is no later than a logged one. The RflyMAD SIL logs keep the controls at
    20 Hz and the PWM at 10 Hz; the HIL logs both at ~255 Hz.
    """
    outputs = topics["actuator_outputs"]
    t_out, pwm = outputs.seconds(start), outputs.columns("output", n_rotors)
    controls = topics.get("actuator_controls_0")
    if (n_rotors != 4 or controls is None or "control[3]" not in controls.data
            or _median_rate(controls.seconds(start)) < FASTER_COMMANDS * _median_rate(t_out)):
        return t_out, pwm, "actuator_outputs"
    from .px4_mixer import mix_quad_x
    t_ctl = controls.seconds(start)
    low, high = pwm_range
    logged = hold(t_out, pwm, t_ctl)
    mixed = np.where(logged.min(axis=1, keepdims=True) >= low,
                     low + (high - low) * mix_quad_x(controls.columns("control", 4)), logged)
    return t_ctl, mixed, "actuator_controls_0 through PX4's quad X mixer"


def _parse_ulog(path, data: bytes):
    """pyulog's parse of `data` (the topics replay reads); a LogError for a file that is no ULog, is cut short
    or has damaged messages, which pyulog would skip (printing) rather than raise."""
    from pyulog import ULog
    from pyulog.exceptions import ULogException

    check_ulog_framing(path, data)
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter):  # pyulog prints what it skips; file_corruption flags it
            ulog = ULog(io.BytesIO(data), list(ULOG_TOPICS))
    except (ULogException, ValueError, struct.error) as error:
        raise LogError(path, f"unreadable ULog ({error})") from None
    if ulog.file_corruption:
        said = chatter.getvalue().strip().splitlines()
        raise LogError(path, f"corrupt ULog (damaged messages{': pyulog says ' + said[0] if said else ''}; "
                             f"a readable log has none)")
    return ulog


def check_ulog_framing(path, data: bytes) -> None:
    """Raise a LogError unless `data` starts with the ULog magic and its messages are whole and end the file.

    A ULog is a 16-byte header, then messages framed as (uint16 payload size, uint8 type, payload). A logger
    stopped mid-write (power loss, a copy cut short) leaves a last message that runs past the end, which pyulog
    drops silently. A frame pyulog calls damaged (type 0, size 0 or > 10000) is rejected here too: pyulog's
    recovery from one can loop forever (pyulog 1.3, in the definitions section).
    """
    if data[:len(ULOG_MAGIC)] != ULOG_MAGIC:
        if len(data) < len(ULOG_MAGIC) and ULOG_MAGIC.startswith(data):
            raise LogError(path, f"truncated ULog (the file ends at byte {len(data)}, inside the 16-byte header)")
        raise LogError(path, f"not a ULog file (bad magic: starts with {data[:len(ULOG_MAGIC)].hex(' ')}; "
                             f"a ULog starts with 'ULog' {ULOG_MAGIC[4:].hex(' ')})")
    if len(data) < ULOG_HEADER_SIZE:
        raise LogError(path, f"truncated ULog (the file ends at byte {len(data)}, inside the 16-byte header)")
    starts = _segment_starts(path, data)
    for start, end in zip(starts, starts[1:] + [len(data)]):
        _walk_frames(path, data, start, end)


def _walk_frames(path, data: bytes, position: int, end: int) -> None:
    """Frames from `position` on until `end`; only the file's last segment must end exactly at the end."""
    while position < end:
        if position + 3 > len(data):
            raise LogError(path, f"truncated ULog (data ends mid-message at byte {len(data)}: the message header "
                                 f"at byte {position} needs 3 bytes, {len(data) - position} left)")
        size, kind = struct.unpack_from("<HB", data, position)
        if kind == 0 or size == 0 or size > 10000:
            raise LogError(path, f"corrupt ULog (damaged message at byte {position}: type {kind}, size {size}; "
                                 f"a message has a type > 0 and 1-10000 bytes)")
        if position + 3 + size > len(data):
            raise LogError(path, f"truncated ULog (data ends mid-message at byte {len(data)}: the message at "
                                 f"byte {position} needs {3 + size} bytes, {len(data) - position} left)")
        position += 3 + size


def _segment_starts(path, data: bytes) -> list:
    """Where each run of messages starts: after the header, and at each appended-data offset.

    A flag-bits message ('B': 8 compat, 8 incompat flag bytes, 3 uint64 offsets) first in the file may mark data
    appended later (a crash dump); the part before such an offset may end mid-message by design.
    """
    flags = ULOG_HEADER_SIZE + 3
    if len(data) < flags + 40 or data[ULOG_HEADER_SIZE + 2] != ord("B") or not data[flags + 8] & 1:
        return [ULOG_HEADER_SIZE]
    offsets = [offset for offset in struct.unpack_from("<3Q", data, flags + 16) if offset]
    if offsets != sorted(set(offsets)) or (offsets and offsets[0] <= flags + 40):
        raise LogError(path, f"corrupt ULog (appended-data offsets {offsets}; expected increasing offsets past the "
                             f"header)")
    if offsets and offsets[-1] > len(data):
        raise LogError(path, f"truncated ULog (appended data starts at byte {offsets[-1]}, the file ends at byte "
                             f"{len(data)})")
    return [ULOG_HEADER_SIZE, *offsets]


class _Topic:
    """One ULog topic's fields, read with checks: a missing field, a non-finite value or a time that does not
    increase is a LogError naming the topic."""

    def __init__(self, path, name: str, data: dict):
        self.path, self.name, self.data = path, name, data

    def field(self, name: str) -> np.ndarray:
        if name not in self.data:
            raise LogError(self.path, f"topic {self.name!r} has no field {name!r}")
        values = np.asarray(self.data[name], dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogError(self.path, f"topic {self.name!r}: field {name!r} is {values[bad[0]]} at sample {bad[0]} "
                                      f"(readings must be finite)")
        return values

    def columns(self, name: str, n: int) -> np.ndarray:
        return np.column_stack([self.field(f"{name}[{i}]") for i in range(n)])

    def seconds(self, start: int) -> np.ndarray:
        """Stamps as s from `start`: at least MIN_SAMPLES, strictly increasing, no gap over MAX_ULOG_GAP."""
        if "timestamp" not in self.data:
            raise LogError(self.path, f"topic {self.name!r} has no field 'timestamp'")
        # int64 first: a few topics carry stamps from before the log's start, which wrap around in uint64.
        t = (self.data["timestamp"].astype(np.int64) - np.int64(start)) * 1e-6
        _check_time(self.path, t, f"topic {self.name!r}", lambda i: f"sample {i}")
        gap = int(np.argmax(np.diff(t)))
        if t[gap + 1] - t[gap] > MAX_ULOG_GAP:
            raise LogError(self.path, f"topic {self.name!r} has a {t[gap + 1] - t[gap]:.3g} s gap after sample {gap} "
                                      f"(at {t[gap]:.3f} s; at most {MAX_ULOG_GAP:g} s accepted)")
        return t


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


def _median_rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t)))


def _navigation(topics: dict, start: int, grid: np.ndarray) -> dict:
    """Attitude (PX4 stores w x y z; ours is scalar-last) and NED position/velocity, where logged, each held
    from its latest sample (zero-order hold): these are the autopilot's estimates at 10-255 Hz, and holding
    them, unlike interpolating, never reads a sample logged after the instant; a detector can tell a fresh
    sample from a held one (as `aekf` does with the env's 100 Hz position)."""
    out = {}
    if "vehicle_attitude" in topics:
        att = topics["vehicle_attitude"]
        q = hold(att.seconds(start), att.columns("q", 4)[:, [1, 2, 3, 0]], grid)
        with np.errstate(invalid="ignore", divide="ignore"):  # a zero q gives NaN, which check_readings reports
            out["attitude"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    if "vehicle_local_position" in topics:
        pos = topics["vehicle_local_position"]
        t = pos.seconds(start)
        out["position"] = hold(t, np.column_stack([pos.field(k) for k in ("x", "y", "z")]), grid)
        out["velocity"] = hold(t, np.column_stack([pos.field(k) for k in ("vx", "vy", "vz")]), grid)
    return out


def _rfly_fault(data: _Topic | None, start: int, n_rotors: int):
    """RflyMAD ground truth: the first `rfly_ctrl_lxl` sample with mode 1 gives the motors' effectiveness.

    Before that the topic holds zeros, which are not a fault. Returns (time, 0-based motor, effectiveness).
    """
    if data is None or not np.any(data.field("mode") == 1):
        return None, None, None
    first = int(np.argmax(data.field("mode") == 1))
    effectiveness = data.columns("controls", n_rotors)[first]
    faulty = np.flatnonzero(effectiveness < 1.0)
    if faulty.size == 0:
        return None, None, None
    target = int(faulty[0])
    return float(data.seconds(start)[first]), target, float(effectiveness[target])


# ----------------------------------------------------------------------------------------- ftcgym recordings

def read_npz(path) -> FlightLog:
    """A recording written by `RecordingWrapper` (NPZ): arrays `time`, `commands`, `reading/<key>`, `metadata`."""
    arrays = _npz_arrays(path, _read_bytes(path))
    for name in ("time", "metadata"):
        if name not in arrays:
            raise LogError(path, f"missing array {name!r} (a recording has time, metadata and reading/<key> arrays; "
                                 f"this one has {', '.join(sorted(arrays)) or 'none'})")
    readings = {name.split("/", 1)[1]: value for name, value in arrays.items() if name.startswith("reading/")}
    metadata = arrays["metadata"]
    if metadata.shape != () or metadata.dtype.kind != "U":
        raise LogError(path, f"array 'metadata' is {metadata.dtype} of shape {metadata.shape}; expected one JSON "
                             f"string")
    return _recorded_log(path, arrays["time"], readings, arrays.get("commands"), _metadata(path, str(metadata)),
                         what=lambda key: f"array {key!r}" if key in ("time", "commands") else f"array 'reading/{key}'",
                         where=lambda i: f"index {i}")


def _npz_arrays(path, data: bytes) -> dict:
    """Every array of an NPZ archive, loaded now, so that a damaged member fails here, as a LogError."""
    if not data.startswith(b"PK"):
        raise LogError(path, f"not an NPZ archive (starts with {data[:4].hex(' ')}; a zip archive starts with 'PK')")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError) as error:
        raise LogError(path, f"unreadable NPZ archive ({error})") from None


def read_csv(path) -> FlightLog:
    """A recording written by `RecordingWrapper` (CSV): `# metadata <json>` line, header `time,gyro[0],...`."""
    lines = _text(path, _read_bytes(path)).splitlines()
    if not lines[0].startswith("# metadata "):
        raise LogError(path, f"not an ftcgym recording (line 1 is {lines[0][:40]!r}, a recording's is "
                             f"'# metadata {{...}}')")
    metadata = _metadata(path, lines[0][len("# metadata "):])
    try:
        rows = list(csv.reader(lines[1:]))
    except csv.Error as error:
        raise LogError(path, f"unreadable CSV ({error})") from None
    if not rows or not rows[0]:
        raise LogError(path, "no header on line 2 (a recording's is time,gyro[0],...)")
    readings = _csv_columns(path, rows[0], _csv_table(path, rows[0], rows[1:]))
    time, commands = readings.pop("time", None), readings.pop("command", None)
    return _recorded_log(path, time, readings, commands, metadata,
                         what=lambda key: f"column {key!r}", where=lambda i: f"line {i + 3}")


def _csv_table(path, header: list, rows: list) -> np.ndarray:
    """(N, len(header)) numbers; a LogError naming the line and column of the first field that is not one."""
    for number, row in enumerate(rows, start=3):
        if len(row) != len(header):
            raise LogError(path, f"line {number} has {len(row)} fields, the header has {len(header)} (every line "
                                 f"has as many)")
    try:
        return np.array(rows, dtype=float).reshape(len(rows), len(header))
    except ValueError as error:
        numpy_says = str(error)
    for number, row in enumerate(rows, start=3):  # only after a failure: find the field to name
        for name, text in zip(header, row):
            try:
                float(text)
            except ValueError:
                raise LogError(path, f"line {number}, column {name!r}: {text[:40]!r} is not a number "
                                     f"(every field of a data line is one)") from None
    raise LogError(path, f"a field is not a number ({numpy_says})")


def _csv_columns(path, header: list, table: np.ndarray) -> dict:
    """Columns grouped by key: `key` alone or `key[0]`, `key[1]`, ... in order, each name once -> (N, k) arrays."""
    groups = {}
    for i, name in enumerate(header):
        key = name.split("[", 1)[0]
        expected = f"{key}[{len(groups.get(key, []))}]"
        if name not in (key, expected) or (name == key and key in groups):
            raise LogError(path, f"header column {i + 1} is {name!r}; expected {expected!r} (a key's columns are "
                                 f"numbered from 0, in order, each once)")
        groups.setdefault(key, []).append(i)
    arrays = {key: table[:, index] for key, index in groups.items()}
    if "time" in arrays and arrays["time"].shape[1] == 1:  # one value per sample; more is refused later
        arrays["time"] = arrays["time"][:, 0]
    return arrays


def _text(path, data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise LogError(path, f"not a text file (byte {data[error.start]:#04x} at offset {error.start} is not "
                             f"UTF-8; a CSV recording is UTF-8 text)") from None


def _metadata(path, text: str) -> dict:
    """The recording's metadata: a JSON object whose keys replay reads have the types it needs."""
    try:
        metadata = json.loads(text)
    except json.JSONDecodeError as error:
        raise LogError(path, f"metadata is not valid JSON ({error.msg} at character {error.pos})") from None
    if not isinstance(metadata, dict):
        raise LogError(path, f"metadata must be a JSON object, got {type(metadata).__name__}")
    for key, accepted, ok in _METADATA_RULES:
        if key in metadata and not ok(metadata[key]):
            raise LogError(path, f"metadata {key!r} is {metadata[key]!r}; expected {accepted}")
    return metadata


def _is_number(value) -> bool:
    """A finite JSON number (an int of any size, a float other than NaN and infinity; not a bool)."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int) or (isinstance(value, float) and math.isfinite(value))


_METADATA_RULES = (   # key, what is accepted, test
    ("actuator_order", "a string", lambda v: isinstance(v, str)),
    ("fault_time", "a finite number or null", lambda v: v is None or _is_number(v)),
    ("fault_target", "a rotor index >= 0 or null", lambda v: v is None or (_is_number(v) and v == int(v) >= 0)),
    ("effectiveness_G", "3 finite numbers", lambda v: isinstance(v, list) and len(v) == 3 and all(map(_is_number, v))),
)


def _recorded_log(path, time, readings: dict, commands, metadata: dict, what, where) -> FlightLog:
    check_readings(path, time, readings, commands, what, where)
    target = metadata.get("fault_target")
    return FlightLog(np.asarray(time, dtype=float), {key: np.asarray(v, dtype=float) for key, v in readings.items()},
                     metadata.get("actuator_order", FTCGYM_ROTOR_ORDER), metadata.get("fault_time"),
                     None if target is None else int(target), str(path),
                     None if commands is None else np.asarray(commands, dtype=float), metadata)


# ----------------------------------------------------------------------------------------- checks

def check_readings(path, time, readings: dict, commands=None, what=repr, where=lambda i: f"sample {i}") -> None:
    """Raise a LogError unless the arrays make a replayable log. The rules:

    - `time`: 1-D, numeric, finite, strictly increasing, at least MIN_SAMPLES long;
    - `readings`: the REQUIRED_READINGS present; each numeric, finite, one row per sample, and of the width
      REQUIRED_READINGS / SHAPED_READINGS give (any width for other keys);
    - `commands` (optional): one row per sample, each row all finite, or all NaN (no command was sent).

    `what(key)` and `where(index)` name a field and a sample as the file does (a column and a line of a CSV).
    """
    if time is None:
        raise LogError(path, f"missing {what('time')} (a recording needs time, {', '.join(REQUIRED_READINGS)})")
    time = _numeric(path, time, what("time"))
    if time.ndim != 1:
        raise LogError(path, f"{what('time')} has shape {time.shape}; expected one value per sample")
    _check_time(path, time, what("time"), where)
    for key in REQUIRED_READINGS:
        if key not in readings:
            raise LogError(path, f"missing {what(key)} (a recording needs time, {', '.join(REQUIRED_READINGS)})")
    for key, value in readings.items():
        width = REQUIRED_READINGS.get(key, SHAPED_READINGS.get(key))
        _check_block(path, _numeric(path, value, what(key)), len(time), width, what(key), where)
    if commands is not None:
        _check_commands(path, _numeric(path, commands, what("commands")), len(time), what("commands"))


def _check_time(path, time: np.ndarray, name: str, where) -> None:
    if len(time) < MIN_SAMPLES:
        raise LogError(path, f"too few samples ({len(time)} in {name}; at least {MIN_SAMPLES} needed)")
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise LogError(path, f"non-finite time at {where(bad[0])} ({name}: {time[bad[0]]}; times must be finite)")
    back = np.flatnonzero(np.diff(time) <= 0)
    if back.size:
        i = back[0] + 1
        raise LogError(path, f"time is not increasing at {where(i)} ({name}: {float(time[i])!r} after "
                             f"{float(time[i - 1])!r}; times must strictly increase)")


def _check_block(path, value: np.ndarray, n: int, width, name: str, where) -> None:
    """(n,) or (n, width) values, all finite."""
    columns = 1 if value.ndim == 1 else int(np.prod(value.shape[1:]))
    if value.ndim == 0 or len(value) != n or (width is not None and (value.ndim != 2 or columns != width)):
        expected = f"({n}, {width})" if width is not None else f"{n} rows"
        raise LogError(path, f"{name} has shape {value.shape}; expected {expected} (one row per time sample)")
    bad = np.argwhere(~np.isfinite(value.reshape(n, -1)))
    if len(bad):
        row, column = bad[0]
        raise LogError(path, f"non-finite value {value.reshape(n, -1)[row, column]} in {name} at {where(row)}, "
                             f"component {column} (readings must be finite numbers)")


def _check_commands(path, commands: np.ndarray, n: int, name: str) -> None:
    if commands.ndim != 2 or len(commands) != n:
        raise LogError(path, f"{name} has shape {commands.shape}; expected ({n}, m): one row per time sample")
    finite = np.isfinite(commands)
    mixed = np.flatnonzero(~(finite.all(axis=1) | np.isnan(commands).all(axis=1)))
    if mixed.size:
        raise LogError(path, f"{name} row {mixed[0]} is {commands[mixed[0]].tolist()}; a row is all finite, or all "
                             f"NaN where no command was sent")


def _numeric(path, value, name: str) -> np.ndarray:
    value = np.asarray(value)
    if value.dtype.kind not in "biuf":
        raise LogError(path, f"{name} holds {value.dtype} values; expected numbers")
    return value.astype(float)


# ----------------------------------------------------------------------------------------- any log

def _read_bytes(path) -> bytes:
    """The whole file; a LogError for one that is missing, a directory, unreadable or empty."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise LogError(path, "no such file") from None
    except IsADirectoryError:
        raise LogError(path, "is a directory; expected a log file (.ulg, .npz, .csv)") from None
    except OSError as error:
        raise LogError(path, f"cannot read the file ({error.strerror or error})") from None
    if not data:
        raise LogError(path, "empty file (0 bytes)")
    return data


def read_log(path, rate_hz: float = 250.0) -> FlightLog:
    """Any supported log by its extension: .ulg (resampled to `rate_hz`), .npz, .csv (as recorded).

    Raises LogError (a ValueError) naming the file and the problem for anything it cannot replay.
    """
    if Path(path).is_dir():
        raise LogError(path, "is a directory; expected a log file (.ulg, .npz, .csv)")
    suffix = Path(path).suffix.lower()
    readers = {".ulg": lambda: read_ulog(path, rate_hz), ".npz": lambda: read_npz(path), ".csv": lambda: read_csv(path)}
    if suffix not in readers:
        raise LogError(path, f"unknown log type {suffix or '(no extension)'!r}; accepted: .ulg, .npz, .csv")
    return readers[suffix]()
