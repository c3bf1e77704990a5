"""`ftcgym/QuadPlaneAutopilot-v0`: the quad-plane flown along its mission by the built-in autopilot; the action
is the airspeed (m/s) the autopilot schedules on (wing skew, surface effectiveness, wing lift, pusher loop;
`agents.quadplane_autopilot`). A policy thus chooses or blends the airspeed source: the pitot reading, a
synthetic estimate (the `airdata_ekf` detector's), or anything in between.

Same kwargs, observation and `info` contract as QuadPlane-v0 (but only the Dict observation and the full `info`),
plus the observation `mission_phase` (index in
`PHASES`) and `info["mission"]` = {"phase", "airspeed_used", "cruise_airspeed"}. Action: Box(0, 60, (1,)) m/s,
clipped; a
non-finite or wrongly shaped action raises ValueError. Reward per step: 1 - min(|a - V_true|, 10) / 10 (how
well the airspeed fed matches the truth; a policy sees only sensors), -100 on a crash. The episode
terminates when the mission ends on the ground (`landed`) or on a crash; truncated after
`max_episode_seconds`. `request_airspeed_offset(dv)` shifts the cruise airspeed target by dv m/s (a
detector's excitation request, 003 Sec. III-D).
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..agents.quadplane_autopilot import PHASES, QuadPlaneAutopilot
from ..envs.action_space import ActionBox
from ..envs.quadplane import CRASH_PENALTY, QuadPlaneEnv
from ..models.checks import real_array
from ..models.tasks import MissionTask, make_task

MAX_AIRSPEED_ACTION = 60.0   # m/s
#: m/s, largest cruise-setpoint change a detector may ask for (stays above stall, below 24 m/s)
MAX_AIRSPEED_OFFSET = 6.0


class QuadPlaneAutopilotEnv(gym.Env):
    """QuadPlane-v0 with the autopilot inside; see the module docstring."""

    metadata = QuadPlaneEnv.metadata
    controls = "airspeed"          # what the action commands (QuadrotorEnv: "rotors", QuadPlaneEnv: "actuators")

    def __init__(self, **kwargs):
        for key, only, why in (("observation_format", "dict", "the autopilot reads the readings by name; gymnasium's "
                                "FlattenObservation flattens them"),
                               ("info_level", "full", "the reward is the error to info['truth']['airspeed']")):
            if kwargs.get(key, only) != only:
                raise ValueError(f"{key}: QuadPlaneAutopilot-v0 takes only {only!r} ({why}), got {kwargs[key]!r}")
        task = make_task(kwargs.get("task", "mission"))
        if not isinstance(task, MissionTask):
            raise ValueError(f"task: the autopilot flies a mission; accepted: 'mission' or a dict with name "
                             f"'mission', got {kwargs['task']!r}")
        self.plane = QuadPlaneEnv(**kwargs)
        self.params, self.agent_hz, self.task = self.plane.params, self.plane.agent_hz, self.plane.task
        self.render_mode = self.plane.render_mode
        self.metadata = self.plane.metadata     # render_fps: the agent rate, as QuadPlane-v0's
        self.autopilot = QuadPlaneAutopilot(self.params, self.agent_hz, self.task)
        self.action_space = ActionBox(0.0, MAX_AIRSPEED_ACTION, (1,), np.float32)
        self.observation_space = spaces.Dict({**self.plane.observation_space.spaces,
                                              "mission_phase": spaces.Box(0.0, len(PHASES) - 1.0, (1,), np.float64)})

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start a mission; `options` as QuadPlane-v0's (`faults`, `wind`, `vehicle_overrides` for one episode)."""
        super().reset(seed=seed)
        obs, info = self.plane.reset(seed=seed, options=options)
        self.autopilot.reset(obs, info)
        self._obs, self._info = obs, info
        return self._observe(obs), self._augment(info)

    def step(self, action):
        airspeed = _check_action(action)
        command = self.autopilot.act(self._obs, self._info, airspeed=airspeed)
        obs, _, terminated, truncated, info = self.plane.step(command)
        self._obs, self._info = obs, info
        landed = self.autopilot.phase == "landed"
        terminated = terminated or landed
        truncated = truncated and not terminated
        error = abs(airspeed - info["truth"]["airspeed"])
        reward = -CRASH_PENALTY if info["crashed"] else 1.0 - min(error, 10.0) / 10.0
        return self._observe(obs), float(reward), terminated, truncated, self._augment(info)

    def request_airspeed_offset(self, offset: float) -> None:
        """Add `offset` m/s (clipped to +-MAX_AIRSPEED_OFFSET) to the autopilot's cruise airspeed target until
        the next request or reset: the excitation a detector asks for (003 Sec. III-D; `fdd.propulsion_bayes`).
        Only the cruise phase uses it; a non-finite offset raises ValueError."""
        if not np.isfinite(offset):
            raise ValueError(f"airspeed offset: must be finite, got {offset!r}")
        self.autopilot.airspeed_offset = float(np.clip(offset, -MAX_AIRSPEED_OFFSET, MAX_AIRSPEED_OFFSET))

    def _observe(self, obs: dict) -> dict:
        return {**obs, "mission_phase": np.array([float(PHASES.index(self.autopilot.phase))])}

    def _augment(self, info: dict) -> dict:
        info["mission"] = {"phase": self.autopilot.phase, "airspeed_used": self.autopilot.airspeed_used,
                           "cruise_airspeed": self.task.cruise_airspeed}
        return info

    def render(self):
        return self.plane.render()

    def close(self):
        self.plane.close()


def _check_action(action) -> float:
    a = real_array(action, "action", "real numbers, one airspeed in m/s").reshape(-1)
    if a.shape != (1,):
        raise ValueError(f"action: expected one airspeed value (shape (1,)), got shape {np.shape(action)}")
    if not np.isfinite(a[0]):
        raise ValueError(f"action: the airspeed must be finite, got {a[0]!r}")
    return float(np.clip(a[0], 0.0, MAX_AIRSPEED_ACTION))
