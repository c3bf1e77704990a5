"""Constant mean wind plus Dryden turbulence (004 eq. (13)-(14), Sec. 5.1).

004 eq. (13): V_w = V_w^l + V_w^h, a constant low-frequency wind plus turbulence. The turbulence
components are white noise through the Dryden filters of 004 eq. (14a-c):

    H_u(s) = sigma_u sqrt(2 V_a / L_u) / (s + V_a/L_u)
    H_v(s) = sigma_v sqrt(3 V_a / L_v) (s + V_a/(sqrt(3) L_v)) / (s + V_a/L_v)^2   (H_w alike)

driven by unit-intensity white noise, so each output has standard deviation sigma exactly.

Implementation: the three filters form one 5-state LTI system (u: 1 state, v: 2, w: 2),
x' = A x + B n, y = C x. It is discretised exactly (Van Loan's method: no Euler error, so the
statistics do not depend on dt) into x[k+1] = Ad x[k] + w[k], w ~ N(0, Qd), and the state starts
from its stationary covariance, so there is no start-up transient. The filter gains live in C and
the noise enters with unit gain, so Qd is always positive definite and a zero sigma gives an
exactly zero component.

Frames: NED world (z down), m/s. 004 gives u, v, w along the vehicle axes; we instead apply them
along NED axes aligned with the mean wind: u along the mean wind's horizontal direction (north when
the mean wind is ~horizontal-calm), v horizontal and 90 deg clockwise from u seen from above (east
when u is north), w down. This keeps the wind a function of time only, independent of attitude.

V_a is the reference airspeed in the filters. `airspeed="mean"` (or None): max(|mean wind|, 1 m/s): a hovering
vehicle's airspeed is the wind speed, and the 1 m/s floor keeps the time constants L/V_a finite. A number fixes it.
`airspeed="vehicle"` makes V_a the vehicle's speed through the mean wind, |v - mean| (floor 1 m/s, in steps of
0.1 m/s), which the env gives once per agent step (`follow`): a quad-plane meets its cruise's turbulence
bandwidth in cruise and its hover's in hover. A V_a that changes calls for the filters in space rather than
time (Taylor's frozen turbulence, on which the Dryden spectra rest: MIL-F-8785C defines them per unit distance,
Omega = omega / V_a): 004 eq. (14) with V_a = 1 and L in metres is the filter per metre flown, driven by white
noise of unit intensity per metre, advanced by ds = V_a dt per step. Its state's stationary distribution does
not depend on V_a, so a change of speed keeps sigma and changes only how fast the gusts pass. At a constant V_a
(a multiple of 0.1 m/s) it gives the time-domain filter's winds (the two state vectors differ by a constant
diagonal scaling; within 5e-13 m/s on the same draws, `tests/test_wind.py`). Each episode starts at the mean
wind's V_a, rounded.

Randomness: only from the numpy Generator passed to reset(). Turbulence draws Gaussian noise in
blocks of _BLOCK steps (bit-identical sequences for a given seed); a calm wind (all sigmas zero)
draws nothing. Give the wind its own child generator if other components share a seed.
"""
from __future__ import annotations

import functools
import itertools
import math

import numpy as np
import scipy.linalg
from numba import njit

from .checks import FINITE, POSITIVE, Range, no_unknown, number, numbers

# 004 Sec. 5.1 ("low altitude and light turbulence", h = 8 m). "moderate" and "severe" are our
# choice: light sigmas times 2 and 4, lengths kept (MIL-F-8785C's low-altitude model scales all
# sigmas with the 20-ft wind, 15/30/45 kt for light/moderate/severe, i.e. 1:2:3, so our "severe"
# is somewhat harsher than that standard's).
_LIGHT_SIGMAS = (1.1006, 0.6576, 0.4168)
_LENGTHS = (65.8567, 19.2356, 2.8)
TURBULENCE_PRESETS: dict[str, dict] = {
    "none": {"sigmas": (0.0, 0.0, 0.0), "lengths": _LENGTHS},
    "light": {"sigmas": _LIGHT_SIGMAS, "lengths": _LENGTHS},
    "moderate": {"sigmas": tuple(2.0 * s for s in _LIGHT_SIGMAS), "lengths": _LENGTHS},
    "severe": {"sigmas": tuple(4.0 * s for s in _LIGHT_SIGMAS), "lengths": _LENGTHS},
}

CONFIG_KEYS = ("mean", "turbulence", "airspeed")
_TURBULENCE_KEYS = ("sigmas", "lengths")
_BLOCK = 1024          # noise steps drawn per refill: amortises the rng/matmul call overhead
_CHUNK = 64            # steps filtered per compiled call (`DrydenWind._turbulent_winds`)
_CALM_HORIZONTAL = 1e-9  # m/s; below this the mean wind has no direction and u points north
VEHICLE = "vehicle"      # `airspeed`: V_a follows the vehicle's speed through the mean wind
MEAN = "mean"            # `airspeed`: V_a is the mean wind's speed (the default of `DrydenWind`)
_MIN_AIRSPEED = 1.0      # m/s, V_a's floor: keeps L/V_a finite


MAX_MEAN_WIND = 50.0                     # m/s, above a category-3 hurricane's sustained wind
_SIGMAS = Range(0.0, 20.0)               # m/s; MIL-F-8785C's severe turbulence stays below 10
_LENGTHS = Range(1.0, 1e5)               # m
_AIRSPEED = Range(0.0, 200.0, open_low=True)   # m/s, the airspeed that scales the turbulence


def _vector3(value, field: str, accepted: Range = FINITE) -> np.ndarray:
    return numbers(value, f"wind {field}", (3,), accepted)


def _positive(value, field: str, accepted: Range = POSITIVE) -> float:
    return number(value, f"wind {field}", accepted)


def _parse_turbulence(turbulence) -> tuple[np.ndarray, np.ndarray]:
    """Preset name or {"sigmas", "lengths"} dict -> validated (sigmas, lengths)."""
    accepted = f"a preset name {sorted(TURBULENCE_PRESETS)} or a dict with keys {list(_TURBULENCE_KEYS)}"
    if isinstance(turbulence, str):
        if turbulence not in TURBULENCE_PRESETS:
            raise ValueError(f"wind turbulence: unknown preset {turbulence!r}; accepted: {accepted}")
        turbulence = TURBULENCE_PRESETS[turbulence]
    if not isinstance(turbulence, dict) or set(turbulence) != set(_TURBULENCE_KEYS):
        raise ValueError(f"wind turbulence: got {turbulence!r}; accepted: {accepted}")
    return _vector3(turbulence["sigmas"], "sigmas", _SIGMAS), _vector3(turbulence["lengths"], "lengths", _LENGTHS)


def dryden_state_space(sigmas, lengths, airspeed: float):
    """Continuous 5-state (A, B, C) of 004 eq. (14a-c), unit-intensity noise input per channel.

    Second-order filters in controllable canonical form: k (s + b) / (s + a)^2 with
    A = [[0, 1], [-a^2, -2a]], B = [0, 1]^T, C = k [b, 1].
    """
    su, sv, sw = sigmas
    a_u, a_v, a_w = (airspeed / length for length in lengths)

    def second_order(sigma, a):
        gain = sigma * math.sqrt(3.0 * a)
        return (np.array([[0.0, 1.0], [-a * a, -2.0 * a]]), np.array([[0.0], [1.0]]),
                gain * np.array([[a / math.sqrt(3.0), 1.0]]))

    blocks = [(np.array([[-a_u]]), np.array([[1.0]]), np.array([[su * math.sqrt(2.0 * a_u)]])),
              second_order(sv, a_v), second_order(sw, a_w)]
    a_mat, b_mat, c_mat = (scipy.linalg.block_diag(*parts) for parts in zip(*blocks))
    return a_mat, b_mat, c_mat


def van_loan(a_mat: np.ndarray, b_mat: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order discretisation of x' = A x + B n (n unit-intensity white): (Ad, Qd)."""
    n = a_mat.shape[0]
    block = np.zeros((2 * n, 2 * n))
    block[:n, :n] = -a_mat
    block[:n, n:] = b_mat @ b_mat.T
    block[n:, n:] = a_mat.T
    expo = scipy.linalg.expm(block * dt)
    ad = expo[n:, n:].T
    qd = ad @ expo[:n, n:]
    return ad, 0.5 * (qd + qd.T)


def _psd_factor(cov: np.ndarray) -> np.ndarray:
    """F with F F^T = cov; Cholesky, or eigen-decomposition if rounding made cov semi-definite."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(cov)
        return vecs * np.sqrt(np.clip(vals, 0.0, None))


def turbulence_axes(mean: np.ndarray) -> np.ndarray:
    """3x3 matrix whose columns are the NED directions of the u, v, w turbulence components."""
    horizontal = math.hypot(mean[0], mean[1])
    if horizontal < _CALM_HORIZONTAL:
        c, s = 1.0, 0.0
    else:
        c, s = mean[0] / horizontal, mean[1] / horizontal
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=np.float64)
    arr.flags.writeable = False
    return arr


class DrydenWind:
    """Wind velocity (NED, m/s) = constant mean + Dryden turbulence, advanced by step()."""

    def __init__(self, dt: float, mean=(0.0, 0.0, 0.0), turbulence="none", airspeed=None):
        self._dt = _positive(dt, "dt")
        self._mean = _readonly(_vector3(mean, "mean"))
        if np.linalg.norm(self._mean) > MAX_MEAN_WIND:
            raise ValueError(f"wind mean: its speed must be <= {MAX_MEAN_WIND:g} m/s, got {mean!r}")
        sigmas, lengths = _parse_turbulence(turbulence)
        self._sigmas, self._lengths = _readonly(sigmas), _readonly(lengths)
        if isinstance(airspeed, str) and airspeed not in (VEHICLE, MEAN):
            raise ValueError(f"wind airspeed: got {airspeed!r}; accepted: a number {_AIRSPEED} m/s, {VEHICLE!r} "
                             f"(the vehicle's speed through the mean wind) or {MEAN!r} (the mean wind's speed, at "
                             f"least {_MIN_AIRSPEED:g} m/s)")
        self.follows_vehicle = airspeed == VEHICLE
        self.airspeed_setting = MEAN if airspeed is None else airspeed   # as given: "vehicle", "mean" or m/s
        if airspeed is None or isinstance(airspeed, str):
            airspeed = max(float(np.linalg.norm(self._mean)), _MIN_AIRSPEED)
            if self.follows_vehicle:
                airspeed = _rounded(airspeed)
        self._airspeed = _positive(airspeed, "airspeed", _AIRSPEED)
        self._chunk = _CHUNK
        self._calm = not np.any(self._sigmas > 0.0)
        self._rng = None
        self._stream = _not_reset()          # the winds step after step (`reset`)
        self._velocity = self._mean.copy()
        self._mean_tuple = tuple(self._mean.tolist())
        if not self._calm:
            self._build_filter()

    def _build_filter(self) -> None:
        if self.follows_vehicle:
            self._build_spatial_filter()
            return
        a_mat, b_mat, c_mat = dryden_state_space(self._sigmas, self._lengths, self._airspeed)
        ad, qd = van_loan(a_mat, b_mat, self._dt)
        # Stationary covariance P = Ad P Ad^T + Qd: the initial state is drawn from it.
        stationary = scipy.linalg.solve_discrete_lyapunov(ad, qd)
        self._init_factor = _psd_factor(0.5 * (stationary + stationary.T))
        self._noise_factor_t = _psd_factor(qd).T
        out = turbulence_axes(self._mean) @ c_mat              # state -> NED wind (3x5)
        # One matvec per step: z = [x'; y'] = [Ad; out Ad] x + [w; out w + mean].
        self._transition = np.vstack([ad, out @ ad])
        self._out = out
        self._state = np.zeros(5)

    def _build_spatial_filter(self) -> None:
        """The filter per metre flown (module docstring): 004 eq. (14) at V_a = 1 m/s, L in metres. Its
        stationary covariance solves the continuous Lyapunov equation A P + P A^T + B B^T = 0, whatever V_a."""
        a_mat, b_mat, c_mat = dryden_state_space(self._sigmas, self._lengths, 1.0)
        stationary = scipy.linalg.solve_continuous_lyapunov(a_mat, -b_mat @ b_mat.T)
        self._init_factor = _psd_factor(0.5 * (stationary + stationary.T))
        self._out = turbulence_axes(self._mean) @ c_mat
        self._state = np.zeros(5)
        self._discretised = {}                # speed -> ([Ad; out Ad], F^T)
        self._start_airspeed = self._airspeed
        self._set_speed(self._airspeed)

    def _set_speed(self, airspeed: float) -> None:
        """Discretise the spatial filter over ds = airspeed dt (`_spatial_step`), once per speed."""
        self._airspeed = airspeed
        if airspeed not in self._discretised:
            ad, noise_factor_t = _spatial_step(tuple(self._lengths.tolist()), airspeed * self._dt)
            self._discretised[airspeed] = (np.vstack([ad, self._out @ ad]), noise_factor_t)
        self._transition, self._noise_factor_t = self._discretised[airspeed]

    def follow(self, velocity, steps: int) -> None:
        """V_a for the next `steps` steps: the speed of `velocity` (the vehicle's, NED m/s) through the mean
        wind, |velocity - mean|, at least 1 m/s, rounded to 0.1 m/s. Only for `airspeed="vehicle"`."""
        if not self.follows_vehicle:
            raise RuntimeError('DrydenWind.follow: this wind has a fixed airspeed; make it with airspeed="vehicle"')
        self._chunk = steps
        if self._calm:
            return
        rounded = _rounded(math.dist(velocity, self._mean_tuple))
        if rounded != self._airspeed:
            self._set_speed(rounded)

    @classmethod
    def from_config(cls, config: dict | None, dt: float, default_airspeed=MEAN) -> DrydenWind:
        """Build from the env's `wind` kwarg: None/{} -> calm; keys "mean", "turbulence", "airspeed" (absent or
        None: `default_airspeed`, the vehicle's choice)."""
        if config is None:
            config = {}
        if not isinstance(config, dict):
            raise ValueError(f"wind config: expected a dict with keys {list(CONFIG_KEYS)} or None, got {config!r}")
        no_unknown(config, CONFIG_KEYS, "wind config key")
        if config.get("airspeed") is None:
            config = {**config, "airspeed": default_airspeed}
        return cls(dt, **config)

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        """Seed the turbulence from its stationary distribution; return the current wind (3,)."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"wind reset: rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self._rng = rng
        if self._calm:
            self._velocity = self._mean.copy()
            self._stream = itertools.repeat(self._mean_tuple)
            return self._velocity.copy()
        self._state = self._init_factor @ rng.standard_normal(5)
        self._velocity = self._out @ self._state + self._mean
        if self.follows_vehicle:                 # each episode starts at the mean wind's V_a (the vehicle at rest)
            self._chunk = _CHUNK
            self._set_speed(self._start_airspeed)
        # winds drawn before this reset are discarded
        self._stream = self._followed_winds() if self.follows_vehicle else self._turbulent_winds()
        return self._velocity.copy()

    def _turbulent_winds(self):
        """The winds step after step. The process noise is drawn `_BLOCK` steps at a time, pre-mapped to
        [w; out w + mean] rows; the filter runs over it `_CHUNK` steps at a time in one compiled loop
        (`_dryden_block`: the turbulence does not depend on the vehicle, so it can run ahead of the physics),
        so an episode ended early pays for few steps it does not fly."""
        while True:
            noise = self._rng.standard_normal((_BLOCK, 5)) @ self._noise_factor_t
            noise = np.hstack([noise, noise @ self._out.T + self._mean])
            for start in range(0, _BLOCK, _CHUNK):
                winds = _dryden_block(self._transition, self._state, noise[start:start + _CHUNK])
                yield from [tuple(row) for row in winds.tolist()]

    def _followed_winds(self):
        """The winds of `airspeed="vehicle"`: `_chunk` steps (one agent step's, `follow`) at a time, at the V_a
        of the time (`_dryden_follow`). The unit noise is drawn `_BLOCK` steps at a time, as the fixed filter's."""
        normals, used = np.empty((0, 5)), 0
        while True:
            steps = self._chunk
            while used + steps > len(normals):
                normals, used = np.vstack([normals[used:], self._rng.standard_normal((_BLOCK, 5))]), 0
            winds = _dryden_follow(self._transition, self._noise_factor_t, self._out, self._mean, self._state,
                                   normals[used:used + steps])
            used += steps
            yield from [tuple(row) for row in winds.tolist()]

    def step(self) -> np.ndarray:
        """Advance by dt; return the wind velocity (3,) NED m/s as a new array."""
        return np.array(self.advance())

    def advance(self) -> tuple:
        """`step` returning the wind as a tuple of 3 floats (the physics loop's form)."""
        wind = self._velocity = next(self._stream)
        return wind

    @property
    def velocity(self) -> np.ndarray:
        """Current wind (3,) NED m/s (a copy)."""
        return np.array(self._velocity)

    @property
    def mean(self) -> np.ndarray:
        return self._mean

    @property
    def sigmas(self) -> np.ndarray:
        return self._sigmas

    @property
    def lengths(self) -> np.ndarray:
        return self._lengths

    @property
    def airspeed(self) -> float:
        """V_a of the filters, m/s (with `airspeed="vehicle"`, the one of the latest `follow`)."""
        return self._airspeed

    @property
    def dt(self) -> float:
        return self._dt


def _rounded(speed: float) -> float:
    """A followed V_a: at least 1 m/s, at most the accepted 200 m/s, to 0.1 m/s (so that each speed's filter is
    discretised once, `_set_speed`)."""
    return round(min(max(speed, _MIN_AIRSPEED), _AIRSPEED.high), 1)


@functools.lru_cache(maxsize=4096)
def _spatial_step(lengths: tuple, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(Ad, F^T) of the filter per metre flown (module docstring) over `distance` metres: Van Loan's exact
    discretisation, and F with F F^T = Qd. The sigmas enter only the output, so the lengths are the key."""
    a_mat, b_mat, _ = dryden_state_space((0.0, 0.0, 0.0), lengths, 1.0)
    ad, qd = van_loan(a_mat, b_mat, distance)
    return ad, _psd_factor(qd).T


def random_mean_wind(rng: np.random.Generator, speed_range) -> list[float]:
    """A horizontal mean wind (NED, m/s): speed uniform in `speed_range` = (lo, hi), direction uniform."""
    speed, direction = rng.uniform(*speed_range), rng.uniform(0.0, 2.0 * np.pi)
    return [float(speed * np.cos(direction)), float(speed * np.sin(direction)), 0.0]


def _not_reset():
    """The winds of a `DrydenWind` not yet reset: none."""
    raise RuntimeError("DrydenWind.step() called before reset(rng)")
    yield  # a generator: the error comes at the first step, not here


@njit(cache=True)
def _dryden_block(transition, state, noise):  # pragma: no cover (compiled)
    """The winds of len(noise) steps of the discretised filter: per step z = [Ad; out Ad] x + noise[k]
    (`DrydenWind._build_filter`), the state x becomes z[:5] (in place) and the wind is z[5:] (row k of the
    result). BLAS's product, as numpy's."""
    winds = np.empty((noise.shape[0], 3))
    for k in range(noise.shape[0]):
        z = np.dot(transition, state)
        z += noise[k]
        state[:] = z[:5]
        winds[k] = z[5:]
    return winds


@njit(cache=True)
def _dryden_follow(transition, noise_factor_t, out, mean, state, normals):  # pragma: no cover (compiled)
    """`_dryden_block` for the filter per metre flown: the process noise w = F n of each unit normal row n is
    made here, since F changes with V_a. BLAS's products."""
    winds = np.empty((normals.shape[0], 3))
    for k in range(normals.shape[0]):
        noise = np.dot(normals[k], noise_factor_t)
        z = np.dot(transition, state)
        state[:] = z[:5] + noise
        winds[k] = z[5:] + np.dot(out, noise) + mean
    return winds
