"""Relaxed hover after a propeller loss: the equilibrium against 001 Part II App. B's script, its
limits, and the simulator holding it open loop."""
import numpy as np
import pytest
from conftest import make_env
from scipy.optimize import fsolve
from scipy.spatial.transform import Rotation

from ftcgym.agents import relaxed_hover_equilibrium
from ftcgym.agents.relaxed_hover import body_moment
from ftcgym.models.quadrotor import GRAVITY, MUELLER2014, make_params

# 001 App. B "mueller" case, as its script has them (I_zz_P with the script's 1e-6 unit slip).
APP_B = {"Ixx": 3.2e-3, "Izz": 5.5e-3, "Izz_P": 1.5e-5 * 1e-6, "m": 0.5, "l": 0.17, "k_f": 6.41e-6,
         "k_t": 1.69e-2, "gamma_1_z": 2.75e-3, "g": 9.81}
# The script's physics in our parameter set: no propeller momentum (the slip makes it 1.5e-11 kg m^2),
# yaw damping only.
SCRIPT_AS_OVERRIDES = {"propeller_inertia": 0.0, "rotational_drag": (0.0, 0.0, 2.75e-3)}


def app_b_script_equilibrium(rho: float) -> dict:
    """App. B eq. 10, 12-14, 16-18 with w_4 = 0, w_1 = w_3, rho = f_2 / f_1, in Mueller's '+' body frame
    (z up), written out as the script writes them (unsigned propeller-speed sum)."""
    c = APP_B

    def residual(x):
        p, q, r, w1 = x
        w2, w3, w4 = np.sqrt(rho) * w1, w1, 0.0
        total = w1 + w2 + w3 + w4
        eq12 = c["k_f"] * (w2**2 - w4**2) * c["l"] - (c["Izz"] - c["Ixx"]) * q * r - c["Izz_P"] * q * total
        eq13 = c["k_f"] * (w3**2 - w1**2) * c["l"] + (c["Izz"] - c["Ixx"]) * p * r + c["Izz_P"] * p * total
        eq14 = -c["gamma_1_z"] * r + c["k_t"] * c["k_f"] * (w1**2 - w2**2 + w3**2 - w4**2)
        eq18 = c["k_f"] * (w1**2 + w2**2 + w3**2 + w4**2) * r / np.sqrt(p * p + q * q + r * r) - c["m"] * c["g"]
        return [eq12, eq13, eq14, eq18]

    p, q, r, w1 = fsolve(residual, [0.0, 4.0, 18.0, 560.0], xtol=1e-13)
    return {"rates": np.array([p, q, r]), "w1": w1, "w2": np.sqrt(rho) * w1, "n_z": r / np.linalg.norm([p, q, r])}


def test_mueller_equilibrium_reproduces_app_b_script():
    """rho = 0.5: same yaw rate, roll/pitch rate, primary axis and rotor speeds as the script (eq. 10-18)."""
    script = app_b_script_equilibrium(0.5)
    ours = relaxed_hover_equilibrium("mueller2014", 0.5, vehicle_overrides=SCRIPT_AS_OVERRIDES)
    rates = ours["body_rates"]
    assert abs(rates[2]) == pytest.approx(script["rates"][2], rel=1e-6)             # 18.51 rad/s
    assert np.hypot(*rates[:2]) == pytest.approx(np.hypot(*script["rates"][:2]), rel=1e-6)   # 4.01 rad/s
    assert -ours["n"][2] == pytest.approx(script["n_z"], rel=1e-6)                   # tilt 12.2 deg
    assert ours["rotor_speeds"][[0, 1, 2]] == pytest.approx([script["w1"], script["w2"], script["w1"]], rel=1e-6)
    # Mueller's '+' vehicle is ours turned 45 deg: the roll/pitch rate lies on the diagonal through the opposite
    # rotor (r2 for a failed r4), as q does on the axis through Mueller's rotor 2.
    assert abs(rates[0]) == pytest.approx(abs(rates[1]), rel=1e-9)
    assert ours["rotor_forces"][1] / ours["rotor_forces"][0] == pytest.approx(0.5)
    assert ours["rotor_forces"][3] == 0.0 and ours["rotor_forces"][0] == ours["rotor_forces"][2]


def test_signed_propeller_momentum_tilts_the_primary_axis_further():
    """With I_p = 1.5e-5 kg m^2 and signed speeds the propellers' momentum opposes the body's spin, softens the
    gyroscopic stiffness (Izz - Ixx) r + h_z, and the axis leans 15.9 deg instead of the script's 12.2."""
    script = relaxed_hover_equilibrium("mueller2014", 0.5, vehicle_overrides=SCRIPT_AS_OVERRIDES)
    physical = relaxed_hover_equilibrium("mueller2014", 0.5)
    assert np.degrees(script["tilt"]) == pytest.approx(12.22, abs=0.01)
    assert np.degrees(physical["tilt"]) == pytest.approx(15.92, abs=0.01)
    assert physical["yaw_rate"] == pytest.approx(18.81, abs=0.01)
    assert np.hypot(*physical["body_rates"][:2]) == pytest.approx(5.37, abs=0.01)
    assert physical["rotor_forces"][[0, 1]] == pytest.approx([2.040, 1.020], abs=1e-3)


@pytest.mark.parametrize("vehicle, rho", [("mueller2014", 0.5), ("bebop2", 0.5)])
@pytest.mark.parametrize("failed", [0, 1, 2, 3])
def test_equilibrium_balances_moments_and_weight(vehicle, rho, failed):
    """Every failed rotor: zero net moment at the body rates, weight carried along n, the constraints kept."""
    eq = relaxed_hover_equilibrium(vehicle, rho, failed_rotor=failed)
    params = make_params(vehicle)
    loaded = np.arange(4) != failed
    assert np.abs(body_moment(params, eq["body_rates"], eq["rotor_forces"], loaded)).max() < 1e-9
    assert eq["thrust"] * -eq["n"][2] == pytest.approx(params.mass * GRAVITY, rel=1e-9)
    assert np.cross(eq["n"], eq["body_rates"]) == pytest.approx(np.zeros(3), abs=1e-9)   # n along Omega
    assert eq["n"][2] < 0 and np.linalg.norm(eq["n"]) == pytest.approx(1.0)
    f = eq["rotor_forces"]
    assert f[failed] == 0.0 and f[eq["adjacent"][0]] == pytest.approx(f[eq["adjacent"][1]])
    assert f[eq["opposite"]] == pytest.approx(rho * f[eq["adjacent"][0]])


def test_no_equilibrium_within_thrust_to_weight_1_5():
    """App. B: at thrust-to-weight 1.5 (37.5% of the weight per rotor) the relaxed hover cannot be held, the
    adjacent rotors needing more than 40% of the weight at every rho. A clear ValueError says so."""
    omega_max = np.sqrt(1.5 * MUELLER2014.mass * GRAVITY / 4 / MUELLER2014.thrust_coefficient)
    for rho in np.linspace(0.1, 1.2, 12):
        with pytest.raises(ValueError, match="omega_max|no equilibrium"):
            relaxed_hover_equilibrium("mueller2014", rho, vehicle_overrides={"omega_max": omega_max})
    with pytest.raises(ValueError, match="above omega_max"):
        relaxed_hover_equilibrium("mueller2014", 1.3)          # 835 rad/s > 700


def test_rotor_below_idle_and_bad_arguments_raise():
    with pytest.raises(ValueError, match="below the idle speed"):
        relaxed_hover_equilibrium("mueller2014", 0.0)          # the opposite rotor would stop
    with pytest.raises(ValueError, match="rho"):
        relaxed_hover_equilibrium("mueller2014", -0.1)
    with pytest.raises(ValueError, match="failed_rotor"):
        relaxed_hover_equilibrium("mueller2014", 0.5, failed_rotor=4)
    with pytest.raises(ValueError, match="vehicle"):
        relaxed_hover_equilibrium("nope", 0.5)


@pytest.mark.parametrize("vehicle, rho, failed", [("mueller2014", 0.5, 3), ("mueller2014", 0.5, 0), ("bebop2", 0.5, 1)])
def test_simulator_holds_the_equilibrium_open_loop(vehicle, rho, failed, quiet_sensors):
    """Started at the equilibrium (n up, body rates, rotor speeds, the circle velocity) with the equilibrium
    commands held and no feedback, the primary axis stays within 5 deg of vertical and the altitude within
    0.5 m for 1 s."""
    eq = relaxed_hover_equilibrium(vehicle, rho, failed_rotor=failed)
    env = make_env(vehicle=vehicle, faults=[{"kind": "rotor_loss", "target": failed, "time": 0.0}],
                   sensors=quiet_sensors, max_episode_seconds=2.0)
    env.reset(seed=0)
    u, p = env.unwrapped, env.unwrapped.params
    attitude = Rotation.align_vectors([[0.0, 0.0, -1.0]], [eq["n"]])[0]       # n points up (NED -z)
    R = attitude.as_matrix()
    spin_world = R @ eq["body_rates"]
    accel = (R @ np.array([0.0, 0.0, -eq["thrust"]])) / p.mass + np.array([0.0, 0.0, GRAVITY])
    velocity = -np.cross(spin_world, accel) / (spin_world @ spin_world)      # on the circle, not beside it
    start = np.array([0.0, 0.0, -5.0])
    u.world.reset(start, attitude.as_quat(), velocity, eq["body_rates"])
    u.rotors.omega[:] = eq["rotor_speeds"]
    u._read_state()
    command = np.clip((eq["rotor_speeds"] - p.omega_min) / (p.omega_max - p.omega_min), 0.0, 1.0)
    command[failed] = 0.0
    for _ in range(int(u.agent_hz)):
        _, _, terminated, _, info = env.step(command.astype(np.float32))
        axis = Rotation.from_quat(info["truth"]["attitude"]).apply(eq["n"])
        assert np.degrees(np.arccos(min(-axis[2], 1.0))) < 5.0
        assert abs(info["truth"]["position"][2] - start[2]) < 0.5
        assert not terminated
