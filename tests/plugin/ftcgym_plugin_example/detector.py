"""A rotor-loss detector of the user's: a propeller that leaves lets its motor spin up (the unloaded motor
runs faster for the same command), so the rotor speed that jumps above the others names the lost rotor."""
import numpy as np


class RotorJumpDetector:
    """Alarms when one rotor's speed exceeds the mean of the others by `margin` (rad/s) for `hold` samples."""

    name = "rotor_jump"
    output_fields = {"excess": (-np.inf, np.inf, (4,))}

    def __init__(self, margin: float = 150.0, hold: int = 5):
        self.margin, self.hold = float(margin), int(hold)
        self.reset()

    @classmethod
    def from_env(cls, env, **kwargs):
        """Built for an env: nothing of it is needed here, but a detector may read `env.unwrapped.params`."""
        return cls(**kwargs)

    def reset(self) -> None:
        self.excess, self.count = np.zeros(4), 0
        self.alarm, self.alarm_time, self.isolated = False, None, None

    def update(self, readings: dict, time: float, command=None) -> None:
        omega = np.asarray(readings["rotor_speed"], dtype=float)
        self.excess = omega - (omega.sum() - omega) / 3.0
        self.count = self.count + 1 if self.excess.max() > self.margin else 0
        if self.count >= self.hold and not self.alarm:
            self.alarm, self.alarm_time, self.isolated = True, float(time), int(np.argmax(self.excess))

    def outputs(self) -> dict:
        return {"excess": self.excess.copy()}

    def status(self) -> dict:
        return {"alarm": self.alarm, "alarm_time": self.alarm_time, "isolated": self.isolated}
