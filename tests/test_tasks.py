"""The square task (004 Sec. 5.1): its legs and corners, its speed excitation, and its reference to the bit."""
import numpy as np
import pytest

from ftcgym.models.tasks import EXCITATION_PEAK, SquareTask, excitation_distance, excitation_speed


def test_before_the_hold_ends_the_reference_rests_at_the_first_corner():
    ref = SquareTask().reference(1.5)
    assert ref.position.tolist() == [0.0, 0.0, -8.0]
    assert ref.velocity.tolist() == [0.0, 0.0, 0.0] and ref.yaw == 0.0


@pytest.mark.parametrize("heading_changes", [False, True])
def test_without_excitation_the_legs_run_north_east_south_west(heading_changes):
    task = SquareTask(side=8.0, speed=2.0, hold=1.0, excitation=False, heading_changes=heading_changes)
    legs = [((1.0, 0.0), 0.0), ((0.0, 1.0), np.pi / 2), ((-1.0, 0.0), -np.pi), ((0.0, -1.0), -np.pi / 2)]
    corners = [(0.0, 0.0), (8.0, 0.0), (8.0, 8.0), (0.0, 8.0)]
    for k, ((north, east), yaw) in enumerate(legs):
        mid = task.reference(1.0 + (k + 0.5) * 4.0)         # halfway along leg k: 4 s a leg
        assert np.allclose(mid.position[:2], np.add(corners[k], [4.0 * north, 4.0 * east]))
        assert mid.velocity.tolist() == [2.0 * north, 2.0 * east, 0.0]
        assert mid.yaw == pytest.approx(yaw if heading_changes else 0.0)
    assert np.allclose(task.reference(1.0 + 16.0).position, [0.0, 0.0, -8.0])   # once round, at the start


def test_the_excitation_distance_is_the_integral_of_its_speed():
    t = np.linspace(0.0, 20.0, 200001)
    speeds = np.array([excitation_speed(x) for x in t[::100]])
    assert np.all(np.abs(speeds) <= EXCITATION_PEAK)
    integral = np.concatenate([[0.0], np.cumsum(np.diff(t) * 0.5 * (
        np.vectorize(excitation_speed)(t[1:]) + np.vectorize(excitation_speed)(t[:-1])))])
    for k in (50000, 123457, 200000):
        assert excitation_distance(t[k]) == pytest.approx(integral[k], abs=1e-8)


def test_the_reference_keeps_its_bits():
    """Pinned values: the seeded trajectories of every square scenario start from these numbers."""
    ref = SquareTask(speed=2.5, heading_changes=True).reference(9.37)
    assert ref.position.tolist() == [6.278138766449821, 8.0, -8.0]
    assert ref.velocity.tolist() == [-2.34779189320121, 0.0, 0.0] and ref.yaw == -np.pi
    ref = SquareTask().reference(13.0)
    assert ref.position.tolist() == [8.0, 2.685168952800046, -8.0]
    assert ref.velocity.tolist() == [0.0, 1.1166835788998326, 0.0] and ref.yaw == 0.0
