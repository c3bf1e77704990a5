"""Settings as data: keyword overrides update a detector's settings field by field, nested tests from JSON."""
import math
import re
from dataclasses import dataclass, field

import gymnasium as gym
import pytest

import ftcgym  # noqa: F401
from ftcgym.fdd import wrap_with_detector
from ftcgym.fdd.airdata_ekf import INNOVATION_DETECTORS, AirdataEkfDetector, AirdataEkfSettings, InnovationTest
from ftcgym.fdd.loe_kalman import LoeKalmanDetector, LoeKalmanSettings
from ftcgym.fdd.pitot_detection import TABLE_2_NORM, ThresholdTest
from ftcgym.models.checks import FRACTION, POSITIVE
from ftcgym.models.vsqp import VSQP
from ftcgym.settings import accepts, updated


def test_keywords_update_the_defaults_and_leave_the_rest():
    detector = LoeKalmanDetector(0.002, k_threshold=0.3)
    assert detector.settings == LoeKalmanSettings(k_threshold=0.3)
    assert detector.k_threshold == 0.3 and detector.p_fail_threshold == LoeKalmanSettings().p_fail_threshold


def test_a_named_test_takes_a_list_in_field_order_or_a_dict_of_its_fields():
    settings = updated(AirdataEkfSettings(), {"norm_criterion": [6.0, 0.3, 4.0]}, "airdata_ekf")
    assert settings.norm_criterion == ThresholdTest(threshold=6.0, hold=0.3, cutoff_hz=4.0)
    settings = updated(AirdataEkfSettings(), {"norm_criterion": {"threshold": 6.5}}, "airdata_ekf")
    assert settings.norm_criterion == TABLE_2_NORM._replace(threshold=6.5)


def test_innovation_tests_come_from_json_dicts():
    spec = {"channels": [3], "norm": [0.5, 0.2, 1.0], "derivative": [250.0, 0.12, 0.1], "sign": 1}
    test = InnovationTest.of(spec)
    assert test.norm == ThresholdTest(0.5, 0.2, 1.0) and test.sign == 1 and test.pitot_confirmation is None
    detector = AirdataEkfDetector(VSQP, 100.0, innovation_detectors={"pusher_rpm": spec})
    assert list(detector.innovation_detectors) == ["pusher_rpm"] and detector._current_variance is None
    assert InnovationTest.of(INNOVATION_DETECTORS["gnss"]) is INNOVATION_DETECTORS["gnss"]


@pytest.mark.parametrize("overrides, message", [
    ({"k_treshold": 0.3}, r"loe_kalman: unknown field\(s\) \['k_treshold'\]; accepted: \['G', 'effectiveness_matrix'"),
])
def test_an_unknown_keyword_names_the_accepted_fields(overrides, message):
    with pytest.raises(ValueError, match=message):
        LoeKalmanDetector(0.002, **overrides)


def test_a_named_test_of_the_wrong_length_says_what_it_takes():
    with pytest.raises(ValueError, match=r"airdata_ekf.cusum: expected 3 values \['drift', 'threshold', 'cutoff_hz'\]"):
        updated(AirdataEkfSettings(), {"cusum": [1.0, 2.0]}, "airdata_ekf")
    with pytest.raises(ValueError, match=r"airdata_ekf.cusum: unknown field\(s\) \['h'\]"):
        updated(AirdataEkfSettings(), {"cusum": {"h": 2.0}}, "airdata_ekf")


def test_detector_kwargs_reach_the_settings_through_the_wrapper():
    env = wrap_with_detector("airdata_ekf", gym.make("ftcgym/QuadPlane-v0"), coefficient_error=0.0,
                             cusum={"threshold": 2.5})
    settings = env.detector.settings
    assert settings.coefficient_error == 0.0 and settings.cusum.threshold == 2.5 and settings.cusum.drift == 1.0
    assert env.detector.cusum.threshold == 2.5
    env.close()


@dataclass(frozen=True)
class Example:
    """Every kind of field `updated` checks an override against."""

    gain: float = 1.0
    count: int = 3
    flag: bool = True
    mode: str = "fast"
    weights: tuple = (1.0, 2.0)
    levels: tuple = field(default=(0.5, 1.0), metadata=accepts(POSITIVE, any_length=True))
    share: float = field(default=0.5, metadata=accepts(FRACTION))
    limit: float = math.inf
    cutoff: float | None = None
    seed: int | None = None
    table: dict | None = None


@pytest.mark.parametrize("overrides, expected", [
    ({"gain": 2}, {"gain": 2.0}),
    ({"count": 4.0}, {"count": 4}),
    ({"weights": [3, 4]}, {"weights": (3.0, 4.0)}),
    ({"levels": [0.1, 0.2, 0.3]}, {"levels": (0.1, 0.2, 0.3)}),
    ({"limit": math.inf, "cutoff": 2.5, "seed": 7}, {"limit": math.inf, "cutoff": 2.5, "seed": 7}),
    ({"cutoff": None, "table": {"any": "thing"}}, {"cutoff": None, "table": {"any": "thing"}}),
])
def test_overrides_of_the_kind_of_the_default_are_taken(overrides, expected):
    settings = updated(Example(), overrides, "ex")
    assert {name: getattr(settings, name) for name in expected} == expected
    assert all(type(getattr(settings, name)) is type(value) for name, value in expected.items())


@pytest.mark.parametrize("overrides, message", [
    ({"gain": math.nan}, "ex.gain: must be finite (no NaN or inf), got nan"),
    ({"gain": math.inf}, "ex.gain: must be finite (no NaN or inf), got inf"),
    ({"gain": "2"}, "ex.gain: expected a number, got str '2'"),
    ({"gain": True}, "ex.gain: expected a number, got bool True"),
    ({"count": 2.5}, "ex.count: expected an integer, got 2.5"),
    ({"flag": 1}, "ex.flag: expected true or false, got 1"),
    ({"mode": 3}, "ex.mode: expected text such as 'fast', got 3"),
    ({"weights": [1.0]}, "ex.weights: expected 2 numbers like [1.0, 2.0], got 1: [1.0]"),
    ({"weights": "ab"}, "ex.weights: expected 2 numbers like [1.0, 2.0], got 'ab'"),
    ({"weights": [1.0, math.nan]}, "ex.weights[1]: must be finite (no NaN or inf), got nan"),
    ({"levels": [0.1, -0.2]}, "ex.levels[1]: must be > 0, got -0.2"),
    ({"levels": []}, "ex.levels: expected at least one number, got []"),
    ({"share": 1.5}, "ex.share: must be in [0, 1], got 1.5"),
    ({"limit": math.nan}, "ex.limit: must be finite (no NaN or inf), got nan"),
    ({"cutoff": math.nan}, "ex.cutoff: must be finite (no NaN or inf), got nan"),
    ({"seed": 1.5}, "ex.seed: expected an integer, got 1.5"),
    ({"gain": None}, "ex.gain: expected a number, got NoneType None"),
])
def test_an_override_the_field_does_not_take_is_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        updated(Example(), overrides, "ex")
