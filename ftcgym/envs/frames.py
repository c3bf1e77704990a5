"""The one place where PyBullet's frames meet the aerospace conventions of the papers.

PyBullet world: X north, Y west, Z up. Public world frame: NED (x north, y east, z down).
PyBullet body: x forward, y left, z up. Public body frame: FRD (x forward, y right, z down).
Both maps are T = diag(1, -1, -1), a rotation of pi about x, so for a body->world rotation
R_ned_frd = T R_pb T, i.e. the quaternion (x, y, z, w) -> (x, -y, -z, w).
"""
from __future__ import annotations

import numpy as np

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


def cross(a, b) -> np.ndarray:
    """3-vector cross product (np.cross's generic axis handling costs ~10 us a call on 3-vectors)."""
    return np.array((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]))


def rotation_matrix(q) -> np.ndarray:
    """Body->world rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of the ZYX (yaw, pitch, roll) Euler angles."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


def euler_from_quat(q) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])
