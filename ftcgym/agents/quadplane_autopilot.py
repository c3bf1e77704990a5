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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.constants import GRAVITY
from ..models.geometry import cross, rotation_from_euler, rotation_matrix
from ..models.pusher import throttle_for_speed
from ..models.quadplane_aero import aero_wrench, skew_schedule
from ..models.tasks import MissionTask

PHASES = ("takeoff", "hover", "transition", "cruise", "back_transition", "return", "land", "landed")
QUAD_PHASES = ("takeoff", "hover", "return", "land")
NO_ROTORS = np.zeros(4)
ONES = np.ones(4)


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
        self._kp, self._kv = np.asarray(g.position, float), np.asarray(g.velocity, float)
        self._katt, self._krate = np.asarray(g.attitude, float), np.asarray(g.rate, float)
        self._max_rate = np.asarray(g.max_rate, float)
        self._krate_i = np.asarray(g.rate_integral, float)
        self._rate_integral_limit = np.asarray(g.rate_integral_limit, float)
        self._inertia = np.asarray(params.inertia, float)
        self._f_max = params.hover_thrust_coefficient * params.hover_omega_max ** 2
        self._yaw_per_newton = params.hover_torque_coefficient / params.hover_thrust_coefficient
        self._regularisation = 1e-3 * np.diag([g.rotor_weight] * 4 + [g.surface_weight] * 3)
        self._limits = np.asarray(params.surface_limit, float)
        self._last_trim = (None, 0.0)
        self.reset()

    def reset(self, obs: dict | None = None, info: dict | None = None) -> None:
        """Start a mission; the take-off heading (from `obs`, else north) orients the transition and circuit."""
        self._mission_heading = _Navigation(obs).heading if obs is not None else 0.0
        self._centre = self.task.circuit_centre(self._mission_heading)
        self.phase = "takeoff"
        self._phase_start = 0.0
        self._time = 0.0
        self._throttle_integral = 0.0
        self._throttle = 0.0
        self._position_integral = np.zeros(3)
        self._rate_integral = np.zeros(3)
        self._altitude_integral = 0.0
        self._heading = self._mission_heading
        self._track = (np.zeros(2), self._mission_heading)
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
        return self._action(rotors, surfaces, self._pusher(airspeed), self._skew_command(airspeed))

    # ------------------------------------------------------------------ mission
    def _advance_phase(self, nav, airspeed: float) -> None:
        t, task, g = self._time, self.task, self.gains
        altitude = -nav.position[2]
        home = np.array([0.0, 0.0, -task.altitude])
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
            ground_speed = float(np.hypot(*nav.velocity[:2]))
            lead = max(ground_speed ** 2 / (2.0 * g.back_transition_decel), 20.0)
            if abs(self._swept) >= 2.0 * np.pi * task.laps - lead / task.circuit_radius:
                self._enter("back_transition")
                # decelerate along the way the nose points now, without sideslip: on the arc that is up to
                # ~35 deg off the mission heading, and a sideslipping skewed wing rolls the airframe over
                self._track = (nav.position[:2].copy(), nav.heading)
        elif (self.phase == "back_transition"
              and min(airspeed, np.hypot(*nav.velocity[:2])) < g.back_transition_done_speed):
            self._enter("return")
            self._heading = nav.heading          # turn home from where the nose points
        elif (self.phase == "return" and np.linalg.norm(nav.position - home) < 3.0
              and np.linalg.norm(nav.velocity) < 1.5):
            self._enter("land")
        elif self.phase == "land" and altitude < 0.5 * self.params.body_size[2] + 0.15 and abs(nav.velocity[2]) < 0.2:
            self._enter("landed")

    def _enter(self, phase: str) -> None:
        self.phase, self._phase_start = phase, self._time
        self._position_integral[:] = 0.0       # each phase has its own trim (attitude, flow, rotor use)

    def _circle_angle(self, position) -> float:
        d = position[:2] - self._centre
        return math.atan2(d[1], d[0])

    # ------------------------------------------------------------------ guidance
    def _guidance(self, nav, airspeed):
        """Desired NED acceleration, yaw, and in forward flight the pitch (None: the outer loop tilts)."""
        task = self.task
        home = np.array([0.0, 0.0, -task.altitude])
        if self.phase in QUAD_PHASES:
            velocity_ref = np.zeros(3)
            target = home.copy()
            if self.phase == "land":
                target[2] = nav.position[2] + 1.0            # always below: sink at the descent rate
                velocity_ref[2] = task.descent_rate
            self.target = target
            return self._quad_acceleration(nav, target, velocity_ref), self._quad_heading(nav, target), None
        if self.phase in ("transition", "back_transition"):
            # hold a line and the altitude (transition: through home along the mission heading; back
            # transition: the track it started on); the pusher (or the drag) owns the speed along the line,
            # so no tilt along it
            origin, heading = self._track if self.phase == "back_transition" else (np.zeros(2), self._mission_heading)
            along = np.array([math.cos(heading), math.sin(heading), 0.0])
            on_line = np.append(origin + along[:2] * float((nav.position[:2] - origin) @ along[:2]), -task.altitude)
            self.target = on_line
            accel = self._quad_acceleration(nav, self.target, along * float(nav.velocity @ along))
            accel -= along * float(accel @ along)
            return accel, heading, None
        return self._circle_guidance(nav, airspeed)

    def _quad_heading(self, nav, target) -> float:
        """Nose toward home while returning from more than 5 m (tail first, the fin destabilises the
        airframe), else into the mean wind (the take-off heading), where the fin weathervanes."""
        offset = target[:2] - nav.position[:2]
        wanted = self._mission_heading             # into the mean wind
        if self.phase == "return" and np.hypot(*offset) > 5.0:
            wanted = math.atan2(offset[1], offset[0])
        # turn at a limited rate: a large yaw error would leak into roll and pitch through the attitude error
        step = self.gains.max_turn_rate * self.dt
        self._heading = _wrap(self._heading + float(np.clip(_wrap(wanted - self._heading), -step, step)))
        return self._heading

    def _quad_acceleration(self, nav, target, velocity_ref) -> np.ndarray:
        """PD on position and velocity plus an integral near the target (wind and the airframe's unmodelled
        forces: the autopilot does not know where the flow comes from while hovering)."""
        g = self.gains
        error = target - nav.position
        velocity_cmd = velocity_ref + self._kp / self._kv * error
        horizontal = np.hypot(*velocity_cmd[:2])
        if horizontal > g.max_horizontal_speed:
            velocity_cmd[:2] *= g.max_horizontal_speed / horizontal
        velocity_cmd[2] = np.clip(velocity_cmd[2], -self.task.climb_rate, self.task.descent_rate)
        near = np.abs(error) < g.integral_zone
        limit = g.integral_limit
        self._position_integral = np.clip(self._position_integral + g.position_integral * near * error * self.dt,
                                          -limit, limit)
        return self._kv * (velocity_cmd - nav.velocity) + self._position_integral

    def _circle_guidance(self, nav, airspeed):
        """Course along the circle's tangent (clockwise), bent toward the circle by the cross-track error;
        lateral acceleration = speed x (the circle's turn rate + a course correction). Altitude: a climb-rate
        command, flown by pitch around the trim pitch (and by the rotors' collective where the wing falls
        short)."""
        g, task = self.gains, self.task
        d = nav.position[:2] - self._centre
        radius = float(np.hypot(*d))
        radial = d / max(radius, 1e-6)
        tangent = np.array([-radial[1], radial[0]])      # clockwise seen from above (NED: north, then east)
        limit = math.radians(g.cross_track_limit_deg)
        correction = float(np.clip(g.cross_track * (radius - task.circuit_radius), -limit, limit))  # outside: turn in
        course_ref = math.atan2(tangent[1], tangent[0]) + correction
        speed = max(float(np.hypot(*nav.velocity[:2])), 1.0)
        course = math.atan2(nav.velocity[1], nav.velocity[0])
        self._course_rate = speed / task.circuit_radius + g.course * _wrap(course_ref - course)
        lateral = speed * self._course_rate
        accel = np.zeros(3)
        accel[:2] = lateral * np.array([-math.sin(course), math.cos(course)])   # + is to the right of the course
        climb_cmd = float(np.clip(g.altitude * (task.altitude + nav.position[2]), -2.0, 2.0))   # m/s, up
        climb_error = climb_cmd + nav.velocity[2]            # climb rate = -v_down
        self._altitude_integral = float(np.clip(self._altitude_integral + g.altitude_integral * climb_error * self.dt,
                                                -0.1, 0.1))
        accel[2] = -g.climb_accel * climb_error
        self.target = np.array([*(self._centre + radial * task.circuit_radius), -task.altitude])
        pitch = self._trim_pitch(airspeed) + g.climb_rate_gain * climb_error + self._altitude_integral
        return accel, nav.heading, pitch          # no heading command: `_turn_rates` turns the nose

    # ------------------------------------------------------------------ outer loop
    def _outer_loop(self, nav, accel, yaw, pitch, airspeed):
        """Attitude (rotation matrix) and hover-rotor collective (N) for the desired acceleration."""
        m = self.params.mass
        force = m * (accel - np.array([0.0, 0.0, GRAVITY]))            # NED, what rotors + wing must give
        if pitch is None:
            tilt_limit = math.radians(self.gains.max_tilt_deg)
            axis = _limit_tilt(force / max(np.linalg.norm(force), 1e-6), tilt_limit)
            R_des = _attitude_from_axis(axis, yaw)
        else:
            right = np.array([-math.sin(yaw), math.cos(yaw)])
            bank_limit = math.radians(self.gains.max_bank_deg)
            bank = float(np.clip(math.atan2(float(accel[:2] @ right), GRAVITY), -bank_limit, bank_limit))
            pitch_limit = math.radians(self.gains.max_pitch_deg)
            pitch = float(np.clip(pitch, -pitch_limit, pitch_limit))
            R_des = rotation_from_euler(bank, pitch, yaw)
        thrust = float(-force @ R_des[:, 2])                              # along -z_des, rotors + wing
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
        return float(np.clip((self._time - self._phase_start - after) / blend, 0.0, 1.0))

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
        air = airspeed * np.array([math.cos(alpha), 0.0, math.sin(alpha)])
        force, _ = aero_wrench(self.params, air, np.zeros(3), nav.skew, np.zeros(3), NO_ROTORS, ONES, 0.0, 0.0)
        return float(-force[2])

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
            air = airspeed * np.array([math.cos(mid), 0.0, math.sin(mid)])
            force, _ = aero_wrench(self.params, air, np.zeros(3), skew, np.zeros(3), NO_ROTORS, ONES, 0.0, 0.0)
            lo, hi = (mid, hi) if -force[2] < weight else (lo, mid)
        return 0.5 * (lo + hi)

    # ------------------------------------------------------------------ inner loop
    def _inner_loop(self, nav, R_des, collective, airspeed):
        R, rates = nav.R, nav.gyro
        e_R = 0.5 * _vee(R_des.T @ R - R.T @ R_des)
        rate_cmd = -self._katt * e_R
        if self.phase == "cruise":
            rate_cmd += self._turn_rates(nav)
        rate_cmd = np.clip(rate_cmd, -self._max_rate, self._max_rate)
        rate_error = rate_cmd - rates
        # integral: the aerodynamic moments the model does not cover (all of them while hovering) are large
        # against this airframe's roll inertia (0.6 N m from a 7 m/s side flow = 21 rad/s^2)
        self._rate_integral = np.clip(self._rate_integral + self._krate_i * rate_error * self.dt,
                                      -self._rate_integral_limit, self._rate_integral_limit)
        alpha_des = self._krate * rate_error + self._rate_integral
        moment = self._inertia * alpha_des + cross(rates, self._inertia * rates)
        moment -= self._airframe_moment(nav, airspeed)
        # the pusher motor's reaction about x, from its measured current (003 eq. 1: k_e I_e drives the rotor)
        moment[0] += self.params.pusher_spin_direction * self.params.pusher_motor_constant * nav.pusher_current
        B = self._effectiveness(nav, airspeed)
        demand = np.append(moment, collective)
        return self._allocate(B, demand, collective)

    def _turn_rates(self, nav) -> np.ndarray:
        """Body rates of the course rate the circle asks for, flown as a heading rate (Euler psi-dot to body
        rates): in forward flight the heading follows the turn, the fin keeps the nose in the air flow."""
        cos_pitch = math.cos(nav.pitch)
        return self._course_rate * np.array([-math.sin(nav.pitch), math.sin(nav.roll) * cos_pitch,
                                             math.cos(nav.roll) * cos_pitch])

    def _allocate(self, B, demand, collective):
        """Regularised weighted least squares over rotors and surfaces (001 Sec. 8.1: WLS allocation), then
        the surfaces clipped to their throws and the rotors re-solved for what the surfaces could not give."""
        preferred = np.zeros(7)
        preferred[:4] = collective / 4.0
        x = preferred + np.linalg.solve(B.T @ B + self._regularisation, B.T @ (demand - B @ preferred))
        surfaces = np.clip(x[4:], -self._limits, self._limits)
        rest = demand - B[:, 4:] @ surfaces
        return self._rotor_forces(B[:, :4], rest), surfaces

    def _rotor_forces(self, Br, demand) -> np.ndarray:
        """Rotor forces for [M_x, M_y, M_z, T], yaw given up first: the yaw moment is scaled down until the
        forces fit [0, f_max] (a yaw demand at the limits would otherwise change the collective)."""
        without_yaw = demand.copy()
        without_yaw[2] = 0.0
        base = np.linalg.lstsq(Br, without_yaw, rcond=None)[0]
        yaw = np.linalg.lstsq(Br, demand - without_yaw, rcond=None)[0]
        scale = 1.0
        for b, y in zip(base, yaw):
            if y > 1e-12 and b + y > self._f_max:
                scale = min(scale, max((self._f_max - b) / y, 0.0))
            elif y < -1e-12 and b + y < 0.0:
                scale = min(scale, max(-b / y, 0.0))
        return np.clip(base + scale * yaw, 0.0, self._f_max)

    def _airframe_moment(self, nav, airspeed) -> np.ndarray:
        if airspeed < 1.0 or self.phase in QUAD_PHASES:
            return np.zeros(3)
        air = nav.air_velocity()
        _, moment = aero_wrench(self.params, air, nav.gyro, nav.skew, np.zeros(3), NO_ROTORS, ONES, 0.0, 0.0)
        return moment

    def _effectiveness(self, nav, airspeed):
        """B (4 x 7): [M_x, M_y, M_z, thrust along -z] per newton of each hover rotor and per radian of each
        surface. Rotors: r_i x a_i plus the drag torque; surfaces: the model's moments at the given airspeed."""
        p = self.params
        positions, axes = p.hover_rotor_positions(nav.skew), p.hover_thrust_axes(nav.skew)
        B = np.zeros((4, 7))
        B[:3, :4] = np.cross(positions, axes).T
        B[2, :4] += self._yaw_per_newton * np.asarray(p.hover_yaw_signs, float)
        B[3, :4] = -axes[:, 2]
        if airspeed >= 1.0 and self.phase not in QUAD_PHASES:   # in quad mode the rotors fly it (001 Sec. 2)
            air = nav.air_velocity()
            _, m0 = aero_wrench(p, air, np.zeros(3), nav.skew, np.zeros(3), NO_ROTORS, ONES, 0.0, 0.0)
            for j in range(3):
                delta = np.zeros(3)
                delta[j] = 0.05
                _, m = aero_wrench(p, air, np.zeros(3), nav.skew, delta, NO_ROTORS, ONES, 0.0, 0.0)
                B[:3, 4 + j] = (m - m0) / 0.05
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
            self._throttle_integral = float(np.clip(integral, -0.3, 0.3))
            wanted = float(np.clip(self._cruise_throttle() + g.airspeed_p * error + self._throttle_integral, 0.0, 1.0))
        step = g.throttle_slew * self.dt
        self._throttle = float(np.clip(wanted, self._throttle - step, self._throttle + step))
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

    def _action(self, rotors, surfaces, throttle, skew) -> np.ndarray:
        p = self.params
        omega = np.sqrt(rotors / p.hover_thrust_coefficient)
        rotor_cmd = (omega - p.hover_omega_min) / (p.hover_omega_max - p.hover_omega_min)
        action = np.concatenate([rotor_cmd, [throttle], surfaces / self._limits, [skew]])
        return np.clip(action, [0, 0, 0, 0, 0, -1, -1, -1, 0], 1.0).astype(np.float32)


class _Navigation:
    """What the autopilot reads from one observation, with the airspeed it was given for this step."""

    def __init__(self, obs, airspeed: float = 0.0):
        self.position = np.asarray(obs["position"], float)
        self.velocity = np.asarray(obs["velocity"], float)
        self.gyro = np.asarray(obs["gyro"], float)
        self.R = rotation_matrix(obs["attitude"])
        self.skew = float(obs["skew"][0])
        self.pitch = float(-math.asin(np.clip(self.R[2, 0], -1.0, 1.0)))
        self.roll = math.atan2(self.R[2, 1], self.R[2, 2])
        self.pusher_current = float(obs["pusher_current"][0])
        self.heading = math.atan2(self.R[1, 0], self.R[0, 0])
        self.airspeed = airspeed
        # angle of attack ~ pitch - the flight-path angle through the air, asin(climb / airspeed) with the wind
        # taken as horizontal (no vane: 001 Sec. 3, the VSQP has none). The path angle over the ground (climb /
        # ground speed) overstates it upwind in strong wind, and the model moment at that alpha would feed every
        # sink back into a pitch-up.
        climb = -float(self.velocity[2])
        self.alpha = self.pitch - math.asin(float(np.clip(climb / max(airspeed, 3.0), -1.0, 1.0)))

    def air_velocity(self) -> np.ndarray:
        """Body air velocity at the step's airspeed and alpha, sideslip taken as zero."""
        return self.airspeed * np.array([math.cos(self.alpha), 0.0, math.sin(self.alpha)])


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _vee(S) -> np.ndarray:
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def _limit_tilt(axis, limit) -> np.ndarray:
    """The unit thrust axis (NED, pointing up-ish) tilted at most `limit` from vertical."""
    up = np.array([0.0, 0.0, -1.0])
    tilt = math.acos(float(np.clip(axis @ up, -1.0, 1.0)))
    if tilt <= limit:
        return axis
    horizontal = axis - (axis @ up) * up
    horizontal /= max(np.linalg.norm(horizontal), 1e-9)
    return math.cos(limit) * up + math.sin(limit) * horizontal


def _attitude_from_axis(thrust_axis, yaw) -> np.ndarray:
    """Rotation (body FRD -> NED) whose -z is `thrust_axis` and whose heading is `yaw`."""
    z = -thrust_axis
    x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    y = np.cross(z, x_c)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.column_stack([x, y, z])
