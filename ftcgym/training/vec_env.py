"""`ParallelVecEnv`: `ftcgym.vector.ParallelVectorEnv` behind Stable-Baselines3's `VecEnv` interface.

The envs step on every core through shared memory (`ftcgym.vector`) instead of one pipe round trip per env
and step (`SubprocVecEnv`). Results follow `DummyVecEnv`'s conventions: an env that ends is reset in the same
step, its last observation in `info["terminal_observation"]`, `info["TimeLimit.truncated"]` set, and the same
seeds give the same observations, rewards and infos.
"""
from __future__ import annotations

from copy import deepcopy

import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from ..vector import ParallelVectorEnv


class ParallelVecEnv(VecEnv):
    """SB3 `VecEnv` of the envs `env_fns` build, stepped by this process and `workers` worker processes
    (None: one per core beyond this one's)."""

    def __init__(self, env_fns, workers: int | None = None):
        self.vector_env = ParallelVectorEnv(env_fns, workers=workers, autoreset_mode=AutoresetMode.SAME_STEP)
        super().__init__(self.vector_env.num_envs, self.vector_env.single_observation_space,
                         self.vector_env.single_action_space)
        self._actions = None

    def reset(self):
        options = self._options[0]
        if any(other != options for other in self._options):
            raise ValueError("ParallelVecEnv.reset: different reset options per env are not supported; "
                             "accepted: the same options for every env")
        obs, self.reset_infos = self.vector_env.reset_each(seed=list(self._seeds), options=options or None)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rewards, terminations, truncations, infos = self.vector_env.step_each(self._actions)
        dones = terminations | truncations
        step_infos = []
        for k, info in enumerate(infos):
            if dones[k]:            # same-step autoreset: the ended episode's info and last observation
                self.reset_infos[k] = {key: value for key, value in info.items()
                                       if key not in ("final_obs", "final_info")}
                info = {**info["final_info"], "terminal_observation": info["final_obs"]}
            info["TimeLimit.truncated"] = bool(truncations[k] and not terminations[k])
            step_infos.append(info)
        return obs, rewards.astype(np.float32), dones, deepcopy(step_infos)   # as DummyVecEnv: copies

    def close(self) -> None:
        self.vector_env.close()

    def get_attr(self, attr_name: str, indices=None) -> list:
        values = self.vector_env.get_attr(attr_name)
        return [values[k] for k in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        chosen = set(self._get_indices(indices))
        if len(chosen) == self.num_envs:
            self.vector_env.set_attr(attr_name, [value] * self.num_envs)
            return
        current = self.vector_env.get_attr(attr_name)
        self.vector_env.set_attr(attr_name, [value if k in chosen else current[k] for k in range(self.num_envs)])

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        """The method's results on the envs of `indices` only, in their order; the other envs are not called."""
        chosen = list(self._get_indices(indices))
        results = dict(zip(sorted(set(chosen)), self.vector_env.call_at(chosen, method_name, *method_args,
                                                                        **method_kwargs)))
        return [results[k] for k in chosen]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        results = self.vector_env.call(is_wrapped, wrapper_class)
        return [results[k] for k in self._get_indices(indices)]

    def get_images(self):
        return list(self.vector_env.call("render"))
