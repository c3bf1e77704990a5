"""Acceptance runs and the comparison plot for `IvChangeDetector` (004 Sec. 5.1 scenario).

    python -m ftcgym.benchmark.iv_study --seeds 100-109 --workers 1 --plot /tmp/iv_change.png

(the plot also writes /tmp/iv_change.pdf beside the PNG.)

Flies the square task (with and without 90 deg heading changes) in light Dryden turbulence and a
(1, -1, 0) m/s mean wind, mass 0.5 -> 1 kg between 40 and 42 s, with the nominal controller, and
prints each seed's alarm time. The alarm rules (the wind test's CUSUM by default, the CUSUM of the IV
increments with `test="iv"`) and the prefilter were tuned on recorded episodes replayed offline (the
detector does not act on the flight); report on seeds not used for tuning (those are listed in
docs/measurements.md, 'Tuning record: fdd/iv_change.py').
`ftcgym bench` hashes its episode seeds from the base seed, so they differ from the env seeds given here.
"""
from __future__ import annotations

import argparse
import time as wallclock
from multiprocessing import Pool

import gymnasium as gym
import numpy as np

import ftcgym  # noqa: F401  (registers the env ids)
from ftcgym.agents import make_policy
from ftcgym.fdd.iv_change import IvChangeSettings, LowPassBank, SixDofResidual, iv_change_wrapper

ONSET, RAMP, SECONDS = 40.0, 2.0, 60.0


def make_scenario(heading_changes: bool):
    task = {"name": "square", "altitude": 8.0}
    if heading_changes:
        task["heading_changes"] = True
    return gym.make("ftcgym/Quadrotor-v0", vehicle="mueller2014", task=task,
                    wind={"mean": [1.0, -1.0, 0.0], "turbulence": "light"},
                    faults=[{"kind": "payload", "time": ONSET, "magnitude": 0.5, "duration": RAMP}],
                    max_episode_seconds=SECONDS)


def fly(seed: int, heading_changes: bool, record: bool = False, **detector_kwargs) -> dict:
    """One episode with the detector in the loop; `record` keeps J and the 6-DOF residual for a plot."""
    env = iv_change_wrapper(make_scenario(heading_changes), **detector_kwargs)
    detector, dt = env.detector, 1.0 / env.unwrapped.agent_hz
    six_dof, smooth = SixDofResidual(env.unwrapped.params, dt), LowPassBank(0.5, 4, dt)
    obs, info = env.reset(seed=seed)
    policy = make_policy("nominal", env)
    policy.reset(obs, info)
    trace = []
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs, info))
        if record:
            res = six_dof.update(obs)
            if smooth.x is None:
                smooth.start(res)
            trace.append((info["time"], *obs["fdd/iv_change/J"], *smooth.step(res),
                          obs["fdd/iv_change/c_hat"][0] / detector.c, obs["fdd/iv_change/cusum"][0]))
        if terminated or truncated:
            break
    # Per-update cost, timed apart from the simulation on the last observation.
    start = wallclock.perf_counter()
    for k in range(2000):
        detector.update(obs, info["time"] + (k + 1) * dt)
    spent = (wallclock.perf_counter() - start) / 2000
    env.close()
    status = info["fdd"]["iv_change"]
    return {"seed": seed, "heading_changes": heading_changes, "alarm_time": status["alarm_time"],
            "crashed": bool(info["crashed"]), "update_us": spent * 1e6, "trace": np.array(trace)}


def _fly(args):
    return fly(*args)


def acceptance(seeds, workers: int = 2) -> list[dict]:
    """Fly every seed with and without heading changes; print alarm times and the pass counts."""
    jobs = [(s, h) for h in (False, True) for s in seeds]
    if workers <= 1:
        rows = [_fly(job) for job in jobs]
    else:
        with Pool(workers) as pool:
            rows = pool.map(_fly, jobs)
    for heading in (False, True):
        print(f"\nheading changes: {heading}")
        print(" seed  alarm_time  verdict")
        ok = 0
        for row in (r for r in rows if r["heading_changes"] == heading):
            t = row["alarm_time"]
            verdict = "missed" if t is None else ("FALSE ALARM" if t < ONSET else "detected")
            ok += verdict == "detected"
            print(f"{row['seed']:5d}  {'-' if t is None else f'{t:8.3f}':>10s}  {verdict}"
                  + ("  (crashed)" if row["crashed"] else ""))
        print(f"alarm after {ONSET:g} s and none before: {ok}/{len(seeds)}")
    print(f"\ndetector update: median {np.median([r['update_us'] for r in rows]):.1f} us")
    return rows


def plot(seed: int, path: str, heading_changes: bool = False) -> str:
    """IV costs J1, J2, the IV estimate c_hat / c_0 and its CUSUM beside the low-passed 6-DOF residual (004 4.1),
    in the look of `style`: a PNG at `path` and a PDF beside it."""
    from matplotlib.figure import Figure  # a bare Figure renders with Agg: no pyplot, no global backend

    from ftcgym.benchmark import style

    row = fly(seed, heading_changes, record=True)
    t, J, res, ratio = row["trace"][:, 0], row["trace"][:, 1:3], row["trace"][:, 3:7], row["trace"][:, 7]
    cusum = row["trace"][:, 8]
    defaults = IvChangeSettings()
    with style.paper():
        figure = Figure(figsize=style.size(2, 7.0), layout="constrained")
        ax_acc, ax_rate, ax_iv, ax_c, ax_g = figure.subplots(5, 1, sharex=True)
        blue, orange = style.COMPONENT_COLORS[:2]
        ax_acc.plot(t, res[:, 2], color=blue, label="$a_x - a_{x,s}$")
        ax_acc.plot(t, res[:, 3], color=orange, label="$a_y - a_{y,s}$")
        ax_acc.set_ylabel(style.wrap("Acceleration residual (m/s²)"))
        ax_acc.set_title("6-DOF simulation-model residual (004 Sec. 4.1), 0.5 Hz low-pass")
        ax_rate.plot(t, res[:, 0], color=blue, label="$p - p_s$")
        ax_rate.plot(t, res[:, 1], color=orange, label="$q - q_s$")
        ax_rate.set_ylabel(style.wrap("Rate residual (rad/s)"))
        ax_iv.semilogy(t, np.maximum(J[:, 0], 1e-10), color=blue, label="$J_{IV1}$ (x)")
        ax_iv.semilogy(t, np.maximum(J[:, 1], 1e-10), color=orange, label="$J_{IV2}$ (y)")
        ax_iv.set_ylim(1e-9, None)
        ax_iv.set_ylabel("IV cost")
        ax_iv.set_title("IV cost (004 eq. 30, forgetting factor 0.999, window 500) of the residuals (29)")
        ax_c.plot(t, ratio, color=style.GREEN, label=r"$\hat c / c_0$ (IV estimate of $\lambda_1/m$)")
        ax_c.axhline(1.0, color=style.GREY, lw=0.8)
        ax_c.axhline(defaults.cusum_ratio, color=style.BLACK, ls=":", lw=0.8, label="CUSUM target $c_1 / c_0$")
        ax_c.set_ylim(-0.2, 1.6)
        ax_c.set_ylabel(style.wrap("Drag per mass / nominal"))
        ax_c.set_title("IV estimate of c (forgetting factor 0.999)")
        ax_g.plot(t, cusum, color=style.VERMILLION, label="CUSUM $g$ of the IV increments (the alarm with test='iv')")
        ax_g.axhline(defaults.cusum_threshold, color=style.GREY, ls="--", lw=0.8, label="alarm threshold")
        if row["alarm_time"] is not None:
            for ax in (ax_c, ax_g):
                ax.axvline(row["alarm_time"], color=style.ALARM_COLOR, ls="--", lw=0.8,
                           label=f"alarm {row['alarm_time']:.2f} s")
        ax_g.set_ylabel(style.wrap(style.label("cusum", "iv_change")))
        ax_g.set_xlabel(style.label("time"))
        for ax in (ax_acc, ax_rate, ax_iv, ax_c, ax_g):
            ax.axvspan(ONSET, ONSET + RAMP, color="0.88", lw=0, zorder=0)
            ax.legend(loc="upper left")
        figure.align_ylabels()
        figure.suptitle(f"Mass 0.5 -> 1 kg at 40-42 s (shaded), light turbulence, seed {seed}"
                        + (", heading changes" if heading_changes else ""))
        style.save(figure, path)
    return path


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="100-109", help="seed range, e.g. 100-109 (tuning used 1000-1019)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--plot", default=None, help="PNG path for the comparison plot")
    parser.add_argument("--plot-seed", type=int, default=100)
    parser.add_argument("--plot-heading-changes", action="store_true", help="plot the heading-change variant")
    args = parser.parse_args(argv)
    if args.seeds != "none":
        acceptance(_seeds(args.seeds), args.workers)
    if args.plot:
        print("plot:", plot(args.plot_seed, args.plot, args.plot_heading_changes))


if __name__ == "__main__":
    main()
