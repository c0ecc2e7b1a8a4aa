"""Found leaves matched to true leaves by IoU (plantsim.evaluation.organ_match), on labels made by hand."""

import itertools

import numpy as np
import pytest

from plantsim.evaluation.organ_match import leaf_labels_from_mesh, match_leaves


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
