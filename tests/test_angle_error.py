"""The angle-error metric: point displacement between true-angle and believed-angle reconstructions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plantsim.evaluation.angle_error import angle_error_displacement, max_believed_minus_true_rad


def lidar_at(x_m: float) -> np.ndarray:
    """A LiDAR at (x, 0, 0) looking along -x in the base x-y plane (beam 0 = -x)."""
    T = np.eye(4)
    T[:3, :3] = [[-1, 0, 0], [0, -1, 0], [0, 0, 1]]
    T[0, 3] = x_m
    return T


def test_displacement_is_the_chord_of_the_angle_error():
    # Beams straight at the axis from 0.5 m, returns at radius r from the axis: a point
    # at radius r turned by d moves 2 r sin(d / 2), whatever the beam.
    radius = np.array([[0.1, 0.2, 0.3], [0.05, 0.15, 0.25]])
    ranges = 0.5 - radius
    true = np.array([[0.0, 0.5, 1.0], [2.0, 3.0, 4.0]])
    error = np.array([[0.01, -0.02, 0.03], [0.0, 0.05, -0.01]])
    out = angle_error_displacement(ranges, np.zeros(3), lidar_at(0.5), true, true + error)
    chord = 2 * radius * np.abs(np.sin(error / 2))
    assert out["n_points"] == 6
    assert out["displacement_max_m"] == pytest.approx(chord.max())
    assert out["displacement_mean_m"] == pytest.approx(chord.mean())
    assert out["angle_error_max_rad"] == pytest.approx(0.05)


def test_no_returns_and_masks():
    ranges = np.array([[np.inf, 0.3], [np.nan, 0.2]])
    true = np.zeros((2, 2))
    out = angle_error_displacement(ranges, np.zeros(2), lidar_at(0.5), true, true + 0.1,
                                   valid=np.array([[True, False], [True, False]]))
    assert out["n_points"] == 0 and out["displacement_max_m"] == 0.0
    with pytest.raises(ValueError, match=r"true_angle_rad \(2, 2\) and believed_angle_rad \(3,\) must match"):
        angle_error_displacement(ranges, np.zeros(2), lidar_at(0.5), true, np.zeros(3))
    with pytest.raises(ValueError, match="T_base_lidar must be 4x4"):
        angle_error_displacement(ranges, np.zeros(2), np.eye(3), true, true)


def test_max_believed_minus_true():
    assert max_believed_minus_true_rad(np.zeros(4), np.array([0.0, -0.3, 0.1, np.nan])) == pytest.approx(0.3)
    assert max_believed_minus_true_rad(np.zeros(0), np.zeros(0)) == 0.0
    with pytest.raises(ValueError, match="same shape"):
        max_believed_minus_true_rad(np.zeros(2), np.zeros(3))
    assert math.isfinite(max_believed_minus_true_rad(np.ones((2, 2)), np.ones((2, 2))))
