"""Synthetic air data: the airspeed and wind EKF of 001 (Larocque 2023) Sec. 3-5 and App. B.

Larocque, "Synthetic Air Data System for Pitot Tube Fault Detection on Hybrid Vehicle", MSc thesis,
TU Delft 2023 (001). Pipeline per sample:

1. Prefilter (Sec. 5): every measurement AND every input through the same 2nd-order 5 Hz Butterworth
   low-pass (`butterworth_prefilter`: scipy.signal.butter, bilinear transform with the cutoff prewarped, at
   the input sample rate), so inputs and measurements carry the same lag.
2. EKF at 25 Hz (Sec. 7.1 "ran at 25 Hz", App. B) on the filtered samples:
   x = [u v w mu_x mu_y mu_z] (eq. 34/43): air velocity in body FRD and wind in NED;
   u = [a_x a_y a_z p q r phi theta psi omega_p omega_h Lambda] (eq. 35/44; attitude kept as a rotation
   matrix, omega_h as the four hover-rotor speeds);
   z = [V_N V_E V_D a_x a_y a_z] (eq. 36/45): GNSS velocity = R [u v w] + mu (eq. 3) and the specific
   force of the component model a = F(x, u) / m (eq. 31-33).
   Kinematics eq. (4): [u v w]' = -(omega + w_omega) x [u v w] + R^T [0 0 g] + a + w_a; wind eq. (5):
   random walk. Q, R: Table 1 (Q per EKF step, see `ekf_predict`). Wind process noise x100 for the first
   20 s (Sec. 5.4); a_z measurement variance x K_az(Lambda) (eq. 39 corrected, `az_covariance_gain`).
   Initial state 0, P0 = I except the wind states, which start at their Q (Sec. 5.3).
3. The filter starts once airborne (Sec. 5.3): when the height, averaged over the last `takeoff_window` s of
   position readings, stands `takeoff_height` above its average over the first `takeoff_window` s
   (`TakeoffGate`). Departure: by the same gate the tests (4-6) stop while the vehicle is back below that
   height (`landing_gate`). 001 waits for the take-off because ground-generated forces are not in its model
   (Sec. 5.3); the same holds at touchdown, where 001 does not stop: the contact jolts the accelerometers, and
   the EKF's model airspeed with them, by several m/s within 0.1 s, which Table 2's derivative criterion read as
   a pitot fault at the end of a fault-free mission (docs/measurements.md, 'The tests stop at touchdown').
4. Pitot fault detection (Sec. 6.1, Table 2; `pitot_detection.PitotResidualDetector`): at each EKF step the
   residual r = pitot reading - EKF airspeed is low-passed at 5 Hz and thresholded by the norm criterion
   (5.5 m/s for 0.25 s) and the derivative criterion (25 m/s^2 for 0.12 s); on either the alarm latches with
   `isolated` = "pitot". The criteria are armed only `detection_delay` s (default: the 20 s wind-boost
   window of Sec. 5.4) after the filter starts: until then the wind estimate is still converging and the
   residual can reach the thresholds in a healthy flight (001 Sec. 6.1 notes exactly this start-of-flight
   transient, and why its norm threshold is high; it chose a high threshold, we also gate, so a pitot fault
   in the first 20 s is flagged only at the end of the window).
   Departure: by default (`pitot_reference="forward"`) the residual compares the pitot with the EKF's air
   velocity along the pitot, max(u, 0), not with |V|: the simulated pitot reads forward flow only
   (`models/sensors.py`), so in hover with the tail or side to a 5 m/s wind it reads ~0 while |V| ~ 5-6 m/s,
   and r = pitot - |V| can cross the 5.5 m/s norm threshold in a fault-free hover (docs/measurements.md,
   'Tuning record: fdd/airdata_ekf.py'). In forward flight u ~ |V| and the two agree. `"airspeed"` gives 001's r.
5. Beside Table 2, two tests for incipient faults, armed with it: a one-sided CUSUM on the drop of the
   filtered residual (`ResidualCusum`, the statistical test 001 Sec. 7.2.2 and 8.1 recommend), and a GLR
   matched to a ramp onset in the raw residual (`RampGlr`, a departure: 001 has no ramp test). `criterion`
   ("table2", "cusum", "ramp", "either": the first of the three) picks which drives the pitot alarm; every
   test's alarm time is published.
6. EKF fault tolerance (Sec. 6.2, Tables 2-3): one detector (low-pass, norm and derivative criteria of
   Table 2) per measurement innovation, GNSS velocity V_N, V_E, V_D (isolates "gnss") and the accelerometer-
   model a_x (isolates "pusher_rpm": the pusher RPM enters a_x's model, eq. 13-14); on an alarm the sensor's
   rows get R = `fault_covariance` for the rest of the flight, so they no longer move the state. Departure:
   an a_x alarm isolates the pusher RPM only while the RPM reading is inconsistent with the pusher current
   (`rpm_current.RpmCurrentCheck`, independent of the EKF); until then it is published as unconfirmed. And
   once the pusher RPM is isolated, a_x stays in use with the speed its current draws (003 eq. 1-4) instead of
   being dropped ("speed_from_current" in INNOVATION_DETECTORS).

Each `update` is compiled (numba) in at most two calls on the detector's state packed in a few float arrays (numba's
call cost grows with each argument): `_prepare` every sample (quaternion sign, prefilter, current checks), and at
each EKF step `_ekf_detect` (the EKF step `_ekf_step`: `ekf_cycle` = `ekf_predict`, `measurement`,
`kalman.update`; the innovation tests, the pitot tests and the outputs). Python only latches an innovation alarm,
rolls back and builds the status. The sub-objects (`pitot_detector`, `cusum`, `ramp`, `innovation_detectors`,
`confirmations`, `current_checks`) keep their attributes, read from their part of those arrays. Every step has the
operations and their order of the numpy and plain-Python code it replaced (BLAS's products and LAPACK's solve, as
numpy's; Python's float power by `py_pow`), so the estimates, statistics and alarms keep their bits.

The force model (`ComponentForceModel`) is 001's (eq. 6-30: fuselage, hover rotors, wing, pusher; control
surfaces and tail neglected as 001 Sec. 4 does): the simulator's own generalised forms
(`ftcgym.models.quadplane_aero`, `ftcgym.models.pusher`) evaluated with its coefficients taken from the vehicle
parameter set passed in and then given an error (a detector must not know the plant exactly): by default every
aerodynamic and propulsive coefficient is multiplied by 1 + `coefficient_error` (10%); with `error_seed` each
one gets a seeded random sign, 1 +- error.

Errata and departures (001 as printed):
- eq. (39) rises from 1 to 100 between 60 and 70 deg; the text (and docs/references.md, 'Known errata') says
  the multiplier falls from 100 (<= 60 deg) to 1 (>= 70 deg): K_az = 10**(2 (70 - Lambda) / 10) between.
- eq. (52) prints x_pred = f(x, u) dt; the Euler step is x_pred = x + f(x, u) dt. eq. (53) uses the
  continuous Jacobian F; the discrete transition is Phi = I + F dt (001's onboard code multiplies P by
  F alone, which resets the wind covariance to Q every step).
- eq. (21) prints C_L = C_L0 alpha + C_L0; meant C_L = C_La alpha + C_L0.
"""
from __future__ import annotations

import math
import operator
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numba import literal_unroll, njit
from numba.core.errors import TypingError
from scipy import signal

from ..models.constants import GRAVITY
from ..models.geometry import rotation_matrix
from ..models.pusher import TWO_PI, pusher_constants, thrust
from ..models.pyfloat import py_pow
from ..models.quadplane_aero import aero_model, fuselage_loads, speed_squared, wing_flow_loads
from ..models.vsqp import VsqpParams
from ..settings import updated
from . import kalman
from .base import (
    ARRAY_TYPES,
    BEYOND_LIMIT,
    READING_LIMIT,
    biquad_constants,
    biquad_step,
    check_reading,
    check_time,
    model_with_error,
    vehicle_params,
    within_limit,
)
from .pitot_detection import (
    C_ALARM,
    C_ALARM_TIME,
    C_STATISTIC,
    CONFIRMATION_CONSTANTS_SIZE,
    CONFIRMATION_STATE_SIZE,
    CRITERIA,
    CUSUM_CONSTANTS_SIZE,
    CUSUM_DEFAULT,
    CUSUM_STATE_SIZE,
    G_ALARM,
    G_ALARM_TIME,
    G_RING,
    G_STATISTIC,
    R_ALARM,
    R_ALARM_TIME,
    R_CRITERION,
    R_DERIVATIVE,
    R_NORM_SIGN,
    R_RESIDUAL,
    RAMP_DEFAULT,
    RAMP_MIN_AIRSPEED,
    RESIDUAL_CONSTANTS_SIZE,
    RESIDUAL_STATE_SIZE,
    TABLE_2_DERIVATIVE,
    TABLE_2_NORM,
    ConfirmationTest,
    CusumTest,
    PitotConfirmation,
    PitotResidualDetector,
    RampGlr,
    RampTest,
    ResidualCusum,
    ThresholdTest,
    confirmation_step,
    criterion_level,
    cusum_step,
    ramp_step,
    residual_step,
)
from .propulsion_bayes import PropulsionModel
from .rpm_current import (
    CHECK_STATE_SIZE,
    RPM_CURRENT_CHECK,
    CurrentCheck,
    RpmCurrentCheck,
    check_step,
)

#: 001 Table 1: process noise (accelerometer, gyro, wind) and measurement noise (GNSS velocity, model accel).
TABLE_1_Q = {"accel": (1.2e-4, 6.2e-4, 3.0e-4), "gyro": (3.1e-9, 1.2e-9, 1.3e-9), "wind": (1.25e-4, 1.25e-4, 1.25e-5)}
TABLE_1_R = (4.1e-5, 4.2e-5, 1.4e-4, 5e-5, 1e-4, 5e-4)
PREFILTER_CUTOFF_HZ = 5.0          # 001 Sec. 5
EKF_HZ = 25.0                      # 001 Sec. 7.1
WIND_BOOST, WIND_BOOST_SECONDS = 100.0, 20.0   # 001 Sec. 5.4
#: Coefficients the detector's model gets wrong (aerodynamic and propulsive); geometry and mass stay exact.
ERROR_COEFFICIENTS = ("fuselage_drag_area", "hover_thrust_coefficient", "hover_drag_coefficient",
                      "pusher_thrust_coefficients", "pusher_thrust_k3", "wing_cl0", "wing_cl_alpha", "wing_cd0",
                      "wing_oswald", "wing_cn90", "wing_spanwise_friction")


#: a_x's variance once the pusher speed comes from its current ("speed_from_current" below)
SPEED_FROM_CURRENT_VARIANCE = 1e-3
@dataclass(frozen=True)
class InnovationTest:
    """One sensor's fault detector on the EKF's measurement innovations (001 Sec. 6.2, Tables 2-3): the norm
    and derivative criteria of Table 2 on each of its channels, and the departures from 001 that
    INNOVATION_DETECTORS documents."""

    channels: tuple             # indices into z = [V_N V_E V_D a_x a_y a_z]
    norm: ThresholdTest         # the norm criterion on the innovation
    derivative: ThresholdTest   # the derivative criterion
    sign: int = 0               # +1 / -1: a one-sided norm criterion; 0: on |innovation|
    pitot_confirmation: ConfirmationTest | None = None   # a third criterion, the pitot residual (`PitotConfirmation`)
    rollback: float = 0.0       # s the EKF re-runs without the sensor once it is isolated
    current_check: CurrentCheck | None = None  # alarm only while the pusher current contradicts the RPM reading
    speed_from_current: float | None = None    # (m/s^2)^2: keep a_x with the current's speed at this variance

    @classmethod
    def of(cls, spec) -> InnovationTest:
        """An InnovationTest from itself or from a dict of its fields (JSON); the tests as lists."""
        if isinstance(spec, cls):
            return spec
        return updated(cls((), TABLE_2_NORM, TABLE_2_DERIVATIVE), dict(spec), "innovation_detectors")


#: `AirdataEkfDetector._pusher_speed`: averaging time (s), least speed (rad/s) and skew (forward flight, 001 Table 5)
SPEED_SCALE_SECONDS, SPEED_SCALE_MIN_SPEED, SPEED_SCALE_MIN_SKEW = 10.0, 300.0, math.radians(80.0)
#: 001 Sec. 6.2 / Table 2-3: one detector per measurement innovation, named by the sensor it isolates.
#: channels index z = [V_N V_E V_D a_x a_y a_z]; norm / derivative = (threshold, time s, cutoff Hz).
#: GNSS: Table 2 as printed; Table 2 gives the norm row for V_x and the derivative row for V_y, both run on each
#: of V_N, V_E, V_D (001: "a similar approach can be used for the other axes").
#: a_x, the accelerometer-model innovation, which Table 3 ties to the pusher RPM (it enters a_x's model through
#: eq. 13-14) and the skew sensor; 001 implements a_x only, as here. Departure from Table 2's 1.25 m/s^2 for 2 s:
#: our EKF absorbs a zeroed RPM reading into u and the wind within ~0.5 s (Table 1's R_ax = 5e-5 trusts the
#: model), so the raw innovation shows the fault as a burst of +0.5..+1.5 m/s^2 over the first 0.1-0.5 s and
#: then mostly as smaller bursts, which 1.25 for 2 s never sees. A reading that fails low makes the model miss
#: thrust, so the innovation (measured - model) goes positive: the criterion is one-sided ("sign": +1), on the
#: innovation low-passed at 1 Hz (to pass the burst), held 0.2 s, at 0.41 m/s^2: the run-rate threshold of
#: `false_alarm.run_rate_threshold` for 0.1% false detection per flight hour (001 Sec. 6.1's budget) on
#: fault-free flights. The cutoff and hold are those that best separate the fault's burst from the fault-free
#: level. The derivative row is Table 2's. Chosen on tuning flights; see docs/measurements.md,
#: 'Tuning record: fdd/airdata_ekf.py'.
INNOVATION_DETECTORS = {
    "gnss": InnovationTest(channels=(0, 1, 2), norm=ThresholdTest(2.5, 0.08, 5.0),
                           derivative=ThresholdTest(30.0, 0.08, 5.0), rollback=0.16),
    "pusher_rpm": InnovationTest(channels=(3,), norm=ThresholdTest(0.41, 0.2, 1.0),
                                 derivative=ThresholdTest(250.0, 0.12, 0.1), sign=1,
                                 pitot_confirmation=ConfirmationTest(0.15, 2.0, 3.0, 0.2), rollback=6.0,
                                 current_check=RPM_CURRENT_CHECK, speed_from_current=SPEED_FROM_CURRENT_VARIANCE),
}
#: "pitot_confirmation" (level m/s^2, window s, residual m/s, hold s; `PitotConfirmation`): a third criterion,
#: for the weak bursts. Our EKF absorbs the zeroed RPM by lowering its airspeed 3-6 m/s within 0.5 s (001 Fig.
#: 11: 2 m/s), so the pitot residual rises; the criterion fires when the a_x innovation (the norm row's 1 Hz
#: low-pass) reached 0.15 m/s^2 within the last 2 s and the residual (Table 2's 5 Hz low-pass) has stayed >= 3 m/s
#: for 0.2 s. A blocked pitot can only lower the residual, so a residual rising right after an a_x burst blames
#: the RPM. The residual level (3 m/s) stands above the largest that fault-free flights hold while the level gate
#: is open; the level gate (0.15 m/s^2) is about 0.6 times the weakest fault burst. Chosen offline on recorded
#: tuning flights; see docs/measurements.md, 'Tuning record: fdd/airdata_ekf.py'.
#: "current_check" ((allowance, threshold A, hold s) of `rpm_current.RpmCurrentCheck`; needs the reading
#: "pusher_current"): the sensor's criteria alarm only while the check holds, i.e. while the pusher's current
#: exceeds what its read speed can draw. The a_x test also fires on large EKF errors of its own, and the check
#: keeps those from isolating the RPM sensor; a criterion that fires while the check does not hold is
#: published as unconfirmed (`innovation_unconfirmed`) and the EKF keeps the measurement.
#: "rollback" (s, default 0): on the alarm the EKF re-runs from its state that long ago without the sensor
#: (`AirdataEkfDetector._roll_back`, a departure from 001). GNSS: 0.16 s = the criteria's 2 samples (0.08 s)
#: plus ~2 samples of delay of the 5 Hz prefilter and innovation low-pass before a zero reading crosses them.
#: Pusher RPM: 6 s, longer than the a_x criterion's slowest detections (~4.4 s on the tuning flights).
#: "speed_from_current" (variance, (m/s^2)^2; pusher RPM only; needs "pusher_current"): once the RPM sensor is
#: isolated, the a_x row stays in use with the pusher speed that the measured current draws at the EKF's airspeed
#: (`rpm_current.speed_from_current`, 003 eq. 1-4 in steady state), its variance raised to this. A departure from
#: 001 Sec. 6.2, which drops the row: without a_x the airspeed along x is tied to the GNSS only through the wing's
#: lift model, and the EKF airspeed ran 1.5-3.5 m/s low for the rest of the flight. The variance 1e-3 and the
#: speed's calibration (`_pusher_speed`) were chosen on tuning flights; see docs/measurements.md,
#: 'Tuning record: fdd/airdata_ekf.py'.
#: Sec. 6.2: "increases its covariance": the variance (units^2) a measurement gets once its detector alarms
FAULT_COVARIANCE = 1e6
PITOT_CRITERIA = ("table2", "cusum", "ramp", "either")
#: `vertical_wind`: "state" estimates mu_z (001 eq. 5, Table 1); "fixed" holds it at 0, an option (a departure
#: from 001) for models whose error the EKF would explain as a vertical wind: with a hover thrust coefficient
#: 10% low (`error_seed` 2 and 3) the EKF meets the thrust deficit in the first hover, under the 20 s wind
#: boost, with a vertical wind, and then reads the airspeed several m/s low. With the default error (+10% on
#: all) the vertical wind stays near 0 anyway. Measurements: docs/measurements.md, 'Tuning record:
#: fdd/airdata_ekf.py'.
VERTICAL_WIND = ("state", "fixed")


def az_covariance_gain(skew: float) -> float:
    """K_az of 001 eq. (39), corrected: 100 at skew <= 60 deg, 1 at >= 70 deg, 10**(2 (70 - skew_deg) / 10)
    between (eq. 39 as printed rises from 1 to 100; the text says it falls; erratum, docs/references.md)."""
    deg = math.degrees(skew)
    if deg <= 60.0:
        return 100.0
    if deg >= 70.0:
        return 1.0
    return 10.0 ** (2.0 * (70.0 - deg) / 10.0)


def butterworth_prefilter(sample_hz: float, cutoff_hz: float = PREFILTER_CUTOFF_HZ):
    """(b, a) of 001 Sec. 5's prefilter: 2nd-order Butterworth low-pass, bilinear transform with the cutoff
    prewarped (scipy.signal.butter with fs), so the digital -3 dB point is exactly `cutoff_hz`."""
    if not (0.0 < cutoff_hz < 0.5 * sample_hz):
        raise ValueError(f"prefilter: cutoff {cutoff_hz!r} Hz must lie in (0, {0.5 * sample_hz}) Hz")
    return signal.butter(2, cutoff_hz, btype="low", fs=sample_hz)



class ComponentForceModel:
    """001 eq. (6)-(33): specific force a = (F_fuselage + F_hover + F_wing + T_pusher) / m in body FRD.

    The fuselage, wing and pusher are the simulator's own formulas (`ftcgym.models.quadplane_aero`,
    `ftcgym.models.pusher`), evaluated on a copy of `params` whose ERROR_COEFFICIENTS are multiplied by
    1 + coefficient_error (error_seed None) or 1 +- coefficient_error with seeded random signs
    (`model_with_error`); `scale` holds the factor applied to each. The hover rotors are 001's own
    simplified model (eq. 15-17), not the simulator's tilted rotors. Control surfaces and tail are
    neglected, as 001 Sec. 4 does. `aero`, `pusher` and `constants` (m, K_zh, k_d) are the compiled
    formulas' constants (`specific_force_of`).
    """

    def __init__(self, params, coefficient_error: float = 0.10, error_seed: int | None = None):
        self.scale, self.params = model_with_error(params, ERROR_COEFFICIENTS, coefficient_error, error_seed)
        p = self.params
        self.mass = float(p.mass)
        self.k_f = p.hover_thrust_coefficient * math.cos(p.hover_tilt)
        self.k_d = p.hover_drag_coefficient
        self.aero, self.pusher = aero_model(p).constants, pusher_constants(p)
        self.constants = np.array([self.mass, self.k_f, self.k_d])

    def specific_force(self, air_velocity_body, omega_p: float, omega_h, skew: float) -> np.ndarray:
        """eq. (31)-(33): [a_x, a_y, a_z] = (F_f + F_w + F_h + T_p e_x) / m, m/s^2 (`specific_force_of`)."""
        u, v, w = (float(x) for x in air_velocity_body)
        hover = hover_terms(self.constants, np.asarray(omega_h, dtype=float).ravel())
        return np.array(specific_force_of(self.aero, self.pusher, self.constants, u, v, w, float(omega_p) / TWO_PI,
                                          hover, math.sin(skew), math.cos(skew)))


#: indices into `ComponentForceModel.constants`
MASS, K_ZH, K_D = range(3)


@njit(cache=True)
def hover_terms(model, omega_h):  # pragma: no cover (compiled)
    """(K_h, T_zh): eq. (16)-(17)'s rotor-drag slope K_h = -k_d sum|omega|, growing with RPM (001 App. A,
    Fig. 17a), so that F = K_h (u, v), and eq. (15)'s thrust T_zh = K_zh omega_h^2 summed over the rotors (along
    -z). The sums run left to right from -0.0, as np.sum does below 8 terms (the 4 rotors)."""
    total = squares = -0.0
    for w in omega_h:
        total += abs(w)
        squares += w * w
    return -model[K_D] * total, -model[K_ZH] * squares


@njit(cache=True)
def specific_force_of(aero, pusher, model, u, v, w, revs, hover, sin_skew, cos_skew):  # pragma: no cover (compiled)
    """eq. (31)-(33): (a_x, a_y, a_z) = (F_f + F_w + F_h + T_p e_x) / m at the air velocity (u, v, w), the pusher
    at `revs` rev/s, the hover terms `hover` (`hover_terms`) and the skew of sine and cosine `sin_skew`,
    `cos_skew`. Summed per component as (F_f + F_w) + F_h, then + T_p on x."""
    fx, fy, fz = fuselage_loads(aero, u, v, w, speed_squared(u, v, w))
    (wx, wy, wz), _, _, _, _ = wing_flow_loads(aero, u, v, w, sin_skew, cos_skew)
    slope, thrust_h = hover
    mass = model[MASS]
    return ((fx + wx + slope * u + thrust(pusher, revs, max(u, 0.0))) / mass, (fy + wy + slope * v) / mass,
            (fz + wz + thrust_h) / mass)


@njit(cache=True)
def ekf_predict(x, P, dt, a, omega, Rot, Q):  # pragma: no cover (compiled)
    """The prediction of 001 App. B with the kinematics of eq. (4)-(5): (x-, P-).

    x- = x + f(x, u) dt (eq. 52 corrected), f = [-omega x [u v w] + R^T [0 0 g] + a, 0] (eq. 4; eq. 5: wind
    f = 0); P- = Phi P Phi^T + L Q L^T with Phi = I + F dt (eq. 53 with the discrete transition), F = df/dx
    (eq. 48), L = df/dw (eq. 49) for w = [w_a, w_omega, w_mu] and Q (9 x 9, Table 1) taken as the covariance
    added per EKF step, as 001's onboard filter does. inputs: filtered specific force `a`, body rates `omega`,
    body->NED rotation `Rot`. (Zeros are added where the array forms this replaced added them, so that even
    the signs of zeros are theirs.)
    """
    p, q, r = omega[0], omega[1], omega[2]
    u, v, w = x[0], x[1], x[2]
    c = (q * w - r * v, r * u - p * w, p * v - q * u)            # omega x [u v w]
    g = np.dot(Rot.T, np.array([0.0, 0.0, GRAVITY]))
    x_pred = np.empty(6)
    for i in range(3):
        x_pred[i] = x[i] + (-c[i] + g[i] + a[i]) * dt             # eq. (4), (52)
    for i in range(3, 6):
        x_pred[i] = x[i] + 0.0 * dt                               # eq. (5)
    # Phi = I + F dt, F = [-[omega]x 0; 0 0]
    Phi = np.eye(6)
    Phi[0, 1], Phi[0, 2] = 0.0 + r * dt, 0.0 + -q * dt
    Phi[1, 0], Phi[1, 2] = 0.0 + -r * dt, 0.0 + p * dt
    Phi[2, 0], Phi[2, 1] = 0.0 + q * dt, 0.0 + -p * dt
    # L = [I [v]x 0; 0 0 I]: accelerometer noise w_a, gyro noise -(w_omega x v) = v x w_omega, wind random walk
    L = np.zeros((6, 9))
    L[0, 0] = L[1, 1] = L[2, 2] = L[3, 6] = L[4, 7] = L[5, 8] = 1.0
    L[0, 4], L[0, 5], L[1, 3], L[1, 5], L[2, 3], L[2, 4] = -w, v, w, -u, -v, u
    return x_pred, kalman.predict(P, np.dot(np.dot(L, Q), L.T), Phi)       # eq. (53)


@njit(cache=True)
def measurement(x, Rot, aero, pusher, model, omega_p, omega_h, skew):  # pragma: no cover (compiled)
    """h(x) of eq. (3) and (31)-(33), z = [V_N V_E V_D a_x a_y a_z] = [R [u v w] + mu, a(x)], and its Jacobian
    H(x) of eq. (50): analytic for the GNSS rows, central differences (+-1e-4 m/s) of the force model."""
    hover, revs = hover_terms(model, omega_h), omega_p / TWO_PI
    sin_skew, cos_skew = math.sin(skew), math.cos(skew)
    u, v, w = x[0], x[1], x[2]
    h = np.empty(6)
    h[:3] = np.dot(Rot, x[:3]) + x[3:]
    h[3], h[4], h[5] = specific_force_of(aero, pusher, model, u, v, w, revs, hover, sin_skew, cos_skew)
    H = np.zeros((6, 6))
    H[:3, :3] = Rot
    H[0, 3] = H[1, 4] = H[2, 5] = 1.0
    # x[:3] +- 1e-4 e_j with the array sums' zeros: + 0.0 turns -0.0 into 0.0 (- 0.0 changes nothing)
    for j, (du, dv, dw) in enumerate(((1e-4, 0.0, 0.0), (0.0, 1e-4, 0.0), (0.0, 0.0, 1e-4))):
        f_plus = specific_force_of(aero, pusher, model, u + du, v + dv, w + dw, revs, hover, sin_skew, cos_skew)
        f_minus = specific_force_of(aero, pusher, model, u - du, v - dv, w - dw, revs, hover, sin_skew, cos_skew)
        for i in range(3):
            H[3 + i, j] = (f_plus[i] - f_minus[i]) / 2e-4
    return h, H


@njit(cache=True)
def ekf_cycle(s, x, P, dt, Rot, Q, R, aero, pusher, model, omega_p):  # pragma: no cover (compiled)
    """One EKF step of 001 App. B on the filtered sample `s` (`AirdataEkfDetector._sample`'s layout) with the
    attitude `Rot`, the covariances Q and R, the force model's constants and the pusher speed `omega_p`:
    `ekf_predict`, then the update eq. (54)-(58) (M = I, Joseph form, `kalman.update`) with the measurement
    z = [V_N V_E V_D a_x a_y a_z] and `measurement` at x-. Returns (x, P, innovation y), new arrays."""
    a, omega = s[0:3], s[3:6]
    x_pred, P_pred = ekf_predict(x, P, dt, a, omega, Rot, Q)
    h, H = measurement(x_pred, Rot, aero, pusher, model, omega_p, s[14:18], s[18])
    z = np.empty(6)
    z[:3], z[3:] = s[10:13], a
    y = z - h                                                     # eq. (54)
    x_new, P_new, _, _ = kalman.update(x_pred, P_pred, y, H, R)
    return x_new, P_new, y


#: `AirdataEkfDetector._ekf_state`: x, P (row-major), the innovation, the pusher speed's scale and its sample count
#: (`_pusher_speed`; the roll-back restores these first EKF_HISTORY values), then 1.0 for each row of z whose
#: sensor is isolated and whether the pusher RPM is
STATE, COVARIANCE, INNOVATION, SPEED_SCALE, SPEED_SCALE_SAMPLES, EKF_HISTORY = (
    slice(0, 6), slice(6, 42), slice(42, 48), 48, 49, 50)
FAULTED, RPM_ISOLATED, EKF_STATE_SIZE = slice(50, 56), 56, 57
#: `AirdataEkfDetector._ekf_constants`: dt, the wind boost's duration, the fault covariance, a_x's variance on the
#: current's speed (NaN: none), 1.0 with the propulsion model, `speed_from_current`'s constants (a, rho D^4 C_Q1,
#: rho D^3 C_Q2, c_v*, k_e, I_0*), the force model's constants, the pusher's, Q, the boosted Q (9 x 9), R
#: (6 x 6; each row-major) and the aerodynamic constants.
(EKF_DT, BOOST_SECONDS, FAULT_VARIANCE, CURRENT_VARIANCE, PROPULSION, SPEED_A, SPEED_B, SPEED_C, SPEED_C_V,
 SPEED_K_E, SPEED_I_0) = range(11)
MODEL, PUSHER, Q_MATRIX, Q_BOOSTED, R_MATRIX, AERO = (
    slice(11, 14), slice(14, 32), slice(32, 113), slice(113, 194), slice(194, 230), slice(230, None))


@njit(cache=True)
def _az_covariance_gain(skew):  # pragma: no cover (compiled)
    """`az_covariance_gain` (eq. 39, corrected), with Python's float power (`py_pow`)."""
    deg = math.degrees(skew)
    if deg <= 60.0:
        return 100.0
    if deg >= 70.0:
        return 1.0
    return py_pow(10.0, 2.0 * (70.0 - deg) / 10.0)


@njit(cache=True)
def _speed_from_current(constants, current, airspeed):  # pragma: no cover (compiled)
    """`rpm_current.speed_from_current` (003 eq. 1-4 in steady state) on its constant factors: the positive root
    of a w^2 + b w + c = 0, 0 when the current cannot turn the propeller."""
    V = 0.0 if airspeed < 0.0 else airspeed                       # max(airspeed, 0.0), as Python's
    a = constants[SPEED_A]
    b = constants[SPEED_C_V] + constants[SPEED_B] * V / TWO_PI
    c = constants[SPEED_C] * V * V - constants[SPEED_K_E] * (current - constants[SPEED_I_0])
    discriminant = b * b - 4.0 * a * c
    if a <= 0.0 or discriminant < 0.0:
        return 0.0
    speed = (-b + math.sqrt(discriminant)) / (2.0 * a)
    return 0.0 if speed < 0.0 else speed


@njit(cache=True)
def _pusher_speed(state, constants, reading, current, skew):  # pragma: no cover (compiled)
    """The pusher speed the EKF uses and, once the RPM sensor is isolated, a_x's variance (NaN: unchanged; see
    INNOVATION_DETECTORS["pusher_rpm"]["speed_from_current"]). While the sensor is trusted, the ratio of the
    read speed to the one the model gives from the current is averaged (over SPEED_SCALE_SECONDS once
    there are that many samples) in forward flight with the pusher driven; after, it scales the model's
    speed. It takes out the propulsion model's own error (`coefficient_error` on k_e and C_Q), which
    alone biased the speed by up to 8%. Not in the transition: spinning up against the ESC's current
    limit the ratio is ~0.86, in cruise ~1.0. The ratio is part of the state the
    roll-back restores, so the faulty samples before the alarm do not enter it."""
    isolated = state[RPM_ISOLATED] == 1.0
    if not isolated and (skew < SPEED_SCALE_MIN_SKEW or reading <= SPEED_SCALE_MIN_SPEED):
        return reading, math.nan
    estimate = _speed_from_current(constants, current, state[0])
    if isolated:
        return state[SPEED_SCALE] * estimate, constants[CURRENT_VARIANCE]
    if estimate > SPEED_SCALE_MIN_SPEED:
        state[SPEED_SCALE_SAMPLES] += 1.0                         # the mean of the ratios so far, then a moving one
        mean, moving = 1.0 / state[SPEED_SCALE_SAMPLES], constants[EKF_DT] / SPEED_SCALE_SECONDS
        weight = moving if moving > mean else mean                # max(mean, moving), as Python's
        state[SPEED_SCALE] += (reading / estimate - state[SPEED_SCALE]) * weight
    return reading, math.nan


@njit(cache=True)
def _ekf_step(s, state, constants, elapsed):  # pragma: no cover (compiled)
    """One EKF step (`ekf_cycle`) on the filtered sample `s`, in place on `state`, `elapsed` s after the start:
    the attitude from the normalised quaternion; Q boosted for the wind during the first seconds (Sec. 5.4); R
    with a_z's variance times K_az (eq. 39, corrected), each isolated sensor's rows at the fault covariance
    (Sec. 6.2), and with the propulsion model the pusher speed of `_pusher_speed` (a_x's variance where it
    gives one)."""
    q = s[6:10]
    q = q / math.sqrt(np.dot(q, q))                               # q / np.linalg.norm(q)
    Rot = rotation_matrix((q[0], q[1], q[2], q[3]))
    omega_p, skew = s[13], s[18]
    Q = (constants[Q_BOOSTED] if elapsed < constants[BOOST_SECONDS] else constants[Q_MATRIX]).reshape(9, 9).copy()
    R = constants[R_MATRIX].reshape(6, 6).copy()
    R[5, 5] *= _az_covariance_gain(skew)                          # eq. (39), corrected
    for c in range(6):
        if state[FAULTED.start + c] == 1.0:                       # Sec. 6.2: a faulty measurement no longer updates
            R[c, c] = constants[FAULT_VARIANCE]
    if constants[PROPULSION] == 1.0:
        omega_p, variance = _pusher_speed(state, constants, omega_p, s[19], skew)
        if variance == variance:
            R[3, 3] = variance                                    # a_x back in use, on the current's speed
    x, P, innovation = ekf_cycle(s, state[STATE].copy(), state[COVARIANCE].reshape(6, 6).copy(), constants[EKF_DT],
                                 Rot, Q, R, constants[AERO], constants[PUSHER], constants[MODEL], omega_p)
    state[STATE], state[COVARIANCE], state[INNOVATION] = x, P.ravel(), innovation


class TakeoffGate:
    """001 Sec. 5.3 starts the EKF once airborne. `gate(z)` (position down, m, one reading per call) is True
    while the height averaged over the last `window` s of readings stands `height` m above its average over
    the first `window` s (the ground): from the take-off on, and no longer once the vehicle is back down
    (`AirdataEkfSettings.landing_gate`). Both are averages because the quad-plane's navigation position carries
    0.3 m of white noise (sampled at 50 Hz): a single reading against the first one opens the gate on that
    noise, sometimes on the ground (docs/measurements.md, 'Tuning record: fdd/airdata_ekf.py'). Over 0.2 s
    (10 position samples) the difference of the two averages has a noise of ~0.13 m, 1/7 of the 1 m height;
    the average lags ~0.1 s."""

    def __init__(self, height: float, window: float, sample_hz: float):
        if not (height > 0 and window > 0):
            raise ValueError(f"takeoff_height {height!r} and takeoff_window {window!r}: both must be > 0")
        self.height, self._recent = float(height), deque(maxlen=max(1, round(window * sample_hz)))
        self.reset()

    def reset(self) -> None:
        self._recent.clear()
        self.ground = None

    def __call__(self, z: float) -> bool:
        self.add(z)
        return self.airborne

    def add(self, z: float) -> None:
        """A reading, the gate asked later (`airborne`)."""
        self._recent.append(z)

    @property
    def airborne(self) -> bool:
        """Whether the gate stands open on the readings so far."""
        if len(self._recent) < self._recent.maxlen:
            return False
        level = sum(self._recent) / len(self._recent)
        if self.ground is None:
            self.ground = level
        return self.ground - level >= self.height


@dataclass(frozen=True)
class AirdataEkfSettings:
    """The parameters of `AirdataEkfDetector`; each `AirdataEkfDetector(..., **overrides)` keyword updates one."""

    ekf_hz: float = EKF_HZ                     # Hz, EKF rate (001 Sec. 7.1)
    prefilter_hz: float = PREFILTER_CUTOFF_HZ  # Hz, cutoff of the inputs' and measurements' low-pass (001 Sec. 5)
    Q_accel: tuple = TABLE_1_Q["accel"]        # (m/s^2)^2 per EKF step, 001 Table 1
    Q_gyro: tuple = TABLE_1_Q["gyro"]          # (rad/s)^2 per EKF step, 001 Table 1
    Q_wind: tuple = TABLE_1_Q["wind"]          # (m/s)^2 per EKF step, 001 Table 1
    R: tuple = TABLE_1_R                       # GNSS velocity (m/s)^2 and model acceleration (m/s^2)^2, Table 1
    wind_boost: float = WIND_BOOST             # factor on Q_wind ...
    wind_boost_seconds: float = WIND_BOOST_SECONDS   # ... for this long after the start (001 Sec. 5.4)
    takeoff_height: float = 1.0                # m the averaged height must rise before the EKF starts (`TakeoffGate`)
    takeoff_window: float = 0.2                # s, the averaging window of the take-off gate
    landing_gate: bool = True                  # the tests stop while the gate is closed again (a departure)
    coefficient_error: float = 0.10            # the detector's model error on ERROR_COEFFICIENTS (`model_with_error`)
    error_seed: int | None = None              # None: every coefficient 1 + error; else seeded signs
    velocity_key: str = "gnss_velocity"        # the GNSS velocity reading
    pitot_key: str = "pitot_airspeed"          # the pitot reading; absent from the readings: no pitot test
    norm_criterion: ThresholdTest = TABLE_2_NORM              # 001 Table 2, pitot residual
    derivative_criterion: ThresholdTest = TABLE_2_DERIVATIVE  # 001 Table 2, its derivative
    detection_delay: float | None = None       # s after the start before the tests arm; None: wind_boost_seconds
    pitot_reference: str = "forward"           # "airspeed": |V| as 001; "forward": max(u, 0), along the pitot
    cusum: CusumTest = CUSUM_DEFAULT           # the CUSUM that runs beside Table 2
    ramp: RampTest = RAMP_DEFAULT              # the ramp-onset GLR that runs beside Table 2 ...
    ramp_min_airspeed: float = RAMP_MIN_AIRSPEED   # m/s: ... while the EKF's forward airspeed is at least this
    criterion: str = "table2"                  # the pitot test that drives `alarm`: PITOT_CRITERIA
    innovation_detectors: dict = field(default_factory=lambda: dict(INNOVATION_DETECTORS))  # sensor -> InnovationTest
    fault_covariance: float = FAULT_COVARIANCE  # variance a measurement gets once its sensor is isolated (Sec. 6.2)
    vertical_wind: str = "state"               # "state": mu_z estimated (001); "fixed": held at 0 (VERTICAL_WIND)
    record: bool = False                       # keep `trace`, the detection signals per armed EKF step


class AirdataEkfDetector:
    """001's synthetic air data EKF; outputs airspeed, wind and the filtered pitot residual, and raises the
    pitot fault alarm of Sec. 6.1 (`status()["alarm"]`, `isolated` = "pitot").

    Readings (QuadPlane-v0 keys): accel (specific force, FRD), gyro, attitude (x y z w, FRD -> NED),
    gnss_velocity (NED), position (NED, for the take-off gate), skew (rad), hover_rotor_speed (4, rad/s),
    pusher_speed (rad/s), pusher_current (A; for the pusher RPM's current check).

    Parameters: params (the vehicle parameter set, read by attribute), sample_hz (rate of `update` calls) and
    the settings (`AirdataEkfSettings`, each field also a keyword; `innovation_detectors` maps a sensor to its
    `InnovationTest`, None or {} turns the innovation tests off).

    Status: `alarm` / `alarm_time` / `isolated` are the first of the pitot alarm (by `criterion`) and the
    innovation alarms, isolated as "pitot", "gnss" or "pusher_rpm"; `pitot_alarm`, `alarm_time_table2`,
    `alarm_time_cusum`, `table2_criterion` ("norm" / "derivative"), `innovation_alarms` ({sensor: time}) and
    `innovation_criteria` ({sensor: "norm" / "derivative" / "pitot_confirmation"}) say which fired and when;
    `innovation_unconfirmed` ({sensor: time}) when a criterion first fired while the sensor's current check
    did not hold.
    """

    name = "airdata_ekf"
    output_fields = {"airspeed": (0.0, 200.0, (1,)), "wind": (-100.0, 100.0, (3,)),
                     "pitot_residual": (-200.0, 200.0, (1,))}

    def __init__(self, params, sample_hz: float, settings: AirdataEkfSettings | None = None, **overrides):
        s = self.settings = updated(settings or AirdataEkfSettings(), overrides, "airdata_ekf")
        ekf_hz = s.ekf_hz
        innovation_detectors = {k: InnovationTest.of(v) for k, v in (s.innovation_detectors or {}).items()}
        if not (math.isfinite(sample_hz) and sample_hz > 0 and 0 < ekf_hz <= sample_hz):
            raise ValueError(f"sample_hz {sample_hz!r} and ekf_hz {ekf_hz!r}: need 0 < ekf_hz <= sample_hz")
        self.model = ComponentForceModel(params, s.coefficient_error, s.error_seed)
        self.sample_hz, self.dt = float(sample_hz), 1.0 / float(ekf_hz)
        self.Q = np.diag(np.concatenate([s.Q_accel, s.Q_gyro, s.Q_wind]).astype(float))
        if s.vertical_wind not in VERTICAL_WIND:
            raise ValueError(f"vertical_wind: {s.vertical_wind!r}; accepted: {list(VERTICAL_WIND)}")
        if s.vertical_wind == "fixed":                        # mu_z stays 0: no process noise, no initial variance
            self.Q[8, 8] = 0.0
        self._Q_boosted = self.Q.copy()
        self._Q_boosted[6:, 6:] *= s.wind_boost                # Sec. 5.4, see `_ekf_cycle`
        self.R = np.diag(np.asarray(s.R, dtype=float))
        self.wind_boost, self.wind_boost_seconds = float(s.wind_boost), float(s.wind_boost_seconds)
        self.takeoff, self.velocity_key = TakeoffGate(s.takeoff_height, s.takeoff_window, sample_hz), s.velocity_key
        self.landing_gate = bool(s.landing_gate)
        self._keys = ("accel", "gyro", "attitude", self.velocity_key, "pusher_speed", "hover_rotor_speed", "skew")
        self._ba = butterworth_prefilter(sample_hz, s.prefilter_hz)
        self._lowpass = biquad_constants(*self._ba)
        if s.pitot_reference not in ("airspeed", "forward"):
            raise ValueError(f"pitot_reference: {s.pitot_reference!r}; accepted: ['airspeed', 'forward']")
        self.pitot_key, self.pitot_reference = s.pitot_key, s.pitot_reference
        self.detection_delay = self.wind_boost_seconds if s.detection_delay is None else float(s.detection_delay)
        self.pitot_detector = PitotResidualDetector(ekf_hz, s.norm_criterion, s.derivative_criterion)
        if s.criterion not in PITOT_CRITERIA:
            raise ValueError(f"criterion: {s.criterion!r}; accepted: {list(PITOT_CRITERIA)}")
        self.criterion = s.criterion
        self.cusum = ResidualCusum(ekf_hz, *s.cusum)
        self.ramp = RampGlr(ekf_hz, *s.ramp)
        self.ramp_min_airspeed = float(s.ramp_min_airspeed)
        # one PitotResidualDetector (low-pass + norm + derivative criteria) per innovation channel
        self.innovation_detectors = {
            sensor: {c: PitotResidualDetector(ekf_hz, spec.norm, spec.derivative, spec.sign) for c in spec.channels}
            for sensor, spec in innovation_detectors.items()}
        self.fault_covariance, self.record = float(s.fault_covariance), bool(s.record)
        # the innovation tests' states and constants, one row per channel (each detector's state is its row), and
        # each row's channel and sensor (`innovation_bank`)
        rows = [(k, c, d) for k, channels in enumerate(self.innovation_detectors.values()) for c, d in channels.items()]
        self._innovation_states = np.zeros((len(rows), RESIDUAL_STATE_SIZE))
        self._innovation_constants = np.zeros((len(rows), RESIDUAL_CONSTANTS_SIZE + 2))
        for i, (k, c, d) in enumerate(rows):
            self._innovation_constants[i] = (*d._constants, c, k)
            d._state = self._innovation_states[i]
        self._hits = np.zeros(len(self.innovation_detectors), dtype=np.int64)
        # the pitot tests' states and constants in one array each (each test's state is its part)
        tests = (self.pitot_detector, self.cusum, self.ramp)
        self._pitot_states = np.concatenate([test._state for test in tests])
        self._pitot_constants = np.concatenate([test._constants for test in tests])
        at = 0
        for test in tests:
            test._state, at = self._pitot_states[at:at + test._state.size], at + test._state.size
        # `_ekf_detect`'s own state (armed, the raw residual, an innovation alarm latched) and constants
        self._detect = np.zeros(DETECT_SIZE)
        self._published = np.zeros(PUBLISHED_SIZE)           # `_publish`
        self._detect[DETECTION_DELAY:] = (self.detection_delay, float(self.pitot_reference == "airspeed"),
                                          self.ramp_min_airspeed)
        self.rollback = {sensor: float(spec.rollback) for sensor, spec in innovation_detectors.items()}
        self.confirmations = {sensor: PitotConfirmation(*spec.pitot_confirmation, ekf_hz)
                              for sensor, spec in innovation_detectors.items() if spec.pitot_confirmation is not None}
        # one row per sensor, its last constant 1.0 where the sensor has a confirmation (its state is the row)
        self._confirmation_states = np.zeros((len(innovation_detectors), CONFIRMATION_STATE_SIZE))
        self._confirmation_constants = np.zeros((len(innovation_detectors), CONFIRMATION_CONSTANTS_SIZE + 1))
        for k, sensor in enumerate(innovation_detectors):
            if sensor in self.confirmations:
                self._confirmation_constants[k] = (*self.confirmations[sensor]._constants, 1.0)
                self.confirmations[sensor]._state = self._confirmation_states[k]
        # the tests' state and constants `_ekf_detect` takes after the sample's
        self._tests = (self._detect, self._innovation_states, self._innovation_constants, self._confirmation_states,
                       self._confirmation_constants, self._hits, self._pitot_states, self._pitot_constants,
                       self._published)
        self.current_checks = {sensor: RpmCurrentCheck(params, sample_hz, *spec.current_check,
                                                       coefficient_error=s.coefficient_error, error_seed=s.error_seed)
                               for sensor, spec in innovation_detectors.items() if spec.current_check is not None}
        # the pusher speed from its current once the RPM sensor is isolated (see INNOVATION_DETECTORS)
        rpm = innovation_detectors.get("pusher_rpm")
        self._current_variance = None if rpm is None else rpm.speed_from_current
        self._propulsion = (PropulsionModel(params, s.coefficient_error, s.error_seed)
                            if self._current_variance is not None else None)
        # `update`'s readings: those of `_keys`, then the pusher current where the EKF or a current check reads it
        reads_current = self._propulsion is not None or bool(self.current_checks)
        self._gather = operator.itemgetter(*self._keys, *(("pusher_current",) if reads_current else ()))
        self._history_length = max([round(t * ekf_hz) for t in self.rollback.values()], default=0) + 1
        # the compiled EKF step's state (`_ekf_step`: x, P, the innovation, the pusher speed's scale and its sample
        # count, then the rows faulted and whether the pusher RPM is isolated) and constants
        self._ekf_state = np.zeros(EKF_STATE_SIZE)
        if self._propulsion is None:
            speed = (0.0,) * 6
        else:
            m = self._propulsion
            _, c_v, i_0 = m.x_star.tolist()
            rho, d, (cq0, cq1, cq2) = m.rho, m.D, m.cq
            # speed_from_current's constant factors, each the product it stands for there, bit for bit
            speed = (rho * d ** 5 * cq0 / (TWO_PI * TWO_PI), rho * d ** 4 * cq1, rho * d ** 3 * cq2, c_v, m.k_e, i_0)
        self._ekf_constants = np.concatenate((
            (self.dt, self.wind_boost_seconds, self.fault_covariance,
             math.nan if self._current_variance is None else self._current_variance,
             float(self._propulsion is not None)), speed, self.model.constants, self.model.pusher, self.Q.ravel(),
            self._Q_boosted.ravel(), self.R.ravel(), self.model.aero))
        # the compiled sample step's state (`_prepare`): the last quaternion, whether there is one, whether the
        # prefilter has started, its memory (2 x the channels it filters: the 19 readings, + the pusher current
        # where the EKF uses it); and the current checks' states, one row each (each check's state is its row)
        self._channels = 20 if self._propulsion is not None else 19
        self._run = np.zeros(PREFILTERED + 3 * self._channels)
        checks = list(self.current_checks.values())
        self._check_states = np.zeros((len(checks), CHECK_STATE_SIZE))
        self._check_constants = np.zeros((len(checks), checks[0]._constants.size if checks else 0))
        for i, check in enumerate(checks):
            self._check_constants[i], check._state = check._constants, self._check_states[i]
        self.reset()

    def reset(self) -> None:
        self._ekf_state[:] = 0.0                               # Sec. 5.3: body velocity and wind start at 0
        self._ekf_state[COVARIANCE] = np.diag(np.concatenate([np.ones(3), np.diag(self.Q)[6:]])).ravel()
        self._ekf_state[SPEED_SCALE] = 1.0
        self.started, self.start_time, self._next_time = False, None, None
        self._run[:] = 0.0
        self.takeoff.reset()
        self._pitot = None
        self._detect[:DETECTION_DELAY] = 0.0
        self.pitot_detector.reset()
        self.cusum.reset()
        self.ramp.reset()
        for channels in self.innovation_detectors.values():
            for detector in channels.values():
                detector.reset()
        for confirmation in self.confirmations.values():
            confirmation.reset()
        for check in self.current_checks.values():
            check.reset()
        self.innovation_alarms = {sensor: None for sensor in self.innovation_detectors}
        self.innovation_criteria = {sensor: None for sensor in self.innovation_detectors}
        self.innovation_unconfirmed = {sensor: None for sensor in self.current_checks}
        self._newest_alarm = None
        self._history = deque(maxlen=self._history_length)
        self.trace = []
        self._published[:] = 0.0                            # the outputs at x = 0, residual 0
        self._status = None                                  # what status() returns, when built

    def update(self, readings: dict, time: float, command=None) -> None:
        check_time(time, self.name)
        try:
            parts = self._gather(readings)                    # the readings of `_keys`, then the pusher current
        except KeyError:
            self._pusher_current(readings)                    # names a missing pusher current
            raise
        # the pitot and, while the gate reads it, the height (NaN is below no height: it would read as on the
        # ground) are checked first, so that a refused sample changes nothing
        pitot = _first(readings[self.pitot_key]) if self.pitot_key in readings else None
        down = float(readings["position"][2]) if self.landing_gate or not self.started else None
        for key, value in ((self.pitot_key, pitot), ("position", down)):
            if value is not None and not abs(value) <= READING_LIMIT:
                raise ValueError(f"airdata_ekf: reading {key!r} {BEYOND_LIMIT} at t = {time}: "
                                 f"{np.asarray(readings[key], dtype=float).tolist()}")
        # the sample s of `_ekf_cycle`, prefiltered (Sec. 5: inputs and measurements alike), and the current
        # checks, every sample, so their filters run before the EKF starts (each low-passes the raw pusher speed
        # and current itself, so it also runs alone)
        if not self._prepare_sample(parts):
            self._reject_non_finite(readings, self._pusher_current(readings), time)
        if pitot is not None:
            self._pitot = pitot
        if not self.started:
            if not self.takeoff(down):          # Sec. 5.3: start once airborne
                return
            self.started, self.start_time, self._next_time = True, float(time), float(time)
            self._status = None
        elif down is not None:
            self.takeoff.add(down)
        if time + 1e-9 >= self._next_time:
            self._next_time += self.dt
            if down is not None:                # the landing gate (module docstring, 3), read at the EKF's rate
                self._detect[LANDED] = 0.0 if self.takeoff.airborne else 1.0
            self._ekf(time)
            self._status = None

    def _prepare_sample(self, parts: tuple) -> bool:
        """`_prepare` on the readings `parts` (the pusher current last, where it is read): arrays, as the env gives
        them, are gathered by the compiled call itself (`_prepare_arrays`, compiled once per layout), anything else
        (scalars, lists, a dtype numba cannot take) through `_flat`."""
        states = self._run, self._lowpass, self._check_states, self._check_constants
        if ARRAY_TYPES.issuperset(map(type, parts)):
            try:
                if len(parts) == len(self._keys):
                    return _prepare_arrays(*states, *parts, _NO_READING)
                return _prepare_arrays(*states, *parts)
            except TypingError:
                pass
        if len(parts) > len(self._keys):                      # the current's first value only
            parts = (*parts[:-1], (_first(parts[-1]),))
        return _prepare(_flat(parts), *states)

    def _reject_non_finite(self, readings: dict, current, time: float) -> None:
        """Raise the ValueError that names the first reading beyond READING_LIMIT (NaN, inf), as `_prepare`
        rejects it (the pusher current where the EKF or a current check reads it, `current` not None)."""
        keys = self._keys + (("pusher_current",) if current is not None else ())
        for key in keys:
            check_reading("airdata_ekf", key, np.asarray(readings[key], dtype=float).reshape(-1), time)
        raise ValueError(f"airdata_ekf: a reading {BEYOND_LIMIT} at t = {time}")   # found by `_prepare` alone

    def _pusher_current(self, readings: dict):
        """The pusher current reading, where the pusher RPM's speed_from_current or a current check needs it."""
        if self._propulsion is None and not self.current_checks:
            return None
        if "pusher_current" not in readings:
            user = ("the pusher_rpm speed_from_current" if self._propulsion is not None
                    else f"the {next(iter(self.current_checks))} current_check")
            raise ValueError(f"airdata_ekf: reading 'pusher_current' missing; {user} needs it (without it, drop "
                             f"that key from innovation_detectors)")
        return readings["pusher_current"]

    def _ekf(self, time: float) -> None:
        """One EKF step and the tests on it, compiled (`_ekf_detect`); on an innovation criterion that fired, the
        sensor's alarm (`_detect_innovation_faults`), the roll-back on a new one, then the pitot tests."""
        state, pitot, time = self._ekf_state[:EKF_HISTORY].copy(), self._pitot, float(time)
        try:
            code = _ekf_detect(self._filtered, self._ekf_state, self._ekf_constants, time - self.start_time, time,
                               math.nan if pitot is None else pitot, pitot is not None, *self._tests)
        except np.linalg.LinAlgError:
            code = None
        if code is None or not (within_limit(self._ekf_state[STATE]) and within_limit(self._published)):
            raise ValueError(f"airdata_ekf: the EKF diverged at t = {time}: its state left the finite numbers within "
                             f"+-{READING_LIMIT:g}, after readings far outside its model in this or a recent sample "
                             f"(this prefiltered one: {self._filtered.tolist()}); reset() it before feeding it again")
        self._history.append((time, self._filtered.copy(), state))
        if code == INNOVATION_HITS:
            if self._detect_innovation_faults(time):
                self._roll_back()
            residual = self._pitot_residual()                # of the re-run state
            if residual is not None:
                _pitot_tests(self._ekf_state, residual, time, self._detect, self._pitot_states, self._pitot_constants)
            _publish(self._ekf_state, self._pitot_states, self._published)
        if self.record and self._armed:
            self.trace.append(self._trace_row(time))

    @property
    def _armed(self) -> bool:
        """Whether the tests are armed (`detection_delay` s after the start, while airborne)."""
        return bool(self._detect[ARMED])

    @property
    def _residual(self) -> float:
        """The last raw pitot residual."""
        return float(self._detect[RESIDUAL])

    @property
    def _filtered(self) -> np.ndarray:
        """The last prefiltered sample (a view of the sample step's state)."""
        return self._run[PREFILTERED:PREFILTERED + self._channels]

    def _pitot_residual(self) -> float | None:
        """Sec. 6.1: r = pitot - EKF airspeed (None without a pitot reading)."""
        if self._pitot is None:
            return None
        reference = self.airspeed if self.pitot_reference == "airspeed" else self.forward_airspeed
        return self._pitot - reference

    def _roll_back(self) -> None:
        """Departure from 001 Sec. 6.2 (which only stops using the measurement): the faulty samples that
        entered before the alarm already moved the state (two GNSS samples of zero, with Table 1's small R,
        drag the wind estimate ~10 m/s off, and without GNSS it then stays there), so the EKF restarts from
        its state `rollback` s ago and re-runs the stored samples with the faulty rows' raised covariance."""
        steps = max(round(self._rollback_seconds() * (1.0 / self.dt)), 0)
        if steps == 0:
            return
        replay = list(self._history)[-min(steps, len(self._history)):]
        self._ekf_state[:EKF_HISTORY] = replay[0][2]
        for time, sample, _ in replay:
            self._ekf_cycle(sample, time)

    def _rollback_seconds(self) -> float:
        return max([self.rollback.get(sensor, 0.0) for sensor, t in self.innovation_alarms.items()
                    if t is not None and t == self._newest_alarm], default=0.0)

    def _ekf_cycle(self, s: np.ndarray, time: float) -> None:
        """One EKF step on the filtered sample `s`, with the covariances of the sensors' current state
        (`_ekf_step`)."""
        _ekf_step(s, self._ekf_state, self._ekf_constants, time - self.start_time)

    @property
    def x(self) -> np.ndarray:
        """The EKF state [u v w mu_x mu_y mu_z] (a view of the detector's state)."""
        return self._ekf_state[STATE]

    @property
    def P(self) -> np.ndarray:
        """Its covariance (a view)."""
        return self._ekf_state[COVARIANCE].reshape(6, 6)

    @property
    def innovation(self) -> np.ndarray:
        """The last EKF step's measurement innovation z - h(x-) (a view)."""
        return self._ekf_state[INNOVATION]

    def _detect_innovation_faults(self, time: float) -> bool:
        """Sec. 6.2: each innovation channel through its Table 2 criteria, and a sensor's `PitotConfirmation`
        where it has one (`innovation_bank`, run by `_ekf_detect`: `_hits`); the first alarm of a sensor's criteria
        latches it (its rows then get `fault_covariance`, see `_ekf_cycle`). True on a new alarm."""
        new = False
        for sensor, hit in zip(self.innovation_detectors, self._hits.tolist()):
            if not hit:
                continue
            check = self.current_checks.get(sensor)
            if check is not None and not check.holding:
                if self.innovation_unconfirmed[sensor] is None:
                    self.innovation_unconfirmed[sensor] = float(time)
                continue
            if self.innovation_alarms[sensor] is None:
                self.innovation_alarms[sensor] = self._newest_alarm = float(time)
                self.innovation_criteria[sensor] = HITS[hit]
                for c in self.innovation_detectors[sensor]:    # Sec. 6.2: its rows no longer update (`_ekf_step`)
                    self._ekf_state[FAULTED.start + c] = 1.0
                if sensor == "pusher_rpm":
                    self._ekf_state[RPM_ISOLATED] = 1.0
                self._detect[LATCHED] = 1.0                  # the pitot tests stop (`_pitot_tests`)
                new = True
        return new

    def _trace_row(self, time: float) -> dict:
        """The detection signals of this EKF step (fault-free statistics for `false_alarm`)."""
        row = {"time": float(time), "skew": float(self._filtered[18]), "airspeed": self.airspeed,
               "forward_airspeed": self.forward_airspeed,
               "pitot_residual_raw": self._residual,
               "pitot_residual": self.pitot_detector.residual,
               "pitot_residual_derivative": self.pitot_detector.derivative, "cusum": self.cusum.statistic,
               "ramp": self.ramp.statistic}
        for sensor, channels in self.innovation_detectors.items():
            for c, detector in channels.items():
                row[f"{sensor}_{c}_innovation"] = detector.residual
                row[f"{sensor}_{c}_innovation_derivative"] = detector.derivative
        for sensor, confirmation in self.confirmations.items():
            row[f"{sensor}_pitot_confirmation"] = confirmation.statistic
        for sensor, check in self.current_checks.items():
            row[f"{sensor}_current_excess"] = check.excess
        return row

    def pitot_alarm_time(self) -> float | None:
        """When the pitot test selected by `criterion` alarmed (None: not yet)."""
        tests = {"table2": self.pitot_detector, "cusum": self.cusum, "ramp": self.ramp}
        chosen = tests.values() if self.criterion == "either" else [tests[self.criterion]]
        times = [test.alarm_time for test in chosen if test.alarm_time is not None]
        return min(times) if times else None

    def first_alarm(self) -> tuple[float | None, str | None]:
        """(time, isolated sensor) of the first alarm: the pitot test or an innovation detector."""
        pitot_alarm_time = self.pitot_alarm_time()
        events = [(t, sensor) for sensor, t in self.innovation_alarms.items() if t is not None]
        if pitot_alarm_time is not None:
            events.append((pitot_alarm_time, "pitot"))
        return min(events) if events else (None, None)

    @property
    def airspeed(self) -> float:
        v = self.x[:3]
        return math.sqrt(v.dot(v))                           # np.linalg.norm(v)

    @property
    def forward_airspeed(self) -> float:
        """The EKF's air velocity along the pitot (body x), max(u, 0)."""
        return max(float(self.x[0]), 0.0)

    def outputs(self) -> dict:
        """The published estimates (`_publish`, after each EKF step): one copy per call, three views of it."""
        published = self._published.copy()
        return {"airspeed": published[0:1], "wind": published[1:4], "pitot_residual": published[4:5]}

    def status(self) -> dict:
        """The status. It changes only at the start and at an EKF step: built once after each, then a new dict
        per call (the lists and dicts in it are built anew after each change and never changed in place)."""
        if self._status is None:
            self._status = self._build_status()
        return dict(self._status)

    def _build_status(self) -> dict:
        """The status from one list of the pitot tests' states and one of the EKF's (as `pitot_alarm_time`,
        `first_alarm` and the tests' properties read them)."""
        v, cusum, ramp = self._pitot_states[:PITOT_STATUS].tolist(), RESIDUAL_STATE_SIZE, PITOT_RAMP
        times = {"table2": v[R_ALARM_TIME] if v[R_ALARM] else None,
                 "cusum": v[cusum + C_ALARM_TIME] if v[cusum + C_ALARM] else None,
                 "ramp": v[ramp + G_ALARM_TIME] if v[ramp + G_ALARM] else None}
        chosen = times.values() if self.criterion == "either" else [times[self.criterion]]
        pitot_times = [t for t in chosen if t is not None]
        pitot_alarm_time = min(pitot_times) if pitot_times else None
        events = [(t, sensor) for sensor, t in self.innovation_alarms.items() if t is not None]
        if pitot_alarm_time is not None:
            events.append((pitot_alarm_time, "pitot"))
        alarm_time, isolated = min(events) if events else (None, None)
        ekf = self._ekf_state[:INNOVATION.stop].tolist()
        return {"alarm": alarm_time is not None, "alarm_time": alarm_time, "isolated": isolated,
                "criterion": self.criterion, "pitot_alarm": pitot_alarm_time is not None,
                "pitot_alarm_time": pitot_alarm_time, "alarm_time_table2": times["table2"],
                "alarm_time_cusum": times["cusum"], "alarm_time_ramp": times["ramp"],
                "table2_criterion": CRITERIA[int(v[R_CRITERION])], "cusum_statistic": v[cusum + C_STATISTIC],
                "ramp_statistic": v[ramp + G_STATISTIC], "innovation_alarms": dict(self.innovation_alarms),
                "innovation_criteria": dict(self.innovation_criteria),
                "innovation_unconfirmed": dict(self.innovation_unconfirmed),
                "pitot_residual": v[R_RESIDUAL],
                "pitot_residual_derivative": v[R_DERIVATIVE],
                "detection_armed": self._armed, "started": self.started,
                "start_time": self.start_time, "airspeed": float(self._published[AIRSPEED]), "wind": ekf[3:6],
                "air_velocity_body": ekf[0:3], "innovation": ekf[INNOVATION]}


#: `innovation_bank`'s answer per sensor: no criterion fired, or the first that did
HITS = (None, "norm", "derivative", "pitot_confirmation")
CHANNEL, SENSOR, CONFIRMED = RESIDUAL_CONSTANTS_SIZE, RESIDUAL_CONSTANTS_SIZE + 1, CONFIRMATION_CONSTANTS_SIZE


@njit(cache=True)
def innovation_bank(innovation, time, armed, pitot_residual, states, constants, confirmation_states,
                    confirmation_constants, hits):  # pragma: no cover (compiled)
    """Sec. 6.2: every innovation channel's Table 2 criteria (`residual_step`, one row of `states` each, in the
    order of the sensors and their channels), then each sensor's `PitotConfirmation` (where it has one and there
    is a pitot residual, NaN: none) on the largest norm-criterion level of its channels (one-sided as the norm
    row; Python's max: the first of equals). `hits[k]` (index into HITS): the criterion that the first of sensor
    k's channels whose alarm is raised fired on, else 3 if its confirmation holds, else 0."""
    hits[:] = 0
    for i in range(states.shape[0]):
        sensor = int(constants[i, SENSOR])
        if residual_step(states[i], constants[i], innovation[int(constants[i, CHANNEL])], time, armed) \
                and hits[sensor] == 0:
            hits[sensor] = int(states[i, R_CRITERION])
    if pitot_residual != pitot_residual:
        return
    for k in range(hits.size):
        if confirmation_constants[k, CONFIRMED] == 0.0:
            continue
        first, level = True, 0.0
        for i in range(states.shape[0]):
            if int(constants[i, SENSOR]) == k:
                value = criterion_level(states[i, R_RESIDUAL], constants[i, R_NORM_SIGN])
                if first or value > level:
                    first, level = False, value
        if confirmation_step(confirmation_states[k], confirmation_constants[k], level, pitot_residual, armed) \
                and hits[k] == 0:
            hits[k] = 3


#: `AirdataEkfDetector._run`: the last quaternion, whether there is one, whether the prefilter has started, then
#: the prefiltered sample and the prefilter's memory (2 x its channels)
LAST_Q, HAS_LAST_Q, PREFILTER_STARTED, PREFILTERED = slice(0, 4), 4, 5, 6


@njit(cache=True)
def _prepare(sample, run, lowpass, checks, check_constants):  # pragma: no cover (compiled)
    """One sample, in place on `run` and the current checks' states: the quaternion's sign kept continuous
    (flipped where its dot product with the last is negative), the prefilter (Sec. 5, `biquad_step`) on the
    first channels (the pusher current only where the EKF uses it), then each current check (`check_step`) on
    the raw pusher speed s[13] and current s[19]. The filtered sample goes to `run`; False, the state untouched,
    if a reading is beyond READING_LIMIT (NaN, inf)."""
    if not within_limit(sample):
        return False
    q = sample[6:10]
    if run[HAS_LAST_Q] == 1.0 and np.dot(q, run[LAST_Q]) < 0.0:
        for i in range(4):
            q[i] *= -1.0
    run[LAST_Q], run[HAS_LAST_Q] = q, 1.0
    channels = (run.size - PREFILTERED) // 3
    memory = run[PREFILTERED + channels:].reshape(2, channels)
    run[PREFILTERED:PREFILTERED + channels] = biquad_step(lowpass, memory, sample[:channels],
                                                          run[PREFILTER_STARTED] == 0.0)
    run[PREFILTER_STARTED] = 1.0
    for i in range(checks.shape[0]):
        check_step(checks[i], check_constants[i], sample[13], sample[19])
    return True


@njit(cache=True)
def _prepare_arrays(run, lowpass, checks, check_constants, accel, gyro, attitude, velocity, pusher_speed,
                    hover_rotor_speed, skew, current):  # pragma: no cover (compiled)
    """`_prepare` on the sample gathered from the readings (their values in order, then the first value of
    `current`, if it has one): `_flat`'s sample without numpy's concatenate."""
    parts = (accel, gyro, attitude, velocity, pusher_speed, hover_rotor_speed, skew)
    size = 1 if current.size > 0 else 0
    for part in literal_unroll(parts):                        # the readings' layouts may differ
        size += part.size
    sample, i = np.empty(size), 0
    for part in literal_unroll(parts):
        for value in part.flat:
            sample[i] = value
            i += 1
    if current.size > 0:
        sample[i] = current.flat[0]
    return _prepare(sample, run, lowpass, checks, check_constants)


#: `AirdataEkfDetector._detect`: whether the tests are armed, the raw pitot residual, whether an innovation alarm
#: has latched, whether the landing gate holds the tests (set by `update`); then its constants: the detection
#: delay, 1.0 for 001's residual (|V|) and the ramp test's least forward airspeed
ARMED, RESIDUAL, LATCHED, LANDED, DETECTION_DELAY, AIRSPEED_REFERENCE, RAMP_MIN_AIRSPEED, DETECT_SIZE = range(8)
#: `_ekf_detect`'s answer besides 0 (done)
INNOVATION_HITS = 1


@njit(cache=True)
def _ekf_detect(s, state, constants, elapsed, time, pitot, has_pitot, detect, innovation_states,
                innovation_constants, confirmation_states, confirmation_constants, hits, pitot_states,
                pitot_constants, published):  # pragma: no cover (compiled)
    """One EKF step on the filtered sample `s` (`_ekf_step`, `elapsed` s after the start) and the tests on it: armed
    `detection_delay` s after the start and while not `LANDED`; the pitot residual r = pitot - EKF airspeed
    (Sec. 6.1, `has_pitot`); the innovation tests (`innovation_bank`, Sec. 6.2); then, unless one of their criteria
    fired (INNOVATION_HITS: the caller latches the alarm and runs the pitot tests), the pitot tests (`_pitot_tests`)
    and the outputs (`_publish`). The pitot reading was checked by `update`."""
    _ekf_step(s, state, constants, elapsed)
    armed = elapsed >= detect[DETECTION_DELAY] - 1e-9 and detect[LANDED] == 0.0
    detect[ARMED] = armed
    residual = pitot - _pitot_reference(state, detect) if has_pitot else math.nan
    innovation_bank(state[INNOVATION], time, armed, residual, innovation_states, innovation_constants,
                    confirmation_states, confirmation_constants, hits)
    for hit in hits:
        if hit != 0:
            return INNOVATION_HITS
    if has_pitot:
        _pitot_tests(state, residual, time, detect, pitot_states, pitot_constants)
    _publish(state, pitot_states, published)
    return 0


#: `AirdataEkfDetector._published`: the outputs (airspeed, wind, pitot residual, clipped to their spaces), then
#: the airspeed itself; where the pitot tests' states start the ramp test's, and the part the status reads
PUBLISHED_SIZE, AIRSPEED = 6, 5
PITOT_RAMP = RESIDUAL_STATE_SIZE + CUSUM_STATE_SIZE
PITOT_STATUS = PITOT_RAMP + G_RING


@njit(cache=True)
def _publish(state, pitot_states, published):  # pragma: no cover (compiled)
    """The outputs after an EKF step: the airspeed |V| (np.linalg.norm), the wind and the filtered pitot residual,
    clipped as np.clip (by Python's min and max, NaN kept), then |V| itself."""
    airspeed = math.sqrt(np.dot(state[0:3], state[0:3]))
    published[0] = 200.0 if airspeed > 200.0 else airspeed          # min(airspeed, 200.0)
    for i in range(3):
        w = -100.0 if state[3 + i] < -100.0 else state[3 + i]      # max(w, -100.0)
        published[1 + i] = 100.0 if w > 100.0 else w                # min(., 100.0)
    r = -200.0 if pitot_states[R_RESIDUAL] < -200.0 else pitot_states[R_RESIDUAL]
    published[4] = 200.0 if r > 200.0 else r
    published[AIRSPEED] = airspeed


@njit(cache=True)
def _pitot_reference(state, detect):  # pragma: no cover (compiled)
    """What the pitot residual compares the pitot with: the EKF airspeed |V| (001), or max(u, 0)."""
    if detect[AIRSPEED_REFERENCE] == 1.0:
        return math.sqrt(np.dot(state[0:3], state[0:3]))            # np.linalg.norm(v)
    return 0.0 if state[0] < 0.0 else state[0]                      # max(u, 0.0), as Python's


@njit(cache=True)
def _pitot_tests(state, residual, time, detect, pitot_states, pitot_constants):  # pragma: no cover (compiled)
    """The pitot tests on the residual (Table 2 `residual_step`, `cusum_step`, `ramp_step`: their states and
    constants one after the other), armed while no innovation alarm has latched (Sec. 6.2: a sensor fault must
    not be blamed on the pitot; and once one is found, 001 Sec. 7.3.2 notes the residual no longer fits the
    fault-free thresholds: the pitot tests stop from then on); the ramp test only at a forward airspeed of at
    least `ramp_min_airspeed`."""
    detect[RESIDUAL] = residual
    armed = detect[ARMED] == 1.0 and detect[LATCHED] == 0.0
    forward = 0.0 if state[0] < 0.0 else state[0]
    cusum_at, ramp_at = RESIDUAL_STATE_SIZE + CUSUM_STATE_SIZE, RESIDUAL_CONSTANTS_SIZE + CUSUM_CONSTANTS_SIZE
    residual_step(pitot_states[:RESIDUAL_STATE_SIZE], pitot_constants[:RESIDUAL_CONSTANTS_SIZE], residual, time,
                  armed)
    cusum_step(pitot_states[RESIDUAL_STATE_SIZE:cusum_at], pitot_constants[RESIDUAL_CONSTANTS_SIZE:ramp_at],
               residual, time, armed)
    ramp_step(pitot_states[cusum_at:], pitot_constants[ramp_at:], residual, time,
              armed and forward >= detect[RAMP_MIN_AIRSPEED])


_NO_READING = np.empty(0)


def _first(reading) -> float:
    """The first value of a reading (the env's are 1-element arrays), as a float."""
    return float(reading[0] if type(reading) is np.ndarray and reading.ndim == 1 else np.ravel(reading)[0])


def _flat(parts: list) -> np.ndarray:
    """The readings `parts` as one flat float64 array (the env's 1-D arrays in one concatenation)."""
    try:
        flat = np.concatenate(parts, dtype=np.float64)
        if flat.ndim == 1:
            return flat
    except (ValueError, TypeError):         # a scalar reading (a recorded log's row), an object array's numbers
        pass
    return np.concatenate([np.asarray(part, dtype=np.float64).reshape(-1) for part in parts])


def airdata_ekf_wrapper(env, params="vehicle", **kwargs):
    """`env` (QuadPlane-v0 or QuadPlaneAutopilot-v0) wrapped with an AirdataEkfDetector at the env's agent
    rate; params="vehicle" reads the env's parameter set (the detector then errs by `coefficient_error`)."""
    from .wrapper import DetectorWrapper
    vehicle = vehicle_params(env, "airdata_ekf", VsqpParams)
    if isinstance(params, str) and params == "vehicle":
        params = vehicle
    return DetectorWrapper(env, AirdataEkfDetector(params, env.get_wrapper_attr("agent_hz"), **kwargs))
