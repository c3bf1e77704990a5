"""READING_LIMIT: a detector refuses a reading (or a command) beyond +-1e6, NaN and inf as before, with a ValueError
naming the detector and the reading, and the refused sample changes nothing: a twin fed the same good samples
publishes the same outputs and status, and both go on alike. Finite values that large overflowed the detectors'
products: loe_kalman's state stayed NaN for the rest of the flight at a rotor speed of 1e20 rad/s, without an alarm;
the EKFs raised numpy's LinAlgError, naming no reading."""
import gymnasium as gym
import numpy as np
import pytest

from ftcgym.agents import make_policy
from ftcgym.fdd import wrap_with_detector
from ftcgym.fdd.base import READING_LIMIT
from ftcgym.fdd.iv_change import SixDofResidual
from ftcgym.models.quadrotor import make_params

QUADROTOR, QUADPLANE = "ftcgym/Quadrotor-v0", "ftcgym/QuadPlaneAutopilot-v0"
BEFORE = 150            # good samples before the bad one: 0.3 s of the quadrotor (armed), 1.5 s of the quad-plane
READS = {"loe_kalman": (QUADROTOR, ("gyro", "accel", "rotor_speed")),
         "loe_cusum": (QUADROTOR, ("gyro", "accel", "rotor_speed")),
         "aekf": (QUADROTOR, ("position", "velocity", "attitude", "gyro", "rotor_speed")),
         "iv_change": (QUADROTOR, ("gyro", "accel", "reference_position", "reference_velocity", "reference_yaw",
                                   "attitude", "velocity", "rotor_speed")),
         "airdata_ekf": (QUADPLANE, ("accel", "gyro", "attitude", "gnss_velocity", "pusher_speed",
                                     "hover_rotor_speed", "skew", "pusher_current", "pitot_airspeed")),
         "propulsion_bayes": (QUADPLANE, ("pusher_speed", "pusher_current", "pitot_airspeed"))}
CASES = [(name, key) for name, (_, keys) in READS.items() for key in keys]


@pytest.fixture(scope="module")
def flights():
    """Readings and times of 300 steps of each env, seeded: the quadrotor hovering (nominal controller), the
    quad-plane under its autopilot's own mission (zero action)."""
    recorded = {}
    for env_id in (QUADROTOR, QUADPLANE):
        env = gym.make(env_id)
        obs, info = env.reset(seed=0)
        policy = make_policy("nominal", env) if env_id == QUADROTOR else None
        if policy is not None:
            policy.reset(obs, info)
        samples = []
        for _ in range(300):
            action = np.zeros(env.action_space.shape) if policy is None else policy.act(obs, info)
            obs, _, _, _, info = env.step(action)
            samples.append(({key: np.array(value) for key, value in obs.items()}, info["time"]))
        env.close()
        recorded[env_id] = samples
    return recorded


def _published(detector) -> str:
    """A detector's outputs and status as text: every float exact (Python's repr), NaN equal to NaN."""
    return repr(({key: value.tolist() for key, value in detector.outputs().items()}, detector.status()))


def _twins(name: str, samples: list):
    """Two detectors `name` fed the same `samples`."""
    env_id = READS[name][0]
    twins = [wrap_with_detector(name, gym.make(env_id)).detector for _ in range(2)]
    for readings, time in samples:
        for detector in twins:
            detector.update(readings, time)
    return twins


def _goes_on_as_its_twin(detector, twin, samples: list) -> None:
    assert _published(detector) == _published(twin)               # the refused sample changed nothing
    for readings, time in samples:
        detector.update(readings, time)
        twin.update(readings, time)
    assert _published(detector) == _published(twin)
    assert all(np.isfinite(value).all() for value in detector.outputs().values())


@pytest.mark.parametrize("value", [1e20, -1e300])
@pytest.mark.parametrize("name, key", CASES)
def test_a_reading_beyond_the_limit_is_refused_and_changes_nothing(name, key, value, flights):
    samples = flights[READS[name][0]]
    detector, twin = _twins(name, samples[:BEFORE])
    readings, time = samples[BEFORE]
    bad = {**readings, key: np.full(readings[key].shape, value)}
    with pytest.raises(ValueError, match=rf"^{name}: reading '{key}' is not finite or beyond \+-1e\+06"):
        detector.update(bad, time)
    _goes_on_as_its_twin(detector, twin, samples[BEFORE:])


@pytest.mark.parametrize("name, key", [("aekf", "attitude"), ("aekf", "rotor_speed"), ("loe_kalman", "rotor_speed"),
                                       ("airdata_ekf", "position"), ("airdata_ekf", "gyro")])
def test_a_first_sample_beyond_the_limit_is_refused(name, key, flights):
    """The first sample takes other paths: aekf initialises its state from it, airdata_ekf reads the height it
    starts at."""
    samples = flights[READS[name][0]]
    detector, twin = _twins(name, [])
    readings, time = samples[0]
    with pytest.raises(ValueError, match=rf"^{name}: reading '{key}' is not finite or beyond \+-1e\+06"):
        detector.update({**readings, key: np.full(readings[key].shape, 1e20)}, time)
    _goes_on_as_its_twin(detector, twin, samples)


@pytest.mark.parametrize("name", ["loe_cusum", "aekf"])
def test_a_command_beyond_the_limit_is_refused(name, flights):
    samples = flights[QUADROTOR]
    detector, twin = _twins(name, samples[:BEFORE])
    readings, time = samples[BEFORE]
    with pytest.raises(ValueError, match=rf"^{name}: the command is not finite or beyond \+-1e\+06"):
        detector.update(readings, time, np.array([0.5, 0.5, 1e20, 0.5]))
    _goes_on_as_its_twin(detector, twin, samples[BEFORE:])


def test_the_limit_itself_is_taken(flights):
    """`abs(v) <= READING_LIMIT`: a rotor speed of 1e6 rad/s is a reading; the next float up is not."""
    detector = _twins("loe_kalman", flights[QUADROTOR][:BEFORE])[0]
    readings, time = flights[QUADROTOR][BEFORE]
    detector.update({**readings, "rotor_speed": np.full(4, READING_LIMIT)}, time)
    with pytest.raises(ValueError, match="rotor_speed"):
        detector.update({**readings, "rotor_speed": np.full(4, np.nextafter(READING_LIMIT, np.inf))}, time + 0.002)


def test_six_dof_residual_refuses_a_reading_beyond_the_limit():
    residual = SixDofResidual(make_params("mueller2014"), 0.002)
    readings = {"gyro": np.zeros(3), "accel": np.array([1e200, 0.0, 0.0]), "rotor_speed": np.zeros(4),
                "attitude": np.array([0.0, 0.0, 0.0, 1.0]), "velocity": np.zeros(3)}
    with pytest.raises(ValueError, match=r"^iv_change: reading 'accel' is not finite or beyond \+-1e\+06"):
        residual.update(readings)


@pytest.mark.parametrize("name", ["aekf", "airdata_ekf"])
def test_a_filter_that_a_reading_within_the_limit_makes_diverge_says_so(name, flights):
    """A gyro of 1e6 rad/s passes the limit, but the EKFs cannot follow it: aekf's outputs went NaN a few samples
    later without an error, airdata_ekf raised numpy's LinAlgError. Now a ValueError names the detector."""
    samples = flights[READS[name][0]]
    detector = _twins(name, samples[:BEFORE])[0]
    readings, time = samples[BEFORE]
    with pytest.raises(ValueError, match=rf"^{name}: the (filter|EKF) diverged at t = .*reset\(\) it"):
        detector.update({**readings, "gyro": np.full(3, READING_LIMIT)}, time)
        for readings, time in samples[BEFORE + 1:]:
            detector.update(readings, time)
