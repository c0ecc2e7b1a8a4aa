"""traits.across_beam_width: a leaf's width read across its beams, which the range noise
does not move.

The fixtures are analytic strips running out from the turntable's axis, as a rig's
beams see them: each point hit from the LiDAR's side of the axis or from the far side,
its beam in the plane through the axis and the point, and moved along that beam by
Gaussian range noise. A strip twisted about its midrib shows its width tilted out of
the turn direction; the width is known exactly.
"""

import math

import numpy as np
import pytest

from plantsim.evaluation import segmentation, traits

LIDAR_DISTANCE_M = 0.35
LIDAR_HEIGHT_M = 0.0


def _beams_to(points):
    """Unit beam directions to ``points`` from a LiDAR ``LIDAR_DISTANCE_M`` from the
    axis whose scan plane holds the axis: the near side's beam runs in towards the
    axis, the far side's out from it (the LiDAR across the axis), alternately."""
    radial = points[:, :2] / np.linalg.norm(points[:, :2], axis=1)[:, None]
    r = np.linalg.norm(points[:, :2], axis=1)
    near = np.arange(len(points)) % 2 == 0
    horizontal = np.where(near, -(LIDAR_DISTANCE_M - r), LIDAR_DISTANCE_M + r)
    beams = np.column_stack([horizontal[:, None] * radial, points[:, 2] - LIDAR_HEIGHT_M])
    return beams / np.linalg.norm(beams, axis=1)[:, None]


def _radial_strip(rng, width_m, twist_deg, sigma_m, n, *, r0=0.05, length_m=0.2, z_m=0.2):
    """A strip ``width_m`` wide running out along +x from ``r0``, ``z_m`` up, twisted
    ``twist_deg`` about its midrib (its width tilted from +y towards +z); its points
    moved by ``sigma_m`` of range noise along their beams. The points and each point's
    noise vector (beam direction times ``sigma_m``)."""
    phi = math.radians(twist_deg)
    x = rng.uniform(r0, r0 + length_m, n)
    s = rng.uniform(-width_m / 2, width_m / 2, n)
    true = np.column_stack([x, s * math.cos(phi), z_m + s * math.sin(phi)])
    beams = _beams_to(true)
    noisy = true + rng.normal(0.0, sigma_m, n)[:, None] * beams
    return noisy, sigma_m * beams


def _cross_section(points, beams, x_lo=0.14, x_hi=0.16):
    member = (points[:, 0] >= x_lo) & (points[:, 0] < x_hi)
    return points[member] - points[member].mean(axis=0), beams[member]


@pytest.mark.parametrize("twist_deg", [0.0, 30.0, 45.0])
def test_a_twisted_strip_reads_its_width_under_noise_that_widens_its_points(twist_deg):
    # A 10 mm strip under 10 mm of range noise (a wheat leaf on a URG-04LX): the
    # points' spread across the midrib reads the noise; across the beams, the width.
    rng = np.random.default_rng(int(twist_deg))
    pts, noise = _radial_strip(rng, 0.010, twist_deg, 0.010, 40_000)
    q, beams = _cross_section(pts, noise)
    width = traits.across_beam_width(q, beams, np.array([1.0, 0.0, 0.0]))
    assert width == pytest.approx(0.010, rel=0.08)
    # The points' own widest spread across the midrib, as node_frames reads it: twice
    # the width or more.
    axis = np.linalg.svd(q[:, 1:], full_matrices=False)[2][0]
    assert segmentation.uniform_width(q[:, 1:] @ axis) > 2.0 * 0.010


def test_the_width_is_the_same_with_and_without_noise_on_a_flat_strip():
    # Points without noise, said to have 1 mm: every beam meets the strip's plane at its
    # point, and the width is the strip's to the sampling (uniform_width's bias taken out).
    rng = np.random.default_rng(5)
    pts, _ = _radial_strip(rng, 0.040, 0.0, 0.0, 40_000)
    section = pts[(pts[:, 0] >= 0.14) & (pts[:, 0] < 0.16)]
    width = traits.across_beam_width(section - section.mean(axis=0), 0.001 * _beams_to(section),
                                     np.array([1.0, 0.0, 0.0]))
    assert width == pytest.approx(0.040, rel=0.02)


def test_beams_that_cannot_read_the_width_read_nothing():
    rng = np.random.default_rng(1)
    t = np.array([1.0, 0.0, 0.0])
    pts, noise = _radial_strip(rng, 0.010, 0.0, 0.010, 40_000)
    q, beams = _cross_section(pts, noise)
    # Beams along the midrib leave no direction across both.
    along_midrib = np.tile([0.010, 0.0, 0.0005], (len(q), 1))
    assert math.isnan(traits.across_beam_width(q, along_midrib, t))
    # Too few points; a beam direction of length 0.
    assert math.isnan(traits.across_beam_width(q[:5], beams[:5], t))
    assert math.isnan(traits.across_beam_width(q, np.zeros_like(q), t))
    # A flat 40 mm strip whose every beam runs along its width (8 mm of noise): no plane
    # explains its points' spread along the beams as the noise (a sliver across the
    # beams leaves the width's share, 1 + 0.04^2 / (12 * 0.008^2) = 3.1 sigma^2).
    n = 4000
    across = np.column_stack([rng.uniform(0.14, 0.16, n), rng.uniform(-0.02, 0.02, n), np.zeros(n)])
    across[:, 1] += rng.normal(0.0, 0.008, n)
    along_width = np.tile([0.0, 0.008, 0.0], (n, 1))
    assert math.isnan(traits.across_beam_width(across - across.mean(axis=0), along_width, t))
    # A 10 mm strip under 10 mm of noise, every beam along its width: its width adds
    # little to the spread along the beams (1 + 0.01^2 / (12 * 0.01^2) = 1.08 sigma^2),
    # but the beams all lie in its plane and meet any other plane through the midrib
    # on one line: the twist is free, and the width (0 on any such plane) is not read.
    narrow = np.column_stack([rng.uniform(0.14, 0.16, n), rng.uniform(-0.005, 0.005, n), np.zeros(n)])
    narrow[:, 1] += rng.normal(0.0, 0.010, n)
    assert math.isnan(traits.across_beam_width(narrow - narrow.mean(axis=0), np.tile([0.0, 0.010, 0.0], (n, 1)), t))
    # The same with the beams crossing it at 60 deg from both sides: they read it.
    b = np.where((np.arange(n) % 2 == 0)[:, None], [0.0, 0.5, math.sqrt(0.75)], [0.0, -0.5, math.sqrt(0.75)])
    true = across.copy()
    true[:, 1] = rng.uniform(-0.02, 0.02, n)
    seen = true + rng.normal(0.0, 0.008, n)[:, None] * b
    assert traits.across_beam_width(seen - seen.mean(axis=0), 0.008 * b, t) == pytest.approx(0.040, rel=0.05)


def test_a_cross_section_no_plane_explains_reads_nothing():
    # A 20 mm stem's cross-section under 2 mm of noise, its beams from both sides at
    # several elevations: no plane through it leaves its points within the noise along
    # their beams.
    rng = np.random.default_rng(3)
    n = 3000
    angle = rng.uniform(0.0, 2.0 * np.pi, n)
    true = np.column_stack([rng.uniform(-0.005, 0.005, n), 0.010 * np.cos(angle), 0.010 * np.sin(angle)])
    elevation = rng.uniform(-0.5, 0.5, n)
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    beams = np.column_stack([np.zeros(n), side * np.cos(elevation), np.sin(elevation)])
    seen = true + rng.normal(0.0, 0.002, n)[:, None] * beams
    assert math.isnan(traits.across_beam_width(seen - seen.mean(axis=0), 0.002 * beams, np.array([1.0, 0.0, 0.0])))


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match=r"offsets_m and noise_m must be \(n, 3\) alike"):
        traits.across_beam_width(np.zeros((10, 3)), np.ones((9, 3)), np.array([1.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"tangent \(3,\)"):
        traits.across_beam_width(np.zeros((10, 3)), np.ones((10, 3)), np.array([1.0, 0.0]))


def _stem_and_twisted_leaf(rng, width_m, twist_deg, sigma_m):
    """A clean 6 mm stem 0.2 m tall on the axis and one strip leaf running out from its
    top, twisted and noisy as :func:`_radial_strip`; the cloud and its noise vectors."""
    theta = rng.uniform(0, 2 * np.pi, 15_000)
    stem = np.column_stack([0.006 * np.cos(theta), 0.006 * np.sin(theta), rng.uniform(0.0, 0.2, 15_000)])
    leaf, noise = _radial_strip(rng, width_m, twist_deg, sigma_m, 12_000, r0=0.006, length_m=0.25)
    return np.vstack([stem, leaf]), np.vstack([np.zeros_like(stem), noise])


@pytest.mark.parametrize("seed", range(2))
def test_a_noisy_narrow_leaf_reads_its_width_and_area_across_the_beams(seed):
    # 10 mm of range noise on a 10 mm leaf twisted 30 deg: its points spread 20-30 mm
    # across the midrib. Read across the beams, its width and area are the strip's.
    rng = np.random.default_rng(seed)
    pts, noise = _stem_and_twisted_leaf(rng, 0.010, 30.0, 0.010)
    t = traits.extract_traits(pts, range_noise_m=noise)
    (leaf,) = t.leaves
    assert leaf.width_m == pytest.approx(0.010, rel=0.15)
    assert leaf.area_m2 == pytest.approx(0.010 * 0.25, rel=0.15)
    assert leaf.width_across_beams_share > 0.5
    assert leaf.width_resolved is True
    (note,) = [n for n in t.notes if n.startswith("leaf widths read across the beams")]
    assert "1 of 1 leaves" in note
    # Without the beams' directions the width is the points' spread: the noise's.
    (blind,) = traits.extract_traits(pts).leaves
    assert blind.width_m > 2.0 * 0.010
    assert math.isnan(blind.width_across_beams_share) and blind.width_resolved is None
