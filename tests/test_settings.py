"""Settings as data: keyword overrides update a detector's settings field by field, nested tests from JSON."""
import gymnasium as gym
import pytest

import ftcgym  # noqa: F401
from ftcgym.fdd import wrap_with_detector
from ftcgym.fdd.airdata_ekf import INNOVATION_DETECTORS, AirdataEkfDetector, AirdataEkfSettings, InnovationTest
from ftcgym.fdd.loe_kalman import LoeKalmanDetector, LoeKalmanSettings
from ftcgym.fdd.pitot_detection import TABLE_2_NORM, ThresholdTest
from ftcgym.models.vsqp import VSQP
from ftcgym.settings import updated


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
