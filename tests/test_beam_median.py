"""Points moved along their own beams onto their neighbours' surface (traits.beam_median_points),
and the plant height read from them (issue 13: a LiDAR looking down on a flat plant spreads
its top into a band of noise several voxels deep)."""

import math

import numpy as np
import pytest

from plantsim.evaluation import segmentation, traits

DOWN_45 = np.array([-math.sqrt(0.5), 0.0, -math.sqrt(0.5)])  # a beam from out and above, 45 deg down


def sheet(z_m=0.1, spacing_m=0.002, side_m=0.08):
    """A horizontal square of points on a grid, 20-100 mm out from the axis along x."""
    u = np.arange(0.0, side_m + 1e-12, spacing_m)
    x, y = np.meshgrid(0.02 + u, u - side_m / 2)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z_m)])


def noisy(points, sigma_m, seed, direction=DOWN_45):
    """Range noise along one beam direction: each point moved by N(0, sigma) along it."""
    e = np.random.default_rng(seed).normal(0.0, sigma_m, len(points))
    noise = np.tile(sigma_m * direction, (len(points), 1))
    return points + e[:, None] * direction, noise


def test_a_noise_free_plane_stays_where_it_is():
    # Every interior point's cylinder holds the grid symmetrically round it: the median offset
    # along the beam is exactly 0, whatever the beam's slant to the plane.
    pts = sheet()
    noise = np.tile(0.01 * DOWN_45, (len(pts), 1))
    moved = traits.beam_median_points(pts, noise, radius_m=0.004)
    interior = (np.abs(pts[:, 0] - 0.06) < 0.03) & (np.abs(pts[:, 1]) < 0.03)
    assert np.abs(moved[interior] - pts[interior]).max() < 1e-12


def test_points_move_only_along_their_beams_and_onto_the_surface():
    truth = sheet()
    pts, noise = noisy(truth, 0.010, seed=1)
    moved = traits.beam_median_points(pts, noise, radius_m=0.004)
    shift = moved - pts
    # Along the beam only: the lateral position a beam angle fixes is kept.
    assert np.abs(np.cross(shift, DOWN_45)).max() < 1e-12
    z_before = np.std(pts[:, 2] - 0.1)
    z_after = np.std(moved[:, 2] - 0.1)
    assert z_before == pytest.approx(0.010 * math.sqrt(0.5), rel=0.1)
    # A median of about 12 neighbours in a 4 mm cylinder: the noise falls by more than half.
    assert z_after < 0.5 * z_before
    assert abs(np.mean(moved[:, 2]) - 0.1) < 0.001


def test_a_stray_point_and_a_noiseless_point_keep_their_place():
    pts, noise = noisy(sheet(), 0.010, seed=2)
    stray = np.array([[0.06, 0.0, 0.3]])
    pts = np.vstack([pts, stray, [[0.06, 0.001, 0.1]]])
    noise = np.vstack([noise, [0.01 * DOWN_45], [[0.0, 0.0, 0.0]]])
    moved = traits.beam_median_points(pts, noise, radius_m=0.004)
    assert np.array_equal(moved[-2:], pts[-2:])
    only = np.zeros(len(pts), dtype=bool)
    only[:10] = True
    part = traits.beam_median_points(pts, noise, radius_m=0.004, moved=only)
    assert np.array_equal(part[10:], pts[10:]) and np.array_equal(part[:10], moved[:10])


def test_bad_beam_median_input_is_refused():
    pts, noise = noisy(sheet(), 0.010, seed=0)
    with pytest.raises(ValueError, match="range_noise_m must be finite and shaped like"):
        traits.beam_median_points(pts, noise[:-1], radius_m=0.004)
    with pytest.raises(ValueError, match="radius_m must be a length > 0"):
        traits.beam_median_points(pts, noise, radius_m=0.0)
    with pytest.raises(ValueError, match="gate_sigmas must be > 0"):
        traits.beam_median_points(pts, noise, radius_m=0.004, gate_sigmas=0.0)
    with pytest.raises(ValueError, match="moved must be one bool a point"):
        traits.beam_median_points(pts, noise, radius_m=0.004, moved=np.ones(3, dtype=bool))
    bad = noise.copy()
    bad[3, 0] = np.nan
    with pytest.raises(ValueError, match="range_noise_m must be finite"):
        traits.robust_height(pts, range_noise_m=bad)


def test_a_top_seen_from_above_reads_its_height_not_its_noise():
    """A sheet 100 mm up seen by beams 45 deg down with 10 mm range noise (7 mm in z): the
    voxel count alone reads it 10-14 mm high; moved along the beams, the noise left (1.6 mm in
    z) lifts the top voxel of 1681 points by 2-5 mm."""
    for seed in range(3):
        pts, noise = noisy(sheet(), 0.010, seed=seed)
        raw = traits.robust_height(pts)
        moved = traits.robust_height(pts, range_noise_m=noise)
        assert raw - 0.1 > 0.008
        assert 0.0 < moved - 0.1 < min(0.005, 0.4 * (raw - 0.1))
        # Zeros are an ideal scan's noise: the points as they are.
        assert traits.robust_height(pts, range_noise_m=np.zeros_like(pts)) == raw


def test_only_the_points_that_can_reach_the_top_are_moved_and_that_changes_nothing():
    # Two sheets: the top one read with the band of points that can reach it moved, and with
    # every point moved, on several grids, gives the same heights.
    low, low_noise = noisy(sheet(z_m=0.05), 0.010, seed=5)
    high, high_noise = noisy(sheet(z_m=0.1, side_m=0.03), 0.010, seed=6)
    pts, noise = np.vstack([low, high]), np.vstack([low_noise, high_noise])
    scale = segmentation.kept_points(pts)[1]
    offsets = [o[:3] for o in segmentation.shifted_grid_offsets(4)]
    banded = traits.heights_over_grids(pts, scale=scale, grid_offsets=offsets, range_noise_m=noise)
    everything = traits.beam_median_points(pts, noise, radius_m=2.0 * scale.spacing_m)
    plain = traits.heights_over_grids(everything, scale=scale, grid_offsets=offsets)
    assert banded == plain
    for o, h in zip(offsets, banded):
        assert h == traits.robust_height(pts, scale=scale, grid_offset=tuple(o), range_noise_m=noise)
        assert abs(h - 0.1) < 0.003
