"""Rigid transforms as 4x4 homogeneous matrices, named by their two frames.

``T_a_b`` maps points expressed in frame ``b`` into frame ``a``, so composition
cancels the inner names: ``T_base_lidar = T_base_mount @ T_mount_lidar``.
Everything here is pure: arrays in, arrays out, radians and metres.
"""

from __future__ import annotations

import numpy as np


def rot_x(angle_rad: float) -> np.ndarray:
    """Rotation about +X by ``angle_rad`` (right hand). Returns (3, 3) float64."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation about +Y by ``angle_rad`` (right hand). Returns (3, 3) float64."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    """Rotation about +Z by ``angle_rad`` (right hand). Returns (3, 3) float64."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_z_batch(angles_rad: np.ndarray) -> np.ndarray:
    """Rotations about +Z, one per angle.

    Args:
      angles_rad: (n,) float64, radians.

    Returns:
      (n, 3, 3) float64.
    """
    angles_rad = np.asarray(angles_rad, dtype=np.float64)
    c, s = np.cos(angles_rad), np.sin(angles_rad)
    R = np.zeros(angles_rad.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    R[..., 2, 2] = 1.0
    return R


def make_T(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """A 4x4 transform from a rotation (3, 3) and a translation (3,), metres."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def invert_T(T_a_b: np.ndarray) -> np.ndarray:
    """Returns ``T_b_a`` for a rigid ``T_a_b`` (no general matrix inverse)."""
    R, t = T_a_b[:3, :3], T_a_b[:3, 3]
    return make_T(R.T, -R.T @ t)


def apply_T(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Maps points from frame b to frame a.

    Args:
      T_a_b: (4, 4) float64.
      points_b: (n, 3) float64, frame b.

    Returns:
      points_a: (n, 3) float64, frame a.
    """
    points_b = np.asarray(points_b, dtype=np.float64)
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def scale_T(scale: float) -> np.ndarray:
    """A uniform scaling as a 4x4 matrix (for unit conversion of a mesh file)."""
    T = np.eye(4)
    T[:3, :3] *= scale
    return T
