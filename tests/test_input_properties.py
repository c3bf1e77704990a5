"""Property tests over what a user passes (make keywords, fault specs, actions): either a ValueError at make
or reset that names the field, or 200 steps of finite observations inside the observation space.

Values are drawn around each field's nominal value (x0.001 to x1000, log-uniform) and among the adversarial ones (zero,
negative, NaN, inf, huge, strings, None, wrong shapes). The examples are derandomized, so CI sees the same
ones every run.
"""
import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ftcgym  # noqa: F401  (registers the envs)
from ftcgym.models.faults import KINDS
from ftcgym.models.quadrotor import BEBOP2
from ftcgym.models.vsqp import VSQP

STEPS = 200
SETTINGS = settings(max_examples=100, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])
JUNK = st.sampled_from([0.0, -1.0, math.nan, math.inf, -math.inf, 1e300, "1.0", None, [], [1.0, 2.0], True,
                        {"a": 1}, 1 + 1j])


def near(nominal):
    """A value x0.001 to x1000 the nominal one (log-uniform), of its shape."""
    shape = np.shape(nominal)
    factors = st.lists(st.floats(-3.0, 3.0).map(lambda e: 10.0 ** e), min_size=max(1, int(np.prod(shape))),
                       max_size=max(1, int(np.prod(shape))))
    return factors.map(lambda f: float(nominal * f[0]) if shape == () else (np.asarray(nominal) * f).tolist())


def overrides_of(params, skip=()):
    """Overrides of one to three fields of `params`: near their nominal values, or junk."""
    names = [f.name for f in dataclasses.fields(params) if f.name not in ("name", "sources", *skip)]
    value = {name: st.one_of(near(getattr(params, name)), JUNK) for name in names}
    return st.lists(st.sampled_from(names), min_size=1, max_size=3, unique=True).flatmap(
        lambda chosen: st.fixed_dictionaries({name: value[name] for name in chosen}))


def fly_or_refuse(env_id, kwargs, data, names):
    """Make, reset and fly `STEPS` random actions; a ValueError at make or reset must name one of `names`."""
    try:
        env = gym.make(env_id, **kwargs)
        obs, info = env.reset(seed=0)
    except ValueError as error:
        assert any(name in str(error) for name in names), str(error)
        return None
    try:
        rng = np.random.default_rng(data)
        for _ in range(STEPS):
            assert env.observation_space.contains(obs), {k: v for k, v in obs.items()
                                                         if not env.observation_space[k].contains(v)}
            assert info["truth"]["mass"] > 0.0 and np.all(np.isfinite(info["truth"]["position"]))
            obs, _, terminated, truncated, info = env.step(rng.uniform(env.action_space.low, env.action_space.high))
            if terminated or truncated:
                break
        return info
    finally:
        env.close()


@SETTINGS
@given(overrides=overrides_of(BEBOP2), seed=st.integers(0, 2**16))
def test_quadrotor_overrides_fly_finite_or_are_refused(overrides, seed):
    fly_or_refuse("ftcgym/Quadrotor-v0", {"vehicle_overrides": overrides}, seed, ["vehicle_overrides"])


@settings(SETTINGS, max_examples=30)
@given(overrides=overrides_of(VSQP), seed=st.integers(0, 2**16))
def test_quadplane_overrides_fly_finite_or_are_refused(overrides, seed):
    fly_or_refuse("ftcgym/QuadPlane-v0", {"vehicle_overrides": overrides, "agent_hz": 250}, seed,
                  ["vehicle_overrides"])


SENSORS = ["gyro", "accel", "attitude", "position", "velocity", "rotor_speed"]
FAULT = st.fixed_dictionaries({"kind": st.one_of(st.sampled_from(KINDS), JUNK)}, optional={
    "target": st.one_of(st.integers(-1, 5), st.lists(st.integers(0, 4), max_size=3), st.sampled_from(SENSORS),
                        st.just("random"), JUNK),
    "time": st.one_of(st.floats(0.0, 0.3), st.tuples(st.floats(0.0, 0.1), st.floats(0.1, 0.3)).map(list), JUNK),
    "magnitude": st.one_of(st.floats(-1.0, 2.0), st.lists(st.floats(-5, 5), min_size=1, max_size=4), JUNK),
    "rate": st.one_of(st.floats(0.01, 10.0), JUNK),
    "duration": st.one_of(st.floats(0.01, 0.3), JUNK),
})


@SETTINGS
@given(faults=st.one_of(st.lists(FAULT, max_size=3), st.sampled_from([f"random:{k}" for k in KINDS]), JUNK),
       seed=st.integers(0, 2**16))
def test_fault_specs_act_as_info_says_or_are_refused(faults, seed):
    info = fly_or_refuse("ftcgym/Quadrotor-v0", {"faults": faults, "agent_hz": 250}, seed, ["faults"])
    if info is None:
        return
    truth = info["truth"]
    assert np.all((truth["rotor_effectiveness"] >= 0.0) & (truth["rotor_effectiveness"] <= 1.0))
    for spec in info["faults"]:                    # every reported fault is resolved and in the schedule's terms
        assert spec["kind"] in KINDS and not isinstance(spec["time"], list) and spec["target"] != "random"


ACTION = st.one_of(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=6),
    st.lists(st.floats(-10.0, 10.0), min_size=4, max_size=4),
    st.lists(JUNK, min_size=4, max_size=4),
    JUNK,
)


@pytest.fixture(scope="module")
def quadrotor():
    env = gym.make("ftcgym/Quadrotor-v0")
    yield env
    env.close()


@SETTINGS
@given(actions=st.lists(ACTION, min_size=1, max_size=20))
def test_actions_step_finite_or_are_refused_before_the_physics(quadrotor, actions):
    obs, _ = quadrotor.reset(seed=0)
    for action in actions:
        time = quadrotor.unwrapped.time
        try:
            obs, *_ = quadrotor.step(action)
        except ValueError as error:
            assert str(error).startswith("action:"), str(error)
            assert quadrotor.unwrapped.time == time      # a refused action does not step
        assert quadrotor.observation_space.contains(obs)
