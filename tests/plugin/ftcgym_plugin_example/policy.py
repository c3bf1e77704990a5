"""A user's recovery policy: ftcgym's spin recovery, switched on by the user's own detector."""
from ftcgym.agents import SpinAfterAlarmPolicy


class SpinOnRotorJump(SpinAfterAlarmPolicy):
    """The nominal controller until `rotor_jump` alarms, then spin recovery without the rotor it isolated."""

    detector = "rotor_jump"

    def __init__(self, env):
        super().__init__(env.unwrapped.params, env.unwrapped.agent_hz)
