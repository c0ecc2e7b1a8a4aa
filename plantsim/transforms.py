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


def translation_quat_xyzw(T_a_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rigid transform as a translation (3,) and a unit quaternion (x, y, z, w), as ROS's TF
    carries it (Shepperd's method: the largest of the four candidates is computed first, so
    the division is well conditioned)."""
    R = np.asarray(T_a_b, dtype=np.float64)[:3, :3]
    t = np.asarray(T_a_b, dtype=np.float64)[:3, 3].copy()
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    candidates = [trace, R[0, 0], R[1, 1], R[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return t, (q if q[3] >= 0 else -q)


def T_from_translation_quat_xyzw(translation: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """The 4x4 transform of a translation and a quaternion (x, y, z, w; normalised here)."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=np.float64) / np.linalg.norm(quat_xyzw)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    return make_T(R, np.asarray(translation, dtype=np.float64))
