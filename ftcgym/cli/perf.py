"""`ftcgym perf`: env throughput and memory, the figures to quote.

Measures, single process: env steps per second (agent and physics) and simulated seconds per wall second for
Quadrotor-v0 with random actions (at 240/240 Hz, 240/30 Hz and the 500/500 Hz defaults) and with the nominal
controller in the loop, and for QuadPlane-v0 with random actions (500 Hz physics, agent at 100 and 500 Hz) and
with the mission autopilot, both with resets included and step time only; mean reset time; peak resident memory
and its growth over the run (a leak check); and the cost of one update of each fault detector, alone and with the
outputs and status its wrapper reads every step (Strack van Schijndel et al. 2023 report 18 us per step on a
Cortex-A9 in C++, the budget the table marks); and how two envs scale in a vector env (Gymnasium's sync and async,
ftcgym's parallel, and two independent processes as the machine's ceiling) at a 500 Hz and a 50 Hz agent rate.
Sensors, Dryden wind and a fault schedule are on in every case.

The reference is a bare PyBullet loop measured in the same run: the ground plane and one box, per physics step
one force and one torque applied, a step and a state read (position, orientation, velocity), as the envs do.
Each case reports its physics steps per second as a share of that loop's, and an estimate of the share of its
time spent inside PyBullet (the bare loop's time per physics step times the case's physics steps, over its wall
time).
"""
from __future__ import annotations

import contextlib
import json
import math
import multiprocessing as mp
import os
import resource
import time
from functools import partial

import gymnasium as gym
import numpy as np

import ftcgym  # noqa: F401  (registers the ids; imported before measuring so memory growth is the run's)
from ftcgym.agents import make_policy
from ftcgym.vector import SPIN_SECONDS

from .common import non_negative_int, positive_int

QUADROTOR, QUADPLANE = "ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0"
#: every case flies with light turbulence and mean wind (sensors are always on); the quadrotor loses a rotor
WORKLOAD = {QUADROTOR: {"wind": {"mean": [1.0, -1.0, 0.0], "turbulence": "light"}, "faults": "random:rotor_loss",
                        "max_episode_seconds": 10.0},
            QUADPLANE: {"wind": {"mean": [-3.0, 4.0, 0.0], "turbulence": "light"}, "max_episode_seconds": 150.0}}
CASES = (
    ("Quadrotor random, 240/240 Hz", QUADROTOR, {"physics_hz": 240, "agent_hz": 240}, "random"),
    ("Quadrotor random, 240/30 Hz", QUADROTOR, {"physics_hz": 240, "agent_hz": 30}, "random"),
    ("Quadrotor random, 500/500 Hz", QUADROTOR, {}, "random"),
    ("Quadrotor nominal, 500/500 Hz", QUADROTOR, {}, "nominal"),
    ("Quadrotor random + loe_kalman, 500/500 Hz", QUADROTOR, {}, "random+loe_kalman"),
    ("QuadPlane random, 500/100 Hz", QUADPLANE, {}, "random"),
    ("QuadPlane random, 500/500 Hz", QUADPLANE, {"agent_hz": 500}, "random"),
    ("QuadPlane autopilot, 500/100 Hz", QUADPLANE, {}, "autopilot"),
)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser("perf", help="measure simulation speed and memory",
                                   description=__doc__.split("\n\n")[1].replace("\n", " "))
    parser.add_argument("--steps", type=positive_int, default=20000, help="env steps per case (default 20000)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="seed of the episodes and random actions (default: 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.set_defaults(run=run)


def measure(env_id: str, env_kwargs: dict, actor: str, steps: int, seed: int) -> dict:
    """Steps/s (agent and physics), simulated s per wall s and reset cost of one case."""
    env = gym.make(env_id, **{**WORKLOAD[env_id], **env_kwargs})
    actor, _, detector = actor.partition("+")      # "random+loe_kalman": the env wrapped with that detector
    if detector:
        from ftcgym.fdd import wrap_with_detector
        env = wrap_with_detector(detector, env)
    # Random actions come from one numpy draw up front: Box.sample() alone costs ~50 us a call, which
    # would measure gymnasium's sampler rather than the env.
    space = env.action_space
    rng = np.random.default_rng(seed)
    random_actions = rng.uniform(space.low, space.high, (steps, *space.shape)).astype(np.float32)
    policy = make_policy(actor, env) if actor != "random" else None
    obs, info = env.reset(seed=seed)
    resets, reset_time, episode = 0, 0.0, 0
    start = time.perf_counter()
    for i in range(steps):
        action = policy.act(obs, info) if policy else random_actions[i]
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            t0 = time.perf_counter()
            episode += 1
            obs, info = env.reset(seed=seed + episode)
            if policy:
                policy.reset(obs, info)
            reset_time += time.perf_counter() - t0
            resets += 1
    wall = time.perf_counter() - start
    agent_hz, substeps = env.unwrapped.agent_hz, env.unwrapped.substeps
    env.close()
    stepping = wall - reset_time
    return {"steps_per_s": steps / wall, "physics_steps_per_s": steps * substeps / wall,
            "sim_s_per_wall_s": steps / agent_hz / wall, "step_only_sim_s_per_wall_s": steps / agent_hz / stepping,
            "step_only_physics_steps_per_s": steps * substeps / stepping, "resets": resets,
            "reset_ms": 1e3 * reset_time / max(resets, 1), "wall_s": wall}


def bare_pybullet_loop(steps: int, physics_hz: float = 500.0, repeats: int = 3) -> float:
    """Physics steps per second of a bare PyBullet loop, the best of `repeats`: the ground plane and one box of
    the default quadrotor's mass and size; per step a force and a torque (world frame), `stepSimulation` and
    the state read (`getBasePositionAndOrientation`, `getBaseVelocity`); sleeping disabled, as for a flying body."""
    from ftcgym.envs.world import p  # PyBullet, imported with its start-up banner silenced
    best = 0.0
    for _ in range(repeats):
        c = p.connect(p.DIRECT)
        try:
            p.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
            p.setTimeStep(1.0 / physics_hz, physicsClientId=c)
            p.createMultiBody(0.0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c), physicsClientId=c)
            box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.165, 0.19, 0.045], physicsClientId=c)
            body = p.createMultiBody(0.374, box, basePosition=[0.0, 0.0, 1.0], physicsClientId=c)
            # a body at rest would fall asleep and step for free; the envs' bodies move
            p.changeDynamics(body, -1, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=c)
            lift, frame = (0.0, 0.0, 0.374 * 9.81), p.WORLD_FRAME
            start = time.perf_counter()
            for _ in range(steps):
                position, _ = p.getBasePositionAndOrientation(body, physicsClientId=c)
                p.applyExternalForce(body, -1, lift, position, frame, physicsClientId=c)
                p.applyExternalTorque(body, -1, (0.0, 0.0, 1e-4), frame, physicsClientId=c)
                p.stepSimulation(physicsClientId=c)
                p.getBaseVelocity(body, physicsClientId=c)
            best = max(best, steps / (time.perf_counter() - start))
        finally:
            p.disconnect(c)
    return best


#: the vehicle each detector is made for (default: the quadrotor)
DETECTOR_ENV = {"airdata_ekf": QUADPLANE, "propulsion_bayes": QUADPLANE}


#: 000's figure for its detector on a Cortex-A9 in C++ (us per update), the budget each detector is held to
DETECTOR_BUDGET_US = 18.0


def detector_costs(steps: int, seed: int, repeats: int = 3) -> dict:
    """Microseconds per `update` of each registered detector, over one recorded fault-free flight of its vehicle
    (quadrotor: nominal hover at 500 Hz; quad-plane: the mission autopilot at 100 Hz), the best of `repeats`
    replays from `reset()` (the machine's noise only ever adds time)."""
    return {name: cost["update_us"] for name, cost in detector_step_costs(steps, seed, repeats).items()}


def detector_step_costs(steps: int, seed: int, repeats: int = 3) -> dict:
    """name -> {"update_us": `update` alone, "step_us": `update` + `outputs` + `status`, what `DetectorWrapper`
    calls on every env step}, microseconds per sample, each the best of `repeats` replays of the flight of
    `detector_costs` (the detector is reset before each), after one untimed replay. The detectors take turns,
    one replay each per round, so a slow minute of the machine does not fall on one detector alone."""
    from ftcgym.fdd import DETECTORS, wrap_with_detector

    flights, detectors = {}, {}
    for name in DETECTORS.builtins:
        env_id = DETECTOR_ENV.get(name, QUADROTOR)
        if env_id not in flights:
            flights[env_id] = _record_flight(env_id, steps, seed)
        env, samples = flights[env_id]
        detectors[name] = (wrap_with_detector(name, env).detector, samples)
    for detector, samples in detectors.values():      # untimed: numba compiles (or loads) each kernel on first use
        _replay(detector, samples, with_outputs=True)
    costs = {name: {"update_us": math.inf, "step_us": math.inf} for name in detectors}
    for _ in range(repeats):
        for name, (detector, samples) in detectors.items():
            for key, with_outputs in (("update_us", False), ("step_us", True)):
                costs[name][key] = min(costs[name][key], _replay(detector, samples, with_outputs))
    for env, _ in flights.values():
        env.close()
    return costs


def _replay(detector, samples, with_outputs: bool) -> float:
    """Microseconds per sample of `detector` replaying `samples` from `reset()`; with `outputs` and `status` read
    after each update where `with_outputs`."""
    update, outputs, status = detector.update, detector.outputs, detector.status
    detector.reset()
    start = time.perf_counter()
    if with_outputs:
        for readings, t, command in samples:
            update(readings, t, command)
            outputs()
            status()
    else:
        for readings, t, command in samples:
            update(readings, t, command)
    return 1e6 * (time.perf_counter() - start) / len(samples)


def _record_flight(env_id: str, steps: int, seed: int):
    """(env, [(observation, time, action)]) of a fault-free flight with the vehicle's own controller."""
    env = gym.make(env_id, **{**WORKLOAD[env_id], "faults": None, "max_episode_seconds": 1e6})
    policy = make_policy("nominal" if env_id == QUADROTOR else "autopilot", env)
    obs, info = env.reset(seed=seed)
    policy.reset(obs, info)
    samples = []
    for _ in range(steps):
        action = policy.act(obs, info)
        obs, _, _, _, info = env.step(action)
        samples.append((obs, info["time"], np.asarray(action, dtype=float)))
    return env, samples


#: the vector-env rows: Quadrotor-v0's defaults with the learning-code settings, vector envs without copies
VECTOR_KWARGS = {"observation_format": "flat", "info_level": "none"}
#: the agent rates of the vector-env rows (Hz): the default, one physics step per env step; and a training rate,
#: ten physics steps per env step, where the hand-over between processes weighs a tenth as much
VECTOR_AGENT_HZ = (500.0, 50.0)


def vector_scaling(steps: int, seed: int, num_envs: int = 2, rounds: int = 8, agent_hz: float = 500.0) -> dict:
    """Aggregate env steps/s of `gym.make_vec` (sync, async and the parallel vector entry point, `num_envs` envs,
    copy=False) and of one env, random actions, on Quadrotor-v0 with `VECTOR_KWARGS` at `agent_hz` (resets
    inside, as autoreset does them); and of `num_envs` independent processes each stepping its own env at once,
    with no hand-over (`independent`): the machine's own ceiling for any vector env. The five take turns in
    `rounds` rounds, so a change in the machine's speed hits all alike, in an order drawn afresh each round: in a
    fixed order the case after Gymnasium's async vector env read up to 0.15x lower at 50 Hz (docs/measurements.md,
    'The parallel vector env's hand-over, timed'). Rates are medians over the rounds, ratios medians of the ratios
    within a round."""
    rng = np.random.default_rng(seed)
    chunk = max(steps // rounds // num_envs, 1)
    actions = rng.uniform(0.0, 1.0, (chunk, num_envs, 4)).astype(np.float32)
    env_kwargs = {**VECTOR_KWARGS, "agent_hz": agent_hz}
    one = gym.make(QUADROTOR, **env_kwargs)
    one.reset(seed=seed)
    envs = {mode: gym.make_vec(QUADROTOR, num_envs=num_envs, vectorization_mode=mode, vector_kwargs={"copy": False},
                               **env_kwargs) for mode in ("sync", "async")}
    envs["parallel"] = gym.make_vec(QUADROTOR, num_envs=num_envs, vectorization_mode="vector_entry_point",
                                    copy=False, **env_kwargs)
    for vector_env in envs.values():
        vector_env.reset(seed=seed)

    def one_env() -> float:
        return actions.shape[0] * num_envs / _seconds_stepping(one, actions.reshape(-1, 4))

    ctx = mp.get_context()
    pipes = [ctx.Pipe() for _ in range(num_envs - 1)]
    others = [ctx.Process(target=_independent_env, args=(child, env_kwargs, seed + k + 1, actions[:, k + 1]),
                          daemon=True)
              for k, (_, child) in enumerate(pipes)]
    for process in others:
        process.start()
    for parent, _ in pipes:
        parent.recv()                          # built and ready

    def independent() -> float:
        for parent, _ in pipes:
            parent.send(True)
        seconds = [_seconds_stepping(one, actions[:, 0])] + [parent.recv() for parent, _ in pipes]
        return actions.shape[0] * num_envs / max(seconds)

    def vector(mode: str) -> float:
        start = time.perf_counter()
        for batch in actions:
            envs[mode].step(batch)
        return actions.shape[0] * num_envs / (time.perf_counter() - start)

    cases = {"one": one_env, **{mode: partial(vector, mode) for mode in envs}, "independent": independent}
    samples = {mode: [] for mode in cases}
    for _ in range(rounds):
        for mode in rng.permutation(list(cases)).tolist():   # a fresh order each round: none always follows another
            time.sleep(2 * SPIN_SECONDS)     # the parallel worker's polling after its last step is over
            samples[mode].append(cases[mode]())
    for parent, _ in pipes:
        parent.send(False)
    for process in others:
        process.join(timeout=10.0)
    one.close()
    for vector_env in envs.values():
        vector_env.close()
    ratios = {mode: float(np.median(np.array(samples[mode]) / samples["one"])) for mode in (*envs, "independent")}
    return {"num_envs": num_envs, "agent_hz": agent_hz, "env_kwargs": VECTOR_KWARGS, "rounds": rounds,
            "steps_per_s": {mode: float(np.median(rates)) for mode, rates in samples.items()},
            "ratio_to_one_env": ratios}


def _seconds_stepping(env, actions) -> float:
    """Wall seconds `env` takes to step `actions`, resetting where an episode ends."""
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - start


def _independent_env(pipe, env_kwargs: dict, seed: int, actions) -> None:
    """A process of `vector_scaling`'s `independent` row: its own env, stepping `actions` whenever told to."""
    env = gym.make(QUADROTOR, **env_kwargs)
    env.reset(seed=seed)
    pipe.send(None)
    while pipe.recv():
        pipe.send(_seconds_stepping(env, actions))
    env.close()


def machine() -> dict:
    """What the figures were measured on: CPU model, cores, load average at the start, Python and libraries."""
    import platform
    from importlib import metadata
    cpu = platform.processor()
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as info:
        cpu = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), cpu)
    return {"cpu": cpu, "cores": os.cpu_count(), "load_average": round(os.getloadavg()[0], 2),
            "python": platform.python_version(),
            **{name: metadata.version(name) for name in ("numpy", "pybullet", "gymnasium", "numba")}}


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run(args, argv: list[str] | None = None) -> int:
    host = machine()
    measure(QUADROTOR, {}, "nominal", 200, args.seed)  # warm-up: one-time allocations must not read as growth
    measure(QUADPLANE, {}, "autopilot", 200, args.seed)
    bare = bare_pybullet_loop(args.steps)
    rows = []
    for name, env_id, kwargs, actor in CASES:
        before = _rss_mib()
        row = measure(env_id, kwargs, actor, args.steps, args.seed)
        row.update(case=name, peak_rss_mib=_rss_mib(), rss_growth_mib=_rss_mib() - before,
                   bare_loop_share=row["step_only_physics_steps_per_s"] / bare,
                   pybullet_share=min(row["physics_steps_per_s"] / bare, 1.0))
        rows.append(row)
    costs = detector_step_costs(min(args.steps, 5000), args.seed)
    vector = [vector_scaling(args.steps, args.seed, agent_hz=hz) for hz in VECTOR_AGENT_HZ]
    if args.json:
        print(json.dumps({"machine": host, "env": rows, "vector": vector, "bare_pybullet_physics_steps_per_s": bare,
                          "detector_us_per_update": {name: c["update_us"] for name, c in costs.items()},
                          "detector_us_per_step": {name: c["step_us"] for name, c in costs.items()},
                          "detector_budget_us": DETECTOR_BUDGET_US}, indent=2))
        return 0
    print(f"ftcgym perf: {args.steps} agent steps per case, one process")
    print("machine: " + ", ".join(f"{key} {value}" for key, value in host.items()))
    for env_id, workload in WORKLOAD.items():
        print(f"workload {env_id}: {workload}")
    print(f"bare PyBullet loop (ground + one box; force, torque, step, state read): {bare:.0f} physics steps/s")
    header = (f"{'case':42} {'steps/s':>9} {'physics/s':>10} {'sim s/s':>8} {'step-only':>9} {'of bare':>8} "
              f"{'in PyB':>7} {'resets':>7} {'reset ms':>9} {'peak MiB':>9} {'growth MiB':>10}")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['case']:42} {r['steps_per_s']:9.0f} {r['physics_steps_per_s']:10.0f} {r['sim_s_per_wall_s']:8.1f} "
              f"{r['step_only_sim_s_per_wall_s']:9.1f} {r['bare_loop_share']:8.0%} {r['pybullet_share']:7.0%} "
              f"{r['resets']:7d} {r['reset_ms']:9.3f} {r['peak_rss_mib']:9.1f} {r['rss_growth_mib']:10.1f}")
    print("\nsim s/s: simulated seconds per wall second, resets included; step-only: the same without the resets' "
          "time;\nof bare: physics steps/s (step-only) as a share of the bare loop's; in PyB: estimated share of the "
          "time inside PyBullet")
    print(f"\ndetector cost per sample (us), best of 3 replays of a recorded flight of its vehicle, the detectors in "
          f"turns; budget "
          f"{DETECTOR_BUDGET_US:g} us per update (Strack van Schijndel et al. 2023, Cortex-A9, C++):")
    print(f"  {'detector':17} {'update':>8} {'+outputs,status':>16}  budget")
    for name, c in costs.items():
        verdict = "under" if c["update_us"] < DETECTOR_BUDGET_US else "OVER"
        print(f"  {name:17} {c['update_us']:8.1f} {c['step_us']:16.1f}  {verdict}")
    print(f"\nvector envs: gym.make_vec({QUADROTOR!r}, num_envs={vector[0]['num_envs']}, copy=False) with "
          f"{VECTOR_KWARGS}, aggregate env steps/s (median of {vector[0]['rounds']} interleaved rounds) and against "
          f"one env; independent: {vector[0]['num_envs']} processes, one env each, no hand-over (the machine's "
          f"ceiling):")
    print(f"  {'agent rate':>10} {'one env':>9} {'sync':>15} {'async':>15} {'parallel':>15} {'independent':>15}")
    for row in vector:
        rates, ratios = row["steps_per_s"], row["ratio_to_one_env"]
        cells = "".join(f" {rates[mode]:8.0f} ({ratios[mode]:.2f}x)" for mode in
                        ("sync", "async", "parallel", "independent"))
        print(f"  {row['agent_hz']:7.0f} Hz {rates['one']:9.0f}{cells}")
    return 0
