"""The PyBullet world of one vehicle: a client, the ground and one rigid body, rebuilt on every reset.

Bodies are built from the parameter set (box collision shape, mass, principal inertia), not URDF tags,
so every number stays visible in `vehicles.py`. Inputs and outputs are NED / FRD (see `frames`), except the
physics step's (`advance`, `read_raw`): it stays in PyBullet's frame, which `frames` maps once per agent step.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import weakref

import numpy as np

from ..models.constants import GRAVITY
from ..models.geometry import rotation_matrix
from .frames import quat_from_ned, vec_to_ned


@contextlib.contextmanager
def _stderr_silenced():
    """PyBullet prints its build time to stderr when imported: noise in every CLI run and worker."""
    sys.stderr.flush()
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)  # flush C stdio while it still points at devnull
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


with _stderr_silenced():
    import pybullet as p

# The calls of every physics step (`read`, `step`) pass their arguments by position: PyBullet parses keywords
# by looking each one up by name, which costs more than the call's own work for these small requests.
_get_pose, _get_velocity = p.getBasePositionAndOrientation, p.getBaseVelocity
_apply_force, _apply_torque, _step = p.applyExternalForce, p.applyExternalTorque, p.stepSimulation
_WORLD_FRAME = p.WORLD_FRAME


#: builds that renew the body alone between two full builds (`PyBulletWorld._build`)
RENEWALS = 200


class PyBulletWorld:
    """One PyBullet client stepping one rigid body at a fixed rate."""

    def __init__(self, physics_hz: float, mass: float, inertia, body_size, gui: bool = False, look=None):
        self.client = p.connect(p.GUI if gui else p.DIRECT)
        # Disconnects when the world is collected: an env dropped without close() releases its client.
        self._release = weakref.finalize(self, _disconnect, self.client)
        self.physics_hz, self.body_size = physics_hz, body_size
        self.look = look     # what a frame shows of the vehicle (`visuals`); None: a plain box
        self.mass = mass
        self.inertia = list(inertia)
        self.half_height = body_size[2] / 2
        self._kept = None    # (body size, collision shape, visual shape) that the next build may reuse
        self._renewals = 0   # bodies made anew since the last full build
        self._build()

    def _build(self) -> None:
        """The ground plane and the vehicle's box, in a freshly reset simulation, drawn as its look (visual
        shapes only: the collision box, mass and inertia are the same with and without one).

        Without a look, a build between two full ones keeps the ground and the box's shapes and makes only the
        body anew (`_renew_body`), at a sixth of the cost: the steps are the same (a new body starts without the
        contact caches of the last one). PyBullet keeps about 1 kB of each removed body until the simulation is
        reset, so every `RENEWALS`-th build is a full one."""
        c = self.client
        if (self.look is None and self._kept is not None and self._kept[0] == tuple(self.body_size)
                and self._renewals < RENEWALS):
            self._renew_body()
            return
        p.resetSimulation(physicsClientId=c)
        p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=c)
        p.setTimeStep(1.0 / self.physics_hz, physicsClientId=c)
        ground = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
        drawn = -1 if self.look is None else self.look.ground_visual(c)   # -1: the collision plane is drawn
        self.ground = p.createMultiBody(0.0, ground, drawn, physicsClientId=c)
        half = [s / 2 for s in self.body_size]
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c)
        if self.look is None:
            visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.2, 0.3, 0.8, 1],
                                         physicsClientId=c)
            self._kept = (tuple(self.body_size), shape, visual)
        else:
            visual = self.look.base_visual(c)
            self._kept = None
        self._renewals = 0
        self._make_body(shape, visual)
        if self.look is not None:
            self.look.attach(c, self.body)

    def _renew_body(self) -> None:
        """Replace the body with a new one of the kept shapes."""
        p.removeBody(self.body, physicsClientId=self.client)
        self._renewals += 1
        self._make_body(*self._kept[1:])

    def _make_body(self, shape: int, visual: int) -> None:
        c = self.client
        self.body = p.createMultiBody(self.mass, shape, visual, basePosition=[0, 0, 1], physicsClientId=c)
        # Aerodynamic damping is modelled explicitly; Bullet's default damping would add an unmodelled drag.
        p.changeDynamics(self.body, -1, localInertiaDiagonal=self.inertia, linearDamping=0.0,
                         angularDamping=0.0, lateralFriction=0.8, restitution=0.0, physicsClientId=c)

    def reset(self, position, quat, velocity, body_rates) -> None:
        """Rebuild the world and place the body. A rebuild, not restoreState: Bullet keeps caches that
        saveState does not hold (the first episode after construction stepped differently from the later ones
        when the vehicle started on the ground), and a seeded reset must give the same steps every time."""
        c = self.client
        self._build()
        p.resetBasePositionAndOrientation(self.body, vec_to_ned(position).tolist(), quat_from_ned(quat),
                                          physicsClientId=c)
        rates_world = rotation_matrix(quat) @ np.asarray(body_rates, dtype=float)
        p.resetBaseVelocity(self.body, vec_to_ned(velocity).tolist(), vec_to_ned(rates_world).tolist(),
                            physicsClientId=c)

    def set_body(self, mass: float, inertia, body_size, look=None) -> None:
        """The body the next `reset` builds (a new episode's parameter set) and its look."""
        self.mass, self.inertia, self.body_size, self.look = mass, list(inertia), body_size, look
        self.half_height = body_size[2] / 2

    def set_mass(self, mass: float) -> None:
        """Change the mass, keeping the parameter set's inertia (a point payload at the centre of mass).

        PyBullet recomputes the inertia from the collision box whenever the mass changes, so it is set again.
        """
        p.changeDynamics(self.body, -1, mass=mass, localInertiaDiagonal=self.inertia, physicsClientId=self.client)

    def read_raw(self) -> tuple:
        """The body's state as PyBullet gives it, in its world frame (z up): (position, quaternion x y z w,
        velocity, angular velocity), tuples of floats; `frames.body_state` gives it in NED / FRD, with the
        rotation matrix PyBullet would give (`frames.bullet_matrix`). The physics step keeps the state in this
        form and converts it once per agent step."""
        c = self.client
        position, orientation = _get_pose(self.body, c)      # (bodyUniqueId, physicsClientId)
        velocity, rates = _get_velocity(self.body, c)
        return position, orientation, velocity, rates

    def advance(self, force, torque, position) -> tuple:
        """One physics step: apply `force` at `position` (the centre of mass) and `torque`, all in PyBullet's world
        frame (`frames.to_bullet`), step, and return the new state as `read_raw` does."""
        c, body = self.client, self.body
        # (objectUniqueId, linkIndex, force or torque, [position,] flags, physicsClientId)
        _apply_force(body, -1, force, position, _WORLD_FRAME, c)
        _apply_torque(body, -1, torque, _WORLD_FRAME, c)
        _step(c)
        position, orientation = _get_pose(body, c)               # `read_raw`, inline: once per physics step
        return (position, orientation, *_get_velocity(body, c))

    def touching_ground(self) -> bool:
        return bool(p.getContactPoints(self.body, self.ground, physicsClientId=self.client))

    def show(self, rotors, skew: float = 0.0) -> None:
        """Bring the look up to date before a frame is drawn: rotor colours from `rotors` (effectiveness,
        loaded, omega) and the wing at `skew`. Nothing without a look."""
        if self.look is not None:
            self.look.show(self.client, self.body, rotors, skew)

    def camera_image(self, target_ned, width: int = 480, height: int = 360) -> np.ndarray:
        """An RGB image from a chase camera looking at `target_ned` from a fixed direction 25 deg above
        the horizon, at the look's distance (TinyRenderer, works headless)."""
        c = self.client
        target = [target_ned[0], -target_ned[1], -target_ned[2]]
        distance = 3.0 if self.look is None else self.look.camera_distance
        view = p.computeViewMatrixFromYawPitchRoll(target, distance, 45.0, -25.0, 0.0, 2, physicsClientId=c)
        proj = p.computeProjectionMatrixFOV(60.0, width / height, 0.05, 2000.0, physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                            physicsClientId=c)
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    def close(self) -> None:
        self._release()
        self.client = None


def _disconnect(client: int) -> None:
    if p.isConnected(client):
        p.disconnect(client)

