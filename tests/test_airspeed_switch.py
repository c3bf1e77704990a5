"""airspeed-switch in closed loop on the incipient pitot fault (001 Sec. 7.2.2): which alarm it switches on
decides how long the autopilot flies on a reading drifting low."""

from ftcgym.agents.airspeed_policies import AirspeedSwitchPolicy
from ftcgym.benchmark import metrics
from ftcgym.benchmark.runner import make_env, roll_out
from ftcgym.benchmark.scenarios import get_scenario

ONSET = 45.0        # qp-pitot-incipient: -2.5 m/s^2 from 45 s, in cruise


def upset_after_onset(policy, seed: int) -> tuple[float, float, float]:
    """(switch delay s, largest roll or pitch deg, altitude loss m) within 8 s of the onset."""
    env = make_env(get_scenario("qp-pitot-incipient"), {"max_episode_seconds": ONSET + 8.0})
    try:
        log = roll_out(env, policy, seed, "airdata_ekf")
    finally:
        env.close()
    roll, pitch = metrics.roll_pitch(log.attitude)
    attitude, loss = metrics.upset(log.time, -log.position[:, 2], roll, pitch, ONSET, window=8.0)
    return policy.switched_at - ONSET, attitude, loss


def test_switching_on_the_first_test_keeps_the_incipient_fault_from_upsetting_the_airframe():
    """Episode 2 of the tuning seeds (`--seed 900`): on Table 2 alone the switch comes ~2.4 s after onset, with the
    reading ~6 m/s low, and the airframe rolls past 90 deg and sinks metres; on the first of Table 2, the CUSUM and
    the ramp test (the ramp test's, ~0.9 s after onset, the reading ~2 m/s low) the bank stays that of the
    circle (~30 deg); on Table 2 and the CUSUM alone the switch comes in between."""
    seed = 3855525203
    delay_t2, attitude_t2, loss_t2 = upset_after_onset(AirspeedSwitchPolicy(tests=("table2",)), seed)
    delay_cusum, _, _ = upset_after_onset(AirspeedSwitchPolicy(tests=("table2", "cusum")), seed)
    delay, attitude, loss = upset_after_onset(AirspeedSwitchPolicy(), seed)
    assert 2.2 < delay_t2 < 2.7 and 0.5 < delay < 1.0 < delay_cusum < delay_t2 - 0.5
    assert attitude_t2 > 60.0 and loss_t2 > 3.0
    assert attitude < 45.0 and loss < 1.0
