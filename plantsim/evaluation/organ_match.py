"""How well a segmentation's leaves match the true leaves, point by point.

A leaf count can be right for the wrong reasons: one leaf split in two and two others
merged into one still count three. When the truth is known per point (a procedural
plant's face labels, read at each point's nearest face, or on a noisy scan at the face
its beam hit), every found leaf is matched to a true leaf as instance segmentations are
scored (Kirillov et al. 2019, "Panoptic segmentation", CVPR, section 4.1):

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
import math
from typing import Any

import numpy as np

__all__ = ["BEAM_WINDOW_SIGMAS", "LeafMatch", "faces_along_beams", "leaf_labels_along_beams",
           "leaf_labels_from_mesh", "match_leaves", "match_procedural_leaves", "procedural_leaf_labels",
           "surface_points_along_beams"]

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


# A noisy point's beam is searched this many standard deviations of its range noise either
# side of the point for the surface it hit (faces_along_beams): Gaussian noise moves one
# point in 16,000 farther.
BEAM_WINDOW_SIGMAS = 4.0


def faces_along_beams(points: Any, range_noise_m: Any, vertices: Any, faces: Any, *,
                      window_sigmas: float = BEAM_WINDOW_SIGMAS) -> np.ndarray:
    """The face each noisy point's beam hit: the first face its beam meets within
    ``window_sigmas`` standard deviations of its range noise either side of the point,
    from the sensor's side; -1 where it meets none there.

    Range noise moves a point along its own beam only. The surface the beam hit lies on
    the line through the point along the beam, within a few standard deviations of it,
    and it is the first surface on that line from the sensor's side: any surface between
    the sensor and it would have stopped the beam. So the first face the segment
    ``[p - k sigma b, p + k sigma b]`` meets (``b`` the beam's unit direction away from
    the sensor, ``k = window_sigmas``) is the face the beam hit whenever the noise moved
    the point less than ``k sigma``. The point's nearest face need not be: a 10 mm noise
    carries a point from a wheat culm 4 mm wide onto the leaf beside it.

    A beam whose axis meets no face within the window (its footprint's edge grazed a
    surface its axis missed, or the noise moved it farther) gets -1, as does a point with
    no noise (its beam is not known; :func:`leaf_labels_from_mesh` reads it exactly).
    Cast with Embree (``embreex``) in float32: about 0.1 micrometre at a metre.

    Args:
        points: (n, 3) float64, metres, the mesh's frame.
        range_noise_m: (n, 3) float64, each point's beam's unit direction (away from the
            sensor) times the standard deviation of its range noise, as
            :func:`plantsim.evaluation.evaluate.range_noise_vectors` gives them; zeros
            for a point with none.
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer rows of ``vertices``.
        window_sigmas: the half-length of the searched segment, in standard deviations (> 0).

    Returns:
        (n,) int64 face index of each point, -1 for none.

    Raises:
        ValueError: shapes that do not match, a non-finite value, or ``window_sigmas`` not > 0.
    """
    return _beam_hits(*_checked_beams(points, range_noise_m, vertices, faces, window_sigmas))[0]


def _checked_beams(points: Any, range_noise_m: Any, vertices: Any, faces: Any, window_sigmas: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """:func:`faces_along_beams`' arguments as arrays, checked (its Raises)."""
    pts = np.asarray(points, dtype=np.float64)
    noise = np.asarray(range_noise_m, dtype=np.float64)
    verts = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(faces)
    if pts.ndim != 2 or pts.shape[1] != 3 or noise.shape != pts.shape:
        raise ValueError(f"points and range_noise_m must both be (n, 3), got {pts.shape} and {noise.shape}")
    if verts.ndim != 2 or verts.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3 or not len(tri):
        raise ValueError(f"vertices must be (v, 3) and faces (f, 3) with f >= 1, got {verts.shape} and {tri.shape}")
    if not np.issubdtype(tri.dtype, np.integer) or tri.min() < 0 or tri.max() >= len(verts):
        raise ValueError(f"faces must be integer rows of vertices (0..{len(verts) - 1})")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(noise)) and np.all(np.isfinite(verts))):
        raise ValueError("points, range_noise_m and vertices must be finite")
    if not (isinstance(window_sigmas, (int, float)) and math.isfinite(window_sigmas) and window_sigmas > 0):
        raise ValueError(f"window_sigmas must be a finite number > 0, got {window_sigmas!r}")
    return pts, noise, verts, tri, float(window_sigmas)


def _beam_hits(pts: np.ndarray, noise: np.ndarray, verts: np.ndarray, tri: np.ndarray,
               window_sigmas: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`faces_along_beams` on checked arrays, and where each beam meets its face
    ((n, 3), NaN where it meets none)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from plantsim.sensor.embree import embreex_mesh_input

    out = np.full(len(pts), -1, dtype=np.int64)
    where = np.full((len(pts), 3), np.nan)
    sigma = np.linalg.norm(noise, axis=1)
    cast = np.flatnonzero(sigma > 0)
    if not len(cast):
        return out, where
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, **embreex_mesh_input(verts, tri.astype(np.int64)))
    half = window_sigmas * sigma[cast]
    beam = noise[cast] / sigma[cast, None]
    origins = pts[cast] - half[:, None] * beam
    found = scene.run(origins.astype(np.float32), beam.astype(np.float32),
                      dists=(2.0 * half).astype(np.float32), output=1)
    hit = np.asarray(found["primID"]).astype(np.int64)
    out[cast] = hit
    ok = hit >= 0
    where[cast[ok]] = origins[ok] + np.asarray(found["tfar"], dtype=np.float64)[ok, None] * beam[ok]
    return out, where


def surface_points_along_beams(points: Any, range_noise_m: Any, vertices: Any, faces: Any, *,
                               window_sigmas: float = BEAM_WINDOW_SIGMAS) -> np.ndarray:
    """Where each noisy point's beam met the mesh (:func:`faces_along_beams`' face): the
    point with its range noise taken away; NaN rows where the beam meets no face within
    the window. Arguments as :func:`faces_along_beams`'.

    Returns:
        (n, 3) float64, metres.
    """
    return _beam_hits(*_checked_beams(points, range_noise_m, vertices, faces, window_sigmas))[1]


def leaf_labels_along_beams(points: Any, range_noise_m: Any, vertices: Any, faces: Any, face_leaf: Any, *,
                            window_sigmas: float = BEAM_WINDOW_SIGMAS) -> tuple[np.ndarray, int]:
    """Each point's true leaf in a noisy scan: the leaf of the face its beam hit
    (:func:`faces_along_beams`), and how many points took their nearest face's instead.

    The nearest face labels a noisy point by where the noise put it: under the URG-04LX's
    ~12 mm range noise a wheat's culm and leaf bases, millimetres apart, trade points, and
    a leaf scored against such truth is scored against the noise. The beam's face is where
    the point was measured. A point whose beam meets no face within the window, or has no
    noise, takes its nearest face's label (:func:`leaf_labels_from_mesh`); the count of
    those is returned.

    Args:
        points, range_noise_m, vertices, faces, window_sigmas: as :func:`faces_along_beams`.
        face_leaf: (f,) int, each face's leaf index, -1 for faces on no leaf.

    Returns:
        ((n,) int64 leaf index of each point, -1 for none; the number labelled by their
        nearest face).
    """
    hit = faces_along_beams(points, range_noise_m, vertices, faces, window_sigmas=window_sigmas)
    labels = _labels("face_leaf", face_leaf, len(np.asarray(faces)))
    out = np.where(hit >= 0, labels[np.maximum(hit, 0)], -1)
    missed = np.flatnonzero(hit < 0)
    if len(missed):
        out[missed] = leaf_labels_from_mesh(np.asarray(points, dtype=np.float64)[missed], vertices, faces, labels)
    return out, int(len(missed))


def procedural_leaf_labels(points_turntable: Any, plant: Any, *, range_noise_m: Any = None) -> np.ndarray:
    """Each point's true leaf in a scan of a procedural plant.

    The plant is placed as a scan places it (:func:`plantsim.plant.mesh.plant_from_arrays`),
    so its faces lie in the cloud's turntable frame; each point's truth is the leaf of its
    nearest face (:func:`leaf_labels_from_mesh`), or, given the range noise, of the face
    its beam hit (:func:`leaf_labels_along_beams`: a noisy point's nearest face is where
    the noise put it).

    Args:
        points_turntable: (n, 3) float64, metres: points of a scan of ``plant``.
        plant: a :class:`plantsim.plant.procedural.ProceduralPlant` (face labels).
        range_noise_m: optional (n, 3), each point's range noise vector
            (:func:`plantsim.evaluation.evaluate.scan_range_noise`); None: nearest faces.

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
    face_leaf = np.where(plant.face_part == PART_LEAF, plant.face_organ, -1)
    if range_noise_m is None:
        return leaf_labels_from_mesh(points_turntable, placed.vertices_turntable, placed.faces, face_leaf)
    return leaf_labels_along_beams(points_turntable, range_noise_m, placed.vertices_turntable, placed.faces,
                                   face_leaf)[0]


def match_procedural_leaves(points_turntable: Any, plant: Any, *, range_noise_m: Any = None) -> LeafMatch:
    """The leaves :func:`plantsim.evaluation.traits.extract_traits` finds in a scan of a
    procedural plant, matched to the plant's true leaves (:func:`procedural_leaf_labels`).

    Args:
        points_turntable: (n, 3) float64, metres: the scan's plant points.
        plant: a :class:`plantsim.plant.procedural.ProceduralPlant` (face labels and traits).
        range_noise_m: optional, each point's range noise vector, as ``extract_traits``
            takes it (the leaves it finds then, scored against the faces their beams hit:
            :func:`procedural_leaf_labels`).

    Returns:
        LeafMatch.
    """
    from plantsim.evaluation.traits import segment_for_traits

    seg = segment_for_traits(points_turntable, range_noise_m=range_noise_m)
    return match_leaves(seg.leaf_label, procedural_leaf_labels(seg.points, plant, range_noise_m=seg.range_noise_m),
                        n_true_leaves=len(plant.traits["leaves"]))
