"""`LearnedPolicy`: a saved Stable-Baselines3 model behind the policy interface of docs/concepts.md
('Policies and oracles').

For a model trained on `ftcgym/RotorLossRecovery-v0` it flies as the task does: the nominal controller
until the `loe_kalman` alarm, then the model on `recovery_features` (normalised with the saved
VecNormalize statistics), its action rescaled to motor commands and held for the task's `action_repeat`
steps. For a model trained on another env id it acts on the raw observation at every step.
Actions are deterministic.

Recovery is scored against the policy's `thrust_axis_reference` (docs/concepts.md, 'Benchmark metrics').
A vehicle without one propeller recovers into the relaxed hover (Mueller & D'Andrea 2014; 001 App. B), whose
thrust axis circles the commanded primary axis at the equilibrium's tilt. `axis_reference` picks how the
learned policy states where its thrust axis belongs after the alarm:
- "ftc-spin" (default): where `ftc-spin`'s would, from the shadow `SpinRecoveryController` engaged on the
  isolated rotor that sees every observation, never flies, and gives the model its guidance features (the
  task's, `recovery_features`). The two policies are then scored by the same rule: the equilibrium's thrust
  axis about the primary axis that ftc-spin's position loop commands (it leans up to 20-30 deg to correct
  position).
- "equilibrium": the equilibrium's thrust axis about the vertical, `thrust_axis_reference_for(R, R^T up,
  n_bar)`; stricter, since leaning to correct position counts as error.
"""
from __future__ import annotations

import numpy as np

from ftcgym.agents import flies_airspeed, is_quadplane, make_policy
from ftcgym.agents.base import UP
from ftcgym.agents.catalogue import check_flown_env
from ftcgym.agents.spin_recovery import SpinRecoveryController, thrust_axis_reference_for
from ftcgym.models.geometry import rotation_matrix
from ftcgym.task_envs.airspeed_source import DETECTOR as AIRSPEED_DETECTOR
from ftcgym.task_envs.airspeed_source import ENV_ID as AIRSPEED_ENV_ID
from ftcgym.task_envs.airspeed_source import airspeed_features, blend, to_weight
from ftcgym.task_envs.rotor_loss_recovery import DETECTOR, N_FEATURES, guided_features, rotor_order, to_motor_command
from ftcgym.training.saved import (  # noqa: F401
    MANIFEST_FILE,
    MODEL_FILE,
    NORMALIZER_FILE,
    SavedModelPolicy,
    load_normalizer,
    model_files,
    read_manifest,
)

TASK_ENV_ID = "ftcgym/RotorLossRecovery-v0"


class LearnedPolicy(SavedModelPolicy):
    """A trained model as a benchmark policy. Build it with `LearnedPolicy.load(path, env)` or, during
    training, from the live model and VecNormalize (`LearnedPolicy(model, normalizer, ...)`)."""

    detector = DETECTOR
    DEFAULT_ENV_ID = TASK_ENV_ID
    AXIS_REFERENCES = ("ftc-spin", "equilibrium")

    def __init__(self, model, normalizer=None, env_id: str = TASK_ENV_ID, task_kwargs: dict | None = None,
                 env=None, axis_reference: str = "ftc-spin"):
        if axis_reference not in self.AXIS_REFERENCES:
            raise ValueError(f"axis_reference: {axis_reference!r}; accepted: {list(self.AXIS_REFERENCES)}")
        self.axis_reference = axis_reference
        self.model, self.normalizer, self.env_id = model, normalizer, env_id
        self.action_repeat = int((task_kwargs or {}).get("action_repeat", 2)) if env_id == TASK_ENV_ID else 1
        self.nominal = None
        if env_id == TASK_ENV_ID:
            shape = tuple(model.observation_space.shape)
            if shape != (N_FEATURES,):
                raise ValueError(f"LearnedPolicy: the model takes {shape} observations; recovery_features gives "
                                 f"({N_FEATURES},); a model of an earlier feature layout (37 or 38) must be "
                                 f"retrained (`ftcgym train`)")
            if env is None:
                raise ValueError("LearnedPolicy: a rotor-loss-recovery model needs the env (for its nominal "
                                 "controller)")
            self.nominal = make_policy("nominal", env)
            self._shadow = SpinRecoveryController(env.unwrapped.params, env.unwrapped.agent_hz)
        self.reset()

    @property
    def thrust_axis_reference(self) -> np.ndarray:
        if self.nominal is None:
            return UP.copy()
        if not self.engaged:
            return self.nominal.thrust_axis_reference
        if self.axis_reference == "ftc-spin":
            return self._shadow.thrust_axis_reference
        return thrust_axis_reference_for(self._attitude, self._attitude.T @ UP, self._primary_axis)

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        self.engaged, self._steps, self._action = False, 0, None
        self._attitude, self._primary_axis = np.eye(3), -UP
        if self.nominal is not None:
            self._shadow.reset()
        if self.nominal is not None:
            self.nominal.reset(obs, info)

    def act(self, obs, info: dict) -> np.ndarray:
        if self.nominal is None:
            return self.predict(obs)
        status = info.get("fdd", {}).get(DETECTOR)
        if status is None:
            raise ValueError(f"LearnedPolicy needs the env wrapped with the {DETECTOR!r} detector")
        if not self.engaged and not status["alarm"]:
            return self.nominal.act(obs, info)
        if not self.engaged:
            self.engaged = True
            self._shadow.engage(int(status["isolated"]), obs)
            self._primary_axis = self._shadow.equilibrium(int(status["isolated"]))["n"]
        self._attitude = rotation_matrix(obs["attitude"])
        self._shadow.act(obs, info)          # its guidance and reference for this observation; never flown
        if self._steps % self.action_repeat == 0:
            features = guided_features(obs, status, self._shadow)
            self._action = to_motor_command(self.predict(features))[rotor_order(status)]
        self._steps += 1
        return self._action


class LearnedAirspeedPolicy(SavedModelPolicy):
    """A model trained on `ftcgym/AirspeedSource-v0` as a benchmark policy on QuadPlaneAutopilot-v0 (with
    the `airdata_ekf` detector): the pitot reading until the detector is armed, then every `action_repeat`
    steps the model's deterministic weight w on `airspeed_features` (normalised with the saved VecNormalize
    statistics), and at each step (1 - w) pitot + w EKF airspeed: the task's features and decision rate.
    Build it with `LearnedAirspeedPolicy.load(path, env)` or from a live model (the evaluation callback)."""

    detector = AIRSPEED_DETECTOR
    DEFAULT_ENV_ID = AIRSPEED_ENV_ID

    def __init__(self, model, normalizer=None, env_id: str = AIRSPEED_ENV_ID, task_kwargs: dict | None = None,
                 env=None):
        self.model, self.normalizer, self.env_id = model, normalizer, env_id
        self.action_repeat = int((task_kwargs or {}).get("action_repeat", 10))
        self.reset()

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        self.engaged, self._steps, self.weight = False, 0, 0.0

    def act(self, obs: dict, info: dict) -> np.ndarray:
        status = info.get("fdd", {}).get(AIRSPEED_DETECTOR)
        if status is None:
            raise ValueError(f"{type(self).__name__} needs the env wrapped with the {AIRSPEED_DETECTOR!r} detector "
                             f"(e.g. `ftcgym bench --detector {AIRSPEED_DETECTOR}`)")
        if not self.engaged and not status["detection_armed"]:
            return np.array([obs["pitot_airspeed"][0]], dtype=np.float32)
        self.engaged = True
        if self._steps % self.action_repeat == 0:
            self.weight = to_weight(self.predict(airspeed_features(obs, {**status, "time": info["time"]},
                                                                   self.weight)))
        self._steps += 1
        return blend(obs, self.weight)


# env id of a training task -> the policy class that flies its models in the benchmark (`load_policy`)
POLICY_CLASSES = {TASK_ENV_ID: LearnedPolicy, AIRSPEED_ENV_ID: LearnedAirspeedPolicy}
# env id of a training task -> the benchmark's name of its learned policy (`ftcgym.training.shipped.SHIPPED`)
POLICY_NAMES = {TASK_ENV_ID: "learned-spin", AIRSPEED_ENV_ID: "learned-airspeed"}
# env id of a training task -> the scenario `ftcgym evaluate` flies its models through by default
DEFAULT_SCENARIOS = {TASK_ENV_ID: "quad-rotor-loss-hover", AIRSPEED_ENV_ID: "qp-pitot-incipient"}


def policy_name(env_id: str) -> str:
    """The benchmark's name for a policy learned on `env_id`: `learned-spin`, `learned-airspeed`, else `learned`."""
    return POLICY_NAMES.get(env_id, "learned")


def trained_env_id(path) -> str:
    """The env id the model saved at `path` was trained on (its manifest's; the rotor-loss task without one)."""
    _, _, manifest_path = model_files(path)
    return read_manifest(manifest_path).get("config", {}).get("env_id", TASK_ENV_ID)


def load_policy(path, env):
    """The model saved by `ftcgym train` at `path` as a benchmark policy for `env`, with the policy class
    of the env id it was trained on (`POLICY_CLASSES`; `LearnedPolicy` for any other id)."""
    env_id = trained_env_id(path)
    _check_vehicle(path, env_id, check_flown_env(env, str(path)))
    try:
        return POLICY_CLASSES.get(env_id, LearnedPolicy).load(path, env)
    except ValueError as error:
        if model_files(path)[2].is_file():
            raise
        raise ValueError(f"{error}. {path} has no {MANIFEST_FILE} beside it, so it was taken for a model of "
                         f"{TASK_ENV_ID} saved by `ftcgym train`; a Stable-Baselines3 model of your own flies as a "
                         f"policy class of yours (docs/howto/own-policy.md)") from None


def _check_vehicle(path, env_id: str, base) -> None:
    """A model flies only the kind of env its task was built on: say so before anything else fails."""
    flies = {TASK_ENV_ID: ("ftcgym/Quadrotor-v0", not is_quadplane(base)),
             AIRSPEED_ENV_ID: ("ftcgym/QuadPlaneAutopilot-v0", flies_airspeed(base))}
    if env_id in flies and not flies[env_id][1]:
        raise ValueError(f"policy: the model {path} was trained on {env_id} and flies {flies[env_id][0]}, "
                         f"not {type(base).__name__}")
