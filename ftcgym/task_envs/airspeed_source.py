"""Task `airspeed-source`: which airspeed to feed the quad-plane autopilot, from the pitot reading
and the `airdata_ekf` detector's outputs.

`ftcgym/AirspeedSource-v0` wraps `ftcgym/QuadPlaneAutopilot-v0` (whose action is the airspeed the autopilot
schedules on) with the `airdata_ekf` detector: 001's (Larocque 2023) synthetic air data EKF, its pitot
residual r = pitot - EKF forward airspeed with the Table 2 alarm (Sec. 6.1) and a CUSUM on r's drop (the test
001 Sec. 7.2.2 / 8.1 recommends for incipient faults).

- Episode: `reset` draws the episode (below), flies the mission feeding the pitot reading until the detector
  is armed (20 s after the EKF starts, 001 Sec. 5.4: before that its wind estimate is still converging and
  no pitot test runs), and returns the first armed observation. The agent then decides every
  `action_repeat` simulator steps (10 at the env's 100 Hz: 10 Hz decisions) until `onset + horizon_seconds`
  (truncated), the landing or a crash (terminated). Fault-free episodes end the same way at their
  would-be onset.
- Action: Box(-1, 1, (1,)): the weight w = (a + 1) / 2 of the synthetic airspeed, held for the repeat; at
  every simulator step the autopilot gets (1 - w) * pitot + w * EKF airspeed from that step's readings.
- Observation: Box(N_FEATURES,) float32 from `airspeed_features`: only what a flight computer has (pitot,
  EKF airspeed and residual outputs, alarms, GNSS ground speed, skew, mission phase, the previous w);
  never `info["truth"]`.
- Reward per decision (the mean over its simulator steps; a decision that ends in a crash gives the whole -100),
  from the simulator's true airspeed V:
  r = 1 - min(|a_fed - V|, 10) / 10 - 0.5 [|a_fed - V| > 2 m/s], and -100 on a crash. The first terms are
  QuadPlaneAutopilot-v0's reward; the 0.5 penalty outside 2 m/s is the benchmark's recovery tolerance
  (`benchmark.metrics.AIRSPEED_TOLERANCE`), so the reward ranks blends as the success metric does.
- Domain randomisation (drawn per episode from the env's seeded RNG): the fault kind from `fault_mix`
  ({"none", "zero", "stuck", "incipient"}: weights), the incipient rate (m/s^2, `incipient_rate`; 001
  Sec. 7.2.2 uses 2.5), the onset time (`onset`, s: in cruise for the default mission, whose cruise starts
  at ~28 s and ends at ~80 s), and the mean wind: speed uniform in `wind_speed` m/s (default 0-6 m/s; the
  autopilot flies mean winds up to 9 m/s in light turbulence), direction uniform, with `turbulence`.
"""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ftcgym.agents.quadplane_autopilot import PHASES
from ftcgym.criteria import AIRSPEED_TOLERANCE
from ftcgym.envs.action_space import ActionBox
from ftcgym.fdd import wrap_with_detector
from ftcgym.models.checks import POSITIVE, keywords_checked, number, real_array, whole_number
from ftcgym.models.wind import DrydenWind, random_mean_wind
from ftcgym.task_envs.rotor_loss_recovery import check_open, interval

ENV_ID = "ftcgym/AirspeedSource-v0"
DETECTOR = "airdata_ekf"
FAULT_KINDS = ("none", "zero", "stuck", "incipient")
N_FEATURES = 12 + len(PHASES)
FEATURE_BOUND = 10.0
AIRSPEED_SCALE = 20.0        # m/s per unit (cruise is 18 m/s)
RESIDUAL_SCALE = 5.0         # m/s per unit (001 Table 2's norm threshold is 5.5 m/s)
DERIVATIVE_SCALE = 25.0      # m/s^2 per unit (001 Table 2's derivative threshold)
CUSUM_SCALE = 2.0            # m/s per unit (the CUSUM threshold is 1.9 m/s)
ALARM_AGE_SCALE = 10.0       # s per unit, capped at 1
CRASH_PENALTY = 100.0
TOLERANCE_PENALTY = 0.5
MAX_RESETS = 20


def airspeed_features(obs: dict, status: dict, weight: float) -> np.ndarray:
    """The flat observation of the task (N_FEATURES float32) from an `airdata_ekf`-wrapped
    QuadPlaneAutopilot-v0 observation, the detector's `info["fdd"]["airdata_ekf"]` status and the previous
    synthetic weight. `LearnedAirspeedPolicy` feeds the model the same features in the benchmark.

    pitot / 20, EKF airspeed / 20, (pitot - EKF) / 5, filtered residual / 5, its derivative / 25, CUSUM / 2,
    pitot alarm (0/1), an innovation (GNSS / pusher RPM) alarm (0/1), seconds since the pitot alarm / 10
    (capped at 1; 0 before), GNSS ground speed / 20, skew / 90 deg, the previous weight, mission phase one-hot.
    Clipped to +-10.
    """
    pitot = float(obs["pitot_airspeed"][0])
    synthetic = float(obs[f"fdd/{DETECTOR}/airspeed"][0])
    alarm_time = status.get("pitot_alarm_time")
    since = 0.0 if alarm_time is None else max(status.get("time", alarm_time) - alarm_time, 0.0)
    age = min(since / ALARM_AGE_SCALE, 1.0)
    innovation = any(t is not None for t in (status.get("innovation_alarms") or {}).values())
    phase = np.zeros(len(PHASES))
    phase[int(round(float(obs["mission_phase"][0])))] = 1.0
    velocity = np.asarray(obs["gnss_velocity"], dtype=float)
    features = np.concatenate((
        [pitot / AIRSPEED_SCALE, synthetic / AIRSPEED_SCALE, (pitot - synthetic) / RESIDUAL_SCALE,
         status["pitot_residual"] / RESIDUAL_SCALE, status["pitot_residual_derivative"] / DERIVATIVE_SCALE,
         status["cusum_statistic"] / CUSUM_SCALE, float(bool(status["pitot_alarm"])), float(innovation), age,
         math.hypot(velocity[0], velocity[1]) / AIRSPEED_SCALE, float(obs["skew"][0]) / (0.5 * math.pi),
         float(weight)],
        phase))
    return np.clip(np.nan_to_num(features), -FEATURE_BOUND, FEATURE_BOUND).astype(np.float32)


def to_weight(action) -> float:
    """The synthetic-airspeed weight in [0, 1] of a Box(-1, 1) action."""
    return float((np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1.0, 1.0) + 1.0) / 2.0)


def blend(obs: dict, weight: float) -> np.ndarray:
    """The airspeed fed to the autopilot: (1 - w) pitot + w EKF airspeed, as QuadPlaneAutopilot-v0's action."""
    pitot, synthetic = float(obs["pitot_airspeed"][0]), float(obs[f"fdd/{DETECTOR}/airspeed"][0])
    return np.array([(1.0 - weight) * pitot + weight * synthetic], dtype=np.float32)


def airspeed_reward(fed: float, true_airspeed: float, crashed: bool) -> float:
    """The task's reward for one simulator step (module docstring)."""
    if crashed:
        return -CRASH_PENALTY
    error = abs(fed - true_airspeed)
    return 1.0 - min(error, 10.0) / 10.0 - TOLERANCE_PENALTY * float(error > AIRSPEED_TOLERANCE)


class AirspeedSourceEnv(gym.Env):
    """`ftcgym/AirspeedSource-v0`; see the module docstring.

    Keywords: fault_mix ({kind: weight} over FAULT_KINDS), incipient_rate ([lo, hi] m/s^2), onset ([lo, hi] s
    from take-off), horizon_seconds (after the onset), wind_speed ([lo, hi] m/s), turbulence (the Dryden
    level), action_repeat (simulator steps per decision), task (QuadPlaneAutopilot-v0's task),
    max_episode_seconds (its time limit), detector_kwargs (for `airdata_ekf`), sensors (sensor overrides).
    """

    metadata = {"render_modes": []}

    @keywords_checked
    def __init__(self, fault_mix=None, incipient_rate=(1.0, 4.0), onset=(30.0, 75.0), horizon_seconds: float = 20.0,
                 wind_speed=(0.0, 6.0), turbulence="light", action_repeat: int = 10, task="mission",
                 max_episode_seconds: float = 240.0, detector_kwargs: dict | None = None,
                 sensors: dict | None = None):
        mix = {"none": 0.2, "zero": 0.35, "incipient": 0.45} if fault_mix is None else fault_mix
        if not isinstance(mix, dict) or not mix:
            raise ValueError(f"fault_mix: expected a dict {{kind: weight}} over {list(FAULT_KINDS)}, got {mix!r}")
        unknown = sorted(set(mix) - set(FAULT_KINDS), key=str)
        if unknown:
            raise ValueError(f"fault_mix: unknown kind(s) {unknown}; accepted: {list(FAULT_KINDS)}")
        weights = np.array([float(w) for w in mix.values()])
        if not (np.all(np.isfinite(weights)) and np.all(weights >= 0) and weights.sum() > 0):
            raise ValueError(f"fault_mix: weights must be finite, >= 0 and not all 0, got {mix!r}")
        self.fault_kinds, self.fault_weights = list(mix), weights / weights.sum()
        self.incipient_rate = interval(incipient_rate, "incipient_rate", positive=True)
        self.onset = interval(onset, "onset")
        self.wind_speed = interval(wind_speed, "wind_speed")
        self.horizon_seconds = number(horizon_seconds, "horizon_seconds", POSITIVE)
        self.action_repeat = whole_number(action_repeat, "action_repeat")
        self.max_episode_seconds = number(max_episode_seconds, "max_episode_seconds", POSITIVE)
        self.turbulence, self.task, self.sensors = turbulence, task, sensors
        if detector_kwargs is not None and not isinstance(detector_kwargs, dict):
            raise ValueError(f"detector_kwargs: expected a dict of {DETECTOR} settings, got {detector_kwargs!r}")
        self.detector_kwargs = dict(detector_kwargs or {})
        self.observation_space = spaces.Box(-FEATURE_BOUND, FEATURE_BOUND, (N_FEATURES,), np.float32)
        self.action_space = ActionBox(-1.0, 1.0, (1,), np.float32)
        self.env, self._closed = None, False
        # built now, so that a bad task, sensor, turbulence or detector setting fails at make
        DrydenWind.from_config({"turbulence": turbulence}, 0.002)
        self._simulator()

    # ------------------------------------------------------------------------------------ episodes
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if options:
            raise ValueError(f"reset options: AirspeedSource-v0 draws each episode from its gym.make keywords and "
                             f"takes none, got {options!r}")
        check_open(self._closed, "reset")
        super().reset(seed=seed)
        for _ in range(MAX_RESETS):
            if self._fly_to_armed():
                return self._features(), self._task_info()
        raise RuntimeError(f"AirspeedSource: the detector never armed in {MAX_RESETS} flights")

    def step(self, action):
        check_open(self._closed, "step")
        action = real_array(action, "action", "one finite number in [-1, 1]")
        if action.shape not in ((), (1,)) or not np.all(np.isfinite(action)):
            raise ValueError(f"action: must be one finite number, got {action!r}")
        self._weight = to_weight(action)
        reward, info, terminated, truncated, n = 0.0, self._info, False, False, 0
        while n < self.action_repeat:
            n += 1
            fed = blend(self._obs, self._weight)
            self._obs, _, terminated, truncated, info = self.env.step(fed)
            self._info = info
            reward += airspeed_reward(float(fed[0]), info["truth"]["airspeed"], info["crashed"])
            if terminated or truncated:
                break
        terminated = bool(terminated)
        truncated = not terminated and (truncated or info["time"] >= self._end_time - 1e-9)
        reward = -CRASH_PENALTY if info["crashed"] else reward / n     # a crash is not averaged away over the repeat
        return self._features(), reward, terminated, truncated, self._task_info()

    def close(self):
        if self.env is not None:
            self.env.close()
            self.env = None
        self._closed = True

    # ------------------------------------------------------------------------------------ internals
    def _fly_to_armed(self) -> bool:
        """Draw an episode and fly it on the pitot until the detector is armed; False if it never was."""
        rng = self.np_random
        env = self._simulator()
        kind = str(rng.choice(self.fault_kinds, p=self.fault_weights))
        onset = float(rng.uniform(*self.onset))
        mean_wind = random_mean_wind(rng, self.wind_speed)
        rate = float(rng.uniform(*self.incipient_rate)) if kind == "incipient" else None
        spec = {"zero": {"target": "zero"}, "stuck": {"target": "stuck"}, "incipient": {"rate": rate}}.get(kind)
        options = {"wind": {"mean": mean_wind, "turbulence": self.turbulence},
                   "faults": [] if spec is None else [{"kind": "pitot_blockage", "time": onset, **spec}]}
        obs, info = env.reset(seed=int(rng.integers(2**31)), options=options)
        while not info["fdd"][DETECTOR]["detection_armed"]:
            obs, _, terminated, truncated, info = env.step(np.array([obs["pitot_airspeed"][0]], dtype=np.float32))
            if terminated or truncated:
                return False
        self._obs, self._info, self._weight = obs, info, 0.0
        self._end_time = onset + self.horizon_seconds
        self._episode = {"fault": kind, "onset_time": onset, "incipient_rate": rate, "mean_wind": mean_wind,
                         "armed_time": info["time"]}
        return True

    def _simulator(self) -> gym.Env:
        if self.env is None:
            env = gym.make("ftcgym/QuadPlaneAutopilot-v0", task=self.task, sensors=self.sensors,
                           max_episode_seconds=self.max_episode_seconds)
            self.env = wrap_with_detector(DETECTOR, env.unwrapped, **self.detector_kwargs)
        return self.env

    def _features(self) -> np.ndarray:
        return airspeed_features(self._obs, self._status(self._info), self._weight)

    def _task_info(self) -> dict:
        return {"time": self._info["time"], "crashed": self._info["crashed"], **self._episode,
                "weight": self._weight, "phase": self._info["mission"]["phase"],
                "airspeed_used": self._info["mission"]["airspeed_used"]}

    @staticmethod
    def _status(info: dict) -> dict:
        return {**info["fdd"][DETECTOR], "time": info["time"]}
