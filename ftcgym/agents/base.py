"""The policy interface of DESIGN.md: `reset(obs, info)` and `act(obs, info) -> action`."""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    """What the benchmark and the training code call. `info` never holds `truth`, `fault` or `faults`."""

    def reset(self, obs: dict, info: dict) -> None: ...

    def act(self, obs: dict, info: dict) -> np.ndarray: ...
