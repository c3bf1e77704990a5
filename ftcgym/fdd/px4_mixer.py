"""PX4's multirotor mixer for the quadrotor X: normalised motor outputs from the attitude controller's commands.

A PX4 log may keep the controller's commands (`actuator_controls_0`: roll, pitch, yaw torque in [-1, 1] and
thrust in [0, 1]) at a higher rate than the motor outputs (`actuator_outputs`: the RflyMAD SIL logs keep 20 Hz
against 10 Hz). Mixing the commands as the autopilot does recovers the outputs at the commands' rate.

Source: PX4 Autopilot (v1.12-v1.13), `src/lib/mixer/MultirotorMixer/MultirotorMixer.cpp`, `mix_airmode_disabled`
(the default, MC_AIRMODE 0), with the normalised table generated from `geometries/quad_x.toml` (`QUAD_X_SCALES`).
Per sample:
1. roll and pitch mixed with the thrust: u_i = roll r_i + pitch p_i + thrust t_i;
2. saturation reduced along the thrust (reducing it only), then along roll, then along pitch
   (`_minimize_saturation`);
3. yaw added, its saturation reduced along yaw (upper bound 1.15) and then along the thrust (reducing only).
The outputs are then clipped to [0, 1]; PWM = PWM_min + u (PWM_max - PWM_min) (no thrust curve: THR_MDL_FAC 0).
On the RflyMAD SIL logs this reproduces the logged PWM to 2 us before the fault and to about 10 us over the
first 0.3 s after it (docs/measurements.md, 'Replay without the answer').
"""
from __future__ import annotations

import numpy as np

#: PX4's normalised quad X table (roll, pitch, yaw, thrust scale) per output: 0 front-right, 1 rear-left,
#: 2 front-left, 3 rear-right
QUAD_X_SCALES = np.array([[-0.707107, 0.707107, 1.0, 1.0],
                          [0.707107, -0.707107, 1.0, 1.0],
                          [0.707107, 0.707107, -1.0, 1.0],
                          [-0.707107, -0.707107, -1.0, 1.0]])
YAW_HEADROOM = 1.15   # upper output bound while yaw is desaturated (PX4 mix_yaw)


def mix_quad_x(controls: np.ndarray) -> np.ndarray:
    """(N, 4) normalised outputs in [0, 1] of (N, 4) controls (roll, pitch, yaw, thrust) (module docstring)."""
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    roll, pitch, yaw, thrust = (controls[:, [i]] for i in range(4))
    roll_scale, pitch_scale, yaw_scale, thrust_scale = QUAD_X_SCALES.T
    outputs = roll * roll_scale + pitch * pitch_scale + thrust * thrust_scale
    outputs = _minimize_saturation(outputs, thrust_scale, reduce_only=True)
    outputs = _minimize_saturation(outputs, roll_scale)
    outputs = _minimize_saturation(outputs, pitch_scale)
    outputs = outputs + yaw * yaw_scale
    outputs = _minimize_saturation(outputs, yaw_scale, high=YAW_HEADROOM)
    outputs = _minimize_saturation(outputs, thrust_scale, reduce_only=True)
    return np.clip(outputs, 0.0, 1.0)


def _minimize_saturation(outputs, direction, low: float = 0.0, high: float = 1.0, reduce_only: bool = False):
    """Shift each row along `direction` by the desaturation gain k1, then by half the gain left (PX4
    `minimize_saturation`); with `reduce_only`, rows whose k1 is positive are left as they are."""
    gain = _desaturation_gain(outputs, direction, low, high)
    if reduce_only:
        gain = np.minimum(gain, 0.0)
        shifted = outputs + gain[:, None] * direction
        second = 0.5 * _desaturation_gain(shifted, direction, low, high)
        return shifted + np.where(gain < 0.0, second, 0.0)[:, None] * direction
    shifted = outputs + gain[:, None] * direction
    return shifted + 0.5 * _desaturation_gain(shifted, direction, low, high)[:, None] * direction


def _desaturation_gain(outputs, direction, low: float, high: float) -> np.ndarray:
    """k_min + k_max over the saturated outputs of each row, k = (bound - u_i) / d_i (PX4
    `compute_desaturation_gain`; k_min <= 0 <= k_max)."""
    usable = direction != 0.0                      # along a zero component nothing can be desaturated
    with np.errstate(divide="ignore", invalid="ignore"):
        below = np.where(usable & (outputs < low), (low - outputs) / direction, 0.0)
        above = np.where(usable & (outputs > high), (high - outputs) / direction, 0.0)
    steps = np.concatenate([below, above], axis=1)
    return np.minimum(steps.min(axis=1), 0.0) + np.maximum(steps.max(axis=1), 0.0)
