"""A user's scenario: hover in calm air, rotor 2 lost at 1 s, scored on the user's detector."""
from ftcgym.benchmark import Scenario


def rotor_loss_hover() -> Scenario:
    return Scenario(name="example-rotor-loss", env_id="ftcgym/Quadrotor-v0",
                    env_kwargs={"task": "hover", "max_episode_seconds": 6.0,
                                "faults": [{"kind": "rotor_loss", "target": 2, "time": 1.0}]},
                    policies=("example-spin",), episodes=2, detector="rotor-jump",
                    description="Hover, rotor 2 lost at 1 s (a plug-in's scenario).")


SCENARIO = rotor_loss_hover()
