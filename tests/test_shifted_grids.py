"""The organs segmented on shifted voxel grids, and traits measured on the LAS file's grid.

A segmentation cuts a cloud with voxels and level sets; where they start moves a
branch near a threshold across it. Traits read the median of several grids and carry
the spread (``TraitSettings.shifted_grids``), on points rounded to the 0.01 mm a LAS
file keeps (``traits.on_file_grid``). The procedural plants' stability under a file's
rounding and a micrometre's jitter is tested in ``test_traits_procedural.py``.
"""

import numpy as np
import pytest

from plantsim.evaluation import segmentation, traits
from test_traits import _cylinder_cloud, _strip


def _plant(seed=3):
    rng = np.random.default_rng(seed)
    r = 0.005
    return np.vstack([
        _cylinder_cloud(rng, (0.0, 0.0), r, 0.3, 20_000),
        _strip(rng, 0.15, 0.02, 5_000, origin=(r, 0.0, 0.10), direction=(1.0, 0.0, 0.0)),
        _strip(rng, 0.12, 0.025, 5_000, origin=(-r, 0.0, 0.20), direction=(-1.0, 0.3, 0.0)),
    ])


def test_the_grid_offsets_start_at_the_origin_and_fill_the_unit_cube():
    offsets = segmentation.shifted_grid_offsets(9)
    assert offsets.shape == (9, 4)
    assert (offsets[0] == 0).all()
    assert ((offsets >= 0) & (offsets < 1)).all()
    assert len({tuple(o) for o in offsets}) == 9
    # Halton in bases 2, 3, 5, 7: the second point is (1/2, 1/3, 1/5, 1/7).
    assert offsets[1] == pytest.approx([1 / 2, 1 / 3, 1 / 5, 1 / 7])
    # Each coordinate's points spread over [0, 1): half of them in each half, to one.
    for axis in range(4):
        assert abs(int((offsets[1:, axis] < 0.5).sum()) - 4) <= 1
    with pytest.raises(ValueError, match="n must be an integer >= 1"):
        segmentation.shifted_grid_offsets(0)


@pytest.mark.parametrize("offset", [(1.0, 0, 0, 0), (0, 0, 0), (0, -0.1, 0, 0), "0000"])
def test_a_grid_offset_outside_the_unit_cube_is_refused(offset):
    with pytest.raises(ValueError, match=r"grid_offset must be 4 numbers in \[0, 1\)"):
        segmentation.SegmentationSettings(grid_offset=offset)


@pytest.mark.parametrize("n", [0, 2, 9.0, "9"])
def test_an_even_or_non_integer_number_of_grids_is_refused(n):
    with pytest.raises(ValueError, match="shifted_grids must be an odd int >= 1"):
        traits.TraitSettings(shifted_grids=n)


def test_each_shifted_grid_is_the_segmentation_with_that_offset():
    pts = _plant()
    offsets = segmentation.shifted_grid_offsets(3)
    grids = segmentation.segment_on_shifted_grids(pts, offsets=offsets)
    assert len(grids) == 3
    for g, o in zip(grids, offsets):
        alone = segmentation.segment_organs(pts, settings=segmentation.SegmentationSettings(grid_offset=tuple(o)))
        assert np.array_equal(g.leaf_label, alone.leaf_label) and np.array_equal(g.stem_label, alone.stem_label)
        # What no grid changes is shared: the kept points, the scale and the stems.
        assert np.array_equal(g.kept, grids[0].kept) and g.scale == grids[0].scale and g.stems == grids[0].stems
    # The default settings are the grid anchored on the origin.
    assert np.array_equal(segmentation.segment_organs(pts).leaf_label, grids[0].leaf_label)
    with pytest.raises(ValueError, match="at least one grid offset"):
        segmentation.segment_on_shifted_grids(pts, offsets=np.zeros((0, 4)))
    # An offset in the settings is not silently replaced by the offsets given.
    shifted = segmentation.SegmentationSettings(grid_offset=(0.5, 0, 0, 0))
    with pytest.raises(ValueError, match="leave settings.grid_offset at zeros"):
        segmentation.segment_on_shifted_grids(pts, settings=shifted, offsets=offsets)


def test_a_shifted_grid_cuts_the_cloud_elsewhere():
    # The voxel nodes of a shifted grid are other nodes: the skeleton's pieces differ
    # even where the organs found are the same.
    pts = _plant()
    a, b = segmentation.segment_on_shifted_grids(pts, offsets=[(0, 0, 0, 0), (0.5, 0.5, 0.5, 0.5)])
    assert len(a.leaf_midribs) == len(b.leaf_midribs) == 2
    assert not all(len(x) == len(y) and np.allclose(x, y) for x, y in zip(a.leaf_midribs, b.leaf_midribs))


def test_traits_keep_the_grid_of_the_median_leaf_count_and_carry_every_grids():
    pts = _plant()
    t = traits.extract_traits(pts)
    assert len(t.leaf_counts_over_grids) == 9 and len(t.leaf_areas_over_grids_m2) == 9
    assert t.leaf_count == sorted(t.leaf_counts_over_grids)[4] == 2
    assert t.leaf_area_m2 in t.leaf_areas_over_grids_m2
    d = t.to_dict()
    assert d["leaf_counts_over_grids"] == list(t.leaf_counts_over_grids)
    one = traits.extract_traits(pts, settings=traits.TraitSettings(shifted_grids=1))
    assert one.leaf_counts_over_grids == t.leaf_counts_over_grids[:1]
    assert one.leaf_areas_over_grids_m2 == t.leaf_areas_over_grids_m2[:1]
    assert one.stem_heights_over_grids_m == t.stem_heights_over_grids_m[:1]
    assert one.heights_over_grids_m == t.heights_over_grids_m[:1] == (t.height_m,)


def test_the_plant_height_on_every_grids_voxels():
    # The height reported is the origin grid's; each grid's is robust_height with the voxel
    # grid shifted as that grid's voxels are (the same offsets as the segmentation's).
    pts = _plant()
    t = traits.extract_traits(pts)
    assert len(t.heights_over_grids_m) == 9 and t.heights_over_grids_m[0] == t.height_m
    on_grid = traits.on_file_grid(pts)
    above = on_grid[traits._above_mask(on_grid, traits.TraitSettings())]
    scale = segmentation.segment_on_shifted_grids(above, offsets=segmentation.shifted_grid_offsets(1))[0].scale
    for o, h in zip(segmentation.shifted_grid_offsets(9), t.heights_over_grids_m):
        assert h == traits.robust_height(above, scale=scale, min_points=traits.top_voxel_min_points(scale),
                                         grid_offset=tuple(o[:3]))
    assert t.to_dict()["heights_over_grids_m"] == list(t.heights_over_grids_m)


def test_robust_height_moves_with_its_voxel_grid_by_less_than_a_voxel():
    # A column of points every mm from 0.5 to 299.5 mm and a stray point 5 cm above it,
    # voxels of 10 mm: the top is the centroid of the highest voxel holding 2 points,
    # which depends on where the grid starts, always within a voxel below the top point.
    body = np.column_stack([np.zeros(300), np.zeros(300), 0.0005 + 0.001 * np.arange(300)])
    pts = np.vstack([body, [[0.0, 0.0, 0.35]]])
    cell = 0.01
    # Voxel faces where z + offset * cell is a multiple of the cell, as the segmentation's.
    expected = {0.0: 0.295,     # voxel 290-300 mm: its 10 points
                0.3: 0.2985,    # voxel 297-307 mm: 3 points
                0.6: 0.297}     # voxel 294-304 mm: 6 points
    for z0, top in expected.items():
        h = traits.robust_height(pts, cell=cell, min_points=2, grid_offset=(0.3, 0.6, z0))
        assert h == pytest.approx(top, abs=1e-9)
        assert 0.2995 - cell < h < 0.2995
    assert traits.robust_height(pts, cell=cell, min_points=2) == pytest.approx(0.295, abs=1e-9)
    for bad in ((0.0, 0.0, 1.0), (0.0, -0.1, 0.0), (0.0, 0.0)):
        with pytest.raises(ValueError, match="grid_offset must be 3 fractions of a cell"):
            traits.robust_height(pts, cell=cell, min_points=2, grid_offset=bad)



def test_traits_carry_the_stem_height_every_grid_reads():
    # Each grid's stem height is the top of the stem points that grid's own walk kept,
    # by the plant height's rule; the one reported is the representative grid's.
    pts = _plant()
    t = traits.extract_traits(pts)
    heights = t.stem_heights_over_grids_m
    assert len(heights) == 9 and t.stem_height_m in heights
    on_grid = traits.on_file_grid(pts)
    above = on_grid[traits._above_mask(on_grid, traits.TraitSettings())]  # above the ground clearance
    grids = segmentation.segment_on_shifted_grids(above, offsets=segmentation.shifted_grid_offsets(9))
    min_points = traits.top_voxel_min_points(grids[0].scale)
    for g, h in zip(grids, heights):
        (stem_points,) = [g.points[g.stem_label == i] for i in range(len(g.stems))]
        assert h == traits.robust_height(stem_points, scale=g.scale, min_points=min_points)
    # The 0.3 m stem reads its height on every grid, within a voxel.
    assert np.allclose(heights, 0.3, atol=grids[0].scale.voxel_m)
    assert t.to_dict()["stem_heights_over_grids_m"] == list(heights)
    # No stem found: NaN on every grid, None in JSON.
    rng = np.random.default_rng(0)
    flat = _strip(rng, 0.15, 0.02, 5_000, origin=(0.0, 0.0, 0.05), direction=(1.0, 0.0, 0.0))
    bare = traits.extract_traits(flat)
    assert bare.stem_count == 0 and len(bare.stem_heights_over_grids_m) == 9
    assert all(np.isnan(h) for h in bare.stem_heights_over_grids_m)
    assert bare.to_dict()["stem_heights_over_grids_m"] == [None] * 9


def test_traits_are_measured_on_the_las_files_grid():
    p = np.array([[0.123456789, -0.5, 1e-6], [0.000004999, 0.000005001, -0.000015]])
    assert traits.on_file_grid(p) == pytest.approx(np.array([[0.12346, -0.5, 0.0], [0.0, 0.00001, -0.00002]]),
                                                   abs=1e-15)
    # A cloud moved by less than the grid's half step reads the same traits.
    pts = traits.on_file_grid(_plant())
    moved = pts + np.random.default_rng(0).uniform(-4e-6, 4e-6, pts.shape)
    a, b = traits.extract_traits(pts), traits.extract_traits(moved)
    assert (a.height_m, a.leaf_count, a.leaf_area_m2, a.leaf_counts_over_grids) == \
           (b.height_m, b.leaf_count, b.leaf_area_m2, b.leaf_counts_over_grids)
