"""How well a segmentation's leaves match the true leaves, point by point.

A leaf count can be right for the wrong reasons: one leaf split in two and two others
merged into one still count three. When the truth is known per point (a procedural
plant's face labels, read at each point's nearest face), every found leaf is matched
to a true leaf as instance segmentations are scored (Kirillov et al. 2019, "Panoptic
segmentation", CVPR, section 4.1):

- a found leaf and a true leaf match when their point sets' intersection over union
  (IoU) exceeds 0.5. Two sets each more than half of their union cannot both overlap a
  third that much, so the matches are one-to-one without any assignment step;
- found leaves with no match are false positives (a leaf split in two: the smaller
  half; two leaves merged: the merged one, unless one leaf dominates it; a stem taken
  for a leaf), true leaves with no match false negatives (missed or merged);
- recognition quality ``RQ = TP / (TP + FP / 2 + FN / 2)`` (an F1 score), segmentation
  quality ``SQ`` the mean IoU of the matches, panoptic quality ``PQ = SQ RQ``.

The points are the segmented cloud's; truth labels are leaf indices (>= 0) or -1 for
points on no leaf (stems, petioles). A true leaf with no points in the cloud was not
seen and is left out (no segmentation can find it); ``unseen`` counts them when the
number of true leaves is given.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

__all__ = ["LeafMatch", "leaf_labels_from_mesh", "match_leaves", "match_procedural_leaves",
           "procedural_leaf_labels"]

# Kirillov et al. 2019: IoU above one half makes a match unique.
MATCH_IOU = 0.5


@dataclasses.dataclass(frozen=True)
class LeafMatch:
    """Found leaves matched to true leaves (:func:`match_leaves`).

    Attributes:
        pairs: (found, true, IoU) per match, by found index.
        found: leaves the segmentation found.
        seen: true leaves with at least one point in the cloud.
        unseen: true leaves with no point (0 unless ``n_true_leaves`` was given).
        true_positives: matches (IoU > 0.5).
        false_positives: found leaves with no match.
        false_negatives: seen true leaves with no match.
        recognition_quality: ``TP / (TP + FP / 2 + FN / 2)``; NaN with no leaf found or seen.
        segmentation_quality: mean IoU of the matches; NaN with none.
        panoptic_quality: their product.
    """

    pairs: tuple[tuple[int, int, float], ...]
    found: int
    seen: int
    unseen: int
    true_positives: int
    false_positives: int
    false_negatives: int
    recognition_quality: float
    segmentation_quality: float
    panoptic_quality: float

    def summary(self) -> str:
        """One line: matches of found and seen leaves, and the qualities."""
        unseen = f", {self.unseen} unseen" if self.unseen else ""
        return (f"{self.true_positives} of {self.found} found match {self.seen} seen leaves{unseen} "
                f"(IoU > {MATCH_IOU:g}; {self.false_positives} unmatched found, {self.false_negatives} "
                f"unmatched true); RQ {self.recognition_quality:.2f} SQ {self.segmentation_quality:.2f} "
                f"PQ {self.panoptic_quality:.2f}")


def _labels(name: str, value: Any, n: int | None) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 1 or (n is not None and len(arr) != n):
        shape = f"({n},)" if n is not None else "(n,)"
        raise ValueError(f"{name} must have shape {shape}, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must hold integers (leaf index, or -1 for none), got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if arr.size and arr.min() < -1:
        raise ValueError(f"{name} holds {int(arr.min())}; labels are leaf indices >= 0 or -1 for none")
    return arr


def match_leaves(found_label: Any, true_label: Any, *, n_true_leaves: int | None = None) -> LeafMatch:
    """Match found leaves to true leaves by the IoU of their points (module docstring).

    Args:
        found_label: (n,) int, the segmentation's leaf index of each point, -1 for none.
        true_label: (n,) int, the true leaf index of the same points, -1 for none.
        n_true_leaves: the plant's true leaf count, to report the leaves with no point
            (None: only the leaves with points are known).

    Returns:
        LeafMatch.
    """
    found = _labels("found_label", found_label, None)
    true = _labels("true_label", true_label, len(found))
    n_found = int(found.max()) + 1 if found.size and found.max() >= 0 else 0
    n_true = int(true.max()) + 1 if true.size and true.max() >= 0 else 0
    if n_true_leaves is not None:
        if n_true_leaves < n_true:
            raise ValueError(f"n_true_leaves is {n_true_leaves} but true_label holds leaf {n_true - 1}")
        n_true = n_true_leaves
    found_size = np.bincount(found[found >= 0], minlength=n_found)
    true_size = np.bincount(true[true >= 0], minlength=n_true)
    both = (found >= 0) & (true >= 0)
    inter = np.bincount(found[both] * max(n_true, 1) + true[both],
                        minlength=n_found * max(n_true, 1)).reshape(n_found, max(n_true, 1))[:, :n_true]
    union = found_size[:, None] + true_size[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros(inter.shape), where=union > 0)
    fi, ti = np.nonzero(iou > MATCH_IOU)
    pairs = tuple((int(f), int(t), float(iou[f, t])) for f, t in zip(fi, ti))
    seen = int((true_size > 0).sum())
    n_found_present = int((found_size > 0).sum())
    tp = len(pairs)
    fp, fn = n_found_present - tp, seen - tp
    denom = tp + 0.5 * fp + 0.5 * fn
    rq = tp / denom if denom > 0 else float("nan")
    sq = float(np.mean([p[2] for p in pairs])) if pairs else float("nan")
    return LeafMatch(pairs=pairs, found=n_found_present, seen=seen, unseen=n_true - seen,
                     true_positives=tp, false_positives=fp, false_negatives=fn,
                     recognition_quality=float(rq), segmentation_quality=sq,
                     panoptic_quality=float(rq * sq) if pairs else (0.0 if denom > 0 else float("nan")))


def leaf_labels_from_mesh(points: Any, vertices: Any, faces: Any, face_leaf: Any) -> np.ndarray:
    """Each point's true leaf: the label of its nearest face (exact point-to-triangle
    distance, :class:`plantsim.evaluation.metrics.MeshProximity`).

    Args:
        points: (n, 3) float64, metres, the mesh's frame (a scan's cloud: the placed mesh).
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer rows of ``vertices``.
        face_leaf: (f,) int, each face's leaf index, -1 for faces on no leaf.

    Returns:
        (n,) int64 leaf index of each point, -1 for none.
    """
    from plantsim.evaluation.metrics import MeshProximity

    labels = _labels("face_leaf", face_leaf, len(np.asarray(faces)))
    return labels[MeshProximity(vertices, faces).query(points).triangle_index]


def procedural_leaf_labels(points_turntable: Any, plant: Any) -> np.ndarray:
    """Each point's true leaf in a scan of a procedural plant.

    The plant is placed as a scan places it (:func:`plantsim.plant.mesh.plant_from_arrays`),
    so its faces lie in the cloud's turntable frame; each point's truth is the leaf of its
    nearest face (:func:`leaf_labels_from_mesh`).

    Args:
        points_turntable: (n, 3) float64, metres: points of a scan of ``plant``.
        plant: a :class:`plantsim.plant.procedural.ProceduralPlant` (face labels).

    Returns:
        (n,) int64 leaf index of each point, -1 for none (stem, ear).

    Raises:
        ValueError: placing the plant dropped faces (the labels would not line up).
    """
    from plantsim.plant.mesh import plant_from_arrays
    from plantsim.plant.procedural import PART_LEAF

    placed = plant_from_arrays(plant.vertices_m, plant.faces)
    if len(placed.faces) != len(plant.faces):
        raise ValueError(f"placing the plant dropped {len(plant.faces) - len(placed.faces)} faces: "
                         "its face labels no longer line up with the mesh")
    return leaf_labels_from_mesh(points_turntable, placed.vertices_turntable, placed.faces,
                                 np.where(plant.face_part == PART_LEAF, plant.face_organ, -1))


def match_procedural_leaves(points_turntable: Any, plant: Any, *, range_noise_m: Any = None) -> LeafMatch:
    """The leaves :func:`plantsim.evaluation.traits.extract_traits` finds in a scan of a
    procedural plant, matched to the plant's true leaves (:func:`procedural_leaf_labels`).

    Args:
        points_turntable: (n, 3) float64, metres: the scan's plant points.
        plant: a :class:`plantsim.plant.procedural.ProceduralPlant` (face labels and traits).
        range_noise_m: optional, each point's range noise vector, as ``extract_traits``
            takes it (the leaves it finds then).

    Returns:
        LeafMatch.
    """
    from plantsim.evaluation.traits import segment_for_traits

    seg = segment_for_traits(points_turntable, range_noise_m=range_noise_m)
    return match_leaves(seg.leaf_label, procedural_leaf_labels(seg.points, plant),
                        n_true_leaves=len(plant.traits["leaves"]))
