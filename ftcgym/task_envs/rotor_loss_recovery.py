"""Training tasks: Gymnasium envs shaped for learning a recovery policy.

`ftcgym/RotorLossRecovery-v0` (task `rotor-loss-recovery`): a motor-level policy that takes over
from the nominal controller at the `loe_kalman` alarm after a propeller loss.

- Episode: `reset` builds `ftcgym/Quadrotor-v0` wrapped with the `loe_kalman` detector, flies the
  nominal controller (`ftcgym.agents.make_policy("nominal", env)`) through the fault until the detector
  alarms, and returns the first post-alarm observation: the agent only ever sees post-alarm steps. An
  episode in which the vehicle crashes or the flight ends before any alarm is discarded and a new one
  drawn. It is truncated `horizon_seconds` after the alarm and terminated on a crash.
- Action: Box(-1, 1, (4,)) float32 motor commands in the canonical rotor order (`rotor_order`), rescaled to
  the quadrotor's Box(0, 1): u = (a + 1) / 2, held for `action_repeat` simulator steps (the detector updates
  on each).
- Observation: Box(41,) float32 from `recovery_features`, only what a flight computer has (sensors,
  the task's set-point, the detector's outputs and the guidance below; never `info["truth"]`), in a frame
  that makes the recovery's symmetries exact (see `recovery_features`).
- Guidance: a shadow `SpinRecoveryController` (the `ftc-spin` recovery, engaged at the alarm on the rotor the
  detector isolated) sees every simulator step's observation, as it would flying; its outer loop's commanded
  axis and collective thrust are features. It never flies: the agent's action is what flies.
- Reward per agent step (the mean over the repeated simulator steps; a step that ends in a crash gives the whole
  -100), from the quadrotor's reward
  (`ftcgym/envs/quadrotor.py` docstring: r = 1 - 0.5 min(|p - p_ref|, 4) - 0.5 (1 - cos tilt) -
  0.05 mean(u^2), and -100 on a crash) with two changes:
      r = 1 - 1.0 min(|h - h_ref|, 4) - 0.25 min(|p_ne - p_ne,ref|, 4) - 0.05 mean(u^2),  -100 on a crash.
  Altitude is split from the horizontal error and weighted x2 (the benchmark's recovery criterion is
  altitude within 0.5 m), the horizontal error x0.5 (a spinning vehicle drifts while it settles); the
  tilt term is dropped, since the relaxed-hover equilibrium without one rotor keeps the body thrust
  axis off the vertical and spins about it (001 App. B). Rewards are computed from the simulator's truth.
- Expert labels (`expert=True`, for imitation pre-training, `ftcgym.training.imitation`):
  `info["expert_action"]` is the guiding controller's command for the observation returned, in the action
  space's [-1, 1].
- Domain randomisation (constructor keywords, drawn per episode from the env's seeded RNG):
  `vehicle` (a name or a list of names), `wind` (a dict, or a list of dicts to draw from, or
  {"mean_speed": [lo, hi], "turbulence": ...} for a random horizontal direction), `onset` ([lo, hi] s, or a
  list of such windows drawn with equal weight),
  `failed_rotor` ("random", an index or a list of indices), `task` (a quadrotor task, or a list of tasks to
  draw from: a policy trained on hover alone meets a rotor loss at speed out of its training distribution).
"""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ftcgym.agents import SpinRecoveryController, make_policy, policy_view
from ftcgym.envs.action_space import ActionBox
from ftcgym.fdd import wrap_with_detector
from ftcgym.models.checks import POSITIVE, keywords_checked, number, real_array, whole_number
from ftcgym.models.constants import GRAVITY
from ftcgym.models.geometry import rotation_matrix
from ftcgym.models.quadrotor import VEHICLES
from ftcgym.models.tasks import make_task
from ftcgym.models.wind import DrydenWind, random_mean_wind

DETECTOR = "loe_kalman"
N_FEATURES = 41
FEATURE_BOUND = 10.0
RATE_SCALE = 10.0            # rad/s per unit (the gyro saturates at 34.9 rad/s = 3.5 units)
POSITION_SCALE = 2.0         # m per unit
VELOCITY_SCALE = 2.0         # m/s per unit
VARIANCE_DECADES = 6.0       # log10 of the detector's variance ceiling (1e6)
MAX_RESETS = 20              # draws of a pre-alarm flight before reset gives up
CRASH_PENALTY = 100.0


# The half turn about body z: rotor r1..r4 (000 eq. 4: front-left, front-right, back-right, back-left) goes to
# r3, r4, r1, r2 and a body vector (or body rate) (x, y, z) to (-x, -y, z). The diagonal rotors sit at
# opposite positions and spin the same way (`rotor_positions` and YAW_SIGNS in models/quadrotor.py), so the
# turned vehicle is the same vehicle: a loss of r3 or r4 is a loss of r1 or r2 seen half a turn round.
HALF_TURN_ROTORS = np.array([2, 3, 0, 1])
HALF_TURN_BODY = np.array([-1.0, -1.0, 1.0])


def rotor_order(status: dict) -> np.ndarray:
    """The canonical rotor order for the detector's `status`: the half turn when the isolated rotor is r3 or
    r4, else as is. Its own inverse: it maps the features' rotor entries and the policy's action alike."""
    isolated = status.get("isolated") if status.get("alarm") else None
    return HALF_TURN_ROTORS if isolated is not None and int(isolated) >= 2 else np.arange(4)


def recovery_features(obs: dict, status: dict, omega_max: float, axis_command, thrust_share: float) -> np.ndarray:
    """The flat observation of the recovery task (N_FEATURES float32) from a detector-wrapped quadrotor
    observation, the detector's `info["fdd"]["loe_kalman"]` status and the guidance of `ftc-spin`'s outer
    loop for that observation: `axis_command`, the world direction (NED unit vector) to spin about, and
    `thrust_share`, the collective thrust it asks for over the nominal weight m g
    (`SpinRecoveryController.axis_command`, `thrust_command`). Also what `LearnedPolicy` feeds the model in the
    benchmark, so training and evaluation see the same features.

    gyro / 10 rad/s (3), the vertical in the body frame (R^T e_z, 3), position error / 2 m, velocity error
    / 2 m/s and reference velocity / 2 m/s in the body frame (3 each), the vertical position and velocity
    errors (2), the commanded axis in the body frame (R^T n_des, 3) and thrust_share - 1 (1), rotor speeds /
    omega_max (4), detector k_hat (4), log10 k_var / 6 (4), p_fail (4), one-hot of the isolated rotor (4,
    zeros before an alarm); body vectors half-turned and rotor entries reordered by `rotor_order`. Clipped to
    +-10.

    The guidance makes the policy a learned attitude and motor layer under `ftc-spin`'s position loop: the
    loop's commanded axis turns at a limited rate (`axis_slew_rate_deg`), a state no single observation holds,
    and imitation of the loop without it fitted badly (docs/measurements.md, '`learned-spin` under
    `ftc-spin`'s guidance').

    Two symmetries of the recovery are built in rather than left to be learned. Heading: gravity is the
    only direction the flight has, so no feature depends on the yaw (with world-frame attitude and errors a
    policy has to learn each leg of the square apart). Half turn: a loss of r3 or r4 is shown as the
    equivalent loss of r1 or r2. Both help on the square; see docs/measurements.md, '`learned-spin` on
    manoeuvres: DAgger attempts'.
    """
    prefix = f"fdd/{DETECTOR}/"
    isolated = np.zeros(4)
    if status.get("alarm") and status.get("isolated") is not None:
        isolated[int(status["isolated"])] = 1.0
    order = rotor_order(status)
    turn = HALF_TURN_BODY if order[0] != 0 else np.ones(3)
    R = rotation_matrix(obs["attitude"])
    position_error = (np.asarray(obs["position"]) - obs["reference_position"]) / POSITION_SCALE
    velocity_error = (np.asarray(obs["velocity"]) - obs["reference_velocity"]) / VELOCITY_SCALE
    reference_velocity = np.asarray(obs["reference_velocity"]) / VELOCITY_SCALE
    features = np.concatenate((
        turn * np.asarray(obs["gyro"]) / RATE_SCALE,
        turn * R[2],
        turn * (R.T @ position_error), turn * (R.T @ velocity_error), turn * (R.T @ reference_velocity),
        [position_error[2], velocity_error[2]],
        turn * (R.T @ np.asarray(axis_command, dtype=float)), [thrust_share - 1.0],
        (np.asarray(obs["rotor_speed"]) / omega_max)[order],
        np.asarray(obs[prefix + "k_hat"])[order],
        (np.log10(np.asarray(obs[prefix + "k_var"]) + 1e-12) / VARIANCE_DECADES)[order],
        np.asarray(obs[prefix + "p_fail"])[order],
        isolated[order],
    ))
    return np.clip(features, -FEATURE_BOUND, FEATURE_BOUND).astype(np.float32)


def guided_features(obs: dict, status: dict, guide: SpinRecoveryController) -> np.ndarray:
    """`recovery_features` with the guidance of `guide`, a shadow `ftc-spin` controller that has acted on `obs`."""
    params = guide.params
    return recovery_features(obs, status, params.omega_max, guide.axis_command,
                             guide.thrust_command / (params.mass * GRAVITY))


def to_motor_command(action) -> np.ndarray:
    """The quadrotor's Box(0, 1) command of a Box(-1, 1) policy action."""
    return (np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) + 1.0) / 2.0


def recovery_reward(info: dict, command: np.ndarray) -> float:
    """The task's reward (module docstring) from the quadrotor's `info` after a step."""
    if info["crashed"]:
        return -CRASH_PENALTY
    error = np.asarray(info["truth"]["position"]) - info["reference"]["position"]
    horizontal = math.hypot(error[0], error[1])
    return float(1.0 - 1.0 * min(abs(error[2]), 4.0) - 0.25 * min(horizontal, 4.0)
                 - 0.05 * float(command @ command) / 4)


class RotorLossRecoveryEnv(gym.Env):
    """`ftcgym/RotorLossRecovery-v0`; see the module docstring.

    Keywords: vehicle, wind, onset, failed_rotor, task (randomisation, module docstring; task default
    "hover"); horizon_seconds (post-alarm episode length, default 5); action_repeat (simulator steps per
    action, default 2); agent_hz (the quadrotor's control rate, default 500); detector_kwargs (for
    `loe_kalman`); sensors (the quadrotor's sensor overrides); expert (add `info["expert_action"]`, module
    docstring).
    """

    metadata = {"render_modes": []}

    @keywords_checked
    def __init__(self, vehicle="bebop2", wind=None, onset=(2.0, 5.0), failed_rotor="random",
                 horizon_seconds: float = 5.0, action_repeat: int = 2, task="hover", agent_hz: float = 500.0,
                 detector_kwargs: dict | None = None, sensors: dict | None = None, expert: bool = False):
        self.vehicles = [vehicle] if isinstance(vehicle, str) else list(vehicle) if isinstance(vehicle, (list, tuple)) \
            else []
        if not self.vehicles or not all(isinstance(v, str) and v in VEHICLES for v in self.vehicles):
            raise ValueError(f"vehicle: expected a parameter set or a list of them, of {sorted(VEHICLES)}; "
                             f"got {vehicle!r}")
        self.winds = wind if isinstance(wind, list) else [wind]
        self.onsets = _onsets(onset)
        self.onset = (min(lo for lo, _ in self.onsets), max(hi for _, hi in self.onsets))   # their span
        self.failed_rotors = _rotors(failed_rotor)
        self.horizon_seconds = number(horizon_seconds, "horizon_seconds", POSITIVE)
        self.action_repeat = whole_number(action_repeat, "action_repeat")
        self.tasks = _tasks(task)
        self.agent_hz, self.sensors = number(agent_hz, "agent_hz", POSITIVE), sensors
        if detector_kwargs is not None and not isinstance(detector_kwargs, dict):
            raise ValueError(f"detector_kwargs: expected a dict of {DETECTOR} settings, got {detector_kwargs!r}")
        self.detector_kwargs = dict(detector_kwargs or {})
        if not isinstance(expert, bool):
            raise ValueError(f"expert: expected true or false, got {expert!r}")
        self.expert = expert
        self._guides: dict[str, SpinRecoveryController] = {}   # ftc-spin's controller per vehicle (guidance)
        self._guide, self._expert_action = None, None
        self.observation_space = spaces.Box(-FEATURE_BOUND, FEATURE_BOUND, (N_FEATURES,), np.float32)
        self.action_space = ActionBox(-1.0, 1.0, (4,), np.float32)
        self._envs: dict[tuple, gym.Env] = {}   # one simulator per (vehicle, task)
        self.env, self._closed = None, False
        try:                   # all built now: a bad wind, sensor, rate or detector setting fails at make
            for vehicle in self.vehicles:
                for task in range(len(self.tasks)):
                    self._simulator(vehicle, task)
            for spec in self.winds:
                DrydenWind.from_config(_draw_wind(spec, np.random.default_rng(0)), 1.0 / self.agent_hz)
        except ValueError:
            self.close()
            raise

    # ------------------------------------------------------------------------------------ episodes
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if options:
            raise ValueError(f"reset options: RotorLossRecovery-v0 draws each episode from its gym.make keywords "
                             f"and takes none, got {options!r}")
        check_open(self._closed, "reset")
        super().reset(seed=seed)
        for _ in range(MAX_RESETS):
            if self._fly_to_alarm():
                return self._features(), self._task_info()
        raise RuntimeError(f"RotorLossRecovery: no alarm in {MAX_RESETS} flights; check the detector settings")

    def step(self, action):
        check_open(self._closed, "step")
        action = real_array(action, "action", "4 finite numbers in [-1, 1]")
        if action.shape != (4,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action: must be 4 finite numbers, got {action!r}")
        command = to_motor_command(action)[self._order]
        reward, info, n = 0.0, self._info, 0
        while n < self.action_repeat:
            n += 1
            self._obs, _, terminated, truncated, info = self.env.step(command)
            self._info = info
            self._follow_guide()
            reward += recovery_reward(info, command)
            if terminated or truncated:
                break
        terminated = bool(info["crashed"])
        truncated = not terminated and (truncated or info["time"] >= self._end_time - 1e-9)
        reward = -CRASH_PENALTY if terminated else reward / n     # a crash is not averaged away over the repeat
        return self._features(), reward, terminated, truncated, self._task_info()

    def close(self):
        for env in self._envs.values():
            env.close()
        self._envs.clear()
        self._closed = True

    # ------------------------------------------------------------------------------------ internals
    def _fly_to_alarm(self) -> bool:
        """Draw an episode and fly the nominal controller until the alarm; False if none came."""
        rng = self.np_random
        self.env = self._simulator(self.vehicles[rng.integers(len(self.vehicles))], int(rng.integers(len(self.tasks))))
        wind = _draw_wind(self.winds[rng.integers(len(self.winds))], rng)
        rotor = int(rng.choice(self.failed_rotors))
        # one window draws no pick, so the episodes of a single-window config keep their seeded draws
        window = self.onsets[rng.integers(len(self.onsets))] if len(self.onsets) > 1 else self.onsets[0]
        onset = float(rng.uniform(*window))
        options = {"wind": wind, "faults": [{"kind": "rotor_loss", "target": rotor, "time": onset}]}
        obs, info = self.env.reset(seed=int(rng.integers(2**31)), options=options)
        base = self.env.unwrapped
        nominal = make_policy("nominal", self.env)
        nominal.reset(obs, policy_view(info, nominal))
        while not info["fdd"][DETECTOR]["alarm"]:
            obs, _, terminated, truncated, info = self.env.step(nominal.act(obs, policy_view(info, nominal)))
            if terminated or truncated:
                return False
        self._obs, self._info = obs, info
        self._end_time = info["time"] + self.horizon_seconds
        self._order = rotor_order(info["fdd"][DETECTOR])     # the alarm is latched: fixed for the episode
        self._episode = {"vehicle": base.params.name, "task": base.task.name,
                         "failed_rotor": rotor, "onset_time": onset, "alarm_time": info["time"]}
        if base.params.name not in self._guides:
            self._guides[base.params.name] = SpinRecoveryController(base.params, base.agent_hz)
        self._guide = self._guides[base.params.name]
        self._guide.reset()
        self._guide.engage(info["fdd"][DETECTOR]["isolated"], obs)
        self._follow_guide()
        return True

    def _follow_guide(self) -> None:
        """`ftc-spin`'s controller on the current observation (it must see every simulator step): its outer
        loop's guidance for the features and, with `expert`, its command as the label. It never flies."""
        command = self._guide.act(self._obs, self._info)
        if self.expert:
            self._expert_action = (2.0 * np.asarray(command, dtype=np.float32) - 1.0)[self._order]

    def _simulator(self, vehicle: str, task: int) -> gym.Env:
        if (vehicle, task) not in self._envs:
            env = gym.make("ftcgym/Quadrotor-v0", vehicle=vehicle, task=self.tasks[task], agent_hz=self.agent_hz,
                           sensors=self.sensors, max_episode_seconds=self.onset[1] + 2.0 + self.horizon_seconds,
                           faults=[{"kind": "rotor_loss", "target": 0, "time": self.onset[1]}])
            self._envs[vehicle, task] = wrap_with_detector(DETECTOR, env.unwrapped, **self.detector_kwargs)
        return self._envs[vehicle, task]

    def _features(self) -> np.ndarray:
        return guided_features(self._obs, self._info["fdd"][DETECTOR], self._guide)

    def _task_info(self) -> dict:
        info = {"time": self._info["time"], "crashed": self._info["crashed"], **self._episode,
                "position_error": (np.asarray(self._info["truth"]["position"])
                                   - self._info["reference"]["position"]).tolist()}
        if self.expert:
            info["expert_action"] = self._expert_action.copy()
        return info


def _draw_wind(spec, rng) -> dict | None:
    """A wind dict for DrydenWind.from_config; {"mean_speed": [lo, hi]} draws a horizontal mean wind."""
    if not isinstance(spec, dict) or "mean_speed" not in spec:
        return spec
    rest = {key: value for key, value in spec.items() if key != "mean_speed"}
    return {**rest, "mean": random_mean_wind(rng, interval(spec["mean_speed"], "wind.mean_speed"))}


def check_open(closed: bool, call: str) -> None:
    """A closed task env stays closed, as the vehicle envs do: a reset would quietly make new simulators."""
    if closed:
        raise RuntimeError(f"{call}: this env is closed (its simulators are released); make a new one")


def interval(value, name: str, positive: bool = False) -> tuple[float, float]:
    """[lo, hi] (or one number) with 0 <= lo <= hi (0 < lo if `positive`); ValueError naming the field."""
    try:
        bounds = real_array(value, name, "a number or [lo, hi]").ravel()
        low, high = float(bounds[0]), float(bounds[-1])
        ok = (np.ndim(value) == 0 or (np.ndim(value) == 1 and len(bounds) == 2)) and math.isfinite(low) \
            and math.isfinite(high)
    except (ValueError, IndexError):
        ok = False
    if not ok or not (0 <= low <= high) or (positive and low <= 0):
        bound = "0 < lo <= hi" if positive else "0 <= lo <= hi"
        raise ValueError(f"{name}: expected a number or [lo, hi] with {bound}, got {value!r}")
    return low, high


def _onsets(value) -> list[tuple[float, float]]:
    """The onset windows to draw from: one [lo, hi] (or a number), or a non-empty list of [lo, hi] windows
    drawn with equal weight (to put more of the training on the hard moments of a task)."""
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, (list, tuple)) for v in value):
        return [interval(v, f"onset[{i}]") for i, v in enumerate(value)]
    return [interval(value, "onset")]


def _tasks(value) -> list:
    """The tasks to draw from: one task (a name or a dict) or a non-empty list of them, each checked now."""
    tasks = list(value) if isinstance(value, (list, tuple)) else [value]
    if not tasks:
        raise ValueError("task: expected a task or a non-empty list of tasks, got []")
    for task in tasks:
        make_task(task)          # raises ValueError naming the bad task or option
    return tasks


def _rotors(value) -> list[int]:
    rotors = list(range(4)) if value == "random" else [value] if not isinstance(value, (list, tuple)) else list(value)
    if not rotors or not all(isinstance(r, (int, np.integer)) and not isinstance(r, bool) and 0 <= r < 4
                             for r in rotors):
        raise ValueError(f"failed_rotor: expected 'random', a rotor index 0-3 or a list of them, got {value!r}")
    return [int(r) for r in rotors]
