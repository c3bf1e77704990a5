"""Quad-plane fault kinds: validation, sensor corruption and the propulsion fault profiles."""
import numpy as np
import pytest

from ftcgym.models.faults import KINDS, QUADPLANE_KINDS, FaultSchedule, parse_faults, resolve

SENSORS = {"pitot_airspeed": 1, "gnss_velocity": 3, "skew": 1, "pusher_speed": 1, "hover_rotor_speed": 4}


def schedule(*specs):
    parsed = parse_faults(list(specs), 4, SENSORS, QUADPLANE_KINDS)
    return FaultSchedule(resolve(parsed, np.random.default_rng(0), 4), 4)


def readings():
    return {"gnss_velocity": np.array([18.0, 1.0, 0.5]), "pusher_speed": np.array([830.0]),
            "skew": np.array([1.2]), "pitot_airspeed": np.array([18.0]), "hover_rotor_speed": np.full(4, 400.0)}


def test_pitot_blockage_abrupt_zero_stuck_and_incipient_ramp():
    zero = schedule({"kind": "pitot_blockage", "time": 10.0})
    assert zero.apply_to_pitot(9.99, 18.0) == 18.0 and zero.apply_to_pitot(10.0, 18.0) == 0.0
    stuck = schedule({"kind": "pitot_blockage", "target": "stuck", "time": 10.0})
    assert stuck.apply_to_pitot(10.0, 17.0) == 17.0 and stuck.apply_to_pitot(20.0, 25.0) == 17.0
    ramp = schedule({"kind": "pitot_blockage", "time": 10.0, "rate": 2.5})   # 001 Sec. 7.2.2
    assert ramp.apply_to_pitot(12.0, 18.0) == pytest.approx(13.0)
    assert ramp.apply_to_pitot(12.0, 20.0) == pytest.approx(15.0)            # tracks the flow, offset grows
    assert ramp.apply_to_pitot(30.0, 18.0) == 0.0


def test_named_sensor_faults_act_on_their_channel_only():
    s = schedule({"kind": "gnss", "time": 1.0}, {"kind": "pusher_rpm_sensor", "time": 1.0},
                 {"kind": "skew_sensor", "time": 1.0, "magnitude": 0.1})
    out = s.apply_to_sensors(2.0, readings())
    assert np.all(out["gnss_velocity"] == 0.0) and out["pusher_speed"][0] == 0.0
    assert out["skew"][0] == pytest.approx(1.3) and np.all(out["hover_rotor_speed"] == 400.0)
    stuck = schedule({"kind": "skew_sensor", "time": 1.0})
    first = stuck.apply_to_sensors(1.0, readings())["skew"][0]
    later = readings()
    later["skew"][:] = 0.4
    assert stuck.apply_to_sensors(3.0, later)["skew"][0] == first
    assert s.current(2.0)["kind"] == "skew_sensor"        # info keeps the user's kind name


@pytest.mark.parametrize("kind, parameter", [("propeller_icing", "theta_1"), ("viscous_friction", "c_v"),
                                             ("static_friction", "I_0")])
def test_propulsion_faults_rise_along_a_sigmoid_to_1_1_over_50_s(kind, parameter):
    """003 Sec. IV-A: each fault parameter grows by the factor 1.1 along a sigmoid over 50 s."""
    s = schedule({"kind": kind, "time": 90.0})
    assert s.propulsion_factors(89.0) == {"theta_1": 1.0, "c_v": 1.0, "I_0": 1.0}
    f = [s.propulsion_factors(t)[parameter] for t in (90.0, 115.0, 140.0, 300.0)]
    assert f[0] == pytest.approx(1.0, abs=1e-3) and f[1] == pytest.approx(1.05)
    assert f[2] == pytest.approx(1.1, abs=1e-3) and f[3] == pytest.approx(1.1)
    assert np.all(np.diff(f) >= 0)
    others = {k: v for k, v in s.propulsion_factors(140.0).items() if k != parameter}
    assert set(others.values()) == {1.0}


def test_a_field_given_as_none_takes_its_default():
    """A FaultSpec leaves the fields it is not given at None; a dict may say None: both mean the default."""
    from ftcgym.models.faults import FaultSpec
    default = parse_faults([{"kind": "viscous_friction", "time": 0.5}], 4, SENSORS, QUADPLANE_KINDS)
    for spec in ({"kind": "viscous_friction", "time": 0.5, "duration": None, "magnitude": None},
                 FaultSpec("viscous_friction", time=0.5)):
        assert parse_faults([spec], 4, SENSORS, QUADPLANE_KINDS) == default
    assert default[0].duration == 50.0 and default[0].magnitude == 1.1
    assert schedule(FaultSpec("viscous_friction", time=0.5)).propulsion_factors(25.5)["c_v"] == pytest.approx(1.05)
    [loe] = parse_faults([FaultSpec("loe", target=0)], 4, SENSORS, QUADPLANE_KINDS)
    assert loe.magnitude == 0.5 and loe.rate is None


def test_bad_quadplane_fault_specs_name_the_field():
    with pytest.raises(ValueError, match=r"faults\[0\].target.*pitot blockage mode"):
        parse_faults([{"kind": "pitot_blockage", "target": "half"}], 4, SENSORS, QUADPLANE_KINDS)
    with pytest.raises(ValueError, match=r"faults\[0\].magnitude"):
        parse_faults([{"kind": "propeller_icing", "magnitude": -1.0}], 4, SENSORS, QUADPLANE_KINDS)
    with pytest.raises(ValueError, match=r"faults\[0\].rate.*not used"):
        parse_faults([{"kind": "gnss", "rate": 1.0}], 4, SENSORS, QUADPLANE_KINDS)
    with pytest.raises(ValueError, match=r"not a fault kind of this vehicle"):
        parse_faults([{"kind": "pitot_blockage"}], 4, {"gyro": 3}, KINDS)           # the quadrotor has no pitot
    with pytest.raises(ValueError, match=r"not a fault kind of this vehicle"):
        parse_faults([{"kind": "payload"}], 4, SENSORS, QUADPLANE_KINDS)
