"""Rotations as Universal Robots writes them: a pose is p[x, y, z, rx, ry, rz], position in metres
and orientation as a rotation vector (axis times angle, rad) in the base frame. Pure numpy."""

from __future__ import annotations

import math

import numpy as np


def rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation matrix of rotation vector r."""
    r = np.asarray(r, dtype=float)
    theta = float(np.linalg.norm(r))
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    out: np.ndarray = np.eye(3) + math.sin(theta) * kx + (1.0 - math.cos(theta)) * (kx @ kx)
    return out


def matrix_to_rotvec(m: np.ndarray) -> np.ndarray:
    """The rotation vector (angle in [0, pi]) of rotation matrix m."""
    m = np.asarray(m, dtype=float)
    c = max(-1.0, min(1.0, (float(np.trace(m)) - 1.0) / 2.0))
    theta = math.acos(c)
    if theta < 1e-9:
        return np.zeros(3)
    if math.pi - theta < 1e-6:
        # near pi: the axis from the symmetric part
        b = (m + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(b)))
        axis = b[:, i] / math.sqrt(max(b[i, i], 1e-300))
        return axis * theta
    w = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    return w * (theta / (2.0 * math.sin(theta)))


def orientation_error(r_target: np.ndarray, r_actual: np.ndarray) -> np.ndarray:
    """The rotation vector (base frame) turning `r_actual` onto `r_target` (both 3 x 3 matrices)."""
    return matrix_to_rotvec(r_target @ r_actual.T)
