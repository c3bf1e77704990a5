"""The scenario catalogue: what `ftcgym bench` flies, by name.

A scenario is an env id with its `gym.make` keyword arguments, the policies and number of episodes
flown by default, and the detector whose alarm the benchmark scores. Add one with `register`.
"""
from __future__ import annotations

import importlib.util
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

from ftcgym.benchmark.random_wind import random_mean_wind_wrapper
from ftcgym.models.sensors import SensorConfig
from ftcgym.registry import Registry

QUADROTOR = "ftcgym/Quadrotor-v0"
QUADPLANE_AUTOPILOT = "ftcgym/QuadPlaneAutopilot-v0"
LIGHT_TURBULENCE = {"mean": [0.0, 0.0, 0.0], "turbulence": "light"}
# Rotor-loss scenarios fly the fault-unaware controller, spin recovery on the detector's alarm, and the oracle
# that switches at the true onset (an upper bound: the gap to ftc-spin is the price of detection).
ROTOR_LOSS_POLICIES = ("nominal", "ftc-spin", "oracle-spin")
# The shipped learned policy (`learned-spin`) joins the hover scenarios' defaults when SB3 is installed to fly
# it. The maneuver scenarios leave it out of their defaults; `--policy learned-spin` flies it there (its figures
# on the square: docs/measurements.md).
HOVER_ROTOR_LOSS_POLICIES = ROTOR_LOSS_POLICIES + (
    ("learned-spin",) if importlib.util.find_spec("stable_baselines3") else ())


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario.

    `detector` names the detector (`ftcgym.fdd.DETECTORS`) the env is wrapped with, built with
    `detector_kwargs`, and whose `info["fdd"]` alarm is scored (None: no detection metrics). `fault_wrappers`
    are callables env -> env applied right after `gym.make`, under the detector, which reads what they corrupt:
    a fault of the user's, reported in `info["fault"]` as the env reports its own, is scored as one of the env's.
    `wrappers` are applied after the detector. Both module-level, so episodes can run in worker processes.
    `default` scenarios are those `ftcgym bench` runs when no `--scenario` is given.
    """

    name: str
    env_id: str
    env_kwargs: dict = field(default_factory=dict)
    policies: tuple[str, ...] = ("nominal",)
    episodes: int = 4
    detector: str | None = None
    detector_kwargs: dict = field(default_factory=dict)
    description: str = ""
    default: bool = False
    wrappers: tuple[Callable, ...] = ()
    fault_wrappers: tuple[Callable, ...] = ()

    def __post_init__(self) -> None:
        """Each field of the kind it must be, named where it is not (a str of policies would fly 'n', 'o', ...)."""
        where = f"Scenario {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Scenario: name must be a non-empty string, got {self.name!r}")
        for name in ("env_id",) + (("detector",) if self.detector is not None else ()):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise ValueError(f"{where}: {name} must be a non-empty string, got {getattr(self, name)!r}")
        for name in ("env_kwargs", "detector_kwargs"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"{where}: {name} must be a dict, got {getattr(self, name)!r}")
        if (not isinstance(self.policies, (tuple, list)) or not self.policies
                or not all(isinstance(p, str) and p for p in self.policies)):
            raise ValueError(f"{where}: policies must be a tuple of one or more policy names, got {self.policies!r}")
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, numbers.Integral) or self.episodes < 1:
            raise ValueError(f"{where}: episodes must be a whole number >= 1, got {self.episodes!r}")
        for name in ("wrappers", "fault_wrappers"):
            value = getattr(self, name)
            if not isinstance(value, (tuple, list)) or not all(callable(wrap) for wrap in value):
                raise ValueError(f"{where}: {name} must be a tuple of callables env -> env, got {value!r}")


SCENARIOS: dict[str, Scenario] = {}
#: scenarios of installed packages (entry-point group `ftcgym.scenarios`) and MODULE:ATTR references
PLUG_INS = Registry("scenario", "ftcgym.scenarios", {}, reserved=lambda: SCENARIOS)


def register(scenario: Scenario) -> Scenario:
    """Add `scenario` to the catalogue of this process; a name can be registered once, and without ':' (which
    marks a MODULE:ATTR reference)."""
    if scenario.name in SCENARIOS:
        raise ValueError(f"scenario {scenario.name!r} is already registered; give yours another name")
    if ":" in scenario.name:
        raise ValueError(f"scenario {scenario.name!r}: a registered name has no ':' (MODULE:ATTR names a "
                         f"scenario in a module without registering it)")
    SCENARIOS[scenario.name] = scenario
    return scenario


def get_scenario(name: str) -> Scenario:
    """The scenario called `name`: a registered one, an installed plug-in (entry-point group
    `ftcgym.scenarios`) or MODULE:ATTR; the latter two may also be a function of no arguments that returns
    one. A scenario found by entry point or reference carries the name as given."""
    if name in SCENARIOS:
        return SCENARIOS[name]
    if isinstance(name, str) and name and ":" not in name and name not in PLUG_INS:
        raise PLUG_INS.unknown(name, known=SCENARIOS)
    found = PLUG_INS.load(name)
    try:
        scenario = found() if callable(found) and not isinstance(found, Scenario) else found
    except Exception as error:  # noqa: BLE001 - the user's factory's own failure, reported in one line
        raise ValueError(f"scenario {name!r}: its factory raised {type(error).__name__}: {error}") from error
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario {name!r}: got {type(scenario).__name__}, not an ftcgym.benchmark.Scenario")
    return replace(scenario, name=name)


def scenario_names() -> list[str]:
    """The registered scenarios, then those of installed packages (entry-point group `ftcgym.scenarios`)."""
    return list(SCENARIOS) + [name for name in PLUG_INS.names() if name not in SCENARIOS]


def default_scenarios() -> list[Scenario]:
    """The scenarios `ftcgym bench` runs with no arguments, in registration order."""
    return [scenario for scenario in SCENARIOS.values() if scenario.default]


# Episode counts keep `ftcgym bench` to a few minutes on 2 cores (about 2,000-4,000 env steps/s
# with the controller in the loop at 500 Hz).
register(Scenario(
    name="quad-hover",
    env_id=QUADROTOR,
    env_kwargs={"task": "hover", "max_episode_seconds": 20.0,
                "wind": {"mean": [1.0, -1.0, 0.0], "turbulence": "light"}},
    episodes=4,
    description="Quadrotor hover for 20 s in a 1.4 m/s wind with light turbulence, no fault.",
    default=True,
))
register(Scenario(
    name="quad-square",
    env_id=QUADROTOR,
    env_kwargs={"task": "square", "max_episode_seconds": 45.0, "wind": LIGHT_TURBULENCE},
    episodes=4,
    description="Quadrotor flies a square for 45 s in light turbulence, no fault.",
    default=True,
))
register(Scenario(
    name="quad-rotor-loss-hover",
    env_id=QUADROTOR,
    env_kwargs={"task": "hover", "max_episode_seconds": 10.0, "wind": LIGHT_TURBULENCE,
                "faults": "random:rotor_loss"},
    policies=HOVER_ROTOR_LOSS_POLICIES,
    episodes=8,
    detector="loe_kalman",
    description="Quadrotor hover in light turbulence; one random rotor loses its propeller at 2-5 s.",
    default=True,
))
register(Scenario(
    name="quad-rotor-loss-maneuver",
    env_id=QUADROTOR,
    env_kwargs={"task": {"name": "square", "speed": 2.5}, "max_episode_seconds": 14.0, "wind": LIGHT_TURBULENCE,
                "faults": [{"kind": "rotor_loss", "target": "random", "time": [4.0, 10.0]}]},
    policies=ROTOR_LOSS_POLICIES,
    episodes=4,
    detector="loe_kalman",
    description="Quadrotor flying the square at 2.5 m/s in light turbulence; a random rotor is lost at 4-10 s.",
    default=True,
))
for _base in ("quad-rotor-loss-hover", "quad-rotor-loss-maneuver"):  # the same flights on Mueller's vehicle
    register(replace(SCENARIOS[_base], name=f"{_base}-mueller", episodes=4,
                     env_kwargs={**SCENARIOS[_base].env_kwargs, "vehicle": "mueller2014"},
                     description=SCENARIOS[_base].description.replace("Quadrotor", "mueller2014 quadrotor", 1)))
# In the style of Chen et al. 2025 (arXiv 2503.02649; docs/results.md), whose released validation run starts at rest
# at (0, 0, 3) m with the set-point (1, 1, 3) m from its first step, and cuts a rotor at 2.5 s: the set-point steps by
# (1, 1, 0) m right after the start (task goto, step_time 0), the vehicle flies there and hovers, and a random rotor
# loses its propeller at 2.5 s; no sensor noise, no wind. 9.5 s remain after the loss (the anchor's run: 5 s).
# Not in the defaults (`ftcgym bench --scenario ...`).
#: every noise, bias and vibration level of the quadrotor's sensors at 0 (ideal sensors; the rates stay)
QUIET_SENSORS = {f.name: 0.0 for f in fields(SensorConfig) if not f.name.endswith("_hz")}
_GOTO = {"task": {"name": "goto", "step_north": 1.0, "step_east": 1.0, "step_altitude": 0.0, "step_time": 0.0},
         "max_episode_seconds": 12.0, "faults": [{"kind": "rotor_loss", "target": "random", "time": 2.5}]}
register(Scenario(
    name="quad-rotor-loss-goto",
    env_id=QUADROTOR,
    env_kwargs={**_GOTO, "wind": {"mean": [0.0, 0.0, 0.0], "turbulence": "none"}, "sensors": QUIET_SENSORS},
    policies=HOVER_ROTOR_LOSS_POLICIES,
    episodes=4,
    detector="loe_kalman",
    description="Quadrotor flies to a set-point (1, 1, 0) m from its start at 5 m and hovers; a random rotor loses "
                "its propeller at 2.5 s; no wind, no sensor noise (after Chen et al. 2025).",
))
register(Scenario(
    name="quad-rotor-loss-goto-wind",
    env_id=QUADROTOR,
    env_kwargs={**_GOTO, "wind": LIGHT_TURBULENCE},
    policies=HOVER_ROTOR_LOSS_POLICIES,
    episodes=4,
    detector="loe_kalman",
    description="As quad-rotor-loss-goto, in light turbulence with the default sensors.",
))
for _base in ("quad-rotor-loss-goto", "quad-rotor-loss-goto-wind"):
    register(replace(SCENARIOS[_base], name=f"{_base}-mueller",
                     env_kwargs={**SCENARIOS[_base].env_kwargs, "vehicle": "mueller2014"},
                     description=SCENARIOS[_base].description.replace("Quadrotor", "mueller2014 quadrotor", 1)
                     .replace("As quad-rotor-loss-goto,", "As quad-rotor-loss-goto-mueller,")))
register(Scenario(
    name="quad-no-fault-long",
    env_id=QUADROTOR,
    env_kwargs={"task": {"name": "square", "speed": 2.0, "heading_changes": True}, "max_episode_seconds": 60.0,
                "wind": {"mean": [1.0, -1.0, 0.0], "turbulence": "light"}},
    episodes=7,
    detector="loe_kalman",
    description="Fault-free 60 s flights: square at 2 m/s with heading changes and speed excitation, "
                "light turbulence and mean wind; counts false alarms.",
))
# 002 Sec. 5.2: LOE ramps of 0.1/s capped at 0.5 on one pair at 5 s and another at 6 s. On our X frame a pitch
# pair and a roll pair always share a rotor (left at 0.25, which no controller can fly); the diagonal pairs
# (r1, r3) and (r2, r4) end, like the paper's "+" pairs, with every rotor at half effectiveness.
register(Scenario(
    name="quad-loe-ramp",
    env_id=QUADROTOR,
    env_kwargs={"task": "hover", "max_episode_seconds": 14.0, "wind": LIGHT_TURBULENCE,
                "faults": [{"kind": "loe", "target": [0, 2], "time": 5.0, "magnitude": 0.5, "rate": 0.1},
                           {"kind": "loe", "target": [1, 3], "time": 6.0, "magnitude": 0.5, "rate": 0.1}]},
    episodes=4,
    detector="aekf",
    description="Lu et al. Sec. 5.2: LOE ramps 0.1/s capped at 0.5 on diagonal pairs (r1, r3) at 5 s and (r2, r4) "
                "at 6 s.",
))
# 004 Sec. 5.1: a 0.5 kg quadcopter (our mueller2014 set) gains 0.5 kg between 40 and 42 s on the square.
_PAYLOAD = {"vehicle": "mueller2014", "max_episode_seconds": 60.0,
            "wind": {"mean": [1.0, -1.0, 0.0], "turbulence": "light"},
            "faults": [{"kind": "payload", "time": 40.0, "magnitude": 0.5, "duration": 2.0}]}
register(Scenario(
    name="quad-payload",
    env_id=QUADROTOR,
    env_kwargs={**_PAYLOAD, "task": {"name": "square", "altitude": 8.0}},
    episodes=4,
    detector="iv_change",
    description="Ho, Hendeby and Enqvist 2020 Sec. 5.1: mass 0.5 -> 1 kg at 40-42 s on the 8 m square, light "
                "turbulence, wind (1, -1, 0).",
))
register(Scenario(
    name="quad-payload-heading",
    env_id=QUADROTOR,
    env_kwargs={**_PAYLOAD, "task": {"name": "square", "altitude": 8.0, "heading_changes": True}},
    episodes=4,
    detector="iv_change",
    description="As quad-payload, turning the heading by 90 deg at each corner (Ho, Hendeby and Enqvist's second "
                "scenario).",
))

# Quad-plane: the autopilot flies the mission (take-off, transition, one 150 m circle at 18 m/s,
# back transition, landing) on the airspeed the policy feeds it.
_QP_MISSION = {"wind": {"mean": [-3.0, 4.0, 0.0], "turbulence": "light"}, "max_episode_seconds": 240.0}
AIRSPEED_POLICIES = ("pitot-only", "oracle-airspeed")
register(Scenario(
    name="qp-mission",
    env_id=QUADPLANE_AUTOPILOT,
    env_kwargs=_QP_MISSION,
    policies=AIRSPEED_POLICIES,
    episodes=2,
    description="Quad-plane mission, fault-free, 5 m/s mean wind and light turbulence.",
    default=True,
))
# Pitot faults: scored on the airdata_ekf pitot alarm (001 Sec. 6.1); airspeed-switch flies on it.
# learned-airspeed (task airspeed-source) beside them when SB3 is installed to fly it: trained on both
# pitot fault kinds; +2 episodes (~30 s of one core) in `ftcgym bench`'s defaults.
PITOT_FAULT_POLICIES = ("pitot-only", "airspeed-switch", "oracle-airspeed") + (
    ("learned-airspeed",) if importlib.util.find_spec("stable_baselines3") else ())
#: The pitot faults are scored on the first of airdata_ekf's pitot tests (Table 2, CUSUM, ramp test): the alarm
#: airspeed-switch acts on. `ftcgym airdata-study` reports each test's own alarm.
PITOT_ALARM = {"criterion": "either"}
register(Scenario(
    name="qp-pitot-abrupt",
    env_id=QUADPLANE_AUTOPILOT,
    env_kwargs={**_QP_MISSION, "faults": [{"kind": "pitot_blockage", "target": "zero", "time": 45.0}]},
    policies=PITOT_FAULT_POLICIES,
    episodes=2,
    detector="airdata_ekf",
    detector_kwargs=PITOT_ALARM,
    description="Quad-plane mission; the pitot reads zero from 45 s, in forward flight (Larocque 2023 Sec. 7.2.1).",
    default=True,
))
register(Scenario(
    name="qp-pitot-incipient",
    env_id=QUADPLANE_AUTOPILOT,
    env_kwargs={**_QP_MISSION, "faults": [{"kind": "pitot_blockage", "rate": 2.5, "time": 45.0}]},
    policies=PITOT_FAULT_POLICIES,
    episodes=2,
    detector="airdata_ekf",
    detector_kwargs=PITOT_ALARM,
    description="Quad-plane mission; from 45 s the pitot reading drifts down at 2.5 m/s^2 (water blockage, "
                "Larocque 2023 Sec. 7.2.2).",
))
# EKF fault tolerance (001 Sec. 7.3): a sensor the EKF uses reads zero in forward flight; scored on
# the airdata_ekf innovation detectors (isolated "gnss" / "pusher_rpm"); airspeed-switch must not switch on them.
SENSOR_FAULT_POLICIES = ("airspeed-switch", "oracle-airspeed")
for _name, _kind, _sensor, _section in (("qp-gnss-fault", "gnss", "GNSS velocity", "7.3.1"),
                                       ("qp-rpm-sensor-fault", "pusher_rpm_sensor", "pusher RPM sensor", "7.3.2")):
    register(Scenario(
        name=_name,
        env_id=QUADPLANE_AUTOPILOT,
        env_kwargs={**_QP_MISSION, "faults": [{"kind": _kind, "time": 45.0}]},
        policies=SENSOR_FAULT_POLICIES,
        episodes=2,
        detector="airdata_ekf",
        description=f"Quad-plane mission; the {_sensor} reads zero from 45 s, in forward flight (Larocque 2023 "
                    f"Sec. {_section}).",
    ))
# False alarms over many fault-free hours: each episode draws its own mean wind (0-9 m/s, any direction, light
# turbulence; benchmark.random_wind) and flies three laps (~4.3 min airborne); 140 episodes ~ 10 flight hours.
register(Scenario(
    name="qp-no-fault-long",
    env_id=QUADPLANE_AUTOPILOT,
    env_kwargs={"task": {"name": "mission", "laps": 3}, "max_episode_seconds": 480.0,
                "wind": {"mean": [0.0, 0.0, 0.0], "turbulence": "light"}},
    policies=("airspeed-switch",),
    episodes=10,
    detector="airdata_ekf",
    description="Fault-free three-lap missions, mean wind 0-9 m/s from a random direction per episode and light "
                "turbulence; counts false alarms of the pitot and innovation detectors.",
    wrappers=(random_mean_wind_wrapper,),
))
# Propulsion faults (003 Sec. IV-V), scored on propulsion_bayes: 8 laps of cruise on the pitot, truncated at
# 300 s. The detector calibrates on early cruise (with its own airspeed step), detects from ~95 s and asks for a
# +4 m/s step to isolate; each fault rises by 10% over 50 s from 100 s (003 Sec. IV-A, Fig. 6).
# Sensors: 003 Sec. IV-B's measurement model for all three of the detector's inputs (additive Gaussian noise: omega
# 5e-1, V_a 7e-4, I_e 1e-5 covariance; the first and last are every quad-plane's defaults). The pitot of the 001
# scenarios (0.3 m/s noise, 0.05 s lag) puts ~6e-4 N m of noise on each 0.5 s sample of Q_a*(omega, V_a), as much
# as a 10% viscous fault: isolation then is a coin toss between the friction modes (docs/measurements.md,
# 'Tuning record: fdd/propulsion_bayes.py'; pass `--env-kwargs '{"sensors": {}}'` to fly it).
PROPULSION_003_SENSORS = {"pitot_noise": math.sqrt(7e-4), "pitot_time_constant": 0.0}
_QP_PROPULSION = {**_QP_MISSION, "task": {"name": "mission", "laps": 8}, "max_episode_seconds": 300.0,
                  "sensors": PROPULSION_003_SENSORS}
for _name, _kind in (("none", None), ("icing", "propeller_icing"), ("viscous", "viscous_friction"),
                     ("static", "static_friction")):
    register(Scenario(
        name=f"qp-propulsion-{_name}",
        env_id=QUADPLANE_AUTOPILOT,
        env_kwargs={**_QP_PROPULSION, "faults": [{"kind": _kind, "time": 100.0}] if _kind else []},
        policies=("pitot-only",),
        episodes=4,
        detector="propulsion_bayes",
        description=(f"Quad-plane 300 s cruise; {_kind} x1.1 over 50 s from 100 s (Haaland et al. Sec. IV-A)"
                     if _kind else
                     "Quad-plane 300 s cruise, no fault: propulsion_bayes false alarms") + ".",
    ))
