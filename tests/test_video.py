"""`ftcgym video` and the vehicle's looks: the frame schedule, the overlay, render_fps, the missing extra, and
physics that the visuals leave bit for bit as they were."""
import sys

import gymnasium as gym
import numpy as np
import pytest

import ftcgym  # noqa: F401  (registers the envs)
from ftcgym.benchmark.video import (
    DIM,
    GREEN,
    ORANGE,
    RED,
    FlightEvents,
    film_window,
    frame_times,
    overlay_lines,
    speed_label,
)
from ftcgym.cli import main
from ftcgym.envs.visuals import LOST, SPINNING, STOPPED, WEAK, rotor_colors


def test_frames_come_at_the_video_rate_over_the_window():
    times = frame_times(2.0, 6.0, fps=30)
    assert len(times) == 120 and times[0] == 2.0 and np.allclose(np.diff(times), 1 / 30)
    assert len(times) / 30 == pytest.approx(6.0 - 2.0)      # real time: the video lasts the window


def test_slow_motion_takes_more_frames_of_the_same_window():
    times = frame_times(2.0, 6.0, fps=30, slowmo=4)
    assert len(times) == 480 and np.allclose(np.diff(times), 1 / 120)
    assert len(times) / 30 == pytest.approx(4 * (6.0 - 2.0))  # the video lasts slowmo x the window
    assert len(frame_times(0.0, 10.0, fps=25, slowmo=0.5)) == 125   # fast forward
    assert len(frame_times(1.0, 1.0, fps=30)) == 1


def test_the_window_is_around_the_onset_within_the_flight():
    assert film_window(3.0, 10.0) == (2.0, 6.0)
    assert film_window(0.4, 10.0, before=1.0, after=3.0) == (0.0, 3.4)
    assert film_window(8.0, 9.5) == (7.0, 9.5)          # the episode ended (a crash) before the window
    assert film_window(None, 7.25) == (0.0, 7.25)       # no fault: the whole flight


EVENTS = FlightEvents("quad-rotor-loss-hover", "ftc-spin", 0, "rotor_loss", 3, 2.809, "loe_kalman", 2.854, 3,
                      3.682, False, 10.0)


def _text(lines):
    return [text for text, _ in lines]


def test_the_overlay_tells_each_event_from_its_time_on():
    before = overlay_lines(2.0, EVENTS, altitude=5.0, airspeed=0.4)
    assert _text(before) == ["quad-rotor-loss-hover  ftc-spin  seed 0", "t =   2.000 s   real time",
                             "altitude   5.00 m   airspeed  0.40 m/s",
                             "fault      Rotor r4 lost at 2.809 s",
                             "alarm      loe_kalman: none", "recovered  not yet"]
    assert [color for _, color in before[3:]] == [DIM, DIM, DIM]
    after_alarm = overlay_lines(3.0, EVENTS, slowmo=4)
    assert after_alarm[1][0] == "t =   3.000 s   4x slow motion"
    assert after_alarm[2] == ("fault      Rotor r4 lost at 2.809 s", RED)
    assert after_alarm[3] == ("alarm      loe_kalman at 2.854 s (+0.045 s), isolated r4", ORANGE)
    assert after_alarm[4] == ("recovered  not yet", DIM)
    assert overlay_lines(4.0, EVENTS)[-1] == ("recovered  at 3.682 s (+0.873 s)", GREEN)


def test_the_overlay_of_a_crash_a_flight_without_fault_and_without_detector():
    crash = FlightEvents("s", "nominal", 1, "loe", [0, 2], 5.0, None, None, None, None, True, 6.5)
    fault = "fault      Loss of effectiveness of rotor r1, r3 at 5.000 s"
    assert _text(overlay_lines(5.5, crash))[2:] == [fault, "recovered  not yet"]
    assert _text(overlay_lines(6.5, crash))[2:] == [fault, "recovered  no", "CRASHED    at 6.500 s"]
    calm = FlightEvents("qp-mission", "pitot-only", 2, end_time=240.0)
    assert _text(overlay_lines(1.0, calm))[2:] == ["fault      none"]
    pitot = FlightEvents("qp", "airspeed-switch", 0, "pitot_blockage", "zero", 45.0, "airdata_ekf", 45.09, "pitot")
    assert overlay_lines(46.0, pitot)[2][0] == "fault      Pitot blockage (reads zero) at 45.000 s"
    assert speed_label(0.25) == "4x fast forward"


def test_rotor_colours_by_state():
    colors = rotor_colors([1.0, 0.0, 0.75, 0.3], [True, False, True, True], [500.0, 900.0, 500.0, 500.0], 500.0)
    assert colors[0] == SPINNING and colors[1] == LOST and colors[3] == WEAK
    assert colors[2] == pytest.approx(tuple((a + b) / 2 for a, b in zip(SPINNING, WEAK)))  # halfway to WEAK
    assert rotor_colors([1.0], [True], [10.0], 500.0) == [STOPPED]


def _fly(env_id, render_size=None, steps=300, every=4, seed=3, **kwargs):
    """Observations (and reward, time, true attitude) of a seeded random-action flight; with `render_size` the
    env draws its look every `every` steps."""
    if render_size is not None:
        kwargs.update(render_mode="rgb_array", render_size=render_size)
    env = gym.make(env_id, **kwargs)
    env.action_space.seed(seed)
    obs, info = env.reset(seed=seed)
    rows, episode = [], 0
    for i in range(steps):
        action = env.action_space.sample()
        if env_id.endswith("Quadrotor-v0"):
            action = np.clip(0.55 + 0.1 * (action - 0.5), 0, 1).astype(np.float32)
        else:
            action[:4] = 0.72 + 0.1 * (action[:4] - 0.5)     # lifts off, skews its wing, tumbles, lands again
            action[5:8] *= 0.2
        obs, reward, terminated, truncated, info = env.step(action)
        rows.append(np.concatenate([np.ravel(v) for _, v in sorted(obs.items())]
                                   + [[reward, info["time"]], info["truth"]["attitude"]]))
        if render_size is not None and i % every == 0:
            assert env.render().shape == (render_size[1], render_size[0], 3)
        if terminated or truncated:
            episode += 1
            obs, info = env.reset(seed=seed + episode)
    env.close()
    return np.array(rows)


@pytest.mark.parametrize("env_id, steps", [("ftcgym/Quadrotor-v0", 600), ("ftcgym/QuadPlane-v0", 300)])
def test_the_visuals_leave_the_physics_bit_for_bit(env_id, steps):
    """The look (compound visual shape, the wing's body, the ground's drawing) and drawing frames change nothing:
    the same seeded flight, crashes and resets included, gives the same observations as without rendering."""
    plain = _fly(env_id, steps=steps)
    drawn = _fly(env_id, render_size=(64, 48), steps=steps)
    assert np.array_equal(plain, drawn)


def test_render_fps_is_the_agent_rate():
    cases = (("ftcgym/Quadrotor-v0", {}, 500), ("ftcgym/Quadrotor-v0", {"agent_hz": 250.0}, 250),
             ("ftcgym/QuadPlane-v0", {}, 100), ("ftcgym/QuadPlaneAutopilot-v0", {"agent_hz": 50}, 50))
    for env_id, kwargs, fps in cases:
        env = gym.make(env_id, **kwargs)
        assert env.metadata["render_fps"] == fps and isinstance(env.metadata["render_fps"], int)
        env.close()
    assert gym.make("ftcgym/Quadrotor-v0").unwrapped.__class__.metadata["render_fps"] == 30  # per instance


def test_a_bad_render_size_is_refused():
    for size in ((640,), (8, 480), (640.5, 480), "ab", (True, 480)):
        with pytest.raises(ValueError, match="render_size"):
            gym.make("ftcgym/Quadrotor-v0", render_mode="rgb_array", render_size=size)


def test_without_imageio_video_is_one_line_naming_the_extra(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "imageio", None)    # import imageio raises ImportError
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    status = main(["video", "--scenario", "quad-rotor-loss-hover", "--policy", "ftc-spin",
                   "--out", str(tmp_path / "x.mp4")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert err == ("ftcgym video: writing a video needs imageio and imageio-ffmpeg: pip install -c constraints.txt "
                   "-e '.[video]' in the ftcgym clone\n")
    assert not (tmp_path / "x.mp4").exists()


@pytest.mark.parametrize("args", [["--size", "641x480"], ["--size", "big"], ["--slowmo", "0"], ["--before", "-1"],
                                  ["--fps", "0"]])
def test_bad_video_options_are_usage_errors(args, tmp_path):
    with pytest.raises(SystemExit) as stop:
        main(["video", "--scenario", "quad-hover", "--out", str(tmp_path / "x.mp4"), *args])
    assert stop.value.code == 2
    with pytest.raises(SystemExit):
        main(["video", "--scenario", "quad-hover", "--out", str(tmp_path / "x.gif")])


def test_a_short_video_end_to_end(tmp_path, capsys):
    """1.5 s of flight with a rotor lost at 0.5 s; the window 0.3-1.0 s at 10 fps in 2x slow motion: 14 frames,
    1.4 s of video."""
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "film.mp4"
    env = '{"max_episode_seconds": 1.5, "faults": [{"kind": "rotor_loss", "target": 1, "time": 0.5}]}'
    status = main(["video", "--scenario", "quad-rotor-loss-hover", "--policy", "ftc-spin", "--seed", "0",
                   "--out", str(out), "--before", "0.2", "--after", "0.5", "--fps", "10", "--slowmo", "2",
                   "--size", "96x64", "--env-kwargs", env])
    printed = capsys.readouterr()
    assert status == 0 and printed.err == ""
    assert "14 frames at 10 fps, 1.40 s of video of t = 0.30-1.00 s" in printed.out
    assert "fault Rotor r2 lost at 0.500 s" in printed.out
    reader = imageio.get_reader(str(out))
    frames = [frame for frame in reader]
    assert reader.get_meta_data()["fps"] == 10 and len(frames) == 14 and frames[0].shape == (64, 96, 3)
