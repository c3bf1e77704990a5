"""Rotation math shared by the simulator, the detectors and the controllers (numpy and numba, no simulator).

Quaternions are (x, y, z, w), scalar last, as in PyBullet and scipy; matrices rotate body vectors into the
world. Euler angles are ZYX (yaw, pitch, roll), as in the papers: R = Rz(psi) Ry(theta) Rx(phi).

Functions marked `register_jitable` run as plain Python/numpy when called from Python and are compiled into the
numba code that calls them (the detectors' and controllers' steps), with the same bits: the same source,
elementwise arithmetic only.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable


@register_jitable
def cross3(a, b) -> tuple:
    """3-vector cross product a x b as a tuple of floats (the fastest form for plain-float callers)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def cross(a, b) -> np.ndarray:
    """3-vector cross product as an array (np.cross's generic axis handling costs ~10 us a call on 3-vectors)."""
    return np.array(cross3(a, b))


@register_jitable
def skew_matrix(a) -> np.ndarray:
    """[a]x, the matrix with [a]x b = a x b."""
    return np.array(((0.0, -a[2], a[1]), (a[2], 0.0, -a[0]), (-a[1], a[0], 0.0)))


@register_jitable
def rotation_matrix(q) -> np.ndarray:
    """Body->world rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


@register_jitable
def rotation_from_euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body->world rotation Rz(psi) Ry(theta) Rx(phi) of ZYX Euler angles."""
    cf, sf, ct, st, cp, sp = (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
                              math.cos(psi), math.sin(psi))
    return np.array(((ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp),
                     (ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp),
                     (-st, sf * ct, cf * ct)))


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


@register_jitable
def euler_from_quat(q) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) of a quaternion (x, y, z, w); pitch is clipped to +-90 deg."""
    x, y, z, w = q
    return np.array((math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
                     math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0)),
                     math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))))


@njit(cache=True)
def blas_dot(a, b):  # pragma: no cover (compiled)
    """a . b of two vectors (tuples or arrays) as numpy's `a @ b` on float64 arrays: BLAS's ddot, whose
    pairings (and fused multiply-adds, where its kernel has them) a plain Python sum need not reproduce."""
    x, y = np.empty(len(a)), np.empty(len(b))
    for i in range(len(a)):
        x[i] = a[i]
    for i in range(len(b)):
        y[i] = b[i]
    return np.dot(x, y)
