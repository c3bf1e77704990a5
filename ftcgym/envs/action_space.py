"""`ActionBox`: the action space of every ftcgym env, a `gymnasium.spaces.Box` whose `sample` is cheap."""
from __future__ import annotations

from copy import deepcopy

import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space


class ActionBox(spaces.Box):
    """A `Box` with finite float bounds whose `sample()` draws Box's values at a fraction of its cost.

    `Box.sample` sorts every coordinate by its kind of interval (bounded, half-bounded, unbounded) on each call
    and draws each kind apart, about as long as an env step at 500 Hz takes; random-action loops (exploration,
    benchmarks) pay it on every step. With every bound finite it reduces to one `np_random.uniform(low, high)`
    cast to the dtype (the draws of the other kinds are empty and leave the generator as it was), which this
    calls directly: a seeded space gives Box's sequence, bit for bit. A mask or probability goes to Box.
    """

    def __init__(self, low, high, shape=None, dtype=np.float32, seed=None):
        super().__init__(low, high, shape, dtype, seed)
        if self.dtype.kind != "f" or not self.is_bounded("both"):
            raise ValueError(f"ActionBox: bounds must be finite floats, got low={self.low}, high={self.high}, "
                             f"dtype={self.dtype}")
        self._uniform_low, self._uniform_high = self.low.astype(np.float64), self.high.astype(np.float64)

    def sample(self, mask=None, probability=None) -> np.ndarray:
        if mask is not None or probability is not None:
            return super().sample(mask, probability)
        return self.np_random.uniform(self._uniform_low, self._uniform_high, self.shape).astype(self.dtype)


@batch_space.register(ActionBox)
def _batch_action_box(space: ActionBox, n: int = 1) -> ActionBox:
    """The action space of a vector env of `n` such envs: Gymnasium's batch of a Box (the bounds tiled, a copy of
    the generator), as an `ActionBox`, so that sampling a batch stays cheap and draws Box's values."""
    repeats = (n,) + (1,) * space.low.ndim
    return ActionBox(np.tile(space.low, repeats), np.tile(space.high, repeats), dtype=space.dtype,
                     seed=deepcopy(space.np_random))
