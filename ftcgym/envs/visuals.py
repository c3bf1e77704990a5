"""What a rendered frame shows of the vehicle: visual shapes only, never part of the dynamics.

A look draws the vehicle's body, arms and rotor discs (the quadrotor), or its fuselage, tail, pusher, landing
gear, hover rotors and a wing that turns with the skew angle (the quad-plane). The world builds a look only for an
env with a `render_mode`; the body keeps its collision box, mass and inertia, so the physics is the same as
without it (tests/test_video.py flies both and compares the observations bit for bit).

- The fixed parts are one compound visual shape of the body (`createVisualShapeArray`): a visual shape takes no
  part in Bullet's dynamics.
- Each rotor disc, and the quad-plane's wing, is a body of its own with no mass and no collision shape (nothing
  moves it, nothing touches it), placed over the vehicle only when a frame is drawn (`show`). The wing and its
  two arm rotors are turned by the skew angle.
- Rotor discs are coloured by state (`rotor_colors`), again only when a frame is drawn: green spinning, grey
  stopped, amber as the effectiveness drops (a loss of effectiveness), red for a lost propeller. Their own bodies
  let the GUI colour them too: its OpenGL renderer draws a compound shape in one colour (the body's, there),
  where the headless TinyRenderer colours each part.
- The ground is drawn as PyBullet's checkered plane, scaled to the flight box.

Shape positions are given in the body frame FRD (x forward, y right, z down) and mapped to PyBullet's FLU here.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pybullet_data

from .world import p

SPINNING = (0.15, 0.65, 0.25, 1.0)   # a rotor turning normally
STOPPED = (0.55, 0.55, 0.55, 1.0)    # a rotor turning slower than a tenth of its hover speed
WEAK = (1.0, 0.55, 0.0, 1.0)         # a rotor at half effectiveness or less (amber in between)
LOST = (0.9, 0.08, 0.08, 1.0)        # a rotor that lost its propeller (or all its effectiveness)
BODY = (0.25, 0.27, 0.32, 1.0)
ARM = (0.12, 0.12, 0.14, 1.0)
NOSE = (1.0, 0.85, 0.1, 1.0)         # marks the front
WING = (0.92, 0.92, 0.95, 1.0)
TAIL = (0.85, 0.3, 0.2, 1.0)
#: effectiveness at and below which a rotor is drawn WEAK (between 1 and this, blended from SPINNING)
WEAK_EFFECTIVENESS = 0.5


def rotor_colors(effectiveness, loaded, omega, spinning_omega: float) -> list[tuple]:
    """The RGBA colour of each rotor disc: LOST without its propeller or effectiveness, STOPPED below a tenth of
    `spinning_omega`, else SPINNING blended toward WEAK as the effectiveness drops to `WEAK_EFFECTIVENESS`."""
    colors = []
    for k, present, w in zip(np.asarray(effectiveness, dtype=float), np.asarray(loaded, dtype=bool),
                             np.asarray(omega, dtype=float)):
        if not present or k <= 1e-3:
            colors.append(LOST)
        elif w < 0.1 * spinning_omega:
            colors.append(STOPPED)
        else:
            share = min(max((1.0 - k) / (1.0 - WEAK_EFFECTIVENESS), 0.0), 1.0)
            colors.append(tuple(float(a + share * (b - a)) for a, b in zip(SPINNING, WEAK)))
    return colors


class _Shapes:
    """A compound visual shape being assembled: boxes and discs with FRD frames and colours."""

    def __init__(self):
        self.types, self.half_extents, self.radii, self.lengths = [], [], [], []
        self.positions, self.orientations, self.colors = [], [], []

    def box(self, center, half, color, yaw: float = 0.0) -> int:
        """A box at `center` (FRD) with half extents `half` along its axes, turned by `yaw` about body z."""
        return self._add(p.GEOM_BOX, center, _about_z(yaw), color, half=half)

    def disc(self, center, radius: float, color, thickness: float = 0.006, axis: str = "z") -> int:
        """A thin cylinder at `center` (FRD), its axis along body z (a rotor) or x (a pusher)."""
        orientation = _about_z(0.0) if axis == "z" else (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))
        return self._add(p.GEOM_CYLINDER, center, orientation, color, radius=radius, length=thickness)

    def _add(self, kind, center, orientation, color, half=(0.0, 0.0, 0.0), radius=0.0, length=0.0) -> int:
        self.types.append(kind)
        self.half_extents.append([float(h) for h in half])
        self.radii.append(float(radius))
        self.lengths.append(float(length))
        self.positions.append(_flu(center))
        self.orientations.append(list(orientation))
        self.colors.append(color)
        return len(self.types) - 1

    def create(self, client: int) -> int:
        return p.createVisualShapeArray(shapeTypes=self.types, halfExtents=self.half_extents, radii=self.radii,
                                        lengths=self.lengths, visualFramePositions=self.positions,
                                        visualFrameOrientations=self.orientations, physicsClientId=client)

    def paint(self, client: int, body: int, last) -> None:
        """Colour each shape (TinyRenderer); the shapes of colour `last` go last, the one colour the GUI shows."""
        order = sorted(range(len(self.colors)), key=lambda i: self.colors[i] == last)
        for index in order:
            p.changeVisualShape(body, -1, shapeIndex=index, rgbaColor=list(self.colors[index]),
                                physicsClientId=client)


def _flu(frd) -> list:
    """A body-frame position, FRD -> PyBullet's FLU."""
    return [float(frd[0]), -float(frd[1]), -float(frd[2])]


def _about_z(yaw_frd: float) -> tuple:
    """The PyBullet (FLU) quaternion of a turn by `yaw_frd` about body z (FRD, so -yaw about FLU z)."""
    return (0.0, 0.0, math.sin(-yaw_frd / 2.0), math.cos(-yaw_frd / 2.0))


def _free_body(client: int, visual: int) -> int:
    """A body with no mass and no collision shape: Bullet never moves it and nothing touches it."""
    return p.createMultiBody(0.0, -1, visual, physicsClientId=client)


class VehicleLook:
    """Base class: `ground_visual` and `base_visual` before the ground and the body are made, `attach` after
    (every world rebuild), `show` before each frame drawn. Subclasses give `_base_shapes()` and
    `_rotor_mounts()`: each rotor's hub (FRD) and radius, and whether it turns with the wing."""

    camera_distance = 3.0    # m, chase camera to the vehicle
    ground_scale = 1.0       # PyBullet's checkered 200 m plane scaled by this: squares of this many metres

    def __init__(self, params):
        self.params = params
        self._rotors, self._painted, self._wing = [], [], None

    def ground_visual(self, client: int) -> int:
        """The ground as drawn: a checkered square of 200 x `ground_scale` m about home (the collision plane's
        own drawing stops at about 100 m)."""
        path = os.path.join(pybullet_data.getDataPath(), "plane100.obj")
        scale = [self.ground_scale, self.ground_scale, 1.0]
        return p.createVisualShape(p.GEOM_MESH, fileName=path, meshScale=scale, physicsClientId=client)

    def base_visual(self, client: int) -> int:
        self._base = self._base_shapes()
        return self._base.create(client)

    def attach(self, client: int, body: int) -> None:
        """Colour the body's shapes and make the rotor discs' (and the wing's) bodies."""
        self._base.paint(client, body, last=BODY)
        self._rotors = []
        for hub, radius, on_wing in self._rotor_mounts():
            visual = p.createVisualShape(p.GEOM_CYLINDER, radius=radius, length=0.006, rgbaColor=list(SPINNING),
                                         physicsClientId=client)
            self._rotors.append((_free_body(client, visual), _flu(hub), on_wing))
        self._painted = [SPINNING] * len(self._rotors)
        wing = self._wing_shapes()
        if wing is not None:
            self._wing = _free_body(client, wing.create(client))
            wing.paint(client, self._wing, last=WING)

    def show(self, client: int, body: int, rotors, skew: float = 0.0) -> None:
        """Place the wing and the rotor discs over the body, and colour the discs by `rotors`' state."""
        position, orientation = p.getBasePositionAndOrientation(body, physicsClientId=client)
        turned = p.multiplyTransforms(position, orientation, (0.0, 0.0, 0.0), _about_z(skew),
                                      physicsClientId=client)
        if self._wing is not None:
            p.resetBasePositionAndOrientation(self._wing, *turned, physicsClientId=client)
        colors = rotor_colors(rotors.effectiveness, rotors.loaded, rotors.omega, self.params.hover_omega)
        for index, ((disc, hub, on_wing), color) in enumerate(zip(self._rotors, colors)):
            frame = turned if on_wing else (position, orientation)
            place = p.multiplyTransforms(*frame, hub, (0.0, 0.0, 0.0, 1.0), physicsClientId=client)
            p.resetBasePositionAndOrientation(disc, *place, physicsClientId=client)
            if self._painted[index] != color:
                p.changeVisualShape(disc, -1, rgbaColor=list(color), physicsClientId=client)
                self._painted[index] = color

    def _wing_shapes(self) -> _Shapes | None:
        return None


class QuadrotorLook(VehicleLook):
    """Body, a nose marker, four arms with motors, and four rotor discs at the parameter set's rotor positions."""

    def __init__(self, params):
        super().__init__(params)
        positions = np.asarray(params.rotor_positions, dtype=float)
        reach = float(np.max(np.hypot(positions[:, 0], positions[:, 1]))) + params.propeller_radius
        self.camera_distance = max(1.0, 3.5 * reach)

    def _base_shapes(self) -> _Shapes:
        prm = self.params
        positions = np.asarray(prm.rotor_positions, dtype=float)
        arm = float(np.min(np.hypot(positions[:, 0], positions[:, 1])))
        height = float(prm.body_size[2])
        shapes = _Shapes()
        shapes.box((0.45 * arm, 0.0, -0.1 * height), (0.08 * arm, 0.12 * arm, 0.15 * height), NOSE)
        for x, y, _ in positions:
            length = math.hypot(x, y)
            shapes.box((x / 2, y / 2, 0.0), (length / 2, 0.06 * arm, 0.08 * height), ARM, yaw=math.atan2(y, x))
            shapes.disc((x, y, -0.25 * height), 0.11 * arm, ARM, thickness=0.3 * height)   # motor
        shapes.box((0.0, 0.0, 0.0), (0.45 * arm, 0.3 * arm, 0.3 * height), BODY)
        return shapes

    def _rotor_mounts(self) -> list:
        height = float(self.params.body_size[2])
        return [((x, y, -0.42 * height), self.params.propeller_radius, False)
                for x, y, _ in np.asarray(self.params.rotor_positions, dtype=float)]


class QuadPlaneLook(VehicleLook):
    """Fuselage, landing gear, tail, pusher, the two fuselage rotors, and the wing with its two arm rotors, which
    `show` turns to the skew angle."""

    def __init__(self, params):
        super().__init__(params)
        self.camera_distance = max(3.0, 2.2 * float(params.wing_span))
        self.ground_scale = 20.0    # the flight box, |north|, |east| <= 2 km, in 20 m squares

    def _base_shapes(self) -> _Shapes:
        prm = self.params
        length, track, height = (float(v) for v in prm.body_size)
        z_rotor = float(prm.hover_rotor_height)
        shapes = _Shapes()
        shapes.box((0.47 * length, 0.0, -0.01), (0.03 * length, 0.04 * length, 0.04 * length), NOSE)
        # landing gear: two skids on the collision box's floor, and their struts
        for side in (-1.0, 1.0):
            shapes.box((0.0, side * track / 2, height / 2 - 0.01), (0.3 * length, 0.01, 0.01), ARM)
            for x in (-0.15 * length, 0.15 * length):
                shapes.box((x, side * track / 4, height / 4), (0.01, track / 4, 0.01), ARM)
        # tail boom, stabilator and fin at the tail arm
        tail = -float(prm.tail_arm)
        shapes.box(((tail - 0.3 * length) / 2, 0.0, -0.02), ((-tail - 0.3 * length) / 2, 0.015, 0.015), ARM)
        shapes.box((tail, 0.0, -0.02), (0.07, float(prm.htail_span) / 2, 0.008), TAIL)
        fin = float(prm.vtail_height)
        shapes.box((tail, 0.0, -0.02 - fin / 2), (0.085, 0.008, fin / 2), TAIL)
        # pusher behind the fuselage, and the spar of the fuselage's hover rotors (0 front, 2 rear)
        shapes.disc((-0.4 * length, 0.0, 0.0), float(prm.pusher_diameter) / 2, ARM, thickness=0.008, axis="x")
        shapes.box((0.0, 0.0, z_rotor + 0.03), (float(prm.hover_fuselage_arm), 0.012, 0.012), ARM)
        shapes.box((0.05 * length, 0.0, 0.0), (0.42 * length, 0.055 * length, 0.055 * length), BODY)
        return shapes

    def _wing_shapes(self) -> _Shapes:
        """In the wing's frame: the body frame turned by the skew about z, so the span lies along x."""
        prm = self.params
        z_rotor = float(prm.hover_rotor_height)
        shapes = _Shapes()
        shapes.box((0.0, 0.0, z_rotor + 0.01), (0.012, float(prm.hover_wing_arm), 0.012), ARM)
        shapes.box((0.0, 0.0, z_rotor + 0.05), (float(prm.wing_span) / 2, float(prm.wing_chord) / 2, 0.012), WING)
        return shapes

    def _rotor_mounts(self) -> list:
        """Rotors 0 front and 2 rear on the fuselage; 1 and 3 on the wing's arm, across the span at +-arm (a
        little above the fuselage's, which they cover when stowed at skew 90 deg)."""
        prm = self.params
        fuselage, wing, z = float(prm.hover_fuselage_arm), float(prm.hover_wing_arm), float(prm.hover_rotor_height)
        radius = float(prm.hover_propeller_diameter) / 2
        return [((fuselage, 0.0, z), radius, False), ((0.0, wing, z - 0.02), radius, True),
                ((-fuselage, 0.0, z), radius, False), ((0.0, -wing, z - 0.02), radius, True)]
