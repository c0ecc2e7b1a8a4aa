"""How far the turntable-angle error moves the points: true angles against believed ones.

Point-to-mesh distance understates an angle error (a point displaced along a
leaf stays on the leaf; about 3x on the seed maize). This metric reconstructs
every return twice, with the table's true angle at its beam's time and with the
angle the reconstruction believed (interpolated encoder readings), and measures
how far each point moved. It needs only the raw record's arrays, no mesh.
"""

from __future__ import annotations


import numpy as np

from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges


def max_believed_minus_true_rad(true_rad: np.ndarray, believed_rad: np.ndarray) -> float:
    """Largest |believed - true| turntable angle, radians (0 for no beams; NaNs ignored).

    Args:
      true_rad, believed_rad: same-shaped float arrays, radians (e.g.
        (n_lines, n_beams)).

    Raises:
      ValueError: the shapes differ.
    """
    true_rad, believed_rad = np.asarray(true_rad, dtype=np.float64), np.asarray(believed_rad, dtype=np.float64)
    if true_rad.shape != believed_rad.shape:
        raise ValueError(f"true_rad {true_rad.shape} and believed_rad {believed_rad.shape} must have the same shape")
    diff = np.abs(believed_rad - true_rad)
    diff = diff[np.isfinite(diff)]
    return float(diff.max()) if diff.size else 0.0


def angle_error_displacement(range_m: np.ndarray, beam_angle_rad: np.ndarray, T_base_lidar: np.ndarray,
                             true_angle_rad: np.ndarray, believed_angle_rad: np.ndarray,
                             valid: np.ndarray | None = None) -> dict:
    """Displacement of each return between reconstructions with true and believed angles.

    Args:
      range_m: (n_lines, n_beams) or (n,) float64, metres (NaN/inf = no return).
      beam_angle_rad: (n_beams,) or same shape as ``range_m``, radians, lidar frame.
      T_base_lidar: (4, 4) float64, the LiDAR's pose in the base frame.
      true_angle_rad: same shape as ``range_m``, the table's true angle at each
        beam's time, radians.
      believed_angle_rad: same shape, the angle the reconstruction used, radians.
      valid: optional bool mask of the same shape (e.g. status OK); default
        every finite, positive range.

    Returns:
      JSON-able dict: ``n_points``, ``displacement_mean_m``, ``displacement_p50_m``,
      ``displacement_p95_m``, ``displacement_p99_m``, ``displacement_max_m`` (metres,
      turntable frame) and ``angle_error_max_rad``; zeros when there are no points.

    Raises:
      ValueError: shapes that do not match, or a T_base_lidar that is not 4x4.
    """
    r = np.asarray(range_m, dtype=np.float64)
    true_a = np.asarray(true_angle_rad, dtype=np.float64)
    bel_a = np.asarray(believed_angle_rad, dtype=np.float64)
    T = np.asarray(T_base_lidar, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T_base_lidar must be 4x4, got {T.shape}")
    if true_a.shape != r.shape or bel_a.shape != r.shape:
        raise ValueError(f"true_angle_rad {true_a.shape} and believed_angle_rad {bel_a.shape} must match "
                         f"range_m {r.shape}")
    beams = np.broadcast_to(np.asarray(beam_angle_rad, dtype=np.float64), r.shape)
    mask = np.isfinite(r) & (r > 0) & np.isfinite(true_a) & np.isfinite(bel_a)
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != r.shape:
            raise ValueError(f"valid {valid.shape} must match range_m {r.shape}")
        mask &= valid
    keys = ("displacement_mean_m", "displacement_p50_m", "displacement_p95_m", "displacement_p99_m",
            "displacement_max_m", "angle_error_max_rad")
    n = int(mask.sum())
    if n == 0:
        return {"n_points": 0, **{k: 0.0 for k in keys}}
    if np.array_equal(true_a[mask], bel_a[mask]):
        # The same angles give the same points bit for bit: every displacement is exactly 0
        # (a perfect encoder), without reconstructing the cloud twice.
        return {"n_points": n, **{k: 0.0 for k in keys}}
    p_base = points_base_from_ranges(r[mask], beams[mask], T)
    d = np.linalg.norm(base_to_turntable(p_base, true_a[mask]) - base_to_turntable(p_base, bel_a[mask]), axis=1)
    p50, p95, p99 = np.percentile(d, [50, 95, 99])
    return {"n_points": n, "displacement_mean_m": float(d.mean()), "displacement_p50_m": float(p50),
            "displacement_p95_m": float(p95), "displacement_p99_m": float(p99),
            "displacement_max_m": float(d.max()),
            "angle_error_max_rad": max_believed_minus_true_rad(true_a[mask], bel_a[mask])}


__all__ = ["angle_error_displacement", "max_believed_minus_true_rad"]
