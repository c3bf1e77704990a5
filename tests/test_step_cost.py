"""The lean physics step: seeded trajectories pinned to the values of the numpy-array step it replaced,
`info_level` and `observation_format`."""
import gymnasium as gym
import numpy as np
import pytest
from conftest import LIGHT_WIND
from gymnasium.spaces import flatten, unflatten

from ftcgym.agents import make_policy

# Recorded with the array-based step (commit 12c0590) on the development machine; the plain-float step gives the
# same bits there. The tolerance leaves room for another BLAS kernel's rounding elsewhere.
QUADROTOR_PIN = [0.2392849878222523, 0.07259869339980213, -4.709252383509034, 0.011114537794929588,
                 -0.053124941964070284, -0.022886464496208403, 0.019426667108255448, -0.03240346530503587,
                 -0.05318511540817684, 0.5285291190814626, -0.8992588592837167, -9.799871223484315, 0.7889762390082443]
# Re-pinned when the hover rotors' spin-up reaction and the propellers' gyroscopic moment joined the physics, the
# pusher's current at its speed limit came from 003 eq. (1), and the GNSS vertical velocity took 001's noise.
QUADPLANE_PIN = [-0.08362560824079447, 0.07131808828835437, -16.883456614095188, -0.09364974026069793,
                 0.022378817064407256, -0.005412327551414517, 5.020896760685396, -0.09610672359740946,
                 0.013995530664741043, -0.012943808043905396, 0.8684439116636071]
# The same flight in the quad-plane's default turbulence, whose V_a follows the vehicle (recorded when that became
# the default, on the development machine).
QUADPLANE_FOLLOWING_PIN = [-0.08217513817332248, 0.05372463591647354, -16.887443919319068, -0.09289874859087209,
                           0.02248348455025195, -0.0069980975795402136, 4.928852968934742, -0.08436677468817606,
                           0.032318730616666756, -0.008346614961745536, 0.8684896929491662]


def _fly(env, policy_name, steps=1000):
    obs, info = env.reset(seed=11)
    policy = make_policy(policy_name, env)
    policy.reset(obs, info)
    for _ in range(steps):
        obs, reward, _, _, info = env.step(policy.act(obs, info))
    return obs, reward, info


def test_quadrotor_trajectory_is_pinned():
    env = gym.make("ftcgym/Quadrotor-v0", wind=LIGHT_WIND, max_episode_seconds=60,
                   faults=[{"kind": "loe", "target": 1, "time": 0.5, "magnitude": 0.3}])
    obs, reward, info = _fly(env, "nominal")
    t = info["truth"]
    got = [*t["position"], *t["body_rates"], *obs["gyro"], *obs["accel"], reward]
    np.testing.assert_allclose(got, QUADROTOR_PIN, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(("airspeed", "pin"), [("mean", QUADPLANE_PIN), (None, QUADPLANE_FOLLOWING_PIN)])
def test_quadplane_trajectory_is_pinned(airspeed, pin):
    wind = {"mean": [-3.0, 4.0, 0.0], "turbulence": "light", **({"airspeed": airspeed} if airspeed else {})}
    obs, reward, info = _fly(gym.make("ftcgym/QuadPlane-v0", wind=wind), "autopilot")
    t = info["truth"]
    got = [*t["position"], *t["body_rates"], t["airspeed"], *obs["gyro"], reward]
    np.testing.assert_allclose(got, pin, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("env_id", ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0"])
def test_minimal_info_omits_only_truth_and_leaves_the_flight_unchanged(env_id):
    full, minimal = gym.make(env_id, wind=LIGHT_WIND), gym.make(env_id, wind=LIGHT_WIND, info_level="minimal")
    for env in (full, minimal):
        env.reset(seed=3)
    action = full.action_space.sample()
    for _ in range(20):
        obs_f, r_f, _, _, info_f = full.step(action)
        obs_m, r_m, _, _, info_m = minimal.step(action)
    assert "truth" in info_f and "truth" not in info_m
    assert set(info_f) - set(info_m) == {"truth"}
    assert r_f == r_m and all(np.array_equal(obs_f[k], obs_m[k]) for k in obs_f)


def test_info_level_is_validated():
    with pytest.raises(ValueError, match="info_level"):
        gym.make("ftcgym/Quadrotor-v0", info_level="verbose")


SENSOR_BIAS = {"kind": "sensor_bias", "target": "gyro", "time": 0.01, "magnitude": [0.1, 0.0, 0.0]}
ROTOR_LOSS = {"kind": "rotor_loss", "target": 1, "time": 0.01}


@pytest.mark.parametrize("env_id", ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0"])
@pytest.mark.parametrize("fault", [SENSOR_BIAS, ROTOR_LOSS], ids=["sensor-fault", "no-sensor-fault"])
def test_flat_observations_are_gymnasiums_flattening_of_the_dict_and_fly_the_same(env_id, fault):
    """`observation_format="flat"` gives `gymnasium.spaces.flatten` of the Dict observation, in a Box that
    contains it (with no sensor fault the quadrotor reorders its sample in one indexing instead); with
    `info_level="none"` info is empty; the flight is the same."""
    kwargs = {"wind": LIGHT_WIND, "faults": [fault]}
    reference = gym.make(env_id, **kwargs)
    flat = gym.make(env_id, **kwargs, observation_format="flat", info_level="none")
    dict_space = flat.unwrapped.dict_observation_space
    assert flat.observation_space.shape == (sum(box.shape[0] for box in dict_space.values()),)
    obs_d, _ = reference.reset(seed=4)
    obs_f, info_f = flat.reset(seed=4)
    action = reference.action_space.sample()
    for _ in range(10):
        obs_d, r_d, _, _, _ = reference.step(action)
        obs_f, r_f, _, _, info_f = flat.step(action)
    assert info_f == {} and r_f == r_d
    assert obs_f.dtype == np.float64 and flat.observation_space.contains(obs_f)
    np.testing.assert_array_equal(obs_f, flatten(reference.observation_space, obs_d))
    np.testing.assert_array_equal(unflatten(dict_space, obs_f)["gyro"], obs_d["gyro"])   # a bias included


def test_observation_format_is_validated():
    with pytest.raises(ValueError, match="observation_format"):
        gym.make("ftcgym/Quadrotor-v0", observation_format="tuple")


@pytest.mark.parametrize("physics_hz, agent_hz", [(500, 500), (240, 30)])
def test_a_non_finite_physics_state_stops_the_step_before_it_reaches_the_rotors(physics_hz, agent_hz):
    """The physics loop keeps PyBullet's state as it comes; a NaN in it raises at the next physics step's loads
    (240/30: eight substeps) or at the agent step's conversion (500/500), and the rotors never see it."""
    from ftcgym.envs.world import p
    env = gym.make("ftcgym/Quadrotor-v0", physics_hz=physics_hz, agent_hz=agent_hz)
    env.reset(seed=0)
    world = env.unwrapped.world
    p.resetBaseVelocity(world.body, [float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=world.client)
    with pytest.raises(FloatingPointError, match="physics state became non-finite"):
        env.step(np.full(4, 0.5, np.float32))
    assert np.isfinite(env.unwrapped.rotors.state).all()
    env.close()


def _episode_bits(env, seed: int, steps: int = 150) -> bytes:
    """The observations of `steps` steps of fixed random actions in the lowest 30% of the action space (the
    quad-plane stays on the ground) from a reset with `seed`."""
    obs, _ = env.reset(seed=seed)
    space = env.action_space
    actions = np.random.default_rng(0).uniform(space.low, space.low + 0.3 * (space.high - space.low),
                                               (steps, space.shape[0]))
    bits = []
    for action in actions:
        obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
        bits.append(np.concatenate([np.ravel(v) for v in obs.values()]))
        if terminated or truncated:
            break
    return np.concatenate(bits).tobytes()


@pytest.mark.parametrize("env_id", ["ftcgym/Quadrotor-v0", "ftcgym/QuadPlane-v0"])
def test_a_seeded_episode_flies_the_same_whether_the_body_was_renewed_or_the_world_rebuilt(env_id, monkeypatch):
    """A reset renews the body alone between full rebuilds of the world (`PyBulletWorld._build`); the quad-plane
    starts on the ground, where the contact caches of a body kept from the last episode change the first steps
    (the fourth flight below differs then). With a full rebuild every third build, the same seed after other
    episodes, renewals and rebuilds flies as in a fresh env."""
    from ftcgym.envs import world
    monkeypatch.setattr(world, "RENEWALS", 2)
    fresh = _episode_bits(gym.make(env_id, max_episode_seconds=2.0), seed=3)
    env = gym.make(env_id, max_episode_seconds=2.0)
    flights = [_episode_bits(env, seed) for seed in (3, 5, 3, 3, 7, 3)]
    assert [flight == fresh for flight in flights] == [True, False, True, True, False, True]


def test_the_physics_loop_skips_the_faults_only_while_they_are_steady():
    """`FaultSchedule.steady_until`: the next onset, or now while a ramp rises, a payload is added or a propulsion
    fault acts."""
    from ftcgym.models.faults import QUADPLANE_KINDS, FaultSchedule, parse_faults, resolve

    def schedule(faults, kinds=None):
        specs = parse_faults(faults, 4, {"gyro": 3}, *([kinds] if kinds else []))
        return FaultSchedule(resolve(specs, np.random.default_rng(0), 4, ["gyro"]), 4)

    steps = schedule([{"kind": "loe", "target": 0, "time": 1.0, "magnitude": 0.4, "rate": 0.2},
                      {"kind": "payload", "time": 5.0, "magnitude": 0.1, "duration": 0.5},
                      {"kind": "rotor_loss", "target": 2, "time": 8.0},
                      {"kind": "sensor_bias", "target": "gyro", "time": 0.5, "magnitude": [0.1, 0.0, 0.0]}])
    assert [steps.steady_until(t) for t in (0.0, 0.99, 1.0, 2.9, 3.0, 4.0, 5.2, 5.5, 7.0, 8.0)] == \
        [1.0, 1.0, 1.0, 2.9, 5.0, 5.0, 5.2, 8.0, 8.0, np.inf]     # the loe ramp ends at 3.0 s, the payload at 5.5
    assert schedule([]).steady_until(3.0) == np.inf
    icing = schedule([{"kind": "propeller_icing", "time": 2.0, "magnitude": 1.3, "duration": 10.0}], QUADPLANE_KINDS)
    assert [icing.steady_until(t) for t in (1.0, 2.0, 30.0)] == [2.0, 2.0, 30.0]


def test_the_compiled_matrix_of_a_quaternion_is_pybullets_bit_for_bit():
    """`frames.bullet_matrix` stands for PyBullet's `getMatrixFromQuaternion` in every physics step: the same
    floats for unit quaternions, quaternions off the unit sphere and the extremes of each axis."""
    import pybullet as p

    from ftcgym.envs.frames import bullet_matrix
    rng = np.random.default_rng(11)
    quats = rng.standard_normal((20000, 4))
    quats[:10000] /= np.linalg.norm(quats[:10000], axis=1, keepdims=True)
    quats = [*quats.tolist(), *np.eye(4).tolist(), [0.0, 0.0, 0.0, -1.0], [1e-9, 0.0, 0.0, 1.0]]
    client = p.connect(p.DIRECT)
    try:
        differ = [q for q in quats if bullet_matrix(*q) != tuple(p.getMatrixFromQuaternion(q, physicsClientId=client))]
    finally:
        p.disconnect(client)
    assert differ == []


def test_a_call_bound_to_its_types_gives_the_dispatcher_s_result_and_plain_python_passes_through():
    from ftcgym.envs.frames import RAW_EXAMPLE, body_state
    from ftcgym.models.compiled import without_dispatch
    raw = ((1.0, 2.0, 3.0), (0.1, -0.2, 0.3, 0.9), (4.0, 5.0, 6.0), (0.5, -0.6, 0.7))
    assert without_dispatch(body_state, RAW_EXAMPLE)(raw) == body_state(raw)
    assert body_state(raw)[0] == (1.0, -2.0, -3.0) and body_state(raw)[3] == (4.0, -5.0, -6.0)

    def plain(x):
        return 2 * x
    assert without_dispatch(plain, 1.0) is plain
