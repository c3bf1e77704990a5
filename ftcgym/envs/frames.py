"""The one place where PyBullet's frames meet the aerospace conventions of the papers.

PyBullet world: X north, Y west, Z up. Public world frame: NED (x north, y east, z down).
PyBullet body: x forward, y left, z up. Public body frame: FRD (x forward, y right, z down).
Both maps are T = diag(1, -1, -1), a rotation of pi about x, so for a body->world rotation
R_ned_frd = T R_pb T, i.e. the quaternion (x, y, z, w) -> (x, -y, -z, w).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

T_FLIP = np.array([1.0, -1.0, -1.0])  # diag(T): PyBullet <-> NED / FRD for vectors


def vec_to_ned(v_pb) -> np.ndarray:
    """A PyBullet world vector in NED (or a PyBullet body vector in FRD)."""
    return np.array((v_pb[0], -v_pb[1], -v_pb[2]))


def quat_to_ned(q_pb) -> np.ndarray:
    """PyBullet body->world quaternion (x, y, z, w) as the FRD->NED quaternion (x, y, z, w)."""
    return np.array((q_pb[0], -q_pb[1], -q_pb[2], q_pb[3]))


def quat_from_ned(q_ned) -> tuple:
    """Inverse of `quat_to_ned` (the map is its own inverse)."""
    return (float(q_ned[0]), -float(q_ned[1]), -float(q_ned[2]), float(q_ned[3]))


@njit(cache=True)
def bullet_matrix(x, y, z, w):  # pragma: no cover (compiled)
    """The rotation matrix of the quaternion (x, y, z, w), row by row, as PyBullet's `getMatrixFromQuaternion`
    computes it (Bullet's btMatrix3x3::setRotation, LinearMath/btMatrix3x3.h: s = 2 / |q|^2, then the products in
    its order), bit for bit (`tests/test_step_cost.py`). Not `models.geometry.rotation_matrix`: that one assumes a
    unit quaternion and rounds otherwise, and the physics step must keep the matrix PyBullet gave it."""
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return (1.0 - (yy + zz), xy - wz, xz + wy, xy + wz, 1.0 - (xx + zz), yz - wx, xz - wy, yz + wx, 1.0 - (xx + yy))


@njit(cache=True)
def body_state(raw):  # pragma: no cover (compiled)
    """The state of a body as PyBullet gives it, `raw` = (position, quaternion, velocity, angular velocity) in its
    world frame (`PyBulletWorld.read_raw`), in NED / FRD: position, quaternion, rotation matrix (9 entries row by
    row), velocity and body rates R^T omega, as tuples of floats. Sign flips only (T R T and the quaternion map
    above) on PyBullet's matrix of the quaternion (`bullet_matrix`), then the body rates. Raises
    FloatingPointError if the state is not finite."""
    (x, y, z), (qx, qy, qz, qw), (u, v, w), (a, b, g) = raw
    if not math.isfinite(x + y + z + u + v + w + a + b + g + qx + qy + qz + qw):
        raise FloatingPointError("physics state became non-finite; please report this as a bug")
    m = bullet_matrix(qx, qy, qz, qw)
    R = (m[0], -m[1], -m[2], -m[3], m[4], m[5], -m[6], m[7], m[8])
    b, g = -b, -g
    rates = (R[0] * a + R[3] * b + R[6] * g, R[1] * a + R[4] * b + R[7] * g, R[2] * a + R[5] * b + R[8] * g)
    return (x, -y, -z), (qx, -qy, -qz, qw), R, (u, -v, -w), rates


@njit(cache=True)
def step_state(raw, raw_before, dt, gravity):  # pragma: no cover (compiled)
    """`body_state` of `raw`, the state after a physics step of `dt` s, then the velocity before it (from
    `raw_before`) and the specific force over it, (dv/dt - g) in the body frame with the attitude R at the
    step's start: PyBullet's semi-implicit step applies the force set with that attitude, so R (not the attitude
    after the step) maps it back exactly; contact forces are included."""
    p, q, R_after, v, rates = body_state(raw)
    _, _, R, v_before, _ = body_state(raw_before)
    d0, d1, d2 = (v[0] - v_before[0]) / dt, (v[1] - v_before[1]) / dt, (v[2] - v_before[2]) / dt - gravity
    specific_force = (R[0] * d0 + R[3] * d1 + R[6] * d2, R[1] * d0 + R[4] * d1 + R[7] * d2,
                      R[2] * d0 + R[5] * d1 + R[8] * d2)
    return p, q, R_after, v, rates, v_before, specific_force


@njit(cache=True)
def to_bullet(loads_ned):  # pragma: no cover (compiled)
    """(force, torque) in PyBullet's world frame from `loads_ned` = (fx, fy, fz, mx, my, mz, ...) NED."""
    return (loads_ned[0], -loads_ned[1], -loads_ned[2]), (loads_ned[3], -loads_ned[4], -loads_ned[5])


#: a state in `PyBulletWorld.read_raw`'s form, to fix the types of the calls that take one (`without_dispatch`)
RAW_EXAMPLE = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
