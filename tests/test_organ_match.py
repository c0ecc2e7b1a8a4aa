"""Found leaves matched to true leaves by IoU (plantsim.evaluation.organ_match), on labels made by hand;
a noisy point's true leaf read where its beam hit."""

import itertools

import numpy as np
import pytest

from plantsim.evaluation.organ_match import (faces_along_beams, leaf_labels_along_beams, leaf_labels_from_mesh,
                                             match_leaves, procedural_leaf_labels)


def test_a_perfect_segmentation_matches_every_leaf_whatever_its_numbering():
    true = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, -1, -1])
    found = np.array([2, 2, 2, 0, 0, 1, 1, 1, 1, -1, -1])
    m = match_leaves(found, true)
    assert sorted((f, t) for f, t, _ in m.pairs) == [(0, 1), (1, 2), (2, 0)]
    assert (m.true_positives, m.false_positives, m.false_negatives) == (3, 0, 0)
    assert m.recognition_quality == m.segmentation_quality == m.panoptic_quality == 1.0


def test_a_split_leaf_keeps_its_larger_part_and_the_smaller_is_a_false_positive():
    # True leaf 0: 10 points, found as 6 + 4; true leaf 1 found whole.
    true = np.array([0] * 10 + [1] * 5)
    found = np.array([0] * 6 + [1] * 4 + [2] * 5)
    m = match_leaves(found, true)
    assert [(f, t) for f, t, _ in m.pairs] == [(0, 0), (2, 1)]
    assert m.pairs[0][2] == pytest.approx(0.6)
    assert (m.found, m.true_positives, m.false_positives, m.false_negatives) == (3, 2, 1, 0)
    # RQ = 2 / (2 + 1/2), SQ = (0.6 + 1) / 2.
    assert m.recognition_quality == pytest.approx(0.8)
    assert m.segmentation_quality == pytest.approx(0.8)
    assert m.panoptic_quality == pytest.approx(0.64)


def test_two_equal_leaves_merged_into_one_match_neither():
    # IoU exactly 0.5 is not a match: it would not be unique.
    true = np.array([0] * 5 + [1] * 5)
    found = np.zeros(10, dtype=int)
    m = match_leaves(found, true)
    assert m.pairs == ()
    assert (m.true_positives, m.false_positives, m.false_negatives) == (0, 1, 2)
    assert m.panoptic_quality == 0.0 and np.isnan(m.segmentation_quality)


def test_a_stem_taken_for_a_leaf_is_a_false_positive_and_the_stem_is_never_a_true_leaf():
    true = np.array([-1] * 8 + [0] * 4)
    found = np.array([0] * 8 + [1] * 4)
    m = match_leaves(found, true)
    assert [(f, t) for f, t, _ in m.pairs] == [(1, 0)]
    assert (m.true_positives, m.false_positives, m.false_negatives) == (1, 1, 0)


def test_leaves_with_no_point_are_unseen_not_missed():
    true = np.array([0, 0, 1, 1])
    found = np.array([0, 0, 1, 1])
    m = match_leaves(found, true, n_true_leaves=5)
    assert (m.seen, m.unseen, m.false_negatives) == (2, 3, 0)
    assert "3 unseen" in m.summary()
    assert match_leaves(found, true).unseen == 0


def test_nothing_found_and_nothing_true():
    m = match_leaves(np.full(4, -1), np.full(4, -1))
    assert (m.found, m.seen, m.true_positives) == (0, 0, 0)
    assert np.isnan(m.recognition_quality) and np.isnan(m.panoptic_quality)
    m = match_leaves(np.full(4, -1), np.array([0, 0, 1, -1]))
    assert (m.false_negatives, m.recognition_quality, m.panoptic_quality) == (2, 0.0, 0.0)


@pytest.mark.parametrize("seed", range(6))
def test_matches_equal_a_brute_force_over_point_sets_and_are_one_to_one(seed):
    rng = np.random.default_rng(seed)
    n = 60
    true = rng.integers(-1, 5, n)
    # A noisy copy: most points keep a relabelled leaf, some move to another or to none.
    perm = rng.permutation(5)
    found = np.where(true >= 0, perm[np.maximum(true, 0)], -1)
    moved = rng.random(n) < 0.3
    found[moved] = rng.integers(-1, 6, int(moved.sum()))
    m = match_leaves(found, true)
    expected = []
    for f, t in itertools.product(range(6), range(5)):
        a, b = set(np.flatnonzero(found == f)), set(np.flatnonzero(true == t))
        if a | b and len(a & b) / len(a | b) > 0.5:
            expected.append((f, t, len(a & b) / len(a | b)))
    assert [(f, t) for f, t, _ in m.pairs] == [(f, t) for f, t, _ in expected]
    assert np.allclose([i for *_, i in m.pairs], [i for *_, i in expected])
    assert len({f for f, _, _ in m.pairs}) == len({t for _, t, _ in m.pairs}) == len(m.pairs)
    assert m.false_positives == len(set(found[found >= 0])) - len(m.pairs)
    assert m.false_negatives == len(set(true[true >= 0])) - len(m.pairs)


@pytest.mark.parametrize("found, true, kwargs, message", [
    (np.zeros((2, 2), int), np.zeros(4, int), {}, r"found_label must have shape \(n,\)"),
    (np.zeros(4, int), np.zeros(3, int), {}, r"true_label must have shape \(4,\)"),
    (np.zeros(4), np.zeros(4, int), {}, "must hold integers"),
    (np.array([0, -2, 0, 0]), np.zeros(4, int), {}, "-1 for none"),
    (np.zeros(4, int), np.array([0, 1, 2, 2]), {"n_true_leaves": 2}, "holds leaf 2"),
])
def test_bad_labels_say_what_is_wrong(found, true, kwargs, message):
    with pytest.raises(ValueError, match=message):
        match_leaves(found, true, **kwargs)


def test_a_points_true_leaf_is_its_nearest_faces():
    # Two unit squares (two triangles each) 1 m apart in z: faces 0-1 leaf 3, faces 2-3 no leaf.
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    vertices = np.vstack([square, square + [0, 0, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    points = np.array([[0.2, 0.7, 0.1], [0.9, 0.1, 0.45], [0.5, 0.5, 0.55], [0.3, 0.3, 2.0]])
    labels = leaf_labels_from_mesh(points, vertices, faces, np.array([3, 3, -1, -1]))
    assert labels.tolist() == [3, 3, -1, -1]
    with pytest.raises(ValueError, match=r"face_leaf must have shape \(4,\)"):
        leaf_labels_from_mesh(points, vertices, faces, np.array([3, 3, -1]))


def _plates(*xs):
    """Squares 40 mm on a side in the planes x = xs[i] (two triangles each), faces 2i, 2i + 1."""
    square = np.array([[0, -0.02, -0.02], [0, 0.02, -0.02], [0, 0.02, 0.02], [0, -0.02, 0.02]])
    vertices = np.vstack([square + [x, 0, 0] for x in xs])
    faces = np.vstack([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * i for i in range(len(xs))])
    return vertices, faces


def test_a_noisy_points_true_leaf_is_where_its_beam_hit_not_its_nearest_face():
    # Leaf 0 at x = 0.100 m, leaf 1 behind it at x = 0.110; beams along +x, sigma 5 mm.
    # A return from leaf 0 carried +8 mm along its beam lies 2 mm from leaf 1: its nearest
    # face is leaf 1's, but the first face on its beam within 4 sigma (x 0.088-0.128 m)
    # is leaf 0's. One carried -6 mm lies nearest leaf 0 either way; a return from leaf 1
    # carried -4 mm lies 6 mm in front of it, 4 mm behind leaf 0: the first face on its beam
    # from the sensor's side is leaf 0's, which would have stopped the beam: a point the
    # noise moved less than 4 sigma comes from the first face, and that is what it reads.
    vertices, faces = _plates(0.100, 0.110)
    face_leaf = np.array([0, 0, 1, 1])
    points = np.array([[0.108, 0.003, 0.001], [0.094, -0.005, 0.002], [0.106, 0.01, -0.01]])
    noise = np.tile([0.005, 0.0, 0.0], (3, 1))
    assert leaf_labels_from_mesh(points, vertices, faces, face_leaf).tolist() == [1, 0, 1]
    labels, nearest = leaf_labels_along_beams(points, noise, vertices, faces, face_leaf)
    assert labels.tolist() == [0, 0, 0] and nearest == 0
    # Each plate's face 2i holds its points with z < y, face 2i + 1 those with z > y.
    assert faces_along_beams(points, noise, vertices, faces).tolist() == [0, 1, 0]
    # The same points seen from the other side (beams along -x) read the first face from
    # that side, leaf 1, for every point within 4 sigma of it.
    labels, _ = leaf_labels_along_beams(points, -noise, vertices, faces, face_leaf)
    assert labels.tolist() == [1, 1, 1]


def test_the_first_face_on_the_beam_is_the_nearer_to_the_sensor_of_two_in_the_window():
    # Both plates lie within the window of a point between them; the beam's own direction
    # says which the sensor met first.
    vertices, faces = _plates(0.100, 0.110)
    point, noise = np.array([[0.105, 0.005, -0.005]]), np.array([[0.005, 0.0, 0.0]])
    assert faces_along_beams(point, noise, vertices, faces).tolist() == [0]
    assert faces_along_beams(point, -noise, vertices, faces).tolist() == [2]
    # A window of 0.8 sigma (4 mm) reaches neither plate: no face.
    assert faces_along_beams(point, noise, vertices, faces, window_sigmas=0.8)[0] == -1


def test_a_beam_that_meets_no_face_or_has_no_noise_takes_its_nearest_faces_leaf():
    vertices, faces = _plates(0.100, 0.110)
    face_leaf = np.array([0, 0, 1, 1])
    # The first beam passes beside the plates (y = 30 mm, they end at 20); the second has
    # no noise (its beam is not known); the third's beam runs along z, parallel to the
    # plates, and meets neither: each takes its nearest face's leaf.
    points = np.array([[0.109, 0.03, 0.0], [0.101, 0.0, 0.0], [0.111, 0.0, 0.0]])
    noise = np.array([[0.005, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -0.005]])
    assert faces_along_beams(points, noise, vertices, faces).tolist() == [-1, -1, -1]
    labels, nearest = leaf_labels_along_beams(points, noise, vertices, faces, face_leaf)
    assert labels.tolist() == [1, 0, 1] and nearest == 3


@pytest.mark.parametrize("change, message", [
    ({"points": np.zeros((2, 2))}, "points and range_noise_m must both be"),
    ({"range_noise_m": np.zeros((3, 3))}, "points and range_noise_m must both be"),
    ({"faces": np.array([[0, 1, 9]])}, "faces must be integer rows of vertices"),
    ({"faces": np.zeros((0, 3), dtype=int)}, "faces"),
    ({"range_noise_m": np.array([[np.nan, 0, 0], [0, 0, 0]])}, "must be finite"),
    ({"window_sigmas": 0.0}, "window_sigmas must be a finite number > 0"),
])
def test_bad_beam_label_inputs_say_what_is_wrong(change, message):
    vertices, faces = _plates(0.1)
    args = {"points": np.zeros((2, 3)), "range_noise_m": np.zeros((2, 3)), "vertices": vertices, "faces": faces}
    args.update(change)
    window = args.pop("window_sigmas", 4.0)
    with pytest.raises(ValueError, match=message):
        faces_along_beams(**args, window_sigmas=window)


def test_a_realistic_scans_beam_labels_agree_with_the_same_beams_without_noise():
    # The obviously right reference: the ideal scan of the same rig casts the same beams
    # (same line, same beam index) without noise, and its point's nearest face is the face
    # the beam hit. On a realistic 2-degree scan of a 3-leaf rosette the beams' labels agree
    # with it on 99 % or more of the points both scans returned; the noisy points' nearest
    # faces on far fewer (their leaves' bases meet round the axis, in the noise's reach).
    from plantsim.evaluation.evaluate import scan_range_noise
    from plantsim.plant.mesh import plant_from_arrays
    from plantsim.plant.procedural import make_rosette
    from plantsim.scan.config import RunConfig
    from plantsim.scan.pipeline import run_scan
    from plantsim.scan.schedule import StepScan

    plant = make_rosette(seed=0, n_leaves=3)
    placed = plant_from_arrays(plant.vertices_m, plant.faces)
    scans = {ideal: run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=2.0)), plant=placed) for ideal in (True, False)}
    clean, noisy = (scans[i].cloud.plant_only() for i in (True, False))
    noise = scan_range_noise(scans[False])[0]
    key = {(int(s), int(b)): i for i, (s, b) in enumerate(zip(clean.scan_index, clean.beam_index))}
    pair = np.array([key.get((int(s), int(b)), -1) for s, b in zip(noisy.scan_index, noisy.beam_index)])
    both = pair >= 0
    assert both.mean() > 0.9
    truth = procedural_leaf_labels(clean.points_turntable, plant)[pair[both]]
    by_beam = procedural_leaf_labels(noisy.points_turntable, plant, range_noise_m=noise)[both]
    nearest = procedural_leaf_labels(noisy.points_turntable, plant)[both]
    assert np.mean(by_beam == truth) >= 0.99
    assert np.mean(nearest == truth) < np.mean(by_beam == truth) - 0.05
