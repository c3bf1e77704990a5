"""The quad-plane autopilot: a mission state machine over a cascaded controller scheduled on airspeed.

Larocque (001 Sec. 2, Sec. 8.1) describes the VSQP's autopilot: cascaded INDI with weighted-least-squares
allocation, where the airspeed sets (1) the control surfaces' effectiveness (eq. 8.3, ~V^2), (2) the wing's
lift in the guidance loop (eq. 8.4-8.6), (3) the wing skew schedule and (4) the airspeed loop. A wrong
airspeed therefore corrupts all four, which is what made pitot faults destabilising in its flight tests
(001 Sec. 1). This autopilot keeps those four dependencies on the airspeed it is GIVEN (`act(...,
airspeed=...)`), so a policy that chooses the airspeed source (QuadPlaneAutopilot-v0) decides its fate.

Structure, per agent step:
1. Mission (`_advance_phase`, phases `PHASES`): take-off, hover, transition heading north, the circuit of
   `MissionTask`, back
   transition, return, landing. Phase changes use navigation data and the given airspeed.
2. Guidance: a desired NED acceleration from position/velocity errors (quad phases) or from the circle's
   cross-track error and the altitude (forward flight). In cruise the heading is not commanded: the circle's
   course rate is flown as a heading rate and the fin keeps the nose in the relative wind, as a fixed-wing
   autopilot coordinates its turns (PX4's fixed-wing yaw controller). Holding the nose on the ground course
   instead forces the crab angle into sideslip, which in a strong crosswind the rudder cannot hold.
3. Outer loop: the acceleration becomes an attitude and a hover-rotor collective. The wing's lift, from the
   model at the given airspeed, the measured skew and alpha ~ pitch (001 eq. 8.6), is subtracted from what
   the rotors must carry; in forward flight the pitch follows the altitude error around the trim pitch. On
   entering cruise the rotors' share is handed to the wing over `transition_blend_time`, not in one step.
4. Inner loop: geometric attitude error (Lee et al. 2010) -> rate command -> angular acceleration -> moment
   (model inversion with the airframe's own aerodynamic moment at the given airspeed), allocated over the
   hover rotors and the surfaces by regularised weighted least squares; the surfaces' columns come from the
   model at the given airspeed (so they vanish at a zero reading).
5. Pusher: PI on the given airspeed toward the phase's target with the trim throttle as feed-forward; in
   cruise the target is the task's cruise airspeed plus `airspeed_offset` (0 unless a detector asks for an
   airspeed step, 003 Sec. III-D: `QuadPlaneAutopilotEnv.request_airspeed_offset`).

Per-step cost: the arithmetic runs on plain floats and in compiled kernels (numba: `_moment_command`,
`_allocate`, `_action`, `_tilted_attitude`) in the order of the numpy version it replaced, the dot and matrix
products and the linear solves BLAS's and LAPACK's as numpy's (`geometry.blas_dot`, np.dot and np.linalg
inside the kernels) and the hypotenuses numpy's (np.hypot, the C library's; math.hypot rounds differently),
so flights keep their bits. The airframe model is `quadplane_aero`'s compiled form (`aero_loads`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..models.constants import GRAVITY
from ..models.geometry import blas_dot, cross3, rotation_from_euler, rotation_matrix
from ..models.pusher import throttle_for_speed
from ..models.quadplane_aero import aero_loads, aero_model, skew_schedule
from ..models.tasks import MissionTask

PHASES = ("takeoff", "hover", "transition", "cruise", "back_transition", "return", "land", "landed")
QUAD_PHASES = ("takeoff", "hover", "return", "land")
ZEROS3 = (0.0, 0.0, 0.0)
ROTORS_OFF, ROTORS_WHOLE = np.zeros(4), np.ones(4)      # the hover rotors' speeds and effectiveness, rotors off
#: rows of `QuadPlaneAutopilot._axis_gains`, per body axis: the AutopilotGains of the same names and the inertia
KATT, KRATE, MAX_RATE, KRATE_I, RATE_INTEGRAL_LIMIT, INERTIA = range(6)


@dataclass
class AutopilotGains:
    # quad-mode guidance
    position: tuple = (0.6, 0.6, 1.2)        # 1/s^2 per m
    velocity: tuple = (1.2, 1.2, 2.0)        # 1/s
    position_integral: float = 0.05          # 1/s^3
    integral_zone: float = 3.0               # m, position error inside which the integral runs
    integral_limit: float = 1.5              # m/s^2
    max_horizontal_speed: float = 9.0        # m/s, quad-mode velocity command limit (rotor drag caps ~10 m/s)
    max_tilt_deg: float = 25.0
    max_turn_rate: float = 0.4               # rad/s, heading-command slew in quad mode
    # forward-flight guidance
    altitude: float = 0.3                    # 1/s, climb-rate command per m of altitude error
    climb_rate_gain: float = 0.08            # rad of pitch per m/s of climb-rate error
    climb_accel: float = 1.0                 # 1/s, rotor-assisted vertical acceleration per m/s of error
    altitude_integral: float = 0.02          # rad of pitch per m of climb-rate error integrated
    max_pitch_deg: float = 12.0
    max_bank_deg: float = 30.0
    cross_track: float = 0.01                # rad of course correction per m off the circle
    rotor_assist_floor: float = 0.1          # share of the weight below which the rotors stay off in cruise
    cruise_alpha_margin_deg: float = 5.0     # alpha above trim the pitch loop may use before the rotors help
    cruise_alpha_max_deg: float = 9.0        # below the wing's C_Lmax (10.7 deg, vsqp.wing_alpha_stall)
    cross_track_limit_deg: float = 30.0
    course: float = 0.35                     # 1/s, course-rate demand per rad of course error
    # inner loop
    attitude: tuple = (4.0, 4.0, 1.5)        # 1/s
    rate: tuple = (14.0, 10.0, 4.0)          # 1/s (the hover motors lag 0.08 s)
    max_rate: tuple = (2.0, 2.0, 1.0)        # rad/s
    rate_integral: tuple = (10.0, 8.0, 2.0)           # 1/s^2
    rate_integral_limit: tuple = (40.0, 10.0, 10.0)   # rad/s^2
    surface_weight: float = 1.0              # WLS cost of a radian of surface relative to a newton of rotor
    rotor_weight: float = 1.0
    # airspeed (pusher)
    airspeed_p: float = 0.08                 # throttle per m/s
    airspeed_i: float = 0.03                 # throttle per m/s s
    throttle_slew: float = 0.5               # 1/s
    # mission
    transition_done_speed_margin: float = 1.0   # m/s below cruise speed that ends the transition
    # s over which the hover rotors hand the weight over to the wing on entering cruise: they keep making up
    # what the wing does not carry at the actual alpha (the transition's rule), faded out linearly into the
    # cruise rule (lift at the trim alpha). Switched in one step, the rotors drop out while alpha is still far
    # below trim, and the airframe dives, enough to raise a false pitot alarm. PX4's VTOL front transition
    # likewise blends the multicopter motors out over a blend time after the transition airspeed is reached
    # rather than cutting them. Measurements: docs/measurements.md, 'Tuning record: agents/quadplane_autopilot.py'.
    transition_blend_time: float = 1.5
    back_transition_done_speed: float = 3.0     # m/s
    back_transition_decel: float = 1.5          # m/s^2, typical deceleration of the back transition


class QuadPlaneAutopilot:
    """Flies `MissionTask` on QuadPlane-v0 actions; `act(obs, info, airspeed=None)` uses the pitot reading
    when no airspeed is given. `phase` is the mission phase (PHASES)."""

    def __init__(self, params, agent_hz: float, task: MissionTask, gains: AutopilotGains | None = None):
        self.params, self.task = params, task
        self.gains = gains or AutopilotGains()
        self.dt = 1.0 / agent_hz
        g = self.gains
        self._kp_kv = tuple(float(kp) / float(kv) for kp, kv in zip(g.position, g.velocity))
        self._kv = tuple(map(float, g.velocity))
        self._axis_gains = np.array([g.attitude, g.rate, g.max_rate, g.rate_integral, g.rate_integral_limit,
                                     params.inertia], dtype=float)
        self._f_max = params.hover_thrust_coefficient * params.hover_omega_max ** 2
        self._yaw_per_newton = params.hover_torque_coefficient / params.hover_thrust_coefficient
        self._yaw_signs = tuple(map(float, params.hover_yaw_signs))
        self._regularisation = 1e-3 * np.diag([g.rotor_weight] * 4 + [g.surface_weight] * 3)
        self._limits = np.asarray(params.surface_limit, float)
        self._hover_rotors = np.array([params.hover_thrust_coefficient, params.hover_omega_min,
                                       params.hover_omega_max])
        self._aero = aero_model(params)
        self._last_trim = (None, 0.0)
        self.reset()

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        """Start a mission; the take-off heading (from `obs`, else north) orients the transition and circuit."""
        self._mission_heading = _Navigation(obs).heading if obs is not None else 0.0
        self._centre = tuple(map(float, self.task.circuit_centre(self._mission_heading)))
        self.phase = "takeoff"
        self._phase_start = 0.0
        self._time = 0.0
        self._throttle_integral = 0.0
        self._throttle = 0.0
        self._position_integral = ZEROS3
        self._rate_integral = np.zeros(3)
        self._altitude_integral = 0.0
        self._heading = self._mission_heading
        self._track = ((0.0, 0.0), self._mission_heading)
        self._course_angle = None
        self._course_rate = 0.0
        self._swept = 0.0
        self.airspeed_used = 0.0
        self.airspeed_offset = 0.0               # m/s added to the cruise airspeed target (an excitation request)
        self.target = np.array([0.0, 0.0, -self.task.altitude])

    # ------------------------------------------------------------------ public
    def act(self, obs: dict, info: dict | None = None, airspeed: float | None = None) -> np.ndarray:
        airspeed = float(obs["pitot_airspeed"][0]) if airspeed is None else float(airspeed)
        if not math.isfinite(airspeed):
            raise ValueError(f"airspeed: must be finite, got {airspeed!r}")
        self.airspeed_used = airspeed = max(airspeed, 0.0)
        self._time = float(info["time"]) if info and "time" in info else self._time + self.dt
        nav = _Navigation(obs, airspeed)
        self._advance_phase(nav, airspeed)
        if self.phase == "landed":
            return np.zeros(9, dtype=np.float32)
        accel, yaw, pitch = self._guidance(nav, airspeed)
        attitude, collective = self._outer_loop(nav, accel, yaw, pitch, airspeed)
        rotors, surfaces = self._inner_loop(nav, attitude, collective, airspeed)
        return _action(rotors, surfaces, self._pusher(airspeed), self._skew_command(airspeed), self._hover_rotors,
                       self._limits)

    # ------------------------------------------------------------------ mission
    def _advance_phase(self, nav, airspeed: float) -> None:
        t, task, g = self._time, self.task, self.gains
        altitude = -nav.position[2]
        if self.phase == "takeoff" and altitude > task.altitude - 0.5:
            self._enter("hover")
        elif self.phase == "hover" and t - self._phase_start > task.hover_time:
            self._enter("transition")
        elif self.phase == "transition" and airspeed > task.cruise_airspeed - g.transition_done_speed_margin:
            self._enter("cruise")
            self._course_angle = self._circle_angle(nav.position)
        elif self.phase == "cruise":
            angle = self._circle_angle(nav.position)
            self._swept += _wrap(angle - self._course_angle)
            self._course_angle = angle
            # leave the circle early enough that the deceleration (~back_transition_decel) ends over home
            ground_speed = float(np.hypot(nav.velocity[0], nav.velocity[1]))
            lead = max(ground_speed ** 2 / (2.0 * g.back_transition_decel), 20.0)
            if abs(self._swept) >= 2.0 * math.pi * task.laps - lead / task.circuit_radius:
                self._enter("back_transition")
                # decelerate along the way the nose points now, without sideslip: on the arc that is up to
                # ~35 deg off the mission heading, and a sideslipping skewed wing rolls the airframe over
                self._track = ((nav.position[0], nav.position[1]), nav.heading)
        elif (self.phase == "back_transition"
              and min(airspeed, np.hypot(nav.velocity[0], nav.velocity[1])) < g.back_transition_done_speed):
            self._enter("return")
            self._heading = nav.heading          # turn home from where the nose points
        elif self.phase == "return" and self._near_home(nav):
            self._enter("land")
        elif self.phase == "land" and altitude < 0.5 * self.params.body_size[2] + 0.15 and abs(nav.velocity[2]) < 0.2:
            self._enter("landed")

    def _near_home(self, nav) -> bool:
        """Within 3 m of home (the take-off point at mission altitude) and slower than 1.5 m/s."""
        x, y, z = nav.position
        offset = (x, y, z + self.task.altitude)
        return math.sqrt(blas_dot(offset, offset)) < 3.0 and math.sqrt(blas_dot(nav.velocity, nav.velocity)) < 1.5

    def _enter(self, phase: str) -> None:
        self.phase, self._phase_start = phase, self._time
        self._position_integral = ZEROS3       # each phase has its own trim (attitude, flow, rotor use)

    def _circle_angle(self, position) -> float:
        return math.atan2(position[1] - self._centre[1], position[0] - self._centre[0])

    # ------------------------------------------------------------------ guidance
    def _guidance(self, nav, airspeed):
        """Desired NED acceleration, yaw, and in forward flight the pitch (None: the outer loop tilts)."""
        task = self.task
        if self.phase in QUAD_PHASES:
            target, velocity_ref = (0.0, 0.0, -task.altitude), ZEROS3
            if self.phase == "land":     # always below: sink at the descent rate
                target, velocity_ref = (0.0, 0.0, nav.position[2] + 1.0), (0.0, 0.0, task.descent_rate)
            self.target = np.array(target)
            return self._quad_acceleration(nav, target, velocity_ref), self._quad_heading(nav, target), None
        if self.phase in ("transition", "back_transition"):
            # hold a line and the altitude (transition: through home along the mission heading; back
            # transition: the track it started on); the pusher (or the drag) owns the speed along the line,
            # so no tilt along it
            (x0, y0), heading = self._track if self.phase == "back_transition" else ((0.0, 0.0), self._mission_heading)
            along = (math.cos(heading), math.sin(heading), 0.0)
            distance = blas_dot((nav.position[0] - x0, nav.position[1] - y0), along[:2])
            target = (x0 + along[0] * distance, y0 + along[1] * distance, -task.altitude)
            self.target = np.array(target)
            speed = blas_dot(nav.velocity, along)
            accel = self._quad_acceleration(nav, target, tuple(a * speed for a in along))
            across = blas_dot(accel, along)
            return tuple(a - b * across for a, b in zip(accel, along)), heading, None
        return self._circle_guidance(nav, airspeed)

    def _quad_heading(self, nav, target) -> float:
        """Nose toward home while returning from more than 5 m (tail first, the fin destabilises the
        airframe), else into the mean wind (the take-off heading), where the fin weathervanes."""
        dx, dy = target[0] - nav.position[0], target[1] - nav.position[1]
        wanted = self._mission_heading             # into the mean wind
        if self.phase == "return" and np.hypot(dx, dy) > 5.0:
            wanted = math.atan2(dy, dx)
        # turn at a limited rate: a large yaw error would leak into roll and pitch through the attitude error
        step = self.gains.max_turn_rate * self.dt
        self._heading = _wrap(self._heading + min(max(_wrap(wanted - self._heading), -step), step))
        return self._heading

    def _quad_acceleration(self, nav, target, velocity_ref) -> tuple:
        """PD on position and velocity plus an integral near the target (wind and the airframe's unmodelled
        forces: the autopilot does not know where the flow comes from while hovering)."""
        g = self.gains
        error = [t - p for t, p in zip(target, nav.position)]
        vx, vy, vz = (v + k * e for v, k, e in zip(velocity_ref, self._kp_kv, error))
        horizontal = np.hypot(vx, vy)
        if horizontal > g.max_horizontal_speed:
            scale = g.max_horizontal_speed / horizontal
            vx, vy = vx * scale, vy * scale
        vz = min(max(vz, -self.task.climb_rate), self.task.descent_rate)
        limit, k_i = g.integral_limit, g.position_integral
        self._position_integral = tuple(
            min(max(i + k_i * (1.0 if abs(e) < g.integral_zone else 0.0) * e * self.dt, -limit), limit)
            for i, e in zip(self._position_integral, error))
        return tuple(k * (c - v) + i for k, c, v, i in zip(self._kv, (vx, vy, vz), nav.velocity,
                                                           self._position_integral))

    def _circle_guidance(self, nav, airspeed):
        """Course along the circle's tangent (clockwise), bent toward the circle by the cross-track error;
        lateral acceleration = speed x (the circle's turn rate + a course correction). Altitude: a climb-rate
        command, flown by pitch around the trim pitch (and by the rotors' collective where the wing falls
        short)."""
        g, task = self.gains, self.task
        dx, dy = nav.position[0] - self._centre[0], nav.position[1] - self._centre[1]
        radius = float(np.hypot(dx, dy))
        rx, ry = dx / max(radius, 1e-6), dy / max(radius, 1e-6)       # radial unit vector
        limit = math.radians(g.cross_track_limit_deg)
        correction = min(max(g.cross_track * (radius - task.circuit_radius), -limit), limit)  # outside: turn in
        course_ref = math.atan2(rx, -ry) + correction    # the tangent (-r_y, r_x): clockwise seen from above
        vx, vy, vz = nav.velocity
        speed = max(float(np.hypot(vx, vy)), 1.0)
        course = math.atan2(vy, vx)
        self._course_rate = speed / task.circuit_radius + g.course * _wrap(course_ref - course)
        lateral = speed * self._course_rate
        climb_cmd = min(max(g.altitude * (task.altitude + nav.position[2]), -2.0), 2.0)   # m/s, up
        climb_error = climb_cmd + vz                         # climb rate = -v_down
        self._altitude_integral = min(max(self._altitude_integral + g.altitude_integral * climb_error * self.dt,
                                          -0.1), 0.1)
        # lateral acceleration: + is to the right of the course
        accel = (lateral * -math.sin(course), lateral * math.cos(course), -g.climb_accel * climb_error)
        self.target = np.array([self._centre[0] + rx * task.circuit_radius, self._centre[1] + ry * task.circuit_radius,
                                -task.altitude])
        pitch = self._trim_pitch(airspeed) + g.climb_rate_gain * climb_error + self._altitude_integral
        return accel, nav.heading, pitch          # no heading command: `_turn_rates` turns the nose

    # ------------------------------------------------------------------ outer loop
    def _outer_loop(self, nav, accel, yaw, pitch, airspeed):
        """Attitude (rotation matrix) and hover-rotor collective (N) for the desired acceleration."""
        m = self.params.mass
        force = np.array([m * accel[0], m * accel[1], m * (accel[2] - GRAVITY)])   # NED, what rotors + wing give
        if pitch is None:
            R_des = _tilted_attitude(force, yaw, math.radians(self.gains.max_tilt_deg))
        else:
            bank_limit = math.radians(self.gains.max_bank_deg)
            bank = min(max(math.atan2(blas_dot(accel[:2], (-math.sin(yaw), math.cos(yaw))), GRAVITY), -bank_limit),
                       bank_limit)
            pitch_limit = math.radians(self.gains.max_pitch_deg)
            pitch = min(max(pitch, -pitch_limit), pitch_limit)
            R_des = rotation_from_euler(bank, pitch, yaw)
        thrust = -blas_dot(force, R_des[:, 2])                            # along -z_des, rotors + wing
        needed = thrust - self._wing_lift(nav, airspeed, pitch is not None)
        share = self._cruise_share()
        if share < 1.0:                        # handing over from the transition: see transition_blend_time
            transition = max(thrust - self._wing_lift(nav, airspeed, False), 0.0)
            needed = share * max(needed, 0.0) + (1.0 - share) * transition
        elif self.phase == "cruise" and needed < self.gains.rotor_assist_floor * m * GRAVITY:
            needed = 0.0                       # the wing flies; the rotors stay off rather than flicker
        return R_des, max(needed, 0.0)

    def _cruise_share(self, after: float = 0.0) -> float:
        """How far the rotors' collective has moved from the transition's rule to the cruise rule: 0 until
        `after` s into cruise, 1 `transition_blend_time` later (and in every other phase, which has its own rule)."""
        blend = self.gains.transition_blend_time
        if self.phase != "cruise" or blend <= 0.0:
            return 1.0
        return min(max((self._time - self._phase_start - after) / blend, 0.0), 1.0)

    def _wing_lift(self, nav, airspeed, in_cruise: bool = False) -> float:
        """Lift along body -z from the model at the given airspeed and the measured skew, at alpha = pitch minus
        flight-path angle (001 eq. 8.6 takes the pitch, i.e. level flight) or, in cruise, at the most the pitch
        loop may ask of the wing (trim alpha + `cruise_alpha_margin_deg`, at most `cruise_alpha_max_deg`):
        there the pitch loop flies the altitude with the wing, and the rotors make up only what the wing cannot
        carry at this airspeed. Counting only the lift at the trim alpha switches the rotors on in every gust's
        sink and steep turn, and their drag in the cross-flow, which this autopilot does not model, pitches the
        airframe."""
        if airspeed < 1.0 or self.phase in QUAD_PHASES:    # hovering, the flow's direction is unknown
            return 0.0
        alpha = nav.alpha
        if in_cruise:
            g = self.gains
            # the margin grows only after the hand-over from the transition (`transition_blend_time`), over as
            # long again: the nose is still coming up then, and crediting the wing during it sank the airframe
            margin = self._cruise_share(after=g.transition_blend_time) * math.radians(g.cruise_alpha_margin_deg)
            alpha = min(self._trim_pitch(airspeed) + margin, math.radians(g.cruise_alpha_max_deg))
        force, _ = self._airframe_wrench(_air_velocity(airspeed, alpha), ZEROS3, nav.skew)
        return -force[2]

    def _trim_pitch(self, airspeed: float) -> float:
        """Pitch that makes the wing carry the weight at this airspeed, by the model (bisection on alpha)."""
        if airspeed < self.params.transition_end_speed:
            return 0.0
        if self._last_trim[0] == airspeed:     # guidance and the lift estimate ask twice per step
            return self._last_trim[1]
        self._last_trim = (airspeed, self._solve_trim_pitch(airspeed))
        return self._last_trim[1]

    def _solve_trim_pitch(self, airspeed: float) -> float:
        weight = self.params.mass * GRAVITY
        lo, hi = math.radians(-2.0), math.radians(12.0)
        skew = math.pi / 2
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            force, _ = self._airframe_wrench(_air_velocity(airspeed, mid), ZEROS3, skew)
            lo, hi = (mid, hi) if -force[2] < weight else (lo, mid)
        return 0.5 * (lo + hi)

    def _airframe_wrench(self, air, rates, skew, surfaces=ZEROS3):
        """Force and moment (3-tuples of floats, body FRD) of the airframe with the hover rotors and the pusher
        off (`quadplane_aero.aero_wrench`, called on its compiled form)."""
        loads = aero_loads(self._aero.constants, *air, *rates, skew, *surfaces, ROTORS_OFF, ROTORS_WHOLE, 0.0, 0.0)
        return loads[:3], loads[3:]

    # ------------------------------------------------------------------ inner loop
    def _inner_loop(self, nav, R_des, collective, airspeed):
        """Hover-rotor forces (N) and surface deflections (rad) for the attitude R_des and the collective."""
        turn_rates = self._turn_rates(nav) if self.phase == "cruise" else None
        moment = _moment_command(nav.R, R_des, nav.gyro, turn_rates, self._rate_integral, self._axis_gains, self.dt)
        airframe = self._airframe_moment(nav, airspeed)
        # the pusher motor's reaction about x, from its measured current (003 eq. 1: k_e I_e drives the rotor)
        pusher = self.params.pusher_spin_direction * self.params.pusher_motor_constant * nav.pusher_current
        demand = np.array([moment[0] - airframe[0] + pusher, moment[1] - airframe[1], moment[2] - airframe[2],
                           collective])
        return _allocate(self._effectiveness(nav, airspeed), demand, collective, self._regularisation, self._limits,
                         self._f_max)

    def _turn_rates(self, nav) -> tuple:
        """Body rates of the course rate the circle asks for, flown as a heading rate (Euler psi-dot to body
        rates): in forward flight the heading follows the turn, the fin keeps the nose in the air flow."""
        cos_pitch, rate = math.cos(nav.pitch), self._course_rate
        return (rate * -math.sin(nav.pitch), rate * (math.sin(nav.roll) * cos_pitch),
                rate * (math.cos(nav.roll) * cos_pitch))

    def _airframe_moment(self, nav, airspeed) -> tuple:
        """The airframe's aerodynamic moment by the model at the given airspeed (zero while hovering)."""
        if airspeed < 1.0 or self.phase in QUAD_PHASES:
            return ZEROS3
        _, moment = self._airframe_wrench(nav.air_velocity(), tuple(nav.gyro.tolist()), nav.skew)
        return moment

    def _effectiveness(self, nav, airspeed):
        """B (4 x 7): [M_x, M_y, M_z, thrust along -z] per newton of each hover rotor and per radian of each
        surface. Rotors: r_i x a_i plus the drag torque; surfaces: the model's moments at the given airspeed."""
        positions, axes = self.params.hover_rotor_geometry(nav.skew)
        B = np.zeros((4, 7))
        for i, (position, axis, sign) in enumerate(zip(positions, axes, self._yaw_signs)):
            mx, my, mz = cross3(position, axis)
            B[:, i] = (mx, my, mz + self._yaw_per_newton * sign, -axis[2])
        if airspeed >= 1.0 and self.phase not in QUAD_PHASES:   # in quad mode the rotors fly it (001 Sec. 2)
            air = nav.air_velocity()
            _, m0 = self._airframe_wrench(air, ZEROS3, nav.skew)
            for j, delta in enumerate(((0.05, 0.0, 0.0), (0.0, 0.05, 0.0), (0.0, 0.0, 0.05))):
                _, m = self._airframe_wrench(air, ZEROS3, nav.skew, delta)
                B[:3, 4 + j] = [(m[i] - m0[i]) / 0.05 for i in range(3)]
        return B

    # ------------------------------------------------------------------ pusher and wing
    def _pusher(self, airspeed: float) -> float:
        """Throttle: full in the transition, PI on the given airspeed in cruise, off otherwise; slew-limited
        so the motor's reaction torque stays within what the hover rotors can hold about x."""
        g = self.gains
        if self.phase not in ("transition", "cruise"):
            self._throttle_integral, wanted = 0.0, 0.0
        elif self.phase == "transition":
            wanted = 1.0
        else:
            error = self.task.cruise_airspeed + self.airspeed_offset - airspeed
            integral = self._throttle_integral + g.airspeed_i * error * self.dt
            self._throttle_integral = min(max(integral, -0.3), 0.3)
            wanted = min(max(self._cruise_throttle() + g.airspeed_p * error + self._throttle_integral, 0.0), 1.0)
        step = g.throttle_slew * self.dt
        self._throttle = min(max(wanted, self._throttle - step), self._throttle + step)
        return self._throttle

    def _cruise_throttle(self) -> float:
        if not hasattr(self, "_throttle_ff"):
            from .quadplane_trim import trim
            t = trim(self.params, self.task.cruise_airspeed)
            self._throttle_ff = float(throttle_for_speed(self.params, t["pusher_omega"], self.task.cruise_airspeed))
        return self._throttle_ff

    def _skew_command(self, airspeed: float) -> float:
        if self.phase in QUAD_PHASES:
            return 0.0
        return skew_schedule(self.params, airspeed) / (0.5 * math.pi)


class _Navigation:
    """What the autopilot reads from one observation, with the airspeed it was given for this step: position and
    velocity as tuples of floats, the gyro and the attitude R as arrays."""

    def __init__(self, obs, airspeed: float = 0.0):
        self.position = tuple(np.asarray(obs["position"], float).tolist())
        self.velocity = tuple(np.asarray(obs["velocity"], float).tolist())
        self.gyro = np.asarray(obs["gyro"], float)
        self.R = rotation_matrix(np.asarray(obs["attitude"], float))
        (r00, _, _), (r10, _, _), (r20, r21, r22) = self.R.tolist()
        self.skew = float(obs["skew"][0])
        self.pitch = -math.asin(min(max(r20, -1.0), 1.0))
        self.roll = math.atan2(r21, r22)
        self.pusher_current = float(obs["pusher_current"][0])
        self.heading = math.atan2(r10, r00)
        self.airspeed = airspeed
        # angle of attack ~ pitch - the flight-path angle through the air, asin(climb / airspeed) with the wind
        # taken as horizontal (no vane: 001 Sec. 3, the VSQP has none). The path angle over the ground (climb /
        # ground speed) overstates it upwind in strong wind, and the model moment at that alpha would feed every
        # sink back into a pitch-up.
        climb = -self.velocity[2]
        self.alpha = self.pitch - math.asin(min(max(climb / max(airspeed, 3.0), -1.0), 1.0))

    def air_velocity(self) -> tuple:
        """Body air velocity at the step's airspeed and alpha, sideslip taken as zero."""
        return _air_velocity(self.airspeed, self.alpha)


def _air_velocity(airspeed: float, alpha: float) -> tuple:
    """Body air velocity (u, v, w) at `airspeed` and angle of attack `alpha`, no sideslip."""
    return airspeed * math.cos(alpha), 0.0, airspeed * math.sin(alpha)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _tilted_attitude(force, yaw, tilt_limit):  # pragma: no cover (compiled)
    """Rotation (body FRD -> NED) whose -z is along `force` tilted at most `tilt_limit` from vertical and whose
    heading is `yaw`."""
    return _attitude_from_axis(_limit_tilt(force / max(math.sqrt(np.dot(force, force)), 1e-6), tilt_limit), yaw)


@njit(cache=True)
def _limit_tilt(axis, limit):  # pragma: no cover (compiled)
    """The unit thrust axis (NED, pointing up-ish) tilted at most `limit` from vertical."""
    up = np.array([0.0, 0.0, -1.0])
    tilt = math.acos(min(max(np.dot(axis, up), -1.0), 1.0))
    if tilt <= limit:
        return axis
    horizontal = axis - np.dot(axis, up) * up
    horizontal /= max(math.sqrt(np.dot(horizontal, horizontal)), 1e-9)
    return math.cos(limit) * up + math.sin(limit) * horizontal


@njit(cache=True)
def _attitude_from_axis(thrust_axis, yaw):  # pragma: no cover (compiled)
    """Rotation (body FRD -> NED) whose -z is `thrust_axis` and whose heading is `yaw`."""
    z = -thrust_axis
    y = np.array(cross3(z, (math.cos(yaw), math.sin(yaw), 0.0)))
    y /= math.sqrt(np.dot(y, y))
    x = cross3(y, z)
    R = np.empty((3, 3))
    for i in range(3):
        R[i, 0], R[i, 1], R[i, 2] = x[i], y[i], z[i]
    return R


@njit(cache=True)
def _moment_command(R, R_des, rates, turn_rates, rate_integral, gains, dt):  # pragma: no cover (compiled)
    """Body moment (N m) that tracks R_des: the geometric attitude error e_R = vee(R_d^T R - R^T R_d) / 2 (Lee
    et al. 2010) -> rate command (plus `turn_rates`, None outside cruise) within +-max_rate -> PI on the rate
    error -> inertia times the angular acceleration plus the gyroscopic w x I w. The integral (in place on
    `rate_integral`, clipped) takes the aerodynamic moments the model does not cover (all of them while
    hovering), large against this airframe's roll inertia (0.6 N m from a 7 m/s side flow = 21 rad/s^2)."""
    E = R_des.T @ R - R.T @ R_des
    e_R = (0.5 * E[2, 1], 0.5 * E[0, 2], 0.5 * E[1, 0])
    alpha = np.empty(3)
    for i in range(3):
        rate_cmd = -gains[KATT, i] * e_R[i]
        if turn_rates is not None:
            rate_cmd += turn_rates[i]
        rate_error = min(max(rate_cmd, -gains[MAX_RATE, i]), gains[MAX_RATE, i]) - rates[i]
        limit = gains[RATE_INTEGRAL_LIMIT, i]
        rate_integral[i] = min(max(rate_integral[i] + gains[KRATE_I, i] * rate_error * dt, -limit), limit)
        alpha[i] = gains[KRATE, i] * rate_error + rate_integral[i]
    inertia = gains[INERTIA]
    return inertia * alpha + np.array(cross3(rates, inertia * rates))


@njit(cache=True)
def _allocate(B, demand, collective, regularisation, limits, f_max):  # pragma: no cover (compiled)
    """Rotor forces (N) and surface deflections (rad) for `demand` [M_x, M_y, M_z, T] by regularised weighted
    least squares over rotors and surfaces (001 Sec. 8.1: WLS allocation) about equal rotor shares of the
    collective, then the surfaces clipped to their throws and the rotors re-solved for what the surfaces could
    not give (`_rotor_forces`)."""
    preferred = np.zeros(7)
    preferred[:4] = collective / 4.0
    x = preferred + np.linalg.solve(B.T @ B + regularisation, B.T @ (demand - B @ preferred))
    surfaces = np.minimum(np.maximum(x[4:], -limits), limits)
    rest = demand - np.ascontiguousarray(B[:, 4:]) @ surfaces
    return _rotor_forces(B[:, :4], rest, f_max), surfaces


@njit(cache=True)
def _rotor_forces(Br, demand, f_max):  # pragma: no cover (compiled)
    """Rotor forces for [M_x, M_y, M_z, T], yaw given up first: the yaw moment is scaled down until the
    forces fit [0, f_max] (a yaw demand at the limits would otherwise change the collective). Least squares
    with numpy's default cut-off for small singular values (machine epsilon times the larger dimension)."""
    rcond = np.finfo(np.float64).eps * max(Br.shape[0], Br.shape[1])
    without_yaw = demand.copy()
    without_yaw[2] = 0.0
    base = np.linalg.lstsq(Br, without_yaw, rcond=rcond)[0]
    yaw = np.linalg.lstsq(Br, demand - without_yaw, rcond=rcond)[0]
    scale = 1.0
    for b, y in zip(base, yaw):
        if y > 1e-12 and b + y > f_max:
            scale = min(scale, max((f_max - b) / y, 0.0))
        elif y < -1e-12 and b + y < 0.0:
            scale = min(scale, max(-b / y, 0.0))
    return np.minimum(np.maximum(base + scale * yaw, 0.0), f_max)


@njit(cache=True)
def _action(rotors, surfaces, throttle, skew, hover_rotors, limits):  # pragma: no cover (compiled)
    """QuadPlane-v0's action (float32): hover-rotor commands for the forces (f = k_f omega^2, normalised between
    idle and full speed; `hover_rotors` = k_f, omega_min, omega_max), throttle, surfaces per their throws and
    the skew command, clipped to the action space."""
    k_f, omega_min, omega_max = hover_rotors[0], hover_rotors[1], hover_rotors[2]
    action = np.empty(9, dtype=np.float32)
    for i in range(4):
        action[i] = min(max((math.sqrt(rotors[i] / k_f) - omega_min) / (omega_max - omega_min), 0.0), 1.0)
    action[4] = min(max(throttle, 0.0), 1.0)
    for i in range(3):
        action[5 + i] = min(max(surfaces[i] / limits[i], -1.0), 1.0)
    action[8] = min(max(skew, 0.0), 1.0)
    return action
