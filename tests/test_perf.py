"""`ftcgym perf`: every registered detector is timed on a flight of its own vehicle."""
import math

from ftcgym.cli.perf import detector_costs
from ftcgym.fdd import DETECTORS


def test_every_detector_gets_a_finite_cost_per_update():
    costs = detector_costs(steps=60, seed=0)
    assert set(costs) == set(DETECTORS)
    assert all(math.isfinite(us) and 0.0 < us < 1e5 for us in costs.values())
