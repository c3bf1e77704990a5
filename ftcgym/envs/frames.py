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
