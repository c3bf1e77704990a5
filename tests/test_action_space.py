"""`ActionBox`: every env's action space draws `gymnasium.spaces.Box`'s seeded sequence, faster."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import ftcgym  # noqa: F401
from ftcgym.envs.action_space import ActionBox

ENV_IDS = ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0", "ftcgym/RotorLossRecovery-v0", "ftcgym/AirspeedSource-v0",
           "ftcgym/QuadPlaneAutopilot-v0"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_env_action_space_samples_box_sequence(env_id):
    env = gym.make(env_id)
    space = env.action_space
    assert isinstance(space, ActionBox)
    box = spaces.Box(space.low, space.high, space.shape, space.dtype)
    space.seed(7)
    box.seed(7)
    for _ in range(2000):
        drawn, expected = space.sample(), box.sample()
        assert drawn.dtype == expected.dtype and np.array_equal(drawn, expected)
        assert space.contains(drawn)
    env.close()


def test_two_dimensional_bounds_keep_box_order():
    low = np.array([[0.0, -1.0, -2.0], [0.5, -3.0, 1.0]], dtype=np.float32)
    space, box = ActionBox(low, low + 2.5), spaces.Box(low, low + 2.5)
    space.seed(3)
    box.seed(3)
    assert all(np.array_equal(space.sample(), box.sample()) for _ in range(500))


@pytest.mark.parametrize("low, high, dtype", [(-np.inf, 1.0, np.float32), (0.0, np.inf, np.float64),
                                              (0, 3, np.int64)])
def test_unbounded_or_integer_boxes_are_refused(low, high, dtype):
    with pytest.raises(ValueError, match="ActionBox: bounds must be finite floats"):
        ActionBox(low, high, (2,), dtype)


def test_masked_sample_is_box_s():
    space = ActionBox(0.0, 1.0, (4,))
    with pytest.raises(gym.error.Error, match="cannot be provided a mask"):
        space.sample(mask=np.ones(4))


@pytest.mark.parametrize("vectorization_mode", ["sync", "vector_entry_point"])
def test_a_vector_env_s_batched_space_is_an_action_box_drawing_box_s_batch(vectorization_mode):
    """Gymnasium batches a space with `batch_space` (SyncVectorEnv, AsyncVectorEnv, ftcgym's parallel vector env):
    a batch of ActionBoxes is one ActionBox, which draws the values of Box's batch (`_batch_action_box`)."""
    vec = gym.make_vec("ftcgym/Quadrotor-v0", num_envs=3, vectorization_mode=vectorization_mode)
    space = vec.action_space
    box = gym.vector.utils.batch_space(spaces.Box(0.0, 1.0, (4,), np.float32), 3)
    assert isinstance(space, ActionBox) and space.shape == (3, 4) and np.array_equal(space.low, box.low)
    space.seed(5)
    box.seed(5)
    assert all(np.array_equal(space.sample(), box.sample()) for _ in range(500))
    vec.close()
