"""Which points a stem's range noise can have made (segmentation.stem_noise_points).

A range sensor's beam angle is exact and its range is not: a hit on a stem stays on its
beam however noisy, so a point is the stem's only if its beam meets the stem's column
and the point lies within a few sigma of where the beam enters it.
"""

import numpy as np
import pytest

from plantsim.evaluation import segmentation

AXIS = (0.0, 0.0)
R = 0.007  # a 14 mm stem
Z = (0.0, 0.3)


def _one(point, noise, **kw):
    args = dict(axis_xy_m=AXIS, radius_m=R, z_range_m=Z)
    args.update(kw)
    return bool(segmentation.stem_noise_points(np.array([point]), np.array([noise]), **args)[0])


def test_hand_computed_beams_through_and_beside_the_stem():
    towards_axis = (-0.01, 0.0, 0.0)  # beam along -x, sigma 10 mm: the gate is 30 mm
    # 20 mm out on the beam's line: it enters the column at x = 7 mm, 13 mm further on.
    assert _one((0.02, 0.0, 0.1), towards_axis)
    # 45 mm out: 38 mm before the column, past the 3-sigma gate, inside a 4-sigma one.
    assert not _one((0.045, 0.0, 0.1), towards_axis)
    assert _one((0.045, 0.0, 0.1), towards_axis, gate_sigmas=4.0)
    # Past the axis: a front hit carried 27 mm on along its beam.
    assert _one((-0.02, 0.0, 0.1), towards_axis)
    # The beam passes 8 mm from the axis: it misses a 7 mm column, whatever the range.
    assert not _one((0.02, 0.008, 0.1), towards_axis)
    assert _one((0.02, 0.008, 0.1), towards_axis, radius_m=0.009)
    # The column's axis may be given per point (a leaning stem's at each point's height).
    assert _one((0.03, 0.02, 0.1), towards_axis, axis_xy_m=np.array([[0.01, 0.02]]))
    # A noiseless point is no stem's noise.
    assert not _one((0.007, 0.0, 0.1), (0.0, 0.0, 0.0))


def test_the_height_is_where_the_beam_enters_the_column():
    # A beam falling at 0.6 (down 36.9 deg), sigma 10 mm: from (20 mm, 0, 305 mm) it
    # enters the column 13 / 0.8 = 16.25 mm further on, 9.75 mm lower: at z = 295.25 mm,
    # within the stem (which ends at 300 mm); the point itself lies above the stem's top.
    falling = (-0.008, 0.0, -0.006)
    assert _one((0.02, 0.0, 0.305), falling)
    assert not _one((0.02, 0.0, 0.305), falling, z_range_m=(0.0, 0.295))
    assert not _one((0.02, 0.0, 0.35), (-0.01, 0.0, 0.0))


def _turntable_hits(radius_m, n_angles, z_m, rng, sigma_m=0.01, lidar=(0.35, 0.0, 0.15)):
    """Front hits on a vertical cylinder on the axis, as a vertical fan through the axis
    sees it from every turntable angle, moved along their beams by Gaussian range noise;
    and each point's noise vector (beam direction times sigma)."""
    theta = np.repeat(np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False), len(z_m))
    z = np.tile(z_m, n_angles)
    # The LiDAR seen from the turntable frame turns by -theta.
    sensor = np.column_stack([lidar[0] * np.cos(-theta), lidar[0] * np.sin(-theta), np.full_like(z, lidar[2])])
    hit = np.column_stack([radius_m * np.cos(-theta), radius_m * np.sin(-theta), z])
    d = hit - sensor
    d /= np.linalg.norm(d, axis=1)[:, None]
    return hit + rng.normal(0.0, sigma_m, len(z))[:, None] * d, sigma_m * d, sensor, d


def test_a_noisy_stems_hits_are_its_noise_and_a_leaf_beside_it_is_not():
    rng = np.random.default_rng(0)
    z = np.linspace(0.05, 0.25, 40)
    stem, noise, _, _ = _turntable_hits(R, 360, z, rng)
    # Spread into a disc several centimetres wide...
    assert np.percentile(np.hypot(stem[:, 0], stem[:, 1]), 95) > 0.02
    # ... every hit is on a beam through the column, 99.73 % within 3 sigma of its entry.
    share = segmentation.stem_noise_points(stem, noise, axis_xy_m=AXIS, radius_m=R, z_range_m=Z).mean()
    assert share == pytest.approx(0.9973, abs=0.002)
    # A strip of leaf 60-150 mm out, seen by the same fan: its beams cross the column too
    # (the fan's plane holds the axis), but the points lie 53 mm or more before it.
    r = rng.uniform(0.06, 0.15, 5000)
    theta = rng.uniform(0.0, 2 * np.pi, 5000)
    leaf = np.column_stack([r * np.cos(-theta), r * np.sin(-theta), np.full(5000, 0.1)])
    sensor = np.column_stack([0.35 * np.cos(-theta), 0.35 * np.sin(-theta), np.full(5000, 0.15)])
    d = leaf - sensor
    d /= np.linalg.norm(d, axis=1)[:, None]
    leaf_noisy = leaf + rng.normal(0.0, 0.01, 5000)[:, None] * d
    share = segmentation.stem_noise_points(leaf_noisy, 0.01 * d, axis_xy_m=AXIS, radius_m=R, z_range_m=Z).mean()
    assert share < 0.01


def test_bad_input_is_refused():
    pts, noise = np.zeros((2, 3)), np.full((2, 3), 0.01)
    call = segmentation.stem_noise_points
    with pytest.raises(ValueError, match="range_noise_m"):
        call(pts, noise[:1], axis_xy_m=AXIS, radius_m=R, z_range_m=Z)
    with pytest.raises(ValueError, match="radius_m"):
        call(pts, noise, axis_xy_m=AXIS, radius_m=0.0, z_range_m=Z)
    with pytest.raises(ValueError, match="z_range_m"):
        call(pts, noise, axis_xy_m=AXIS, radius_m=R, z_range_m=(0.3, 0.0))
