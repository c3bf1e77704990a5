"""Log readers, effectiveness identification, recording and replay, against numbers.

RflyMAD ground truth (data/README.md): motor 1 (output 0) fails at 33.06 s in TestCase_1_1000000000 (SIL)
and at 19.16 s in TestCase_2_2000000001 (HIL).
"""
import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401  (registers the env ids)
from ftcgym.agents import make_policy
from ftcgym.fdd.loe_kalman import loe_kalman_wrapper
from ftcgym.fdd.logs import (
    FTCGYM_ROTOR_ORDER,
    PX4_QUAD_X_ORDER,
    FlightLog,
    first_order_lag,
    hold,
    pwm_to_rotor_speed,
    read_csv,
    read_npz,
)
from ftcgym.fdd.recording import RecordingWrapper
from ftcgym.fdd.replay import ROTOR_SIGNS, identify_effectiveness, make_detector, replay

REPO = Path(__file__).resolve().parents[1]
RFLYMAD = next((p for p in (REPO / "shared", REPO.parent / "shared") if (p / "data" / "rflymad").is_dir()),
               REPO / "shared") / "data" / "rflymad"
SIL, HIL = "TestCase_1_1000000000.ulg", "TestCase_2_2000000001.ulg"
README_FAULT_TIMES = {SIL: 33.06, HIL: 19.16}
needs_rflymad = pytest.mark.skipif(not (RFLYMAD / SIL).exists(), reason="RflyMAD logs not available")


@pytest.fixture(scope="module")
def ulogs():
    pytest.importorskip("pyulog")
    from ftcgym.fdd.logs import read_ulog
    return {name: read_ulog(RFLYMAD / name) for name in (SIL, HIL)}


# ----------------------------------------------------------------------------------------- ULog reading

@needs_rflymad
@pytest.mark.parametrize("name", [SIL, HIL])
def test_ulog_fault_time_and_target_match_the_ground_truth_table(ulogs, name):
    log = ulogs[name]
    assert log.fault_time == pytest.approx(README_FAULT_TIMES[name], abs=0.05)
    assert log.fault_target == 0
    assert log.actuator_order == PX4_QUAD_X_ORDER


@needs_rflymad
@pytest.mark.parametrize("name, duration", [(SIL, 36.1), (HIL, 22.3)])
def test_ulog_is_resampled_to_a_uniform_250_hz_grid(ulogs, name, duration):
    log = ulogs[name]
    n = len(log)
    assert np.allclose(np.diff(log.time), 0.004, atol=1e-9)
    assert n == pytest.approx(duration * 250, rel=0.01)
    assert log.readings["gyro"].shape == (n, 3)
    assert log.readings["accel"].shape == (n, 3)
    assert log.readings["rotor_speed"].shape == (n, 4)
    assert log.readings["attitude"].shape == (n, 4)
    assert np.allclose(np.linalg.norm(log.readings["attitude"], axis=1), 1.0)
    # hovering before the fault: specific force ~ -g along body z, rotors near their common hover speed
    hover = (log.time > log.fault_time - 3) & (log.time < log.fault_time - 1)
    assert log.readings["accel"][hover, 2].mean() == pytest.approx(-9.8, abs=0.1)
    speeds = log.readings["rotor_speed"][hover]
    assert speeds.mean() == pytest.approx(150 + 850 * 0.265, rel=0.02)  # PWM ~1265 us
    assert np.ptp(speeds.mean(axis=0)) < 5.0


def test_pwm_maps_linearly_from_idle_to_full_speed_and_disarmed_is_stopped():
    pwm = np.array([900.0, 1000.0, 1500.0, 2000.0, 2100.0])
    expected = [0.0, 150.0, 150.0 + 0.5 * 850.0, 1000.0, 1000.0]
    assert pwm_to_rotor_speed(pwm, (1000, 2000), 1000.0, 150.0) == pytest.approx(expected)


def test_motor_lag_reaches_63_percent_of_a_step_after_one_time_constant():
    dt, tau = 0.001, 0.02
    command = np.r_[np.zeros(10), np.ones(200)]
    speed = first_order_lag(command[:, None], dt, tau)[:, 0]
    assert speed[9] == 0.0
    assert speed[9 + 20] == pytest.approx(1 - np.exp(-1), abs=1e-9)
    assert first_order_lag(command[:, None], dt, 0.0)[:, 0] == pytest.approx(command)


def test_hold_uses_only_samples_logged_at_or_before_each_instant():
    t = np.array([0.0, 0.1, 0.2])
    values = np.array([[1.0], [2.0], [3.0]])
    assert hold(t, values, np.array([0.0, 0.05, 0.1, 0.199, 0.3]))[:, 0] == pytest.approx([1, 1, 2, 2, 3])


# ----------------------------------------------------------------------------------------- identification

def synthetic_log(B, bias, seconds=20.0, rate=250.0, seed=0) -> FlightLog:
    """Rotors swept slowly around hover; p, q integrate B omega^2 + bias exactly (so their backward
    difference gives it back), a_z = B omega^2 + bias plus a little sensor noise."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    time = np.arange(int(seconds * rate)) * dt
    frequencies = rng.uniform(0.2, 1.5, (3, 4))
    phases = rng.uniform(0, 2 * np.pi, (3, 4))
    omega = 500.0 * (1 + 0.08 * np.sin(2 * np.pi * frequencies[None] * time[:, None, None] + phases).sum(axis=1))
    z = omega ** 2 @ B.T + bias
    gyro = np.zeros((len(time), 3))
    gyro[:, :2] = np.cumsum(z[:, :2], axis=0) * dt
    accel = np.zeros((len(time), 3))
    accel[:, 2] = z[:, 2] + rng.normal(0, 0.02, len(time))
    return FlightLog(time, {"gyro": gyro, "accel": accel, "rotor_speed": omega}, "test rotors")


def test_identified_effectiveness_recovers_a_known_matrix_to_one_percent():
    B = np.array([[-210e-6, 190e-6, 230e-6, -205e-6],
                  [220e-6, -200e-6, 215e-6, -225e-6],
                  [-17e-6, -16e-6, -18e-6, -17.5e-6]])
    bias = np.array([0.3, -0.2, 0.4])
    log = synthetic_log(B, bias)
    B_hat, bias_hat = identify_effectiveness(log, 2.0, 20.0)
    assert np.allclose(B_hat, B, rtol=0.01, atol=0)
    assert bias_hat == pytest.approx(bias, abs=0.05)


def test_identification_with_known_signs_fits_one_gain_per_axis():
    signs = ROTOR_SIGNS[PX4_QUAD_X_ORDER]
    gains = np.array([200e-6, 230e-6, 17e-6])
    log = synthetic_log(gains[:, None] * signs, np.zeros(3), seed=1)
    B_hat, bias_hat = identify_effectiveness(log, 2.0, 20.0, signs=signs, bias=False)
    assert np.allclose(B_hat, gains[:, None] * signs, rtol=0.01, atol=0)
    assert bias_hat == pytest.approx(np.zeros(3))


def test_identification_uses_only_the_window_it_is_given():
    B = 1e-4 * np.array([[-2.0, 2, 2, -2], [2, -2, 2, -2], [-0.2, -0.2, -0.2, -0.2]])
    log = synthetic_log(B, np.zeros(3))
    log.readings["accel"][log.time > 15.0, 2] *= 0.5  # a "fault" after 15 s
    B_before, _ = identify_effectiveness(log, 1.0, 14.0)
    assert np.allclose(B_before[2], B[2], rtol=0.01)


# ----------------------------------------------------------------------------------------- replay

class ToggleDetector:
    """Stub: alarm (isolating rotor 1) inside the given time windows, nothing else."""

    name = "toggle"
    output_fields = {"level": (0.0, 1.0, (1,))}

    def __init__(self, windows):
        self.windows = windows
        self.reset()

    def reset(self):
        self.alarm, self.updates = False, 0

    def update(self, readings, time, command=None):
        self.updates += 1
        self.alarm = any(start <= time < end for start, end in self.windows)

    def outputs(self):
        return {"level": np.array([float(self.alarm)])}

    def status(self):
        return {"alarm": self.alarm, "alarm_time": None, "isolated": 1 if self.alarm else None}


def test_replay_reports_every_rising_edge_of_the_alarm_in_log_time():
    time = 5.0 + np.arange(100) * 0.01
    log = FlightLog(time, {"gyro": np.zeros((100, 3))}, FTCGYM_ROTOR_ORDER)
    detector = ToggleDetector([(5.2, 5.3), (5.505, 5.6)])
    result = replay(log, detector)
    assert detector.updates == 100
    assert result == {"detector": "toggle", "alarms": [{"time": pytest.approx(5.2), "target": 1, "rotor": 1},
                                                       {"time": pytest.approx(5.51), "target": 1, "rotor": 1}],
                      "final_estimate": [0.0]}


@needs_rflymad
@pytest.mark.parametrize("name", [SIL, HIL])
def test_loe_kalman_on_rflymad_alarms_on_motor_0_soon_after_the_fault_and_never_before(ulogs, name):
    log = ulogs[name]
    result = replay(log, make_detector("loe_kalman", log))
    assert len(result["alarms"]) == 1
    alarm = result["alarms"][0]
    assert alarm["target"] == 0
    assert 0.0 <= alarm["time"] - log.fault_time <= 0.15


# ----------------------------------------------------------------------------------------- recordings

def fly_recorded(path, seed=3):
    """A hover with rotor 2 lost at 1 s, watched online by loe_kalman and recorded to `path`."""
    env = gym.make("ftcgym/Quadrotor-v0", faults=[{"kind": "rotor_loss", "target": 2, "time": 1.0}],
                   max_episode_seconds=1.5)
    env = RecordingWrapper(loe_kalman_wrapper(env), path)
    obs, info = env.reset(seed=seed)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    steps = 0
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs, info))
        steps += 1
        if terminated or truncated:
            env.close()
            return info, steps


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "flight.npz"
    info, steps = fly_recorded(path)
    return path, info, steps


def test_recording_holds_every_sample_and_the_fault_ground_truth(recording):
    path, info, steps = recording
    log = read_npz(path)
    assert len(log) == steps + 1                     # the reset observation and every step's
    assert log.time[0] == 0.0 and log.time[-1] == pytest.approx(info["time"])
    assert log.dt == pytest.approx(1 / 500)
    assert (log.fault_time, log.fault_target) == (1.0, 2)
    assert log.actuator_order == FTCGYM_ROTOR_ORDER
    assert log.readings["rotor_speed"].shape == (steps + 1, 4)
    assert not any(key.startswith(("fdd/", "reference_")) for key in log.readings)
    assert np.isnan(log.commands[0]).all() and np.isfinite(log.commands[1:]).all()


def test_replay_of_a_recording_gives_the_online_alarm(recording):
    path, info, _ = recording
    online = info["fdd"]["loe_kalman"]
    assert online["alarm"] and online["isolated"] == 2
    log = read_npz(path)
    result = replay(log, make_detector("loe_kalman", log))
    assert result["alarms"] == [{"time": pytest.approx(online["alarm_time"], abs=log.dt), "target": 2, "rotor": 2}]
    assert result["final_estimate"] == pytest.approx(online["k_hat"])


def test_csv_recording_reads_back_the_same_samples(recording, tmp_path):
    path, _, _ = recording
    fly_recorded(tmp_path / "flight.csv")
    from_npz, from_csv = read_npz(path), read_csv(tmp_path / "flight.csv")
    assert np.array_equal(from_csv.time, from_npz.time)
    for key, value in from_npz.readings.items():
        assert np.array_equal(from_csv.readings[key], value), key
    assert (from_csv.fault_time, from_csv.fault_target) == (1.0, 2)
    results = [replay(log, make_detector("loe_kalman", log)) for log in (from_csv, from_npz)]
    assert results[0] == results[1]


def test_recording_path_rejects_unknown_formats():
    with pytest.raises(ValueError, match=r"\.npz or \.csv"):
        RecordingWrapper(gym.make("ftcgym/Quadrotor-v0"), "flight.txt")


# ----------------------------------------------------------------------------------------- command line

def run_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ftcgym.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=120)


def test_cli_json_is_exactly_one_object_with_the_replay_fields(recording):
    path, info, _ = recording
    done = run_cli("replay", path, "--detector", "loe_kalman", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert set(result) == {"detector", "alarms", "final_estimate"}
    assert result["detector"] == "loe_kalman"
    assert [set(alarm) for alarm in result["alarms"]] == [{"time", "target", "rotor"}]
    assert result["alarms"][0]["rotor"] == result["alarms"][0]["target"]       # an ftcgym recording: same order
    assert result["alarms"][0]["time"] == pytest.approx(info["fdd"]["loe_kalman"]["alarm_time"])
    assert len(result["final_estimate"]) == 4


@needs_rflymad
def test_cli_replays_a_ulog(ulogs):
    pytest.importorskip("pyulog")
    done = run_cli("replay", RFLYMAD / HIL, "--detector", "loe_kalman", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["alarms"][0]["target"] == 0
    assert result["alarms"][0]["rotor"] == 1          # PX4 output 0 is the front-right rotor, ftcgym index 1
    assert 0.0 <= result["alarms"][0]["time"] - ulogs[HIL].fault_time <= 0.15


def test_cli_table_and_errors(recording, capsys):
    from ftcgym.cli import main
    path, _, _ = recording
    assert main(["replay", str(path), "--detector", "loe_kalman"]) == 0
    table = capsys.readouterr().out
    assert "alarm time" in table and "logged fault: rotor 2 at 1.000 s" in table
    assert main(["replay", "no_such_log.ulg", "--detector", "loe_kalman"]) == 2
    missing = capsys.readouterr()
    assert missing.out == "" and "no_such_log.ulg" in missing.err
    assert main(["replay", str(path), "--detector", "nope"]) == 2
    assert "cannot replay a log; replay sets up: loe_kalman" in capsys.readouterr().err
