"""Stems beside the turntable's axis that the range noise hides from the base slices, found
in the turn angles of their points (segmentation.find_beam_stems, track_beam_stem).

A 2D LiDAR whose scan plane holds the turntable's axis casts each beam in a plane through
the axis: range noise moves a point along its beam, within that plane, and leaves its turn
angle as scanned. A wheat tiller's 4 mm culm 40-60 mm from the axis, under the URG-04LX's
10-12 mm of range noise, is a streak a few turn angles wide and centimetres long along the
beams. The scenes are ray-cast exactly (vertical cylinders and flat plates), with Gaussian
range noise along each beam.
"""

import math

import numpy as np
import pytest

from conftest import turntable_first_hits as _first_hits
from plantsim.evaluation import segmentation, traits


def _polar(rho, deg, r, h):
    return (rho * math.cos(math.radians(deg)), rho * math.sin(math.radians(deg)), r, h)


# A wheat-like plant: a 4 mm culm on the axis and three 4 mm tillers 40-60 mm from it.
AXIS = (0.0, 0.0, 0.002, 0.32)
TILLERS = (_polar(0.060, -95.0, 0.002, 0.30), _polar(0.042, 20.0, 0.002, 0.26), _polar(0.055, 140.0, 0.002, 0.22))
# A leaf leaving the first tiller 0.12 m up and crossing in front of it, out to 0.15 m.
CROSSING = ((TILLERS[0][0] - 0.03, TILLERS[0][1] + 0.0, 0.12), (0.06, -0.09, 0.04), (0.0, 0.0, 0.012))


def _scale(pts):
    return segmentation.kept_points(pts)[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_tillers_the_noise_hides_are_found_in_their_turn_angles_and_followed_to_their_tops(seed):
    rng = np.random.default_rng(seed)
    pts, noise, obj = _first_hits(rng, (AXIS,) + TILLERS, plates=[CROSSING], which=True)
    scale = _scale(pts)
    # The slices see noisy columns centimetres wide (the tillers' where no leaf joins
    # them, as here), no ring.
    slices = segmentation.find_stems(pts, base_z=0.0, scale=scale, max_diameter_m=0.05)
    assert slices and all(not st.diameter_resolved and st.diameter_m > 0.015 for st in slices)
    found = segmentation.find_beam_stems(pts, noise, base_z=0.0, scale=scale, max_diameter_m=0.05, stems=slices)
    assert len(found) == 3 and all(st.found_in_beams and st.diameter_resolved for st in found)
    # A noisy column off the axis gives way to the stem found in its turn angles.
    stems = segmentation.with_beam_stems(slices, found)
    assert len(stems) == 4 and sum(not st.found_in_beams for st in stems) == 1
    for i, (x, y, r, h) in enumerate(TILLERS, start=1):
        st = min(found, key=lambda st: math.hypot(st.center_xy_m[0] - x, st.center_xy_m[1] - y))
        rho = math.hypot(x, y)
        # Its turn angle is exact; its distance the median of points noisy along it.
        assert math.hypot(st.center_xy_m[0] - x, st.center_xy_m[1] - y) < 0.006
        # To a scanned step (1 deg) at its distance: 0.7-1.0 mm.
        assert st.diameter_m == pytest.approx(2 * r, abs=math.radians(1.0) * rho + 1e-4)
        track = segmentation.track_beam_stem(pts, noise, st, base_z=0.0,
                                             slice_m=segmentation.BEAM_STEM_SLICE_VOXELS * scale.voxel_m)
        # The leaf crossing the first tiller does not end or divert it.
        assert track.top_z_m == pytest.approx(h, abs=0.01)
        # Its points, though the noise moves them along their beams by centimetres: nearly
        # all its own hits (those beyond the axis's noise disc, where it is looked for),
        # and few of any other object's.
        on = segmentation.on_beam_stem(pts, noise, track, axis_stem=True)
        own = obj == i
        outside = np.hypot(pts[:, 0], pts[:, 1]) > 2.5 * 0.012
        assert np.mean(on[own & outside]) > 0.9
        assert np.mean(own[on]) > 0.9


def test_traits_count_and_measure_each_tiller_found_in_the_turn_angles():
    rng = np.random.default_rng(2)
    pts, noise = _first_hits(rng, (AXIS,) + TILLERS, plates=[CROSSING])
    t = traits.extract_traits(pts, range_noise_m=noise)
    assert t.stem_count == 4
    beside = [st for st in t.stems if st.found_in_beams]
    assert len(beside) == 3 and all(st.height_from == "turn angles" for st in beside)
    for x, y, r, h in TILLERS:
        st = min(beside, key=lambda st: math.hypot(st.center_xy_m[0] - x, st.center_xy_m[1] - y))
        assert st.height_m == pytest.approx(h, rel=0.05)
        assert st.diameter_resolved and st.diameter_m < 0.006 and st.diameter_from == "turn angles"
    assert any("found in the turn angles" in n for n in t.notes)
    # The plant's stem diameter is the mean of the diameters read; the axis culm's noisy
    # column (20-25 mm, an upper bound) is left out, and a note says so.
    assert not [st for st in t.stems if not st.found_in_beams][0].diameter_resolved
    assert t.stem_diameter_m == pytest.approx(np.mean([st.diameter_m for st in beside]))
    assert any(n.startswith("stem diameter: ") and "left out" in n for n in t.notes)
    # No stem reads above the plant's top: the culm on the axis, 0.32 m, read 0.324 m by
    # its points as measured, where the plant's top, read with its points moved along
    # their beams, is 0.317 m.
    assert all(st.height_m <= t.height_m for st in t.stems)


def test_without_noise_or_with_beams_off_the_axis_no_stem_is_found_in_the_turn_angles():
    rng = np.random.default_rng(3)
    pts, noise = _first_hits(rng, (AXIS,) + TILLERS)
    scale = _scale(pts)
    args = dict(base_z=0.0, scale=scale, max_diameter_m=0.05)
    assert len(segmentation.find_beam_stems(pts, noise, **args)) == 3
    # No noise given: the turn angles hold nothing the points do not.
    assert segmentation.find_beam_stems(pts, np.zeros_like(noise), **args) == ()
    # A scan plane 50 mm beside the axis: the beams are not in planes through it, a
    # point's noise moves its turn angle too, and the rule does not apply.
    pts_off, noise_off = _first_hits(rng, (AXIS,) + TILLERS, beside_m=0.05)
    assert segmentation.find_beam_stems(pts_off, noise_off, **args) == ()


def test_a_leaf_running_out_from_the_axis_is_no_stem():
    # A leaf low on the stem running out from the axis is narrow in turn angle too, but
    # its points spread along the beams as far as it runs, not as the noise alone does;
    # one rising steeply beside the axis changes its distance slice by slice.
    rng = np.random.default_rng(4)
    flat = ((0.012, -0.004, 0.02), (0.15, 0.0, 0.01), (0.0, 0.008, 0.0))
    rising = ((-0.01, 0.03, 0.0), (-0.002, 0.12, 0.2), (0.008, 0.0, 0.0))
    pts, noise = _first_hits(rng, (AXIS,), plates=[flat, rising])
    scale = _scale(pts)
    stems = segmentation.find_stems(pts, base_z=0.0, scale=scale, max_diameter_m=0.05)
    assert segmentation.find_beam_stems(pts, noise, base_z=0.0, scale=scale, max_diameter_m=0.05,
                                        stems=stems) == ()


def test_a_culm_inside_the_axis_noise_disc_is_not_placed_at_its_edge():
    # Culms 10-15 mm from the axis under 12 mm of range noise (the seed rig's wheat: 13-27
    # mm under 16 mm) share the axis's noise disc: only their tails reach past it, a streak
    # whose points beyond the disc read 30-40 mm out. Their own points (the streak's turn
    # angles less those beside them) say how far out they stand: inside the disc, where
    # they cannot be told from the axis stem's noise; no stem is placed at its edge.
    rng = np.random.default_rng(5)
    near = (_polar(0.015, -100.0, 0.002, 0.3), _polar(0.010, 30.0, 0.002, 0.3), _polar(0.012, 150.0, 0.002, 0.3))
    pts, noise = _first_hits(rng, (AXIS,) + near)
    scale = _scale(pts)
    stems = segmentation.find_stems(pts, base_z=0.0, scale=scale, max_diameter_m=0.05)
    assert segmentation.find_beam_stems(pts, noise, base_z=0.0, scale=scale, max_diameter_m=0.05,
                                        stems=stems) == ()
    # The same culms 45-60 mm out are found, each where it stands.
    far = tuple(_polar(r, deg, 0.002, 0.3) for r, deg in ((0.045, -100.0), (0.06, 30.0), (0.05, 150.0)))
    pts, noise = _first_hits(rng, (AXIS,) + far)
    scale = _scale(pts)
    stems = segmentation.find_stems(pts, base_z=0.0, scale=scale, max_diameter_m=0.05)
    found = segmentation.find_beam_stems(pts, noise, base_z=0.0, scale=scale, max_diameter_m=0.05, stems=stems)
    assert len(found) == 3
    for x, y, _, _ in far:
        assert min(math.hypot(st.center_xy_m[0] - x, st.center_xy_m[1] - y) for st in found) < 0.006


def test_plantsim_traits_marks_the_stems_found_in_the_turn_angles(tmp_path, capsys):
    # The bundled wheat scanned with the URG-04LX model: its sidecar gives the range noise,
    # and the three tillers beside the axis are found in their turn angles.
    from pathlib import Path

    from plantsim.cli.app import main

    wheat = Path(__file__).resolve().parent.parent / "assets" / "wheat.stl"
    cloud = tmp_path / "wheat.las"
    assert main(["scan", str(wheat), "-o", str(cloud), "--no-pictures"]) == 0
    capsys.readouterr()
    assert main(["traits", str(cloud)]) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("stems: ")]
    stems = line.split("; ")
    assert len(stems) == 4 and sum(s.endswith("(in the turn angles)") for s in stems) == 3, line
