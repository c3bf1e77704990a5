"""Log readers, effectiveness identification, recording and replay, against numbers.

RflyMAD ground truth (data/README.md): motor 1 (output 0) fails at 33.06 s in TestCase_1_1000000000 (SIL)
and at 19.16 s in TestCase_2_2000000001 (HIL).
"""
import json
import os
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
    LogError,
    first_order_lag,
    hold,
    pwm_to_rotor_speed,
    read_csv,
    read_log,
    read_npz,
)
from ftcgym.fdd.px4_mixer import mix_quad_x
from ftcgym.fdd.recording import RecordingWrapper, _write_csv, _write_npz
from ftcgym.fdd.replay import (
    CANNOT_REPLAY,
    IDENTIFICATION_RULE,
    REPLAYABLE,
    ROTOR_SIGNS,
    aekf_model,
    effectiveness_for_detector,
    identification,
    identification_window,
    identify_effectiveness,
    make_detector,
    replay,
)

REPO = Path(__file__).resolve().parents[1]
RFLYMAD = Path(os.environ.get("FTCGYM_RFLYMAD") or REPO / "data" / "rflymad")   # docs/howto/replay.md
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
    assert result == {"detector": "toggle", "identification": None,
                      "alarms": [{"time": pytest.approx(5.2), "target": 1, "rotor": 1,
                                  "isolated_time": pytest.approx(5.2)},
                                 {"time": pytest.approx(5.51), "target": 1, "rotor": 1,
                                  "isolated_time": pytest.approx(5.51)}],
                      "estimate_at_alarm": [1.0], "final_estimate": [0.0], "logged_fault": None}


def test_replay_reports_the_estimate_at_the_first_alarm_and_passes_the_window_and_ground_truth_through():
    time = np.arange(100) * 0.01
    log = FlightLog(time, {"gyro": np.zeros((100, 3))}, FTCGYM_ROTOR_ORDER, fault_time=0.5, fault_target=1)
    window = {"start": 0.1, "end": 0.3, "rule": "given (--identify)"}
    result = replay(log, ToggleDetector([]), window)
    assert (result["alarms"], result["estimate_at_alarm"]) == ([], None)
    assert result["identification"] == window and result["logged_fault"] == {"time": 0.5, "target": 1}


ALL_RFLYMAD = sorted(p.name for p in RFLYMAD.glob("TestCase_*.ulg"))


@needs_rflymad
@pytest.mark.parametrize("name", ALL_RFLYMAD)
def test_loe_kalman_on_every_rflymad_log_alarms_on_motor_0_within_100_ms_and_never_before(name):
    pytest.importorskip("pyulog")
    log = read_log(RFLYMAD / name)
    plan = identification(log)
    result = replay(log, make_detector("loe_kalman", log), plan)
    assert plan["end"] < log.fault_time
    assert [alarm["target"] for alarm in result["alarms"]] == [0]
    assert 0.0 <= result["alarms"][0]["time"] - log.fault_time <= 0.1


@needs_rflymad
@pytest.mark.parametrize("name, isolated", [(SIL, False), (HIL, True)])
def test_aekf_on_rflymad_alarms_at_the_fault_and_isolates_motor_0_where_attitude_is_logged_fast(ulogs, name,
                                                                                               isolated):
    log = ulogs[name]
    result = replay(log, make_detector("aekf", log), identification(log))
    assert len(result["alarms"]) == 1
    alarm = result["alarms"][0]
    # the flag is logged at 10 Hz: the fault starts within 0.1 s before it (the previous sample says no fault)
    assert -0.1 <= alarm["time"] - log.fault_time <= 0.1
    assert alarm["target"] == (0 if isolated else None)     # SIL: attitude at 20 Hz, LOE still < 0.1 at the alarm


@needs_rflymad
def test_aekf_model_identified_from_a_log_reproduces_its_gains(ulogs):
    log = ulogs[HIL]
    window = identification_window(log)
    B = np.abs(effectiveness_for_detector(log, window))
    model = aekf_model(log, window)
    c_T, (I_x, I_y, _) = model.thrust_coefficient, model.inertia
    assert c_T / model.mass == pytest.approx(B[2].mean())
    assert (c_T * 1.0 / I_x, c_T * 1.0 / I_y) == pytest.approx((B[0].mean(), B[1].mean()))
    assert model.rotor_positions[0][:2] == (1.0, 1.0)          # PX4 output 0: front-right
    named = aekf_model(log, window, "bebop2")
    assert (named.mass, named.inertia) == (0.374, (1.448e-3, 1.255e-3, 2.520e-3))
    assert named.thrust_coefficient / named.mass == pytest.approx(B[2].mean())
    assert named.torque_coefficient / named.thrust_coefficient == pytest.approx(1.9203e-8 / 1.9035e-6)


@needs_rflymad
def test_sil_commands_come_from_the_faster_controls_through_px4s_mixer(ulogs):
    assert ulogs[SIL].metadata["motor_commands"].startswith("actuator_controls_0")
    assert ulogs[SIL].metadata["actuator_rate_hz"] == pytest.approx(20.0, rel=0.05)
    assert ulogs[HIL].metadata["motor_commands"] == "actuator_outputs"     # both ~255 Hz: the PWM itself
    assert ulogs[HIL].metadata["actuator_rate_hz"] > 200


@needs_rflymad
def test_px4_mixer_reproduces_the_logged_pwm_of_a_sil_flight():
    from pyulog import ULog
    ulog = ULog(str(RFLYMAD / SIL), ["actuator_outputs", "actuator_controls_0"])
    data = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    outputs, controls = data["actuator_outputs"], data["actuator_controls_0"]
    same = np.searchsorted(controls["timestamp"], outputs["timestamp"])      # logged in the same cycle
    assert np.array_equal(controls["timestamp"][same], outputs["timestamp"])
    pwm = np.column_stack([outputs[f"output[{i}]"] for i in range(4)])
    mixed = 1000 + 1000 * mix_quad_x(np.column_stack([controls[f"control[{i}]"][same] for i in range(4)]))
    armed_before_fault = (pwm.min(axis=1) >= 1000) & ((outputs["timestamp"] - ulog.start_timestamp) * 1e-6 < 33.0)
    assert armed_before_fault.sum() > 150
    assert np.abs(mixed - pwm)[armed_before_fault].max() <= 2.0      # us


def test_px4_mixer_desaturates_along_roll_then_adds_yaw():
    # roll and pitch drive output 1 below 0: roll is cut until it is 0, then yaw is added (worked by hand)
    outputs = mix_quad_x([[-0.287, 0.294, 0.018, 0.303]])[0]
    assert outputs == pytest.approx([0.624, 0.018, 0.397779, 0.172221], abs=2e-6)
    assert mix_quad_x([[0.0, 0.0, 0.0, 0.4]])[0] == pytest.approx([0.4] * 4)
    assert mix_quad_x([[0.0, 0.0, 0.0, 1.3]])[0] == pytest.approx([1.0] * 4)   # thrust reduced to fit


# ----------------------------------------------------------------------------------------- identification window

def flight(wobble=(3.0, 9.0), seconds=30.0, rate=100.0, seed=0) -> FlightLog:
    """A PX4-order quad: on the ground to 2 s, climbs 1 m/s to 10 m, then hovers. Inside `wobble` its rates
    oscillate at 0.6 rad/s (> 20 deg/s: not steady); otherwise small noise, a_z = -g."""
    rng = np.random.default_rng(seed)
    time = np.arange(int(seconds * rate)) / rate
    n = len(time)
    z = -np.clip(time - 2.0, 0.0, 10.0)
    gyro = rng.normal(0.0, 0.01, (n, 3))
    shaking = (time >= wobble[0]) & (time < wobble[1])
    gyro[shaking, 0] += 0.6 * np.sin(2 * np.pi * 0.5 * time[shaking]) + 0.6 * np.sign(np.sin(2 * np.pi * 0.5 *
                                                                                               time[shaking]))
    accel = np.column_stack([np.zeros(n), np.zeros(n), -9.81 + rng.normal(0.0, 0.05, n)])
    position = np.column_stack([np.zeros(n), np.zeros(n), z])
    readings = {"gyro": gyro, "accel": accel, "rotor_speed": np.full((n, 4), 400.0), "position": position}
    return FlightLog(time, readings, PX4_QUAD_X_ORDER, source="flight")


def test_the_window_is_the_first_5_s_of_steady_flight_from_3_s_after_take_off():
    # take-off (1 m up) at 3 s, settled from 6 s; the rates wobble until 9 s: the window is in the hover after
    start, end = identification_window(flight())
    assert start == pytest.approx(9.0) and end == pytest.approx(14.0, abs=0.011)
    # no wobble: from take-off + 3 s, in the climb (steady: unaccelerated)
    assert identification_window(flight(wobble=(0.0, 0.0))) == pytest.approx((6.0, 11.0), abs=0.011)


def test_the_window_never_reads_the_logged_fault():
    log = flight()
    before = identification_window(log)
    log.fault_time, log.fault_target = 10.0, 0      # even a fault inside the window: the log alone decides
    assert identification_window(log) == before
    assert identification(log) == {"start": before[0], "end": before[1], "rule": IDENTIFICATION_RULE}


def test_a_flight_that_never_settles_or_never_climbs_has_no_window():
    with pytest.raises(LogError, match=r"flight: the flight never settles: no 5 s of steady flight .* --identify"):
        identification_window(flight(wobble=(0.0, 30.0)))
    grounded = flight()
    grounded.readings["position"][:] = 0.0
    with pytest.raises(LogError, match="never climbs 1.0 m"):
        identification_window(grounded)


def test_a_given_window_is_checked_against_the_log():
    log = flight()
    assert identification(log, (12.0, 20.0)) == {"start": 12.0, "end": 20.0, "rule": "given (--identify)"}
    with pytest.raises(LogError, match=r"identification window 25:40 s is outside the log \(0.00-29.99 s\)"):
        identification(log, (25.0, 40.0))
    with pytest.raises(LogError, match="START < END"):
        identification(log, (5.0, 5.0))


def test_an_ftcgym_recording_is_not_identified_unless_a_window_is_given():
    log = flight()
    log.actuator_order = FTCGYM_ROTOR_ORDER
    assert identification(log) is None
    assert identification(log, (6.0, 11.0))["rule"] == "given (--identify)"


@pytest.mark.parametrize("text", ["3:8", "0:0.5", " 1.5 : 2"])
def test_identify_option_parses_start_end(text):
    from ftcgym.cli import build_parser
    args = build_parser().parse_args(["replay", "log.ulg", "--detector", "loe_kalman", "--identify", text])
    assert args.identify == tuple(float(t) for t in text.split(":"))


@pytest.mark.parametrize("text", ["8:3", "3:3", "-1:2", "3", "3:4:5", "a:b", "nan:4", "1:inf", ""])
def test_identify_option_refuses_what_is_not_a_window(text, capsys):
    from ftcgym.cli import build_parser
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["replay", "log.ulg", "--detector", "loe_kalman", f"--identify={text}"])
    assert exit_.value.code == 2
    assert "--identify: expected START:END in seconds" in capsys.readouterr().err


def test_cli_exits_2_with_one_line_for_a_flight_without_a_window(tmp_path, capsys):
    from ftcgym.fdd.logs import read_npz
    path = tmp_path / "shaky.npz"
    log = flight(wobble=(0.0, 30.0))
    _write_npz(path, log.time, log.readings, np.full((len(log), 4), np.nan), {"actuator_order": PX4_QUAD_X_ORDER})
    assert read_npz(path).actuator_order == PX4_QUAD_X_ORDER
    status, lines = replay_in_process(path, capsys)
    assert status == 2 and len(lines) == 1 and lines[0].startswith(f"ftcgym replay: {path}: the flight never settles")
    from ftcgym.cli import main
    assert main(["replay", str(path), "--detector", "loe_kalman", "--identify", "40:50"]) == 2
    assert "identification window 40:50 s is outside the log" in capsys.readouterr().err
    assert main(["replay", str(path), "--detector", "loe_kalman", "--identify", "3:8", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["identification"] == {"start": 3.0, "end": 8.0, "rule": "given (--identify)"}


def test_every_registered_detector_replays_or_says_why_not():
    from ftcgym.fdd import DETECTORS
    assert set(DETECTORS.builtins) == set(REPLAYABLE) | set(CANNOT_REPLAY)
    assert not set(REPLAYABLE) & set(CANNOT_REPLAY)


@pytest.mark.parametrize("name", sorted(CANNOT_REPLAY))
def test_a_detector_that_cannot_replay_exits_2_saying_why_in_one_line(name, tmp_path, capsys):
    from ftcgym.cli import main
    assert main(["replay", str(tmp_path / "never-read.ulg"), "--detector", name]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"ftcgym replay: detector {name!r} cannot replay a log: {CANNOT_REPLAY[name]}; replay "
                          f"sets up: loe_kalman, aekf")


def test_only_aekf_reads_a_vehicle_and_an_unknown_one_is_named(recording, capsys):
    from ftcgym.cli import main
    assert main(["replay", str(recording[0]), "--detector", "loe_kalman", "--vehicle", "bebop2"]) == 2
    assert capsys.readouterr().err == ("ftcgym replay: vehicle 'bebop2': only aekf reads a vehicle; loe_kalman "
                                       "identifies its model from the log (leave --vehicle out)\n")
    assert main(["replay", str(recording[0]), "--detector", "aekf", "--vehicle", "nope"]) == 2
    assert capsys.readouterr().err.endswith("vehicle: unknown name 'nope'; accepted: bebop2, mueller2014\n")


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
    at = pytest.approx(online["alarm_time"], abs=log.dt)
    assert result["alarms"] == [{"time": at, "target": 2, "rotor": 2, "isolated_time": at}]
    assert result["final_estimate"] == pytest.approx(online["k_hat"])


def test_aekf_replays_a_recording_on_the_vehicle_it_names(recording):
    log = read_npz(recording[0])
    assert log.metadata["vehicle"] == "bebop2"
    result = replay(log, make_detector("aekf", log))
    assert [alarm["target"] for alarm in result["alarms"]] == [2]
    assert 0.0 < result["alarms"][0]["time"] - 1.0 < 0.1
    del log.metadata["vehicle"]
    with pytest.raises(LogError, match="no vehicle for aekf's model .* --vehicle NAME"):
        make_detector("aekf", log)


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
    assert set(result) == {"detector", "identification", "alarms", "estimate_at_alarm", "final_estimate",
                           "logged_fault"}
    assert result["detector"] == "loe_kalman"
    assert result["identification"] is None             # an ftcgym recording: the vehicle's own G
    assert result["logged_fault"] == {"time": 1.0, "target": 2}
    assert len(result["estimate_at_alarm"]) == 4 and result["estimate_at_alarm"][2] < 0.25
    assert [set(alarm) for alarm in result["alarms"]] == [{"time", "target", "rotor", "isolated_time"}]
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
    window = result["identification"]
    assert window["rule"] == IDENTIFICATION_RULE
    assert window["end"] - window["start"] == pytest.approx(5.0, abs=0.01)
    assert window["start"] >= 3.79 + 3.0 and window["end"] < ulogs[HIL].fault_time   # after take-off, before the fault
    assert result["logged_fault"] == {"time": pytest.approx(ulogs[HIL].fault_time), "target": 0}
    assert result["estimate_at_alarm"][0] < 0.25


def test_cli_table_and_errors(recording, capsys):
    from ftcgym.cli import main
    path, _, _ = recording
    assert main(["replay", str(path), "--detector", "loe_kalman"]) == 0
    table = capsys.readouterr().out
    assert "alarm time" in table and "logged fault: rotor 2 at 1.000 s" in table
    assert "estimate at first alarm: " in table and "final estimate (log end, after any crash): " in table
    assert main(["replay", "no_such_log.ulg", "--detector", "loe_kalman"]) == 2
    missing = capsys.readouterr()
    assert missing.out == "" and "no_such_log.ulg" in missing.err
    assert main(["replay", str(path), "--detector", "nope"]) == 2
    assert "detector: unknown name 'nope'; replay sets up: loe_kalman, aekf" in capsys.readouterr().err
    assert main(["replay", str(path), "--detector", "loe_kalmann"]) == 2
    assert ("detector: unknown name 'loe_kalmann' (did you mean 'loe_kalman'?); replay sets up: loe_kalman, aekf"
            in capsys.readouterr().err)


# ----------------------------------------------------------------------------------------- logs that cannot be read

def small_recording(n=20):
    """A valid recording of `n` samples at 500 Hz: level hover, every rotor at 500 rad/s."""
    time = np.arange(n) * 0.002
    readings = {"gyro": np.zeros((n, 3)), "accel": np.tile([0.0, 0.0, -9.81], (n, 1)),
                "rotor_speed": np.full((n, 4), 500.0)}
    commands = np.vstack([np.full((1, 4), np.nan), np.full((n - 1, 4), 0.5)])
    return time, readings, commands, {"actuator_order": FTCGYM_ROTOR_ORDER, "fault_time": None}


def csv_lines(**edits):
    """The small recording as CSV lines (metadata, header, rows), with `edits` applied (see CSV_CASES)."""
    time, readings, commands, metadata = small_recording()
    for key in edits.get("drop", ()):
        readings.pop(key, None)
        time = None if key == "time" else time
    columns = {"time": time[:, None]} if time is not None else {}
    columns.update({**readings, "command": commands})
    header = [name if name == "time" else f"{name}[{i}]" for name, block in columns.items()
              for i in range(block.shape[1])]
    rows = [",".join(repr(float(v)) for v in row) for row in np.hstack(list(columns.values()))]
    return [f"# metadata {json.dumps(metadata)}", ",".join(header), *rows]


def write_csv_case(path, rows=None, swap=None, cell=None, short_row=None, **edits):
    """rows: keep that many data rows; swap: exchange two rows' times; cell: (row, column, text) replaced;
    short_row: (row, fields) keeps only that row's first fields."""
    lines = csv_lines(**edits)
    table = [line.split(",") for line in lines[2:]]
    if swap:
        (a, b), t = swap, [row[0] for row in table]
        table[a][0], table[b][0] = t[b], t[a]
    if cell:
        table[cell[0]][cell[1]] = cell[2]
    if short_row:
        table[short_row[0]] = table[short_row[0]][:short_row[1]]
    body = [",".join(row) for row in table][:rows]
    path.write_text("\n".join([*lines[:2], *body]) + "\n")


def write_npz_case(path, drop=(), **replace):
    time, readings, commands, metadata = small_recording()
    arrays = {"time": time, "commands": commands, "metadata": np.array(json.dumps(metadata)),
              **{f"reading/{key}": value for key, value in readings.items()}}
    arrays.update(replace)
    np.savez(path, **{name: value for name, value in arrays.items() if name not in drop})


def real_ulog_bytes(name=HIL) -> bytes:
    if not (RFLYMAD / name).exists():
        pytest.skip("RflyMAD logs not available")
    return (RFLYMAD / name).read_bytes()


def ulog_without_sensors(path):
    pytest.importorskip("pyulog")
    from pyulog import ULog
    real_ulog_bytes()
    ULog(str(RFLYMAD / HIL), ["actuator_outputs", "vehicle_attitude"]).write_ulog(str(path))


def damaged_ulog(path):
    data = bytearray(real_ulog_bytes())
    data[16 + 2] = 0          # the first message's type byte: 0 is no message type
    path.write_bytes(bytes(data))


RANDOM = np.random.default_rng(35).integers(0, 256, 4096, dtype=np.uint8).tobytes()

#: file name -> (how to make it in a folder, a word the one-line message must contain)
CORRUPT = {
    "random.ulg": (lambda p: p.write_bytes(RANDOM), "not a ULog file (bad magic"),
    "empty.ulg": (lambda p: p.write_bytes(b""), "empty file"),
    "truncated.ulg": (lambda p: p.write_bytes(real_ulog_bytes()[:int(0.6 * len(real_ulog_bytes()))]),
                      "truncated ULog (data ends mid-message"),
    "header_cut.ulg": (lambda p: p.write_bytes(real_ulog_bytes()[:10]), "truncated ULog"),
    "damaged.ulg": (damaged_ulog, "corrupt ULog (damaged message at byte 16"),
    "no_sensors.ulg": (ulog_without_sensors, "missing topic 'sensor_combined'"),
    "random.npz": (lambda p: p.write_bytes(RANDOM), "not an NPZ archive"),
    "empty.npz": (lambda p: p.write_bytes(b""), "empty file"),
    "zip_cut.npz": (lambda p: (write_npz_case(p), p.write_bytes(p.read_bytes()[:300])), "unreadable NPZ archive"),
    "no_time.npz": (lambda p: write_npz_case(p, drop=("time",)), "missing array 'time'"),
    "no_gyro.npz": (lambda p: write_npz_case(p, drop=("reading/gyro",)), "missing array 'reading/gyro'"),
    "short_gyro.npz": (lambda p: write_npz_case(p, **{"reading/gyro": np.zeros((19, 3))}), "has shape (19, 3)"),
    "text_time.npz": (lambda p: write_npz_case(p, time=np.array(["a"] * 20)), "expected numbers"),
    "random.csv": (lambda p: p.write_bytes(RANDOM), "not a text file"),
    "empty.csv": (lambda p: p.write_bytes(b""), "empty file"),
    "no_metadata.csv": (lambda p: p.write_text("time,gyro[0]\n0,0\n"), "not an ftcgym recording"),
    "bad_metadata.csv": (lambda p: p.write_text("# metadata {oops\ntime\n"), "metadata is not valid JSON"),
    **{f"no_{key}.csv": (lambda p, key=key: write_csv_case(p, drop=(key,)), f"missing column '{key}'")
       for key in ("time", "gyro", "accel", "rotor_speed")},
    "header_only.csv": (lambda p: write_csv_case(p, rows=0), "too few samples (0"),
    "one_row.csv": (lambda p: write_csv_case(p, rows=1), "too few samples (1"),
    "out_of_order.csv": (lambda p: write_csv_case(p, swap=(5, 6)), "time is not increasing at line 9"),
    "nan.csv": (lambda p: write_csv_case(p, cell=(4, 2, "nan")), "non-finite value nan in column 'gyro' at line 7"),
    "text.csv": (lambda p: write_csv_case(p, cell=(4, 2, "abc")), "line 7, column 'gyro[1]': 'abc' is not a number"),
    "ragged.csv": (lambda p: write_csv_case(p, short_row=(4, 2)), "line 7 has 2 fields"),
    "flight.txt": (lambda p: p.write_text("time\n"), "unknown log type '.txt'"),
    "missing.csv": (lambda p: None, "no such file"),
    "folder.ulg": (lambda p: p.mkdir(), "is a directory"),
}


def replay_in_process(path, capsys) -> tuple[int, list[str]]:
    from ftcgym.cli import main
    status = main(["replay", str(path), "--detector", "loe_kalman"])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    return status, [line for line in captured.err.splitlines() if line.strip()]


def test_the_small_recordings_are_valid_before_they_are_damaged(tmp_path, capsys):
    write_csv_case(tmp_path / "ok.csv")
    write_npz_case(tmp_path / "ok.npz")
    for name in ("ok.csv", "ok.npz"):
        assert replay_in_process(tmp_path / name, capsys) == (0, [])


@pytest.mark.parametrize("name", CORRUPT)
def test_a_log_that_cannot_be_read_exits_2_with_one_line_naming_the_file_and_the_problem(name, tmp_path, capsys):
    make, problem = CORRUPT[name]
    path = tmp_path / name
    make(path)
    status, lines = replay_in_process(path, capsys)
    assert status == 2
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ftcgym replay: {path}: ") and problem in lines[0]
    with pytest.raises(LogError) as error:             # a library user gets the same message, as a ValueError
        read_log(path)
    assert isinstance(error.value, ValueError) and lines[0] == f"ftcgym replay: {error.value}"


def test_a_recording_for_another_rotor_count_is_refused_by_loe_kalman(tmp_path, capsys):
    path = tmp_path / "hexa.npz"
    write_npz_case(path, **{"reading/rotor_speed": np.full((20, 6), 500.0)})
    assert replay_in_process(path, capsys) == (2, [f"ftcgym replay: {path}: 'rotor_speed' has 6 columns; "
                                                   f"loe_kalman models a quadrotor (4 rotors)"])


def test_a_truncated_ulog_exits_2_with_one_line_and_no_traceback_end_to_end(tmp_path):
    path = tmp_path / "cut.ulg"
    data = real_ulog_bytes()
    path.write_bytes(data[:int(0.6 * len(data))])
    done = subprocess.run([sys.executable, "-m", "ftcgym.cli", "replay", str(path), "--detector", "loe_kalman"],
                          capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert f"{path}: truncated ULog (data ends mid-message at byte {path.stat().st_size}" in done.stderr


# ----------------------------------------------------------------------------------------- fuzz

def ulog_message_ends(data: bytes) -> set:
    """Byte offsets where a ULog message ends (16-byte header, then frames of uint16 size, uint8 type, payload)."""
    ends, position = set(), 16
    while position + 3 <= len(data):
        position += 3 + int.from_bytes(data[position:position + 2], "little")
        ends.add(position)
    return ends


def csv_cut_is_detectable(text: str, cut: int) -> bool:
    """A CSV cut inside the metadata or header line, or leaving a data line short of fields. Cut at a line end
    or inside a line's last field, it is a shorter valid recording, which nothing can tell from a whole one."""
    done, partial = text[:cut].rsplit("\n", 1) if "\n" in text[:cut] else ("", text[:cut])
    header = text.split("\n")[1]
    return done.count("\n") < 1 or (partial != "" and partial.count(",") < header.count(","))


@pytest.fixture(scope="module")
def csv_recording(recording, tmp_path_factory) -> bytes:
    log = read_npz(recording[0])
    path = tmp_path_factory.mktemp("csv") / "flight.csv"
    _write_csv(path, log.time, log.readings, log.commands, log.metadata)
    return path.read_bytes()


def assert_refused(path, capsys):
    status, lines = replay_in_process(path, capsys)
    assert status == 2 and len(lines) == 1 and path.name in lines[0], (path.stat().st_size, lines)


def test_fuzz_random_bytes_are_refused(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for i in range(10):
        path = tmp_path / f"random{i}{('.ulg', '.npz', '.csv')[i % 3]}"
        path.write_bytes(rng.integers(0, 256, int(rng.integers(0, 3000)), dtype=np.uint8).tobytes())
        assert_refused(path, capsys)


def test_fuzz_a_real_ulog_cut_anywhere_but_a_message_end_is_refused(tmp_path, capsys):
    data = real_ulog_bytes()
    ends, rng = ulog_message_ends(data), np.random.default_rng(1)
    cuts = [int(cut) for cut in rng.integers(1, len(data), 12) if cut not in ends][:10]
    assert len(cuts) == 10
    for cut in cuts:
        path = tmp_path / f"cut{cut}.ulg"
        path.write_bytes(data[:cut])
        assert_refused(path, capsys)


def test_fuzz_a_real_csv_recording_cut_inside_a_field_is_refused(csv_recording, tmp_path, capsys):
    text, rng = csv_recording.decode(), np.random.default_rng(2)
    cuts = [int(cut) for cut in rng.integers(1, len(text), 40) if csv_cut_is_detectable(text, int(cut))][:10]
    cuts += [int(rng.integers(1, text.index("\n")))]                    # and one inside the metadata line
    assert len(cuts) == 11
    for cut in cuts:
        path = tmp_path / f"cut{cut}.csv"
        path.write_text(text[:cut])
        assert_refused(path, capsys)
