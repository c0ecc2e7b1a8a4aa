"""Plant traits from a point cloud, the same traits from the truth, and their errors.

What a phenotyping pipeline extracts from a scan with no access to the mesh, so that
plantsim can reproduce the hand measurements of the paper's Tables I and II (stem
diameter, distance between stems, plant height, leaf width) automatically, and report
each as the paper does: ``|S - R| / R``.

Clouds are in the turntable frame: z up along the turntable axis, the plant base at
``z = base_z`` (0 by default) near the origin. Every method below is a deliberate,
simple estimator; its limits are stated where it is defined:

- height: :func:`extract_traits` reads :func:`robust_height` (the top voxel holding
  enough points that one stray point cannot set it; given the range noise, on the
  points moved along their beams onto their neighbours' surface,
  :func:`beam_median_points`); :func:`plant_height` is the
  ``percentile`` of z minus ``base_z`` (default 100: the maximum, which is what the
  paper's CloudCompare measurement and the mesh's top vertex mean).
- stems: :func:`extract_traits` takes them from the segmentation (columns persisting
  base-up, :func:`plantsim.evaluation.segmentation.find_stems`). :func:`estimate_stems`,
  the one-slice building block: a horizontal slice near the base is split into connected components in XY
  (radius graph on voxel centroids, cKDTree), and each component gets a circle fit
  (Kasa algebraic, then geometric least squares with one 3-sigma outlier rejection).
  Stems closer than ``stem_link_distance`` merge; leaves inside the slice bias the
  fit; components whose circle is implausible (wider than ``stem_max_diameter`` or
  a too-short arc) are dropped and logged. The diameter depends on the slice
  height (stems taper; the maize mesh reads 15.1 mm at 2 cm, the paper 12.5 mm).
- leaves (:func:`extract_traits`): organs from
  :func:`plantsim.evaluation.segmentation.segment_organs` (a level-set skeleton from
  the stems found base-up); per leaf, length along the midrib, width across it, area
  as the ribbon between its margins and inclination (:func:`_leaf_measures`). Noise
  widens a width by about its spread across the leaf: given each point's range noise
  along its beam, each cross-section's width is read where the beams meet the leaf
  (:func:`across_beam_width`), and where they cannot, checked against the width that
  noise alone reads (:func:`leaf_noise_width`, ``Leaf.width_resolved``). :func:`leaf_length_width` measures
  one leaf's points alone (geodesic double sweep, bins along the geodesic distance, the
  widest bin across the local direction): on flat and curled strips both within 2 %.
- convex-hull volume: scipy ``ConvexHull`` of all points above the base.
- projected area (XY): occupied cells of a square grid times the cell area. It reads
  high by about half a cell along every outline and low where the cloud is sparser
  than the cell.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import typing
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import optimize, sparse
from scipy.sparse import csgraph
from scipy.spatial import ConvexHull, QhullError, cKDTree

from plantsim.evaluation import metrics

logger = logging.getLogger(__name__)

__all__ = [
    "CircleFit", "LabelledLeaves", "Leaf", "PlantTraits", "Stem", "StemDistance", "TraitComparison", "TraitError",
    "TraitSettings", "across_beam_width", "axis_crowding", "beam_median_points", "compare_traits", "connected_components",
    "convex_hull_volume", "encircling_leaves", "estimate_stems", "extract_traits", "fit_circle",
    "heights_over_grids", "leaf_bases_at_stem", "leaf_count_of", "leaf_groups_of", "leaf_length_width",
    "leaf_noise_width", "measure_labelled_leaves", "on_file_grid", "plant_height",
    "projected_area_xy", "robust_height", "segment_for_traits", "stem_distances", "top_voxel_min_points", "trait_error",
    "traits_and_segmentation", "traits_from_mesh", "traits_from_truth", "true_leaf_groups",
]

_NAN = float("nan")


def _as_cloud(points: Any, name: str = "points_turntable") -> np.ndarray:
    return metrics._as_points(points, name, hint="drop misses before extracting traits")


# --------------------------------------------------------------------------
# settings and results
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class TraitSettings:
    """How traits are extracted from a cloud. Lengths in metres, turntable frame.

    Attributes:
        base_z: z of the plant base (the turntable top).
        ground_clearance: points below ``base_z + ground_clearance`` are ignored for
            leaves, hull and projected area (they are the turntable or the soil).
        height_percentile: percentile of z taken as the top (100 = maximum).
        stem_slice_z: centre of the stem slice above ``base_z``.
        stem_slice_thickness: thickness of the stem slice.
        stem_link_distance: XY points closer than this are in the same stem; must be
            smaller than the gap between neighbouring stems.
        stem_min_points: components of the slice with fewer points are not stems.
        stem_max_diameter: fitted circles wider than this are not stems; nor are those
            whose radius exceeds twice the component's extent (too short an arc).
        stem_removal_margin: added to a stem's radius when removing it before leaves.
        leaf_link_distance: 3D points closer than this are on the same leaf.
        leaf_min_points: components with fewer points are not leaves.
        leaf_bin_length: length of the bins along a leaf's midrib.
        grid_cell: cell of the projected-area occupancy grid.
        shifted_grids: the organs are segmented on this many voxel grids and level-set
            phases (:func:`plantsim.evaluation.segmentation.shifted_grid_offsets`); the
            organs are those of the grid whose leaf count is the median and, of
            those, whose leaf area is nearest their median (an odd number, so a grid
            holds the median; 1: the grid anchored on the origin alone).
    """

    base_z: float = 0.0
    ground_clearance: float = 0.005
    height_percentile: float = 100.0
    stem_slice_z: float = 0.02
    stem_slice_thickness: float = 0.01
    stem_link_distance: float = 0.004
    stem_min_points: int = 8
    stem_max_diameter: float = 0.05
    stem_removal_margin: float = 0.003
    leaf_link_distance: float = 0.006
    leaf_min_points: int = 30
    leaf_bin_length: float = 0.01
    grid_cell: float = 0.005
    shifted_grids: int = 9

    def __post_init__(self) -> None:
        positive = (
            "stem_slice_z",
            "stem_slice_thickness",
            "stem_link_distance",
            "stem_max_diameter",
            "leaf_link_distance",
            "leaf_bin_length",
            "grid_cell",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number > 0 metres, got {value!r}")
        for name in ("ground_clearance", "stem_removal_margin"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number >= 0 metres, got {value!r}")
        if not math.isfinite(self.base_z):
            raise ValueError(f"base_z must be finite, got {self.base_z!r}")
        if not 0 < self.height_percentile <= 100:
            raise ValueError(f"height_percentile must be in (0, 100], got {self.height_percentile!r}")
        for name in ("stem_min_points", "leaf_min_points"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 3):
                raise ValueError(f"{name} must be an int >= 3, got {value!r}")
        if not (isinstance(self.shifted_grids, int) and self.shifted_grids >= 1 and self.shifted_grids % 2):
            raise ValueError("shifted_grids must be an odd int >= 1 (a grid then holds the median leaf count), "
                             f"got {self.shifted_grids!r}")


@dataclasses.dataclass(frozen=True)
class CircleFit:
    """A circle fitted to XY points.

    Attributes:
        center_xy: (2,) float64, metres, turntable frame.
        radius: metres.
        rms_residual: RMS of the radial residuals of the inliers, metres.
        n_points: points given.
        n_inliers: points kept after the 3-sigma rejection.
    """

    center_xy: tuple[float, float]
    radius: float
    rms_residual: float
    n_points: int
    n_inliers: int


@dataclasses.dataclass(frozen=True)
class Stem:
    """One stem.

    Attributes:
        index: order in the plant (truth) or of detection (cloud).
        center_xy_m: (x, y) of the stem axis at the slice (cloud) or base (truth).
        diameter_m: stem diameter.
        rms_residual_m: circle-fit residual (NaN for truth).
        n_points: points in the slice component (0 for truth).
        diameter_resolved: False when noise hides the stem's diameter in its base
            slices (no ring fits) and the beams do not read it: ``diameter_m`` is then
            an upper bound.
        diameter_from: how the cloud's diameter was read: ``"rings"`` fitted in its
            base slices, ``"turn angles"`` for a stem found in them (``found_in_beams``),
            ``"beams"`` for a noisy stem on the turntable's axis read where the beams
            through the axis meet it
            (:func:`plantsim.evaluation.segmentation.beam_stem_diameter`), ``"column"``
            where none could and it is the noisy column's width (an upper bound);
            ``""`` for the truth.
        height_m: its top above the plant's base: its own points' :func:`robust_height`
            (cloud; :attr:`PlantTraits.stem_height_m` is the tallest stem's), or the
            truth's ``height_m`` (NaN: not measured, or not in the truth). A tiller's
            height is its own.
        height_from: how the cloud's stem top was read: ``"beams"`` where the beams
            through the turntable's axis ended a noisy stem below the skeleton's walk
            (:func:`plantsim.evaluation.segmentation.beam_stem_top`), ``"walk"`` where
            the walk up the stem's column stopped (a trait note says why the beams did
            not end a noisy one), ``"turn angles"`` for a stem found in the turn angles
            (``found_in_beams``: its track's top); ``""`` for the truth.
        found_in_beams: True for a stem beside the turntable's axis that the range noise
            hides from the base slices, found as a streak of its points' turn angles
            (:func:`plantsim.evaluation.segmentation.find_beam_stems`): its diameter is
            the scanned turn angles it spans times its distance from the axis (resolved
            to one step there), its points and top its track's up the plant
            (:func:`plantsim.evaluation.segmentation.track_beam_stem`).
    """

    index: int
    center_xy_m: tuple[float, float]
    diameter_m: float
    rms_residual_m: float = _NAN
    n_points: int = 0
    diameter_resolved: bool = True
    height_m: float = _NAN
    height_from: str = ""
    found_in_beams: bool = False
    diameter_from: str = ""


@dataclasses.dataclass(frozen=True)
class StemDistance:
    """Horizontal distance between two stem axes, metres."""

    stems: tuple[int, int]
    distance_m: float


@dataclasses.dataclass(frozen=True)
class Leaf:
    """One lamina: a simple leaf's blade, or one leaflet of a compound leaf.

    Attributes:
        index: order in the plant (truth) or of detection (cloud).
        length_m: along the midrib, of the lamina (a stalk, a petiole, left out).
        width_m: largest width across the midrib.
        n_points: points of the cloud component (0 for truth).
        area_m2: one-sided area.
        inclination_deg: the base-to-tip chord's angle above the horizontal (the
            junction, or the lamina's base past a stalk).
        noise_width_m: the width the sensor's range noise alone reads across the leaf
            (the 2nd-98th percentile extent of its along-beam noise projected across
            the midrib; NaN when the noise was not given).
        width_resolved: False when half or more of the cross-sections the width is
            read over read the noise's spread (the noise's own width across them 45 %
            of theirs or more: a strip read that wide reads 23 % or more wide) and their
            beams could not read them (:func:`across_beam_width`): the width, and the
            area built from it, read the noise; None when not checked.
        width_across_beams_share: the share of the cross-sections the width is read
            over whose width was read where their beams meet the leaf
            (:func:`across_beam_width`), not from their points' spread; NaN when the
            noise was not given.
        group: the leaf this lamina belongs to, 0 to ``leaf_count - 1``: the leaflets
            of one compound leaf (laminae on one petiole) share it, a simple leaf has
            its own.
    """

    index: int
    length_m: float
    width_m: float
    n_points: int = 0
    area_m2: float = _NAN
    inclination_deg: float = _NAN
    noise_width_m: float = _NAN
    width_resolved: bool | None = None
    width_across_beams_share: float = _NAN
    group: int = -1


@dataclasses.dataclass(frozen=True)
class PlantTraits:
    """Traits of one plant; NaN where a trait could not be measured.

    Aggregates: ``stem_diameter_m`` is the mean over the stems whose diameter is
    resolved (a ring, or the turn angles), over all of them (an upper bound) when none
    is: a noisy column's width is no diameter to average with one; ``mean_stem_distance_m``
    the mean over all pairs of stems; ``mean_nearest_stem_distance_m`` the mean, over
    stems, of the distance to the nearest other stem; ``leaf_width_m`` and
    ``leaf_length_m`` the largest over leaves. ``leaf_count`` counts leaves as a
    botanist does, a compound leaf (a trifoliate bean leaf: three leaflets on one
    petiole) once; ``lamina_count`` counts its leaflets, and ``leaves`` and the
    per-leaf tuples (``leaf_lengths_m``, ...) hold one entry per lamina, its
    ``Leaf.group`` the leaf it belongs to. For simple leaves the two counts agree.
    ``leaf_counts_over_grids``,
    ``leaf_areas_over_grids_m2`` and ``stem_heights_over_grids_m``: the leaf count, leaf
    area and stem height on each shifted grid the organs were segmented on
    (:attr:`TraitSettings.shifted_grids`), the first the grid anchored on the origin
    (NaN where a grid found no leaf, or no stem); their spread is the segmentation's
    own uncertainty (empty for a truth not measured from a cloud).
    ``heights_over_grids_m``: the plant height (:func:`robust_height`) with its voxel
    grid shifted as each of those grids' voxels are; ``height_m`` is the first (the
    origin's). A noisy or sparse top moves with the grid: the realistic 1-degree
    3-leaf maize of ``scripts/traits_accuracy.py`` reads 3.3 % low to 0.2 % high over
    the 9 (3.4-8.7 % low before its points were moved along their beams,
    :func:`beam_median_points`). ``height_beam_gap_m``: the gap between neighbouring
    beams at the top voxel (the origin grid's), half of which the height holds over
    that voxel's centroid (:func:`robust_height`); NaN when no gaps were given.
    """

    height_m: float
    stems: tuple[Stem, ...] = ()
    stem_diameter_m: float = _NAN
    stem_distances: tuple[StemDistance, ...] = ()
    mean_stem_distance_m: float = _NAN
    mean_nearest_stem_distance_m: float = _NAN
    leaves: tuple[Leaf, ...] = ()
    leaf_width_m: float = _NAN
    leaf_length_m: float = _NAN
    convex_hull_volume_m3: float = _NAN
    projected_area_xy_m2: float = _NAN
    stem_count: int = 0
    stem_height_m: float = _NAN
    leaf_count: int = 0
    leaf_area_m2: float = _NAN
    lamina_count: int = 0
    leaf_lengths_m: tuple[float, ...] = ()
    leaf_widths_m: tuple[float, ...] = ()
    leaf_areas_m2: tuple[float, ...] = ()
    leaf_inclinations_deg: tuple[float, ...] = ()
    leaf_counts_over_grids: tuple[int, ...] = ()
    leaf_areas_over_grids_m2: tuple[float, ...] = ()
    stem_heights_over_grids_m: tuple[float, ...] = ()
    heights_over_grids_m: tuple[float, ...] = ()
    height_beam_gap_m: float = _NAN
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (NaN becomes None)."""
        return metrics._to_jsonable(self)


# --------------------------------------------------------------------------
# building blocks
# --------------------------------------------------------------------------
def plant_height(points_turntable: Any, *, base_z: float = 0.0, percentile: float = 100.0) -> float:
    """Height of the plant: the ``percentile`` of z above ``base_z``.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame.
        base_z: z of the plant base, metres.
        percentile: in (0, 100]; 100 is the maximum (the default of the paper's
            hand measurement); lower values ignore stray points above the plant.

    Returns:
        Height in metres.
    """
    pts = _as_cloud(points_turntable)
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile!r}")
    return float(np.percentile(pts[:, 2], percentile) - base_z)


def _voxel_centroids(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Centroid of the points in each occupied voxel of side ``cell``, and each point's
    voxel: (centroids (m, d), inverse (n,) with points[i] in voxel inverse[i])."""
    ijk = np.floor(points / cell).astype(np.int64)
    _, inverse = np.unique(ijk, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    m = int(inverse.max()) + 1
    counts = np.bincount(inverse, minlength=m).astype(np.float64)
    centroids = np.column_stack(
        [np.bincount(inverse, weights=points[:, j], minlength=m) / counts for j in range(points.shape[1])]
    )
    return centroids, inverse


def connected_components(points: Any, *, link_distance: float, min_points: int = 1) -> list[np.ndarray]:
    """Split points into groups linked by chains of neighbours closer than ``link_distance``.

    Single-linkage clustering: components of the radius graph (cKDTree pairs). Dense
    clouds would make that graph huge, so points are first merged into the centroids
    of voxels of side ``link_distance / 4``, and centroids closer than
    ``link_distance`` are linked: two points are linked when about ``link_distance``
    apart (within half a voxel diagonal, 0.22 ``link_distance`` in 3D).

    Args:
        points: (n, d) float64, metres (d = 2 or 3).
        link_distance: metres (> 0).
        min_points: groups with fewer points are dropped.

    Returns:
        Index arrays into ``points``, largest group first.
    """
    pts = np.asarray(points, dtype=np.float64)
    if not link_distance > 0:
        raise ValueError(f"link_distance must be > 0 metres, got {link_distance!r}")
    if pts.shape[0] == 0:
        return []
    reps, inverse = _voxel_centroids(pts, link_distance / 4)
    m = reps.shape[0]
    pairs = cKDTree(reps).query_pairs(link_distance, output_type="ndarray")
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    _, rep_labels = csgraph.connected_components(graph, directed=False)
    labels = rep_labels[inverse]
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(labels[order])) + 1
    groups = [g for g in np.split(order, bounds) if g.size >= min_points]
    groups.sort(key=lambda g: -g.size)
    return groups


def fit_circle(points_xy: Any) -> CircleFit:
    """Fit a circle to 2D points: Kasa, then geometric least squares.

    The algebraic fit of Kasa (1976), ``x^2 + y^2 + D x + E y + F = 0`` solved
    linearly, starts a geometric fit (``scipy.optimize.least_squares`` on the radial
    residuals ``|p - c| - r``, which does not share Kasa's shrinking bias on short
    arcs). Points whose residual exceeds 3 robust sigmas (1.4826 MAD) are then
    dropped once and the geometric fit repeated.

    Args:
        points_xy: (n, 2) float64, metres, n >= 3.

    Returns:
        CircleFit.
    """
    xy = np.asarray(points_xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"points_xy must have shape (n, 2), got shape {xy.shape}")
    if xy.shape[0] < 3:
        raise ValueError(f"a circle needs at least 3 points, got {xy.shape[0]}")
    if not np.isfinite(xy).all():
        raise ValueError("points_xy holds NaN or inf")
    # Centre the data first: the normal equations are badly conditioned far from 0.
    mean = xy.mean(axis=0)
    p = xy - mean
    a = np.column_stack([p, np.ones(len(p))])
    b = -(p**2).sum(axis=1)
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    c0 = np.array([-d / 2, -e / 2])
    r0 = math.sqrt(max(c0 @ c0 - f, 0.0)) or float(np.linalg.norm(p, axis=1).mean())

    def geometric(pts: np.ndarray, start: np.ndarray) -> np.ndarray:
        def resid(x: np.ndarray) -> np.ndarray:
            return np.hypot(pts[:, 0] - x[0], pts[:, 1] - x[1]) - x[2]

        def jac(x: np.ndarray) -> np.ndarray:
            # d(|p - c| - r)/d(cx, cy, r): the analytic Jacobian, 10x fewer
            # residual calls than finite differences.
            dx, dy = pts[:, 0] - x[0], pts[:, 1] - x[1]
            rho = np.maximum(np.hypot(dx, dy), 1e-300)
            return np.column_stack([-dx / rho, -dy / rho, -np.ones(len(pts))])

        return optimize.least_squares(resid, start, jac=jac,
                                      method="lm" if len(pts) >= 3 else "trf").x

    x = geometric(p, np.array([c0[0], c0[1], r0]))
    res = np.hypot(p[:, 0] - x[0], p[:, 1] - x[1]) - x[2]
    sigma = 1.4826 * np.median(np.abs(res - np.median(res)))
    keep = np.abs(res) <= 3 * sigma if sigma > 0 else np.ones(len(p), dtype=bool)
    if 3 <= keep.sum() < len(p):
        x = geometric(p[keep], x)
        res = np.hypot(p[keep, 0] - x[0], p[keep, 1] - x[1]) - x[2]
    return CircleFit(
        center_xy=(float(x[0] + mean[0]), float(x[1] + mean[1])),
        radius=float(abs(x[2])),
        rms_residual=float(np.sqrt(np.mean(res**2))),
        n_points=int(len(p)),
        n_inliers=int(keep.sum()) if 3 <= keep.sum() else int(len(p)),
    )


def estimate_stems(points_turntable: Any, *, settings: TraitSettings | None = None) -> tuple[Stem, ...]:
    """Find the stems in a slice near the base and fit a circle to each.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame.
        settings: slice height and thickness, clustering distance (defaults if None).

    Returns:
        Stems sorted by x then y of their centre; empty if the slice holds no stem.
        Components whose circle is implausible are left out and logged (INFO).
    """
    s = settings or TraitSettings()
    pts = _as_cloud(points_turntable)
    z0 = s.base_z + s.stem_slice_z - s.stem_slice_thickness / 2
    z1 = z0 + s.stem_slice_thickness
    slab = pts[(pts[:, 2] >= z0) & (pts[:, 2] < z1), :2]
    groups = connected_components(slab, link_distance=s.stem_link_distance, min_points=s.stem_min_points)
    fits = []
    for g in groups:
        fit = fit_circle(slab[g])
        extent = float(np.ptp(slab[g], axis=0).max())
        # A short, nearly straight arc (a leaf edge, or one side of a stem) fits any
        # large circle; a stem's points span at least about a radius.
        if 2 * fit.radius > s.stem_max_diameter or fit.radius > 2 * extent:
            logger.info(
                "slice component of %d points at (%.4f, %.4f) m is no stem: circle diameter "
                "%.4g m, extent %.4g m (stem_max_diameter %.4g m)",
                g.size, *fit.center_xy, 2 * fit.radius, extent, s.stem_max_diameter,
            )
            continue
        fits.append((fit, g.size))
    fits.sort(key=lambda t: t[0].center_xy)
    return tuple(
        Stem(
            index=i,
            center_xy_m=fit.center_xy,
            diameter_m=2 * fit.radius,
            rms_residual_m=fit.rms_residual,
            n_points=n,
        )
        for i, (fit, n) in enumerate(fits)
    )


def stem_distances(stems: tuple[Stem, ...]) -> tuple[tuple[StemDistance, ...], float, float]:
    """Pairwise horizontal distances between stem axes.

    Args:
        stems: stems with ``center_xy_m`` in metres.

    Returns:
        (pairs, mean over all pairs, mean over stems of the nearest other stem);
        the means are NaN with fewer than two stems.
    """
    if len(stems) < 2:
        return (), _NAN, _NAN
    c = np.array([st.center_xy_m for st in stems])
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    pairs = tuple(
        StemDistance(stems=(stems[i].index, stems[j].index), distance_m=float(d[i, j]))
        for i in range(len(stems))
        for j in range(i + 1, len(stems))
    )
    np.fill_diagonal(d, np.inf)
    return pairs, float(np.mean([p.distance_m for p in pairs])), float(d.min(axis=1).mean())


def _remove_stems(pts: np.ndarray, stems: tuple[Stem, ...], s: TraitSettings) -> np.ndarray:
    """Mask of points not on a stem, following each stem upward slice by slice."""
    keep = np.ones(len(pts), dtype=bool)
    if not stems:
        return keep
    order = np.argsort(pts[:, 2])
    z_sorted = pts[order, 2]
    dz = s.stem_slice_thickness
    z_top = float(z_sorted[-1])
    for st in stems:
        r = st.diameter_m / 2
        reach = r + s.stem_removal_margin
        centre = np.array(st.center_xy_m)
        z = s.base_z
        while z <= z_top:
            lo, hi = np.searchsorted(z_sorted, [z, z + dz])
            idx = order[lo:hi]
            if idx.size:
                dxy = np.linalg.norm(pts[idx, :2] - centre, axis=1)
                near = idx[dxy <= reach + s.stem_link_distance]
                if near.size >= s.stem_min_points:
                    # Follow a leaning stem, but only on a fit that still looks like it.
                    fit = fit_circle(pts[near, :2])
                    moved = np.linalg.norm(np.array(fit.center_xy) - centre)
                    if 0.5 * r <= fit.radius <= 1.5 * r and moved <= r:
                        centre = np.array(fit.center_xy)
                keep[idx[np.linalg.norm(pts[idx, :2] - centre, axis=1) <= reach]] = False
            z += dz
    return keep


def _tangents(centroids: np.ndarray) -> np.ndarray:
    """Unit midrib direction at each centroid: main axis of the centroids within two
    places either side (wider than a central difference, so jitter tilts it less)."""
    tangents = np.empty_like(centroids)
    for i in range(len(centroids)):
        window = centroids[max(0, i - 2) : i + 3]
        _, _, vt = np.linalg.svd(window - window.mean(axis=0), full_matrices=False)
        ahead = centroids[min(i + 1, len(centroids) - 1)] - centroids[max(i - 1, 0)]
        tangents[i] = vt[0] if vt[0] @ ahead >= 0 else -vt[0]
    return tangents


def _bin_widths(pts, b, bins, centroids, tangents) -> np.ndarray:
    """Extent of each bin's points across the midrib: range along the main axis of the
    points projected on the plane normal to the local direction."""
    widths = np.empty(len(bins))
    for i, bin_id in enumerate(bins):
        q = pts[b == bin_id] - centroids[i]
        q = q - np.outer(q @ tangents[i], tangents[i])
        _, _, vt = np.linalg.svd(q, full_matrices=False)
        widths[i] = np.ptp(q @ vt[0])
    return widths


def leaf_length_width(points: Any, *, link_distance: float, bin_length: float) -> tuple[float, float]:
    """Length along the midrib and largest width across it, of one leaf's points.

    See the module docstring for the method (geodesic double sweep, bins along the
    geodesic distance, centroid polyline, width across the local direction).

    Args:
        points: (n, 3) float64, metres, one connected leaf.
        link_distance: graph edges join points closer than this, metres.
        bin_length: bin length along the midrib, metres.

    Returns:
        (length_m, width_m); NaN if the leaf has fewer than 3 points.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 3:
        return _NAN, _NAN
    # Geodesics on voxel centroids (side link_distance / 4): the graph stays small
    # on dense clouds; each point takes its voxel's geodesic distance.
    reps, inverse = _voxel_centroids(pts, link_distance / 4)
    m = len(reps)
    pairs = cKDTree(reps).query_pairs(link_distance, output_type="ndarray")
    w = np.linalg.norm(reps[pairs[:, 0]] - reps[pairs[:, 1]], axis=1)
    graph = sparse.coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(m, m)).tocsr()
    d0 = csgraph.dijkstra(graph, directed=False, indices=0)
    d0[~np.isfinite(d0)] = -1.0
    a = int(np.argmax(d0))
    t = csgraph.dijkstra(graph, directed=False, indices=a)[inverse]
    ok = np.isfinite(t)
    pts, t = pts[ok], t[ok]
    nb = max(1, int(math.ceil(t.max() / bin_length)))
    b = np.minimum((t / bin_length).astype(np.int64), nb - 1)
    counts = np.bincount(b, minlength=nb)
    # Bins at the two ends are cut by the leaf's outline (the sweep starts and ends at
    # a corner), so their centroids sit off the midrib: only bins holding at least
    # half the median count carry the midrib; the rest extend it at the ends.
    full = np.flatnonzero(counts >= 0.5 * np.median(counts[counts > 0]))
    if len(full) < 2:
        # Shorter than two bins: fall back to the extents along the principal axes.
        q = pts - pts.mean(axis=0)
        _, _, vt = np.linalg.svd(q, full_matrices=False)
        ext = np.ptp(q @ vt.T, axis=0)
        return float(ext[0]), (float(ext[1]) if ext.size > 1 else 0.0)
    centroids = np.array([pts[b == i].mean(axis=0) for i in full])
    tangents = _tangents(centroids)
    widths = _bin_widths(pts, b, full, centroids, tangents)
    # Within about one width of either end, bins of geodesic distance from a point of
    # the outline are arcs rather than cross-sections: their centroids leave the
    # midrib and they read too wide. Leaves taper there anyway, so those bins are
    # left out of the midrib and the width when enough remain; the leaf beyond the
    # first and last kept centroid is measured straight along the end directions.
    mid_t = (full + 0.5) * bin_length
    typical = float(np.median(widths))
    inner = (mid_t > typical) & (mid_t < t.max() - typical)
    if inner.sum() >= 2:
        keep = np.flatnonzero(inner)
        full, centroids = full[keep], centroids[keep]
        tangents = _tangents(centroids)
        widths = _bin_widths(pts, b, full, centroids, tangents)
    head = pts[b <= full[0]]
    tail = pts[b >= full[-1]]
    length = float(np.linalg.norm(np.diff(centroids, axis=0), axis=1).sum())
    length += max(0.0, float(((centroids[0] - head) @ tangents[0]).max()))
    length += max(0.0, float(((tail - centroids[-1]) @ tangents[-1]).max()))
    width = float(widths.max())
    return length, width


def convex_hull_volume(points: Any) -> float:
    """Volume of the convex hull (scipy ``ConvexHull``, Qhull), cubic metres.

    Args:
        points: (n, 3) float64, metres.

    Returns:
        Volume in m^3; NaN (with a warning logged) when the points are fewer than 4
        or coplanar.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 4:
        logger.warning("convex hull needs 4 points, got %d; volume is NaN", len(pts))
        return _NAN
    try:
        return float(ConvexHull(_hull_candidates(pts)).volume)
    except QhullError as exc:
        # Qhull's message runs to forty lines of options and coordinates; its first
        # line names the failure.
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        logger.warning("convex hull failed (flat or degenerate cloud), volume is NaN: %s", first)
        return _NAN


def _hull_candidates(pts: np.ndarray) -> np.ndarray:
    """The points that can be vertices of the convex hull of ``pts`` (n, 3).

    Akl-Toussaint throw-away (Akl & Toussaint 1978, Inf. Proc. Letters 7(5)):
    the extreme points along 26 directions span a polytope inside the hull; a point
    strictly inside it is no hull vertex, so dropping it leaves the hull exactly the
    same while Qhull sees a few per cent of a dense cloud.
    """
    if len(pts) < 200:
        return pts
    dirs = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                     if (i, j, k) != (0, 0, 0)], dtype=np.float64)
    centred = pts - pts.mean(axis=0)
    extreme = np.unique(np.argmax(centred @ dirs.T, axis=0))
    try:
        inner = ConvexHull(centred[extreme])
    except QhullError:
        return pts
    # Inside every facet plane by a margin (relative to the cloud's size): safe to drop.
    margin = 1e-9 * float(np.ptp(centred, axis=0).max())
    inside = (centred @ inner.equations[:, :3].T + inner.equations[:, 3] < -margin).all(axis=1)
    return pts[~inside]


def projected_area_xy(points: Any, *, cell: float = 0.005) -> float:
    """Area of the cloud's shadow on the XY plane, by an occupancy grid.

    Counts the square cells of side ``cell`` holding at least one point (grid aligned
    on the origin). It reads high by about ``cell / 2`` times the outline's length, and
    low where points are sparser than ``cell``.

    Args:
        points: (n, 3) or (n, 2) float64, metres.
        cell: grid cell side, metres.

    Returns:
        Area in m^2.
    """
    pts = np.asarray(points, dtype=np.float64)
    if not cell > 0:
        raise ValueError(f"cell must be > 0 metres, got {cell!r}")
    if len(pts) == 0:
        return 0.0
    ij = np.floor(pts[:, :2] / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    # One int64 key a cell: np.unique on rows sorts structured records, far slower.
    return float(len(np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1])) * cell * cell)


# --------------------------------------------------------------------------
# whole plants
# --------------------------------------------------------------------------
def top_voxel_min_points(scale: "segmentation.CloudScale") -> int:
    """Points a voxel needs to set :func:`robust_height`: 2, up to 4 as the noise reaches the spacing.

    ``2 + round(2 min(1, noise / spacing))``. On a noise-free cloud two points in a voxel
    are a surface (one stray point is not). Range noise spreads a surface's points into
    a band a few noise widths deep, and as the noise approaches the point spacing, pairs
    of points from the band's upper tail share voxels above the surface; more points a
    voxel pull the top back into the band. A flat sheet with 3 mm noise (3.8 mm spacing)
    reads 8.6 mm high with 2 points and 6.3 mm with 4. On the realistic 1-degree scans of
    ``scripts/traits_accuracy.py``: maize +1.3 -> -0.3 %, wheat +2.4 -> +1.6 %, 30-leaf
    rosette +4.5 -> -0.7 %, dicot +3.9 -> +2.6 %; the ideal scans (noise under a quarter
    of the spacing) keep 2 and their heights. Not removed: mixed-pixel points (a beam's
    footprint split between a near and a far leaf), which lie between organs, e.g. above
    a rosette's centre: every turn's beams cross the axis, and :func:`robust_height`
    asks the voxels there for more points (:func:`axis_crowding`; the 12-leaf rosette
    read +5.3 % with 2 or 4 points a voxel, -2.0 % so).
    """
    ratio = scale.noise_m / scale.spacing_m if scale.spacing_m > 0 else 0.0
    return 2 + round(2.0 * min(1.0, ratio))


# How far along its beam a point's neighbours reach, in its noise's standard deviations
# (beam_median_points), and so how far a point can move.
_BEAM_GATE_SIGMAS = 3.0


def beam_median_points(points_turntable: Any, range_noise_m: Any, *, radius_m: float,
                       moved: Any = None, gate_sigmas: float = _BEAM_GATE_SIGMAS, min_support: int = 3,
                       block: int = 512) -> np.ndarray:
    """Each point moved along its own beam to the surface its neighbours see there.

    Method: a range sensor's noise lies along the beam (a 2D LiDAR's beam angle is
    exact to the encoder; its range is not), so a point is only moved along its beam.
    For point ``i`` with beam ``d_i`` and noise ``sigma_i`` (``range_noise_m[i] =
    sigma_i d_i``), its neighbours are the points within ``radius_m`` of the line
    through it along ``d_i`` and within ``gate_sigmas sigma_i`` of it along that line:
    samples of the same patch of surface, whose offsets along ``d_i`` are the patch's
    depth plus the noise. The point moves to their median offset (robust to a mixed
    pixel or a second surface in the cylinder: Huber 1981, "Robust Statistics"; the
    median, not the mean, as a range-image median filter uses it). It is
    :mod:`plantsim.cloud.denoise`'s idea (ranges refitted among their neighbours, along
    the beams) on a cloud, which has no range image but gives each point its beam. A
    point with fewer than ``min_support`` points in its cylinder (itself counted), such
    as a stray point, keeps its place.

    Validity: surfaces wider than ``radius_m`` (a planar patch's median offset is its
    depth at the beam; a curved one is flattened by its sag over ``radius_m``); a
    point with ``sigma_i = 0`` keeps its place. Within ``radius_m`` the surfaces the
    noise overlaps are averaged into the majority, as the raw ranges cannot tell them
    apart either. A sheet sampled every 2 mm, seen 45 deg from above with 10 mm range
    noise, spreads 7.1 mm in z, and 1.6 mm once moved (``radius_m`` 4 mm,
    ``tests/test_beam_median.py``). On the realistic 1-degree scans of
    ``scripts/traits_accuracy.py`` (``radius_m`` two spacings) :func:`robust_height`
    reads the 3-leaf maize -0.1 % for -3.6 % (every shifted grid within 3.3 %, for
    8.7 %), and a 3-leaf rosette seen from 45 deg above, whose noise is 7 mm vertical,
    -1.0 % for +9.5 %.

    Args:
        points_turntable: (n, 3) float64, metres.
        range_noise_m: (n, 3) float64 metres, per point its beam's unit direction
            times its range noise's standard deviation
            (:func:`plantsim.evaluation.evaluate.range_noise_vectors`).
        radius_m: the cylinder's radius round each beam, metres (> 0).
        moved: optional (n,) bool, the points to move (None: all); the others keep
            their place but count as neighbours.
        gate_sigmas: the cylinder's half-length along the beam, in ``sigma_i``.
        min_support: points a cylinder needs to move its point.
        block: points per neighbour query (bounds memory).

    Returns:
        (n, 3) float64, the moved points.
    """
    from plantsim.evaluation import segmentation

    pts = _as_cloud(points_turntable)
    noise = segmentation.checked_range_noise(range_noise_m, pts)
    if not (math.isfinite(radius_m) and radius_m > 0):
        raise ValueError(f"radius_m must be a length > 0 metres, got {radius_m!r}")
    if not (math.isfinite(gate_sigmas) and gate_sigmas > 0) or min_support < 1 or block < 1:
        raise ValueError(f"gate_sigmas must be > 0 and min_support and block at least 1, got {gate_sigmas!r}, "
                         f"{min_support!r}, {block!r}")
    if moved is not None and np.shape(moved) != (len(pts),):
        raise ValueError(f"moved must be one bool a point ({len(pts)}), got shape {np.shape(moved)}")
    sigma = np.linalg.norm(noise, axis=1)
    todo = sigma > 0
    if moved is not None:
        todo &= np.asarray(moved, dtype=bool)
    out = pts.copy()
    idx = np.flatnonzero(todo)
    if not len(idx):
        return out
    tree = cKDTree(pts)
    # Each cylinder is covered by balls of radius 1.25 radius_m spaced 1.5 radius_m along
    # the beam (a ball that far from the next one still covers the cylinder's radius): far
    # fewer points to look at than one ball round the whole cylinder, 3 sigma long.
    ball, spacing = 1.25 * radius_m, 1.5 * radius_m
    for start in range(0, len(idx), block):
        chunk = idx[start:start + block]
        half = gate_sigmas * sigma[chunk]
        n_balls = np.ceil(2.0 * half / spacing).astype(np.int64) + 1
        owner = np.repeat(np.arange(len(chunk)), n_balls)
        first = np.r_[0, np.cumsum(n_balls)[:-1]]
        k = np.arange(len(owner)) - first[owner]
        t = -half[owner] + k * (2.0 * half[owner] / np.maximum(n_balls[owner] - 1, 1))
        dirs = noise[chunk] / sigma[chunk, None]
        here = pts[chunk]
        centres = here[owner] + t[:, None] * dirs[owner]
        found = tree.query_ball_point(centres, ball, return_sorted=False)
        # Every (point, neighbour) pair the balls found, once, then the cylinder's test and
        # each point's median offset, for the whole block at once.
        lengths = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
        neighbour = np.fromiter(itertools.chain.from_iterable(found), dtype=np.int64, count=int(lengths.sum()))
        who = np.repeat(owner, lengths)
        key = np.unique(who * len(pts) + neighbour)
        who, neighbour = key // len(pts), key % len(pts)
        v = pts[neighbour] - here[who]
        along = np.einsum("ij,ij->i", v, dirs[who])
        lateral_sq = np.einsum("ij,ij->i", v, v) - along * along
        near = (lateral_sq < radius_m * radius_m) & (np.abs(along) < half[who])
        who, along = who[near], along[near]
        order = np.lexsort((along, who))
        who, along = who[order], along[order]
        count = np.bincount(who, minlength=len(chunk))
        begin = np.r_[0, np.cumsum(count)[:-1]]
        ok = count >= min_support
        lo = along[begin[ok] + (count[ok] - 1) // 2]
        hi = along[begin[ok] + count[ok] // 2]
        out[chunk[ok]] = here[ok] + (0.5 * (lo + hi))[:, None] * dirs[ok]
    return out


def _top_voxels(pts: np.ndarray, cell: float, min_points: float,
                offsets: list[np.ndarray]) -> list[tuple[float, np.ndarray]]:
    """On each grid, the highest centroid of the voxels holding enough points, and the
    indices of that voxel's points (the highest point's alone when no voxel holds enough)."""
    from plantsim.evaluation import segmentation

    tops = []
    for offset in offsets:
        cent, inv = segmentation.voxel_centroids(pts, cell, offset)
        counts = np.bincount(inv, minlength=len(cent))
        ok = np.flatnonzero(counts >= min_points * axis_crowding(cent, pts, cell))
        if len(ok):
            top = int(ok[np.argmax(cent[ok, 2])])
            tops.append((float(cent[top, 2]), np.flatnonzero(inv == top)))
        else:
            highest = int(np.argmax(pts[:, 2]))
            tops.append((float(pts[highest, 2]), np.array([highest])))
    return tops


def _half_beam_gaps(tops: list[tuple[float, np.ndarray]], gaps: np.ndarray | None) -> list[float]:
    """On each grid, half the median beam gap (:func:`robust_height`'s ``beam_gaps_m``)
    of the top voxel's points (``tops``: :func:`_top_voxels`'); 0 without gaps, or
    where none of them is known."""
    out = []
    for _, members in tops:
        known = np.zeros(0) if gaps is None else gaps[members][np.isfinite(gaps[members])]
        out.append(0.5 * float(np.median(known)) if len(known) else 0.0)
    return out


def _checked_gaps(beam_gaps_m: Any, n: int) -> np.ndarray | None:
    if beam_gaps_m is None:
        return None
    gaps = np.asarray(beam_gaps_m, dtype=np.float64)
    if gaps.shape != (n,):
        raise ValueError(f"beam_gaps_m must give one gap a point ({n}), got shape {gaps.shape}")
    if np.any(gaps[np.isfinite(gaps)] < 0) or np.any(np.isinf(gaps)):
        raise ValueError("beam_gaps_m must be metres >= 0, or NaN where not known")
    return gaps


def heights_over_grids(points_turntable: Any, *, base_z: float = 0.0, cell: float | None = None,
                       min_points: int | None = None,
                       scale: "segmentation.CloudScale | None" = None,
                       grid_offsets: Any = ((0.0, 0.0, 0.0),),
                       range_noise_m: Any = None, beam_gaps_m: Any = None) -> tuple[float, ...]:
    """:func:`robust_height` on each of several voxel grids, the points moved along
    their beams once for all of them.

    Moving the points (:func:`beam_median_points`) does not depend on the grid; only
    those that can reach a top voxel are moved: a point moves by at most 3 sigma
    ``|d_z|`` in z, and a top voxel's points lie within a cell below its centroid, so
    the band of points moved is widened until it holds every point that can reach the
    lowest top found, and the heights equal those of the whole cloud moved (tested).

    Args:
        points_turntable, base_z, cell, min_points, scale, range_noise_m, beam_gaps_m:
            as :func:`robust_height`'s.
        grid_offsets: a sequence of :func:`robust_height`'s ``grid_offset``.

    Returns:
        One height a grid, metres, in the order of ``grid_offsets``.
    """
    from plantsim.evaluation import segmentation

    pts = _as_cloud(points_turntable)
    if scale is None and (cell is None or min_points is None or range_noise_m is not None):
        scale = segmentation.kept_points(pts)[1]
    if cell is None:
        cell = scale.voxel_m
    if min_points is None:
        min_points = top_voxel_min_points(scale)
    offsets = [np.asarray(o, dtype=np.float64) for o in grid_offsets]
    for offset in offsets:
        if offset.shape != (3,) or not np.all((offset >= 0) & (offset < 1)):
            raise ValueError(f"grid_offset must be 3 fractions of a cell in [0, 1), got {tuple(offset)!r}")
    gaps = _checked_gaps(beam_gaps_m, len(pts))
    noise = None if range_noise_m is None else segmentation.checked_range_noise(range_noise_m, pts)
    tops, _, _, halves = _heights_moved_along_beams(pts, cell, min_points, offsets, noise,
                                                    2.0 * scale.spacing_m if noise is not None else 0.0, gaps)
    return tuple(top + half - base_z for top, half in zip(tops, halves))


def _heights_moved_along_beams(pts: np.ndarray, cell: float, min_points: float, offsets: list[np.ndarray],
                               noise: np.ndarray | None, radius_m: float, gaps: np.ndarray | None = None
                               ) -> tuple[list[float], list[float], int, list[float]]:
    """(tops with the points moved along their beams, tops as measured, points moved,
    half the top voxel's beam gap on each grid, :func:`_half_beam_gaps`); the two tops
    equal and 0 moved without noise (None or zeros). The tops do not hold the half gaps."""
    voxels = _top_voxels(pts, cell, min_points, offsets)
    raw = [z for z, _ in voxels]
    if noise is None or not np.any(noise != 0):
        return raw, raw, 0, _half_beam_gaps(voxels, gaps)
    # Only points that can reach a top voxel once moved need moving: a point moves at
    # most 3 sigma |d_z| in z, and a top voxel's points lie within a cell below its
    # centroid. Widen the band until it holds every point that can reach the lowest
    # top found; the heights are then those of the whole cloud moved.
    reach_z = _BEAM_GATE_SIGMAS * np.abs(noise[:, 2])
    moved_pts = pts.copy()
    done = np.zeros(len(pts), dtype=bool)
    tops = raw
    cut = min(tops) - cell
    while True:
        band = (pts[:, 2] + reach_z >= cut) & ~done
        if band.any():
            moved_pts[band] = beam_median_points(pts, noise, radius_m=radius_m, moved=band)[band]
            done |= band
        voxels = _top_voxels(moved_pts, cell, min_points, offsets)
        tops = [z for z, _ in voxels]
        if min(tops) - cell >= cut or done.all():
            break
        cut = min(tops) - cell
    return (tops, raw, int(np.count_nonzero(np.any(moved_pts != pts, axis=1))),
            _half_beam_gaps(voxels, gaps))


def robust_height(points_turntable: Any, *, base_z: float = 0.0, cell: float | None = None,
                  min_points: int | None = None,
                  scale: "segmentation.CloudScale | None" = None,
                  grid_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  range_noise_m: Any = None, beam_gaps_m: Any = None) -> float:
    """Height of the plant that one stray point, or the noise's upper tail, cannot set.

    Method: the highest centroid of the voxels (side ``cell``; default the cloud's
    working resolution ``max(2 spacing, 1.5 noise)``, :func:`plantsim.evaluation
    .segmentation.estimate_scale`) holding at least ``min_points`` points (default
    :func:`top_voxel_min_points`: 2 on a noise-free cloud, up to 4 on a noisy one)
    times the voxel's :func:`axis_crowding` (a turntable scan samples the voxels near
    its axis more densely, and stray points crowd there with the surfaces' points). A
    stray point is alone in its voxel; averaging within a voxel pulls a noisy top back
    towards the surface. Valid when the top organ carries at least ``min_points`` points
    a voxel (more near the axis, as a turntable scan gives it); a top seen by fewer
    beams reads low by up to one voxel.

    Given each point's range noise (``range_noise_m``), the points are first moved
    along their beams onto the surface their neighbours see (:func:`beam_median_points`,
    in a cylinder of radius two spacings round each beam): a voxel count alone cannot
    tell a noisy top from the band the noise spreads it into, which is several voxels
    deep when the beams look down on the top (a LiDAR raised above a flat plant, as ``--fit-rig`` sets it:
    the 3-leaf rosette's top read +9.5 % on one grid, -0.8 % on another). Only the
    points that can reach the top are moved.

    Given each point's beam gap (``beam_gaps_m``: how far up the vertical through it
    the fan's next beam passes), half the top voxel's median gap is added. A scan
    samples the plant on its beams, and the top of a thin organ (a leaf's tip) lies
    between the highest beam that hits it and the next, which passes over it; with
    nothing to say where in that interval, its middle is the estimate whose error is
    least on average (uniformly placed, the error is then within half a gap, not one
    gap always low). On the default rig the URG's beams, 0.35 deg apart, pass 1.9-2.7
    mm apart at a rosette's top: the ideal 0.5-degree scans of nine rosettes 67-78 mm
    tall read 0.7-2.9 % low without it, -1.6..+0.8 % with it, and those of 17
    procedural plants (``scripts/traits_accuracy.py`` and ``scripts/traits_other_seeds.py
    --ideal --step 0.5``) 0.96 % off on average without it, 0.44 % with it. A top that
    is a broad surface, seen by many beams as the table turns, is sampled to within a
    fraction of a gap, and reads high by up to half one (the ideal dicots and 3-leaf
    bean +0.3 %): valid where half a gap is small against the height.

    The segmentation's outlier removal is not applied first: its threshold is global
    (Rusu et al. 2008), and a plant's sparse top is what it drops. The ideal 1-degree
    scan of the seed rig's wheat lost 178 of the 456 points of its ears that way and
    read 6.9 % low; a stray point needs no removal to be ignored here.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame, n >= 17.
        base_z: z of the plant base, metres.
        cell: voxel side, metres (None: from the cloud's scale).
        min_points: points a voxel at the median point's distance from the axis needs
            to count (None: from the cloud's scale); nearer the axis, more
            (:func:`axis_crowding`).
        scale: the cloud's :class:`~plantsim.evaluation.segmentation.CloudScale`
            when already estimated (``Segmentation.scale``); None estimates it when
            needed (:func:`plantsim.evaluation.segmentation.kept_points`' scale).
        grid_offset: where the voxel grid starts, x, y, z in fractions of ``cell``
            in [0, 1), as :func:`plantsim.evaluation.segmentation.voxel_centroids`
            takes it (zeros: anchored on the origin). The height depends on it by up
            to a voxel where the top is sparse or noisy (:attr:`PlantTraits
            .heights_over_grids_m`).
        range_noise_m: optional (n, 3) float64 metres, per point its beam's unit
            direction times its range noise's standard deviation
            (:func:`plantsim.evaluation.evaluate.range_noise_vectors`); None or zeros
            (an ideal scan): the points as they are.
        beam_gaps_m: optional (n,) float64 metres, per point how far up the vertical
            through it the fan's next beam passes, NaN where not known
            (:func:`plantsim.evaluation.evaluate.beam_gaps_m`); None: the top as
            sampled, nothing added.

    Returns:
        Height in metres.
    """
    return heights_over_grids(points_turntable, base_z=base_z, cell=cell, min_points=min_points,
                              scale=scale, grid_offsets=(grid_offset,), range_noise_m=range_noise_m,
                              beam_gaps_m=beam_gaps_m)[0]


def axis_crowding(centres_turntable: Any, points_turntable: Any, cell: float) -> np.ndarray:
    """How many times more densely than the cloud's median point a turntable scan
    samples each voxel: ``max(1, r_median / max(r, cell))``, ``r`` the voxel centre's
    distance from the turntable axis and ``r_median`` the median point's.

    Between two scans the fan sweeps a point at distance ``r`` from the axis through
    ``r * step``: a surface's points crowd towards the axis as ``1 / r``, and every
    scan's fan crosses the voxels on the axis. Stray points crowd there too: noise
    tails and mixed pixels of the beams passing over a rosette's centre, between a
    near leaf's edge and a far leaf, from every turn. On the realistic 1-degree scans
    of ``scripts/traits_accuracy.py`` the median count of the occupied voxels doubles
    with each halving of their radius (12-leaf rosette: 4 at 30-60 mm, 8 at 15-30 mm,
    15 at 8-15 mm, 28 within a voxel of the axis; maize 2, 5, 28, 86 from 60 mm in).

    Validity: turntable scans (and clouds whose density grows towards the axis
    like theirs). A cloud sampled evenly, by a scanner that does not turn the plant,
    is asked for up to ``r_median / cell`` times the points its voxels near the axis
    hold: a top there reads low, at the highest voxel that holds that many.

    Args:
        centres_turntable: (m, 3) float64, metres, the voxel centres.
        points_turntable: (n, 3) float64, metres, the cloud.
        cell: voxel side, metres.

    Returns:
        (m,) float64, at least 1.
    """
    centres = np.asarray(centres_turntable, dtype=np.float64)
    pts = np.asarray(points_turntable, dtype=np.float64)
    r_median = float(np.median(np.hypot(pts[:, 0], pts[:, 1]))) if len(pts) else 0.0
    return np.maximum(1.0, r_median / np.maximum(np.hypot(centres[:, 0], centres[:, 1]), cell))


# The 2nd-98th percentile extent of a normal distribution, in standard deviations
# (2 x Phi^-1(0.98)): what a leaf width (node_frames) reads from noise alone.
_NOISE_EXTENT_SIGMAS = 2.0 * 2.053748910631823
# A leaf's width is resolved while the noise's own extent across it is under this share
# of the width read. A uniform strip of width w under Gaussian noise sigma reads
# (segmentation.uniform_width of its 2nd-98th percentile extent, many points; exact
# percentiles of the uniform-normal convolution) 1.14 w at sigma = 0.1 w (noise extent
# 36 % of the read width), 1.23 w at 0.135 w (45 %), 1.27 w at 0.15 w (48 %), 1.42 w at
# 0.2 w (58 %): at 45 %, the width reads about 23 % wide, the issue's tolerance for
# leaf traits (20 %).
_RESOLVED_NOISE_SHARE = 0.45


def _node_noise_widths(noise_m: np.ndarray, node: np.ndarray, tangent: np.ndarray, normal: np.ndarray
                       ) -> np.ndarray:
    """Per midrib node, the width the range noise alone reads across it
    (:func:`leaf_noise_width`); NaN with under 3 points or no normal."""
    m = len(tangent)
    across = np.cross(normal, tangent)
    across /= np.maximum(np.linalg.norm(across, axis=1), 1e-12)[:, None]
    count = np.bincount(node, minlength=m)
    ok = (count >= 3) & np.all(np.isfinite(normal), axis=1)
    safe = np.where(ok[:, None], across, 0.0)
    sq = np.einsum("ni,ni->n", noise_m, safe[node]) ** 2
    mean_sq = np.bincount(node, weights=sq, minlength=m) / np.maximum(count, 1)
    return np.where(ok, _NOISE_EXTENT_SIGMAS * np.sqrt(mean_sq), _NAN)


def leaf_noise_width(noise_m: np.ndarray, node: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                     nodes: np.ndarray) -> float:
    """The width the range noise alone reads across a leaf: the median over ``nodes``
    of ``4.11 sqrt(mean((v_i . u)^2))``, ``v_i`` each point's noise vector (its beam's
    unit direction times the noise's standard deviation) and ``u`` the node's direction
    across the midrib in the leaf's plane (``normal x tangent``); NaN with no node of 3
    points and a normal.

    Noise along a beam that crosses a leaf at a slant moves the point within the leaf's
    plane, and the width reads it; along the leaf's normal it does not.

    Args:
        noise_m: (m, 3) float64 metres, each of the leaf's points' noise vector.
        node: (m,) int, each point's midrib node.
        tangent, normal: (k, 3) per node (:func:`plantsim.evaluation.segmentation.node_frames`).
        nodes: the node indices the width is read over.
    """
    per_node = _node_noise_widths(noise_m, node, tangent, normal)[np.asarray(nodes, dtype=np.int64)]
    per_node = per_node[np.isfinite(per_node)]
    return float(np.median(per_node)) if len(per_node) else _NAN


# across_beam_width's limits: the beams must cross the fitted leaf plane at more than
# asin(0.2) = 12 deg for half the cross-section's points, and a point's own beam at more
# than asin(0.1) = 6 deg, or where it meets the plane is its noise magnified; a point whose
# beam meets the plane more than 3 standard deviations of its range noise away is no
# point of that leaf (the fit's truncated quadratic loss); and the plane must explain the
# points' spread along their beams as the noise: the mean truncated squared residual, in
# standard deviations, at most 2 (0.995 for Gaussian noise alone; a strip w wide whose
# width lies along the beams leaves 1 + w^2 / (12 sigma^2)).
_ACROSS_BEAM_MIN_SIN = 0.2
_ACROSS_BEAM_POINT_MIN_SIN = 0.1
_ACROSS_BEAM_OUTLIER_SIGMAS = 3.0
_ACROSS_BEAM_MAX_MEAN_Z2 = 2.0
# The twist must be determined: every plane 30 deg or more from the fitted one explains
# the points worse by at least 4 in the cost (a likelihood ratio of e^2: 2 standard
# deviations). Beams that all lie in one plane with the midrib meet every other plane
# through it on one line, and leave the twist free.
_ACROSS_BEAM_TWIST_FREE_DEG = 30.0
_ACROSS_BEAM_MIN_COST_GAIN = 4.0
# The twist is fitted on at most this many of the points (across_beam_width).
_ACROSS_BEAM_FIT_POINTS = 3000
# A leaf's width read across the beams at a midrib node fits its twist over the nodes
# this many steps either side of it too (_leaf_measures).
_ACROSS_BEAM_TWIST_NODES = 2
_ACROSS_BEAM_MIN_POINTS = 6


def across_beam_width(offsets_m: Any, noise_m: Any, tangent: Any, *, own: Any = None) -> float:
    """The width of a leaf's cross-section read where its points' beams meet the leaf,
    which the range noise does not move; NaN where the beams cannot read it.

    Range noise moves each point along its own beam only: the beam, the line through
    the point along its direction, is exact, and only the distance along it is noisy.
    The cross-section is modelled as a strip through its centre along the midrib's
    tangent ``t``, turned by ``phi`` about it (a leaf's twist): a plane. For each
    ``phi`` every beam meets that plane at a distance ``lambda_i`` along the beam from
    its point; the plane fitted is the one the range noise explains best, least
    ``sum(min((lambda_i / sigma_i)^2, 9))`` (``sigma_i`` the point's range noise: the
    likelihood of Gaussian noise along each beam, truncated at 3 standard deviations
    so that another organ's points in the cross-section do not pull it), over ``phi``
    in 2 deg steps refined to 0.05 deg. The width is
    :func:`plantsim.evaluation.segmentation.uniform_width` of where the beams of the
    points within 3 standard deviations meet the plane, across the midrib.

    A turntable rig's beams lie in planes through its axis: on a leaf running out from
    the axis they cross its width nearly at right angles, and its width is, the noise
    notwithstanding, about the arc its points' turn angles span (exact on a plane strip
    without noise: ``tests/test_across_beam_width.py``). A 10 mm leaf under 10 mm of
    range noise reads its width within 8 % at twists of 0-45 deg, where its points
    spread two to three times as wide.

    NaN with under 6 points or a beam direction of length 0; when half the points'
    beams cross the fitted plane within 12 deg of it (the beams run along the midrib,
    or graze the leaf); when the plane leaves the points spread along their beams
    more than the noise does (the mean truncated squared residual over 2 standard
    deviations squared: the leaf's width lies along the beams); with under 6 points
    whose beams meet the plane within 3 standard deviations; or when the twist is not
    determined: some plane 30 deg or more from the fitted one explains the points
    within 4 of its cost (a likelihood ratio under e^2). Beams that all lie in one
    plane with the midrib meet every other plane through it on one line, at no width.

    Its limit: a leaf whose plane holds every beam that meets the cross-section (seen
    edge-on from every view: a leaf running round the axis at the LiDAR's height) is
    told from a sliver across the beams only by the spread its width adds along them,
    ``w^2 / (12 sigma^2)`` a point; when they also lie in one plane the twist is free
    (above). Either reads NaN: the points' width (the noise's) stands, and
    :attr:`Leaf.width_resolved` says so.

    The twist can be fitted over more points than the width is read from: the
    neighbouring cross-sections' (``own`` marks the cross-section's own), each about
    its own centre. A leaf's twist changes slowly along it, and a narrow leaf's points
    under noise as wide as it hold little of its twist: fitted node by node alone, a
    10 mm strip under 10 mm of noise, twisted 30-45 deg, read up to 17-21 mm wide on
    some nodes (a twist read too far reads the width ``1 / cos`` of the error wide).

    Args:
        offsets_m: (n, 3) float64 metres, the points about their cross-section's centre
            (the midrib's node: the mean of its points), their component along the
            midrib removed or not (only offsets across it count).
        noise_m: (n, 3) float64 metres, each point's beam direction times its range
            noise's standard deviation (> 0): as :func:`extract_traits`'
            ``range_noise_m``.
        tangent: (3,) float64, the midrib's direction at the cross-section.
        own: optional (n,) bool, the points of the cross-section whose width is read
            (the others only help fit the twist); None: all.

    Returns:
        The width in metres, or NaN.
    """
    from plantsim.evaluation.segmentation import uniform_width

    q = np.asarray(offsets_m, dtype=np.float64)
    v = np.asarray(noise_m, dtype=np.float64)
    t = np.asarray(tangent, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 3 or v.shape != q.shape or t.shape != (3,):
        raise ValueError(f"offsets_m and noise_m must be (n, 3) alike and tangent (3,), got "
                         f"{q.shape}, {v.shape} and {t.shape}")
    t_norm = float(np.linalg.norm(t))
    sigma = np.linalg.norm(v, axis=1)
    if not t_norm > 0 or not np.all(sigma > 0):
        return _NAN
    t = t / t_norm
    b = v / sigma[:, None]
    mine = np.ones(len(q), dtype=bool) if own is None else np.asarray(own, dtype=bool)
    if mine.shape != (len(q),):
        raise ValueError(f"own must be (n,) bool like offsets_m's rows, got shape {mine.shape}")
    if int(mine.sum()) < _ACROSS_BEAM_MIN_POINTS:
        return _NAN
    # Two directions across the midrib; the strip's width at phi is cos(phi) e1 + sin(phi) e2.
    e1 = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t, e1)
    limit = _ACROSS_BEAM_OUTLIER_SIGMAS ** 2

    def normals(phi: np.ndarray) -> np.ndarray:
        return np.outer(-np.sin(phi), e1) + np.outer(np.cos(phi), e2)  # t x width

    def meets(phi: np.ndarray, rows: Any = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        n = normals(phi)
        bn = b[rows] @ n.T
        ok = np.abs(bn) >= _ACROSS_BEAM_POINT_MIN_SIN
        lam = -(q[rows] @ n.T) / np.where(ok, bn, 1.0)
        z2 = np.where(ok, (lam / sigma[rows, None]) ** 2, np.inf)
        return lam, z2

    # The twist is fitted on at most _ACROSS_BEAM_FIT_POINTS of the points, every k-th:
    # a blob of thousands of points (a flat plant seen from above as one leaf) holds its
    # twist many times over, and each trial angle costs a pass over the points.
    fit = (slice(None) if len(q) <= _ACROSS_BEAM_FIT_POINTS
           else np.linspace(0, len(q) - 1, _ACROSS_BEAM_FIT_POINTS).round().astype(np.int64))

    def cost(phi: np.ndarray) -> np.ndarray:
        return np.minimum(meets(phi, fit)[1], limit).sum(axis=0)

    grid = np.radians(np.arange(0.0, 180.0, 2.0))
    grid_cost = cost(grid)
    best = float(grid[int(np.argmin(grid_cost))])
    off = np.abs((grid - best + 0.5 * np.pi) % np.pi - 0.5 * np.pi)
    far = off >= math.radians(_ACROSS_BEAM_TWIST_FREE_DEG)
    if float(grid_cost[far].min() - grid_cost.min()) < _ACROSS_BEAM_MIN_COST_GAIN:
        return _NAN
    fine = best + np.radians(np.arange(-2.0, 2.0 + 1e-9, 0.05))
    phi = float(fine[int(np.argmin(cost(fine)))])
    n = normals(np.array([phi]))[0]
    lam, z2 = meets(np.array([phi]))
    if float(np.median(np.abs(b[mine] @ n))) < _ACROSS_BEAM_MIN_SIN:
        return _NAN
    if float(np.minimum(z2[mine, 0], limit).mean()) > _ACROSS_BEAM_MAX_MEAN_Z2:
        return _NAN
    inlier = mine & (z2[:, 0] <= limit)
    if int(inlier.sum()) < _ACROSS_BEAM_MIN_POINTS:
        return _NAN
    width_dir = math.cos(phi) * e1 + math.sin(phi) * e2
    on_plane = q[inlier] + lam[inlier, 0:1] * b[inlier]
    return uniform_width(on_plane @ width_dir)


def _beam_stem_diameter(seg: "segmentation.Segmentation", i: int, noise: np.ndarray | None,
                        base_z: float) -> float:
    """Stem ``i``'s diameter where the beams through the turntable's axis meet it
    (:func:`plantsim.evaluation.segmentation.beam_stem_diameter`, on the segmentation's
    points, slices of half a voxel, up to the stem's top as segmented), for the stems the
    beams through the axis read (:func:`plantsim.evaluation.segmentation.read_by_axis_beams`,
    as the segmentation takes them for the beams' top); NaN elsewhere."""
    from plantsim.evaluation import segmentation

    st = seg.stems[i]
    if not segmentation.read_by_axis_beams(st, noise is not None and bool(np.any(noise))):
        return _NAN
    return segmentation.beam_stem_diameter(
        seg.points, noise, base_z=base_z, top_z=float(seg.stem_tops_m[i, 2]),
        slice_m=segmentation.CUP_SLICE_VOXELS * seg.scale.voxel_m, max_miss_m=0.25 * seg.scale.spacing_m)


def _base_widths_of(seg: "segmentation.Segmentation", i: int) -> np.ndarray | None:
    """Leaf ``i``'s base node widths the beams read (``Segmentation.leaf_base_widths_m``), or None."""
    widths = seg.leaf_base_widths_m[i] if i < len(seg.leaf_base_widths_m) else None
    return widths if widths is not None and len(widths) else None


class _LeafMeasures(typing.NamedTuple):
    """What :func:`_leaf_measures` reads of one leaf (the noise fields NaN and None
    without the range noise)."""

    length_m: float
    width_m: float
    area_m2: float
    inclination_deg: float
    noise_width_m: float
    width_resolved: bool | None
    across_beams_share: float
    junction_widths_ramped: int = 0


# Cross-sections this many standard deviations of the range noise or less from a leaf's
# junction hold the stem's and the other leaves' points the noise spreads there
# (_ramp_junction_widths).
_JUNCTION_NOISE_SIGMAS = 3.0


def _ramp_junction_widths(widths: np.ndarray, midrib: np.ndarray, along: np.ndarray, unread: np.ndarray,
                          read_across: np.ndarray, noise_m: np.ndarray | None) -> int:
    """Ramp the widths of a leaf's unread cross-sections at its junction, in place;
    returns how many. ``along``: each midrib node's distance along it from the junction.

    Within :data:`_JUNCTION_NOISE_SIGMAS` of the range noise of the junction, the
    noise spreads the stem's points and the other leaves' bases (a rosette's, all
    from the axis) into the leaf's cross-sections: their points' spread is the noise's,
    and their beams, crossing several organs, read no one plane
    (:func:`across_beam_width`). The leading run of such ``unread`` nodes (from node
    1), those that close to the junction, take the width of a leaf that narrows to its
    junction, as the area already takes it between the junction and the first node:
    linear along the midrib from 0 at the junction to the first node past them. Only
    when a node past them was read across the beams: a leaf none of whose widths the
    beams read keeps its points' widths, and says so (``width_resolved``). The
    realistic 3-leaf rosette, its leaves split round its axis
    (segmentation._split_at_axis), read +42 % in area with their bases' noise, +25 %
    with them ramped; no other plant of tests/test_traits_procedural.py changes."""
    if noise_m is None or len(widths) < 3:
        return 0
    sigma = float(np.median(np.linalg.norm(noise_m, axis=1)))
    run = 1
    while run < len(widths) and unread[run]:
        run += 1
    near = np.linalg.norm(midrib[1:run] - midrib[0], axis=1) <= _JUNCTION_NOISE_SIGMAS * sigma
    k = 1 + int(np.argmin(near)) if not near.all() else run  # the first node past them
    if k == 1 or k >= len(widths) or not read_across[k:].any() or not along[k] > 0:
        return 0
    widths[1:k] = widths[k] * along[1:k] / along[k]
    return k - 1


def _leaf_measures(points: np.ndarray, midrib: np.ndarray, *, link: float | None = None,
                   noise_m: np.ndarray | None = None, base_widths_m: np.ndarray | None = None
                   ) -> _LeafMeasures:
    """Length, width, area, inclination and noise width of one segmented leaf.

    ``base_widths_m``: the widths of the midrib's first nodes where the beams read them
    (:attr:`plantsim.evaluation.segmentation.Segmentation.leaf_base_widths_m`), in place
    of the points' there.

    Length: the midrib polyline (skeleton centroids, junction to tip) plus the leaf's
    reach beyond its last centroid. A stalk is left out of length, area and inclination:
    the midrib's leading nodes narrower than ``STALK_WIDTH_SHARE`` of the leaf's width
    (a petiole; the procedural dicots' truth is the lamina), when the first of them holds
    a point per spacing (at most a quarter ``link``) along the step to it; the lamina
    starts halfway between the last narrow node and the first wide one. Width: per
    midrib node, the robust extent (2nd to 98th percentile) of the node's points across
    the midrib, along their main in-plane axis, read as a uniformly sampled strip's width
    (:func:`plantsim.evaluation.segmentation.uniform_width`), with ``link`` (the
    skeleton's link) only over the cross-section's runs in the leaf's own plane
    (another leaf crossing it at a node is left out:
    :func:`plantsim.evaluation.segmentation.node_frames`); the 90th percentile over
    the nodes of the outer four fifths of the midrib (the largest is where a
    neighbour touches; the base is sheath). Area: the triangulated ribbon between the
    two margins, i.e. sum over midrib segments of the mean of the two node widths
    times the segment length (a leaf surface unrolled along its midrib, as in the
    length-width area models of Montgomery 1911, here with the measured width
    profile); it fills holes inside a cross-section that occlusion leaves.
    Inclination: angle of the junction-to-tip chord (the lamina's base past a stalk)
    above the horizontal, degrees.
    Given ``noise_m`` ((m, 3) per point: its beam's unit direction times the range
    noise's standard deviation), each node's width is read where its points' beams meet
    the leaf (:func:`across_beam_width`, the twist fitted over the node and
    ``_ACROSS_BEAM_TWIST_NODES`` either side), where the beams can read it; a base node
    whose width the stem's column read as an arc takes that reading where it is wider.
    Noise width: :func:`leaf_noise_width` over the nodes the width is read over; the
    width is resolved unless half or more of them read the noise (its spread 45 % of
    their width or more) and were not read across the beams. Without ``noise_m`` the
    noise fields are NaN and None.
    """
    if len(midrib) < 2 or len(points) < 3:
        return _LeafMeasures(_NAN, _NAN, _NAN, _NAN, _NAN, None, _NAN)
    from plantsim.evaluation.segmentation import node_frames

    seg = np.diff(midrib, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    # Per node its width; each point to its nearest midrib node.
    tangent, normal, widths, node = node_frames(points, midrib, link=link)
    if base_widths_m is not None:
        # The base in a noisy stem's column, its widths read from the beams (segmentation
        # ._leaf_bases_from_beams): the noise moves no point in turn angle there.
        widths[:len(base_widths_m)] = base_widths_m[:len(widths)]
    # A cross-section whose points' width reads the range noise (its along-beam spread
    # across the midrib 45 % of the width or more) and which its beams cannot read
    # (across_beam_width) leaves the width unresolved.
    reads_noise = np.zeros(len(midrib), dtype=bool)
    read_across = np.zeros(len(midrib), dtype=bool)
    node_noise = np.full(len(midrib), _NAN)
    if noise_m is not None:
        node_noise = _node_noise_widths(noise_m, node, tangent, normal)
        reads_noise = np.isfinite(node_noise) & (node_noise >= _RESOLVED_NOISE_SHARE * widths)
        reads_noise[0] = False
        if base_widths_m is not None:
            reads_noise[:len(base_widths_m)] = False
        # Every cross-section with noise is read across its beams where they allow: the
        # noise widens the points' spread across the midrib by about its own share
        # (leaf_noise_width) whether or not that share reaches 45 %. The twist is fitted
        # over the node and its neighbours on either side, each point about its own
        # node's centre, and the midrib's direction is the chord across them: one step's
        # direction wobbles with the noise in the nodes.
        count = np.bincount(node, minlength=len(midrib))
        centre = np.column_stack([np.bincount(node, weights=points[:, k], minlength=len(midrib))
                                  for k in range(3)]) / np.maximum(count, 1)[:, None]
        offsets = points - centre[node]
        k = _ACROSS_BEAM_TWIST_NODES
        n_base = 0 if base_widths_m is None else len(base_widths_m)
        for j in range(1, len(midrib)):
            if not node_noise[j] > 0:
                continue
            near = np.abs(node - j) <= k
            chord = midrib[min(j + k, len(midrib) - 1)] - midrib[max(j - k, 0)]
            w = across_beam_width(offsets[near], noise_m[near], chord, own=node[near] == j)
            if not math.isfinite(w):
                continue
            if j < n_base:
                # The arc the stem's column reads is the part of the leaf inside it: where
                # the leaf leaves the column it reads a sliver of the cross-section.
                if w > widths[j]:
                    widths[j], read_across[j] = w, True
                continue
            widths[j], read_across[j], reads_noise[j] = w, True, False
    along = np.r_[0.0, np.cumsum(seg_len)]
    ramped = _ramp_junction_widths(widths, midrib, along, reads_noise & ~read_across, read_across, noise_m)
    tip_dir = seg[-1] / max(seg_len[-1], 1e-12)
    # The leaf's reach past its last node; none when no point is nearest that node (a
    # midrib can end past its points, as two merged halves' tips averaged do).
    at_tip = points[node == len(midrib) - 1]
    beyond = float(max(0.0, ((at_tip - midrib[-1]) @ tip_dir).max())) if len(at_tip) else 0.0
    widths[0] = 0.0  # the junction node is the stem's

    def outer_of(first: int, base_along: float) -> np.ndarray:
        # The widest cross-sections are where a neighbouring organ touches: the 90th
        # percentile of the node widths reads the leaf's own maximum width. The basal
        # fifth of the midrib (from ``base_along`` on) is left out: there the sheath
        # wraps the stem and the stem's off-axis points join the leaf
        # (segmentation._release_leaf_bases).
        nodes = first + np.flatnonzero(along[first:] - base_along >= 0.2 * (along[-1] - base_along))
        return nodes if len(nodes) else np.arange(max(first, 1), len(widths))

    outer_nodes = outer_of(0, 0.0)
    # A stalk (a petiole) is no part of the lamina: the nodes from the junction up to
    # the first as wide as STALK_WIDTH_SHARE of the leaf go; the lamina starts halfway
    # between that node and the last narrow one.
    wide = np.flatnonzero(widths[1:] >= STALK_WIDTH_SHARE * np.percentile(widths[outer_nodes], 90)) + 1
    first = int(wide[0]) if len(wide) else 1
    # A stalk is seen where it leaves the junction: its first node holds a point per
    # spacing (at most a quarter link) along the step to it, as a sampled surface does.
    # A leaf's base hidden under another leaf leaves a long step to a narrow sliver
    # instead (a rosette's leaf, whose narrow collar is in its truth: 17 points 43 mm out).
    seen = link is None or int(np.count_nonzero(node == 1)) >= seg_len[0] / (0.25 * link)
    if first >= 2 and seen:
        base = 0.5 * (midrib[first - 1] + midrib[first])
        lamina, lamina_widths = np.vstack([base, midrib[first:]]), np.r_[0.0, widths[first:]]
        outer_nodes = outer_of(first, along[first] - float(np.linalg.norm(midrib[first] - base)))
    else:
        lamina, lamina_widths = midrib, widths
    lamina_len = np.linalg.norm(np.diff(lamina, axis=0), axis=1)
    length = float(lamina_len.sum() + beyond)
    area = float(np.sum(0.5 * (lamina_widths[:-1] + lamina_widths[1:]) * lamina_len))
    chord = lamina[-1] - lamina[0]
    incl = float(np.degrees(np.arctan2(chord[2], np.hypot(chord[0], chord[1]))))
    width = float(np.percentile(widths[outer_nodes], 90))
    if noise_m is None:
        return _LeafMeasures(length, width, area, incl, _NAN, None, _NAN)
    checked = outer_nodes[np.isfinite(node_noise[outer_nodes])]
    noise_width = leaf_noise_width(noise_m, node, tangent, normal, outer_nodes)
    resolved = None if not len(checked) else bool(np.mean(reads_noise[checked]) < 0.5)
    return _LeafMeasures(length, width, area, incl, noise_width, resolved,
                         float(np.mean(read_across[outer_nodes])), ramped)


# A midrib's leading nodes narrower than this share of the leaf's width are its stalk (a
# petiole), not its lamina (:func:`_leaf_measures`). See docs/traits.md for how it was set.
STALK_WIDTH_SHARE = 0.2


# A leaf spans a sector round the stem it grows from: the outer half of every leaf found
# in the ideal and realistic scans of tests/test_traits_procedural.py spans 153 deg or
# less round its stem (a wheat leaf arching over its tiller), and clusters of 2-6 merged
# leaves 185 deg or less; the one cluster of a realistic rosette's leaves spans 359 deg.
ENCIRCLING_DEG = 270.0


def encircling_leaves(seg: "segmentation.Segmentation") -> list[tuple[int, float]]:
    """The found leaves that surround their stem, which no single leaf does.

    For each leaf, the points of its outer half (farther from the stem's axis than half
    its 95th-percentile reach) and the largest gap between their bearings round that
    axis: the span is 360 deg minus the gap. The axis is the found stem nearest the
    leaf's junction, or the cloud's median (x, y) with no stem. A leaf spanning more than
    ``ENCIRCLING_DEG`` is no single leaf: a ring of leaves (a rosette whose leaves the
    noise blurred together; the leaf count is then a lower bound) or a ring round the
    stem that is no leaf (the seed rig maize's mesh carries its turntable disk, and its
    realistic scan finds one 5-60 mm above the disk top, 9 cm in radius: the disk's
    top lifted by the range noise).

    Returns:
        (leaf index, span in degrees) of each such leaf.
    """
    pts = seg.points
    stems_xy = np.array([st.center_xy_m for st in seg.stems], dtype=np.float64).reshape(-1, 2)
    fallback = np.median(pts[:, :2], axis=0)
    out = []
    for i, midrib in enumerate(seg.leaf_midribs):
        q = pts[seg.leaf_label == i, :2]
        if len(q) < 5:
            continue
        axis = (stems_xy[np.argmin(np.linalg.norm(stems_xy - midrib[0, :2], axis=1))] if len(stems_xy)
                else fallback)
        d = q - axis
        r = np.hypot(d[:, 0], d[:, 1])
        outer = d[r > 0.5 * np.percentile(r, 95)]
        if len(outer) < 5:
            continue
        bearing = np.sort(np.degrees(np.arctan2(outer[:, 1], outer[:, 0])))
        span = 360.0 - float(np.diff(np.r_[bearing, bearing[0] + 360.0]).max())
        if span > ENCIRCLING_DEG:
            out.append((i, span))
    return out


def _above_mask(pts: np.ndarray, s: TraitSettings) -> np.ndarray:
    """The points traits read: those at or above ``base_z + ground_clearance``."""
    return pts[:, 2] >= s.base_z + s.ground_clearance


def on_file_grid(points: np.ndarray) -> np.ndarray:
    """Points rounded to the grid a LAS file keeps (0.01 mm,
    :data:`plantsim.cloud.export.LAS_SCALE_M`).

    Traits are measured on this grid, so a scan's traits in memory and those of the
    LAS file it was written to are the same numbers: the segmentation cuts the cloud
    with voxels and level sets, and a rounding that moves every point by up to 5 um
    moved a leaf across a boundary (an ideal maize read 9 leaves in memory and 10
    from its file). A float32 file (PLY, PCD) moves a coordinate by up to 0.03 um,
    and a few of its points round the other way. 0.01 mm is far below any scanner's
    range resolution (the URG-04LX's is 1 mm).
    """
    from plantsim.cloud.export import LAS_SCALE_M

    return np.round(points / LAS_SCALE_M) * LAS_SCALE_M


def leaf_groups_of(seg: "segmentation.Segmentation") -> tuple[int, ...]:
    """Each found lamina's leaf (:attr:`plantsim.evaluation.segmentation.Segmentation.leaf_group`;
    each lamina its own leaf when the segmentation gives no groups)."""
    n = len(seg.leaf_midribs)
    return tuple(seg.leaf_group) if len(seg.leaf_group) == n else tuple(range(n))


def leaf_count_of(seg: "segmentation.Segmentation") -> int:
    """The leaves a segmentation found, a compound leaf counted once."""
    return len(set(leaf_groups_of(seg)))


class _Grids(typing.NamedTuple):
    """The organs of a cloud on its shifted grids (:func:`_segment_above`)."""

    points_above: np.ndarray
    segmentation: "segmentation.Segmentation"  # the representative grid's
    leaf_counts: tuple[int, ...]
    leaf_areas_m2: tuple[float, ...]
    grids: tuple["segmentation.Segmentation", ...]  # every grid's, in the offsets' order
    leaf_measures: tuple["_LeafMeasures", ...]  # the representative grid's, leaf by leaf


def _segment_above(pts: np.ndarray, s: TraitSettings, noise: np.ndarray | None = None) -> _Grids:
    """The points above the ground clearance and their segmentation on
    ``s.shifted_grids`` grids, as traits read them: of the grids whose leaf count is
    the median, the one whose leaf area (:func:`_leaf_measures`) is nearest their
    median area (the first on a tie); and each grid's leaf count and leaf area.

    The median member in count, then in area: a micrometre's jitter changes a few
    grids' outcomes, and the median count rarely (scripts/traits_stability.py). The
    area moves more: where the grids' areas fall in two groups (a leaf lost to the
    stem's column on some grids), a jitter can pick a grid of the other group.
    ``noise``: each point of ``pts``' range noise vector, or None
    (:func:`plantsim.evaluation.segmentation.segment_organs`' ``range_noise_m``)."""
    from plantsim.evaluation import segmentation

    mask = _above_mask(pts, s)
    above = pts[mask]
    if len(above) < 17:
        raise ValueError(f"points_turntable holds {len(above)} points above the ground clearance; "
                         "traits need at least 17")
    grids = segmentation.segment_on_shifted_grids(
        above, settings=segmentation.SegmentationSettings(base_z=s.base_z, max_stem_diameter_m=s.stem_max_diameter),
        offsets=segmentation.shifted_grid_offsets(s.shifted_grids),
        range_noise_m=None if noise is None else noise[mask])
    counts = np.array([leaf_count_of(g) for g in grids])
    noise_above = None if noise is None else noise[mask]

    def measures_of(g: "segmentation.Segmentation") -> list[_LeafMeasures]:
        g_noise = None if noise_above is None else noise_above[g.kept]
        return [_leaf_measures(g.points[g.leaf_label == i], m, link=g.link_m,
                               noise_m=None if g_noise is None else g_noise[g.leaf_label == i],
                               base_widths_m=_base_widths_of(g, i))
                for i, m in enumerate(g.leaf_midribs)]

    measures = [measures_of(g) for g in grids]
    areas = np.array([sum(lm.area_m2 for lm in ms) if ms else _NAN for ms in measures], dtype=np.float64)
    candidates = np.flatnonzero(counts == int(np.median(counts)))
    pick = int(candidates[0])
    known = candidates[np.isfinite(areas[candidates])]
    if len(known):
        pick = int(known[np.argmin(np.abs(areas[known] - float(np.median(areas[known]))))])
    return _Grids(above, grids[pick], tuple(int(c) for c in counts), tuple(float(a) for a in areas),
                  tuple(grids), tuple(measures[pick]))


@dataclasses.dataclass(frozen=True)
class LabelledLeaves:
    """Leaves measured from labels given with the points (:func:`measure_labelled_leaves`).

    Attributes:
        labels: each leaf's label, in order.
        n_points: per leaf, its points measured (above the ground clearance, kept).
        lengths_m, widths_m, areas_m2: per leaf, as :class:`Leaf`'s (NaN with under 10
            points: not measured).
        leaf_area_m2: the sum of the measured areas (NaN when none was measured).
        widths_resolved: per leaf, as :attr:`Leaf.width_resolved` (None without the range noise).
    """

    labels: tuple[int, ...]
    n_points: tuple[int, ...]
    lengths_m: tuple[float, ...]
    widths_m: tuple[float, ...]
    areas_m2: tuple[float, ...]
    leaf_area_m2: float
    widths_resolved: tuple[bool | None, ...]

    @property
    def leaf_count(self) -> int:
        """The leaves measured (10 points or more)."""
        return sum(1 for a in self.areas_m2 if math.isfinite(a))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN becomes None)."""
        return metrics._to_jsonable({"leaf_count": self.leaf_count, "leaf_area_m2": self.leaf_area_m2,
                                     "labels": list(self.labels), "n_points": list(self.n_points),
                                     "lengths_m": list(self.lengths_m), "widths_m": list(self.widths_m),
                                     "areas_m2": list(self.areas_m2),
                                     "widths_resolved": list(self.widths_resolved)})


def leaf_bases_at_stem(points: Any, leaf_label: Any, stem_points: Any) -> np.ndarray | None:
    """Where each labelled leaf meets its stem: per label 0..k-1 (as
    :func:`measure_labelled_leaves` takes ``leaf_bases_m``), the leaf's point nearest any of
    ``stem_points``; None with no stem point (the measure then starts each leaf nearest the
    turntable's axis) or no leaf.

    Args:
        points: (n, 3) float64, metres.
        leaf_label: (n,) int, each point's leaf 0..k-1, or -1 for none.
        stem_points: (m, 3) float64, metres (m may be 0).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(leaf_label, dtype=np.int64)
    stem = np.asarray(stem_points, dtype=np.float64).reshape(-1, 3)
    if not len(stem) or not (labels >= 0).any():
        return None
    gap = cKDTree(stem).query(pts)[0]
    bases = np.full((int(labels.max()) + 1, 3), np.nan)
    for k in np.unique(labels[labels >= 0]):
        own = np.flatnonzero(labels == k)
        bases[k] = pts[own[int(np.argmin(gap[own]))]]
    return bases


# A labelled leaf is measured from this many points up (measure_labelled_leaves).
LABELLED_LEAF_MIN_POINTS = 10


def measure_labelled_leaves(points_turntable: Any, leaf_label: Any, *, leaf_bases_m: Any = None,
                            range_noise_m: Any = None, settings: TraitSettings | None = None) -> LabelledLeaves:
    """Each labelled leaf measured alone, by the per-leaf measures :func:`extract_traits`
    uses, with no segmentation: what those measures read on a perfect segmentation.

    The leaves are the points' labels (a user's own segmentation, or the truth: each point
    of a scan of a labelled mesh labelled by the face its beam hit,
    :func:`plantsim.evaluation.organ_match.leaf_labels_along_beams`). As
    :func:`extract_traits` reads them: the points rounded to a LAS file's grid, those at or
    above ``base_z + ground_clearance`` that the segmentation's outlier removal keeps, at the
    voxel of the cloud's scale (:func:`plantsim.evaluation.segmentation.kept_points`; give
    the plant's points: a sparse soil or pot in the cloud coarsens the voxel). Per leaf, its
    midrib is the centroids of the level sets (four voxels wide, as the segmentation's) of
    the geodesic distance over its own points from its base, the base first
    (:func:`plantsim.evaluation.segmentation._midrib_of`); length, width and area as
    :func:`extract_traits`' leaves (the ribbon between the margins, widths read across the
    beams given the range noise). A leaf with under :data:`LABELLED_LEAF_MIN_POINTS`
    points is not measured (NaN).

    Set against the traits :func:`extract_traits` reads, it splits a trait's error into
    the segmentation's and the rest (what the scan sees, how the measures read it): on the
    realistic 1-degree scans of ``scripts/traits_area_bound.py`` the 30-leaf rosette's
    true leaves read -6 % in area where its segmentation's one blob reads -82 %, and the
    wheat's +187 % where its found leaves read +156 %: the rosette's miss is the
    segmentation's, the wheat's is not.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame.
        leaf_label: (n,) int, each point's leaf (>= 0) or -1 for none.
        leaf_bases_m: optional (k, 3), per label 0..k-1 where its leaf meets its stem
            (its base on a mesh); None: each leaf's point nearest the turntable's axis (a
            rosette's or a maize's leaves grow from it).
        range_noise_m: optional (n, 3), as :func:`extract_traits`' (widths then read
            across the beams where they can, and checked against the noise).
        settings: extraction settings (defaults if None): ``base_z``, ``ground_clearance``.

    Returns:
        LabelledLeaves, the leaves in label order.

    Raises:
        ValueError: shapes that do not match, a non-finite value, a label below -1, or
            ``leaf_bases_m`` without a row for every label.
    """
    from plantsim.evaluation import segmentation

    s = settings or TraitSettings()
    pts = on_file_grid(_as_cloud(points_turntable))
    labels = np.asarray(leaf_label)
    if labels.shape != (len(pts),) or (labels.size and not np.issubdtype(labels.dtype, np.integer)):
        raise ValueError(f"leaf_label must be (n,) integers, one per point ({len(pts)}), got shape {labels.shape}"
                         f" and dtype {labels.dtype}")
    if labels.size and labels.min() < -1:
        raise ValueError(f"leaf_label must be a leaf index >= 0 or -1 (none), got {int(labels.min())}")
    labels = labels.astype(np.int64)
    noise = None if range_noise_m is None else segmentation.checked_range_noise(range_noise_m, pts)
    ids = np.unique(labels[labels >= 0])
    bases = None
    if leaf_bases_m is not None:
        bases = np.asarray(leaf_bases_m, dtype=np.float64)
        need = int(ids.max()) + 1 if len(ids) else 0
        if bases.ndim != 2 or bases.shape[1] != 3 or len(bases) < need or not np.all(np.isfinite(bases)):
            raise ValueError(f"leaf_bases_m must be finite (k, 3) with a row for every label 0..{need - 1}, "
                             f"got shape {bases.shape}")
    above = _above_mask(pts, s)
    pts, labels = pts[above], labels[above]
    noise = None if noise is None else noise[above]
    lengths, widths, areas, counts, resolved = [], [], [], [], []
    if len(ids):
        # The points the segmentation keeps (its outlier removal), at its voxel.
        kept, scale = segmentation.kept_points(pts)
        pts, labels = pts[kept], labels[kept]
        noise = None if noise is None else noise[kept]
        v = scale.voxel_m
        settings_seg = segmentation.SegmentationSettings()
    for k in ids:
        own = labels == k
        counts.append(int(own.sum()))
        if counts[-1] < LABELLED_LEAF_MIN_POINTS:
            lengths.append(_NAN), widths.append(_NAN), areas.append(_NAN), resolved.append(None)
            continue
        lp = pts[own]
        base = bases[k] if bases is not None else lp[int(np.argmin(np.hypot(lp[:, 0], lp[:, 1])))]
        midrib = segmentation._midrib_of(lp, base, cell=v, bin_w=settings_seg.bin_factor * v)
        lm = _leaf_measures(lp, midrib, link=settings_seg.link_factor * v,
                            noise_m=None if noise is None else noise[own])
        lengths.append(lm.length_m), widths.append(lm.width_m), areas.append(lm.area_m2)
        resolved.append(lm.width_resolved)
    measured = [a for a in areas if math.isfinite(a)]
    return LabelledLeaves(labels=tuple(int(k) for k in ids), n_points=tuple(counts), lengths_m=tuple(lengths),
                          widths_m=tuple(widths), areas_m2=tuple(areas),
                          leaf_area_m2=float(sum(measured)) if measured else _NAN,
                          widths_resolved=tuple(resolved))


def segment_for_traits(points_turntable: Any, *, settings: TraitSettings | None = None,
                       range_noise_m: Any = None) -> "segmentation.Segmentation":
    """The segmentation :func:`extract_traits` reads its organs from: the points above
    ``base_z + ground_clearance`` on the LAS grid (:func:`on_file_grid`), segmented
    with the settings' base and widest stem on ``settings.shifted_grids`` grids: of the
    grids of the median leaf count, the one whose leaf area is nearest their median
    (:func:`plantsim.evaluation.segmentation.segment_on_shifted_grids`).

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame.
        settings: extraction settings (defaults if None).
        range_noise_m: optional (n, 3) per point, as :func:`extract_traits`' (the
            stems' noise is then no leaf).

    Returns:
        Segmentation (its ``points`` are the kept points above the clearance).
    """
    from plantsim.evaluation import segmentation

    pts = on_file_grid(_as_cloud(points_turntable))
    noise = None if range_noise_m is None else segmentation.checked_range_noise(range_noise_m, pts)
    return _segment_above(pts, settings or TraitSettings(), noise).segmentation


def extract_traits(points_turntable: Any, *, settings: TraitSettings | None = None,
                   range_noise_m: Any = None, beam_gaps_m: Any = None) -> PlantTraits:
    """Extract every trait from a cloud, without the mesh.

    Organs come from :func:`plantsim.evaluation.segmentation.segment_organs`
    (level-set skeleton from stems found base-up; method, sources and validity
    there), on the points rounded to a LAS file's 0.01 mm grid (:func:`on_file_grid`:
    a scan and its file read the same traits) and on ``settings.shifted_grids`` voxel
    grids: the organs are the median grid's (:func:`segment_for_traits`), and
    ``leaf_counts_over_grids``, ``leaf_areas_over_grids_m2`` and
    ``stem_heights_over_grids_m`` say what every grid read, the segmentation's own
    uncertainty (the ideal 0.5-degree maize of ``scripts/traits_accuracy.py``: 9-11
    leaves, stem height 0.25-0.51 m for 0.42; the ideal 30-leaf rosette 13-25 leaves).
    Then:

    - height: :func:`robust_height`. With ``range_noise_m``, the points that can reach
      the top are first moved along their beams onto their neighbours' surface
      (:func:`beam_median_points`), and the top voxel asks for the points of the
      smaller of the cloud's apparent noise and the sensor's (the median of the
      points' range noise): an ideal scan of thin organs looks noisy to a plane fit,
      and its sparse top (a wheat's ears) would otherwise need 4 points a voxel.
      A note gives the points moved and the height with the points as measured.
      Read on the origin's voxel grid; ``heights_over_grids_m`` reads it on every
      shifted grid's voxels, the spread a grid's origin alone makes (the realistic
      1-degree scans of ``scripts/traits_accuracy.py``: -3.3..+2.0 % over all grids
      and plants, -8.7..+2.7 % with the points as measured). With ``beam_gaps_m``,
      half the top voxel's beam gap is added (the top lies between the highest beam
      that hits it and the next, :func:`robust_height`), and ``height_beam_gap_m``
      and a note say how much.
    - stems: count and centre from the base slices (median circle fit over the
      slices a stem persists in), diameter above the basal flare (the median ring in
      the upper half of the stem's lowest three diameters; a maize's root collar is
      25 mm wide where its stem is 14 mm); "no stem" (count 0, diameter NaN and a note)
      when no column persists; a note for each stem whose diameter the noise hides
      (most base slices noise-dominated: the value is an upper bound). Stem height:
      the top of the stem's points (those its skeleton walk kept) above ``base_z``
      by :func:`robust_height`'s rule on the points as measured (so on an ideal scan no
      stem reads taller than the plant; given the range noise, the plant's top is read
      with its points moved along their beams, and a stem reaching it can read a few
      millimetres taller on some grids: the realistic wheat's 539.3 mm on one, for a
      plant of 534.9; moved as well, the stems' own points read up to 7 % higher still);
      largest over stems (valid while the stem is not hidden by leaves wrapped round
      it; reads low where the stem's path is lost in a whorl, and high where a noisy
      column is walked up through the leaves round the axis).
    - leaves: one per skeleton tip branch that is a sampled surface (a branch with
      fewer points than spacings along it is a trail of mixed pixels, strays or a
      filament such as a tassel branch: not counted, with a note; with
      ``range_noise_m``, a branch a noisy stem's own hits make, carried along their
      beams, is the stem's, with a note (step 8 of
      :mod:`plantsim.evaluation.segmentation`: the realistic 3-leaf bean's area
      +19 % for +77 %); a leaf that surrounds its stem is no single leaf,
      :func:`encircling_leaves`, said in a note); per leaf length, width, area and
      inclination (:func:`_leaf_measures`); ``leaf_area_m2`` their sum (one side).
      With no branch long enough to be a leaf: count 0, area, length and width
      NaN (not measured, never 0) and a note naming the length a branch needed
      (``Segmentation.min_leaf_length_m``).
    - with ``range_noise_m``, each cross-section's width is read where its points'
      beams meet the leaf (:func:`across_beam_width`; ``Leaf.width_across_beams_share``,
      with a note), which the noise does not move; where the beams cannot read it, it
      is checked against the width the sensor's range noise alone reads across it
      (``Leaf.noise_width_m``, :func:`leaf_noise_width`): at 45 % of the width or more
      on half the cross-sections, ``Leaf.width_resolved`` is False and a note gives the
      leaves and the share of the leaf area they hold.
      A URG-04LX (10 mm noise floor along the beam) reads 9 mm wheat leaves 40-46 mm
      wide: the plane-fit noise the cloud itself shows (3-6 mm, across the surfaces)
      cannot see noise that lies in a leaf's plane; the beams' directions can.
    - convex hull volume (Qhull) and projected XY area (occupancy grid, cell
      ``max(grid_cell, 2 voxels)``) of the points above the ground clearance; a
      flat cloud's volume is NaN, with a note.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame, base at
            ``settings.base_z``.
        settings: extraction settings (defaults if None).
        range_noise_m: optional (n, 3) float64 metres, per point of
            ``points_turntable``: its beam's unit direction in the turntable frame
            times the range noise's standard deviation there (at least the sensor's
            floor: :func:`plantsim.evaluation.evaluate.range_noise_vectors`); zeros for a
            noiseless sensor. None: the widths are not checked (``width_resolved`` None).
        beam_gaps_m: optional (n,) float64 metres, per point of ``points_turntable``
            how far up the vertical through it the fan's next beam passes, NaN where
            not known (:func:`plantsim.evaluation.evaluate.beam_gaps_m`; ``plantsim
            traits`` reads them from the scan's sidecar). None: the height is the top
            as sampled.

    Returns:
        PlantTraits; NaN where a trait could not be measured, with notes saying why.
    """
    return traits_and_segmentation(points_turntable, settings=settings, range_noise_m=range_noise_m,
                                   beam_gaps_m=beam_gaps_m)[0]


def traits_and_segmentation(points_turntable: Any, *, settings: TraitSettings | None = None,
                            range_noise_m: Any = None, beam_gaps_m: Any = None
                            ) -> tuple[PlantTraits, "segmentation.Segmentation"]:
    """:func:`extract_traits`' traits, and the segmentation their organs came from (the
    grid :func:`segment_for_traits` gives): to score the organs against a truth without
    segmenting twice. Arguments as :func:`extract_traits`'."""
    from plantsim.evaluation import segmentation

    s = settings or TraitSettings()
    pts = on_file_grid(_as_cloud(points_turntable))
    noise = None if range_noise_m is None else segmentation.checked_range_noise(range_noise_m, pts)
    gaps = _checked_gaps(beam_gaps_m, len(pts))
    above, seg, grid_counts, grid_areas, grids, measures = _segment_above(pts, s, noise)
    noise_above = None if noise is None else noise[_above_mask(pts, s)]
    gaps_above = None if gaps is None else gaps[_above_mask(pts, s)]
    notes: list[str] = []
    height_scale = seg.scale
    if noise is not None:
        # Apparent noise the sensor cannot have made is the plant's own fine structure (thin
        # organs crossing within a plane fit's ball: the seed rig's ideal wheat shows 2.3 mm):
        # the top voxel asks for the points of the noise the scan really has.
        sensor_noise_m = float(np.median(np.linalg.norm(noise_above, axis=1)))
        height_scale = dataclasses.replace(seg.scale, noise_m=min(seg.scale.noise_m, sensor_noise_m))
    top_min_points, apparent_min_points = top_voxel_min_points(height_scale), top_voxel_min_points(seg.scale)
    if top_min_points != apparent_min_points:
        notes.append(f"height: the top voxel needed {top_min_points} points, for the sensor's range noise "
                     f"({1e3 * height_scale.noise_m:.2g} mm), not {apparent_min_points} for the "
                     f"noise the cloud shows a plane fit ({1e3 * seg.scale.noise_m:.2g} mm: structure the fit "
                     "reads as noise, such as thin organs crossing within its reach or mixed pixels)")
    # The plant height on every grid's voxels (the first, the origin's, is the one reported).
    tops, tops_measured, n_moved, halves = _heights_moved_along_beams(
        above, seg.scale.voxel_m, top_min_points,
        [np.asarray(o[:3], dtype=np.float64) for o in segmentation.shifted_grid_offsets(s.shifted_grids)],
        noise_above, 2.0 * seg.scale.spacing_m, gaps_above)
    heights = tuple(top + half - s.base_z for top, half in zip(tops, halves))
    if n_moved:
        notes.append(f"height: {1e3 * (tops[0] - s.base_z):.1f} mm at the top voxel, read with the {n_moved} "
                     "points that can reach the top moved along their beams onto their neighbours' surface (by "
                     f"the range noise given; {1e3 * (tops_measured[0] - s.base_z):.1f} mm with the points as "
                     "measured)")
    beam_gap = 2.0 * halves[0] if gaps_above is not None and halves[0] > 0 else _NAN
    if math.isfinite(beam_gap):
        notes.append(f"height: {1e3 * heights[0]:.1f} mm, half the {1e3 * beam_gap:.2g} mm between the beams at "
                     f"the top voxel above its centroid ({1e3 * (tops[0] - s.base_z):.1f} mm): the top lies "
                     "between the highest beam that hits it and the next, which passes over it")
    height = heights[0]
    # A noisy stem on the axis: its diameter where the beams through the axis meet it.
    seg_noise = None if noise_above is None else noise_above[seg.kept]
    beam_diameters = [_beam_stem_diameter(seg, i, seg_noise, s.base_z) for i in range(len(seg.stems))]
    stems = tuple(Stem(index=i, center_xy_m=st.center_xy_m,
                       diameter_m=beam_diameters[i] if math.isfinite(beam_diameters[i]) else st.diameter_m,
                       rms_residual_m=st.rms_residual_m, n_points=st.n_points,
                       diameter_resolved=st.diameter_resolved or math.isfinite(beam_diameters[i]),
                       found_in_beams=st.found_in_beams,
                       diameter_from=("turn angles" if st.found_in_beams else "rings" if st.diameter_resolved
                                      else "beams" if math.isfinite(beam_diameters[i]) else "column"))
                  for i, st in enumerate(seg.stems))
    if not stems:
        notes.append("no stem: no compact column persists in the base slices "
                     f"(noise {1e3 * seg.scale.noise_m:.2g} mm, spacing {1e3 * seg.scale.spacing_m:.2g} mm)")
    for i, st in enumerate(seg.stems):
        at = f"stem at ({1e3 * st.center_xy_m[0]:.0f}, {1e3 * st.center_xy_m[1]:.0f}) mm"
        if not st.diameter_resolved and math.isfinite(beam_diameters[i]):
            notes.append(f"{at}: diameter {1e3 * beam_diameters[i]:.1f} mm, read where the beams through the "
                         "turntable's axis meet it, a radius in front of the axis (the mode over the turn "
                         "of each cell's median return, up the lower half of the stem; "
                         "segmentation.beam_stem_diameter): no ring fits its noisy column, "
                         f"{1e3 * st.diameter_m:.0f} mm wide in the base slices")
        elif not st.diameter_resolved:
            notes.append(f"{at}: diameter not resolved, {1e3 * st.diameter_m:.0f} mm is the width of its noisy "
                         "column in the base slices (no ring fits), an upper bound")
    beside = [st for st in seg.stems if st.found_in_beams]
    if beside:
        notes.append(f"{len(beside)} stem{'s' if len(beside) > 1 else ''} beside the turntable's axis found in "
                     "the turn angles of their points, which the range noise hides from the base slices (it "
                     "spreads a thin stem's points centimetres along its beams, and leaves their turn angles "
                     "as scanned): at " + ", ".join(
                         f"({1e3 * st.center_xy_m[0]:.0f}, {1e3 * st.center_xy_m[1]:.0f}) mm, "
                         f"{1e3 * st.diameter_m:.1f} mm wide" for st in beside)
                     + "; each diameter is the turn angles its beams span times its distance from the axis, "
                     "to a scanned step there, and each stem is followed up the plant by its turn angles to "
                     "its top (segmentation.find_beam_stems, track_beam_stem)")
    for si, st in enumerate(seg.stems):
        walk = seg.stem_walk_tops_z_m[si] if si < len(seg.stem_walk_tops_z_m) else _NAN
        if math.isfinite(walk):
            from_beams = sum(1 for w in seg.leaf_base_widths_m if len(w))
            cup = si < len(seg.stem_tops_in_cup) and seg.stem_tops_in_cup[si]
            notes.append(f"stem at ({1e3 * st.center_xy_m[0]:.0f}, {1e3 * st.center_xy_m[1]:.0f}) mm: it ends "
                         + ("where the beams through the turntable's axis meet, all round, the leaves standing "
                            f"round it, {1e3 * (seg.stem_tops_m[si, 2] - s.base_z):.0f} mm up, which is its height "
                            if cup else
                            "where the beams through the turntable's axis stop meeting it, "
                            f"{1e3 * (seg.stem_tops_m[si, 2] - s.base_z):.0f} mm up, and its height is read from "
                            "its points below ")
                         + "(the skeleton's walk up its noisy column went on to "
                         f"{1e3 * (walk - s.base_z):.0f} mm); {from_beams} "
                         f"{'leaf' if from_beams == 1 else 'leaves'}' bases in the column read from the beams "
                         + ("(segmentation.cup_stem_top)" if cup else "(segmentation.beam_stem_top)"))
    # The plant's stem diameter: the stems whose diameter was read; a noisy column's width
    # (an upper bound, tens of millimetres) only where no stem's was.
    read = [st.diameter_m for st in stems if st.diameter_resolved]
    stem_diameter = float(np.mean(read or [st.diameter_m for st in stems])) if stems else _NAN
    if read and len(read) < len(stems):
        notes.append(f"stem diameter: {1e3 * stem_diameter:.1f} mm, the mean of the {len(read)} stems whose "
                     f"diameter was read; the {len(stems) - len(read)} whose noisy column hides it "
                     "(its width an upper bound) left out")
    pairs, mean_pair, mean_nn = stem_distances(stems)
    leaves: list[Leaf] = []
    groups = leaf_groups_of(seg)
    for i, lm in enumerate(measures):  # measured as the grid was chosen (_segment_above)
        leaves.append(Leaf(index=i, length_m=lm.length_m, width_m=lm.width_m,
                           n_points=int(np.count_nonzero(seg.leaf_label == i)),
                           area_m2=lm.area_m2, inclination_deg=lm.inclination_deg, noise_width_m=lm.noise_width_m,
                           width_resolved=lm.width_resolved, width_across_beams_share=lm.across_beams_share,
                           group=groups[i]))
    n_leaves = len(set(groups))
    if n_leaves < len(leaves):
        compound = len({g for g in groups if groups.count(g) > 1})
        notes.append(f"{compound} compound lea{'f' if compound == 1 else 'ves'} (several laminae "
                     f"on one stalk out of the stem's column): {len(leaves)} laminae make "
                     f"{n_leaves} leaves; leaf_count counts a compound leaf once, lamina_count every "
                     "lamina, and the per-leaf lengths, widths, areas and inclinations are per lamina")
    if seg.stem_noise_branches:
        n = seg.stem_noise_branches
        notes.append(f"{n} branch{'es' if n > 1 else ''} long enough to be a leaf not counted as "
                     f"lea{'ves' if n > 1 else 'f'}: {100 * segmentation.STEM_NOISE_SHARE:.0f} % or more of "
                     f"{'their' if n > 1 else 'its'} points lie on beams through the stem's column, within "
                     f"{segmentation.STEM_NOISE_GATE_SIGMAS:g} sigma of the range noise of where the beam enters "
                     f"it, and {'they end' if n > 1 else 'it ends'} within that reach of the stem: the stem's own "
                     "hits, spread along their beams by the noise; given to the stem")
    if seg.axis_split_leaves:
        n = seg.axis_split_leaves
        notes.append(f"{n} lea{'ves' if n > 1 else 'f'} found by splitting leaves the range noise merged round "
                     "the turntable's axis: the noise moves each point along its beam, in a plane through the "
                     "axis, and leaves its azimuth; beyond the noise's disc round the axis their points fall "
                     "into sectors parted by empty ones, each as long as a leaf (segmentation._split_at_axis)")
    if seg.petal_split_leaves:
        n = seg.petal_split_leaves
        notes.append(f"{n} lea{'ves' if n > 1 else 'f'} found by splitting a cup of touching leaves round the "
                     "axis at their tips: where the level sets held them as one, the farthest reach of its "
                     "points round the axis had a lobe per leaf (segmentation._split_petals)")
    if seg.surface_split_leaves:
        n = seg.surface_split_leaves
        notes.append(f"{n} lea{'ves' if n > 1 else 'f'} found by splitting a cup of touching leaves round the "
                     "axis where their smooth surfaces meet at a crease (region growing with a smoothness "
                     "constraint, pieces one quadric fits joined; segmentation._split_smooth_surfaces)")
    if seg.joined_leaves:
        n = seg.joined_leaves
        notes.append(f"{n} found lea{'ves' if n > 1 else 'f'} too small for a leaf's surface (fewer points a "
                     f"spacing apart than a strip {segmentation.SMOOTH_WIDTH_NODES:g} wide and a leaf long) "
                     "joined to the leaf they touch most, not counted (segmentation._join_fragments)")
    ramped = sum(1 for lm in measures if lm.junction_widths_ramped)
    if ramped:
        notes.append(f"{ramped} lea{'ves' if ramped > 1 else 'f'}' widths within "
                     f"{_JUNCTION_NOISE_SIGMAS:g} sigma of the range noise of their junction not read (the "
                     "stem's and the other leaves' points the noise spreads there) and taken as narrowing to "
                     "the junction, from the first width past them read (_ramp_junction_widths)")
    if seg.sparse_branches:
        notes.append(f"{seg.sparse_branches} branch{'es' if seg.sparse_branches > 1 else ''} long enough to be "
                     "a leaf not counted as leaves: each holds fewer points than there are point spacings "
                     "along it, a trail rather than a sampled surface (mixed pixels strung behind a leaf's "
                     "edge, stray points, or a filament thinner than the spacing, such as a tassel branch)")
    for i, span in encircling_leaves(seg):
        axis = "its stem" if seg.stems else "the plant's centre"
        notes.append(f"leaf {i} surrounds {axis} (its outer half spans {span:.0f} deg round it; one leaf "
                     "spans a sector): it is no single leaf but leaves merged into a ring (the leaf count is "
                     "then a lower bound) or a ring that is no leaf (a pot's rim, the soil, a disk under the "
                     "plant); its length, width and area describe the ring")
    unresolved = [lf for lf in leaves if lf.width_resolved is False]
    if unresolved:
        share = sum(lf.area_m2 for lf in unresolved) / max(sum(lf.area_m2 for lf in leaves), 1e-300)
        def mm(values):
            lo, hi = round(1e3 * min(values)), round(1e3 * max(values))
            return f"{lo}" if lo == hi else f"{lo}-{hi}"

        notes.append(f"leaf widths not resolved: the range noise alone reads "
                     f"{mm([lf.noise_width_m for lf in unresolved])} mm across "
                     f"{len(unresolved)} of {len(leaves)} leaves, at least 45 % of the widths of half "
                     "or more of their cross-sections, and their beams could not read them "
                     f"(across_beam_width): their {mm([lf.width_m for lf in unresolved])} mm widths read "
                     f"the noise's spread (23 % wide or more), and so does their area, {100 * share:.0f} % "
                     "of the leaf area")
    across = [lf for lf in leaves if lf.width_across_beams_share > 0]
    if across:
        lo, hi = (round(100 * f(lf.width_across_beams_share for lf in across)) for f in (min, max))
        notes.append(f"leaf widths read across the beams on {len(across)} of {len(leaves)} leaves "
                     f"({lo if lo == hi else f'{lo}-{hi}'} % of the cross-sections their width is read "
                     "over): the range noise moves each point along its beam, and there the width is read "
                     "where the beams meet the leaf, which the noise does not move, its twist fitted to the "
                     "points (across_beam_width); elsewhere from the points' spread")
    # Each stem's top by the plant height's own rule (robust_height on its points): the
    # highest skeleton piece of a noisy column can be a few stray points above the plant's
    # top. A stem found in the turn angles ends where its track does
    # (segmentation.track_beam_stem): its top slice's highest point; the top-voxel rule on
    # its sparse points read a 0.30 m ray-cast culm 0.14 m. A stem the beams ended where
    # they meet the leaves standing round it (segmentation.cup_stem_top, slices of half a
    # voxel) ends there: the top voxel of a 20 mm crown's points read 10 mm for 18. No
    # stem reads taller than the plant: its points as measured, where the plant's top is
    # read with its points moved along their beams, read a ray-cast 0.32 m culm on the
    # axis 0.324 m for a plant 0.317 m.
    def stem_heights_of(grid) -> list[float]:
        out = []
        for i, st in enumerate(grid.stems):
            if st.found_in_beams or (i < len(grid.stem_tops_in_cup) and grid.stem_tops_in_cup[i]
                                     and math.isfinite(grid.stem_walk_tops_z_m[i])):
                top = float(grid.stem_tops_m[i, 2]) - s.base_z
            else:
                sp = grid.points[grid.stem_label == i]
                top = robust_height(sp, base_z=s.base_z, scale=grid.scale, min_points=top_min_points) \
                    if len(sp) else _NAN
            out.append(min(top, height) if math.isfinite(top) else top)
        return out

    def tallest(heights: list[float]) -> float:
        return max((h for h in heights if not math.isnan(h)), default=_NAN)

    def stem_height_of(grid) -> float:
        return tallest(stem_heights_of(grid))

    own_heights = stem_heights_of(seg)
    # The beams ended a stem where its walk's top is recorded (Segmentation.stem_walk_tops_z_m).
    walk_tops = list(seg.stem_walk_tops_z_m) + [_NAN] * (len(stems) - len(seg.stem_walk_tops_z_m))
    stems = tuple(dataclasses.replace(st, height_m=own_heights[st.index],
                                      height_from="turn angles" if st.found_in_beams else
                                      "beams" if math.isfinite(walk_tops[st.index]) else "walk")
                  for st in stems)
    stem_height = tallest(own_heights)
    # What every grid reads: where the walk up a stem goes on or stops depends on the
    # grid (the ideal 9-leaf maize's stem, 0.42 m, reads 0.25-0.51 m over the 9 grids).
    grid_stem_heights = tuple(stem_height if g is seg else stem_height_of(g) for g in grids)
    for si, why in enumerate(seg.stem_beam_top_refusals):
        if not why or math.isnan(own_heights[si]):
            continue
        st = seg.stems[si]
        h_mm = 1e3 * own_heights[si]
        notes.append(f"stem at ({1e3 * st.center_xy_m[0]:.0f}, {1e3 * st.center_xy_m[1]:.0f}) mm: its "
                     f"top, {h_mm:.0f} mm up, is where the skeleton's walk up its column stopped, "
                     "and a leaf rising from the stem within that column carries the walk on up it (it "
                     f"then reads high); the beams through the turntable's axis cannot end it: {why} "
                     "(segmentation.beam_stem_top)")
    if not leaves:
        start = "the stem" if stems else "the cloud's lowest points"
        notes.append(f"no leaf: no skeleton branch reaches {1e3 * seg.min_leaf_length_m:.0f} mm (the "
                     f"shortest leaf counted) beyond {start}; leaf area, length and width are not "
                     "measured (NaN)")
    hull_volume = convex_hull_volume(above)
    if math.isnan(hull_volume):
        notes.append("convex hull volume NaN: the points above the ground clearance are flat "
                     "or degenerate (they span no volume)")
    cell = max(s.grid_cell, 2 * seg.scale.voxel_m)
    return PlantTraits(
        height_m=height,
        stems=stems,
        stem_diameter_m=stem_diameter,
        stem_distances=pairs,
        mean_stem_distance_m=mean_pair,
        mean_nearest_stem_distance_m=mean_nn,
        leaves=tuple(leaves),
        leaf_width_m=max((lf.width_m for lf in leaves), default=_NAN),
        leaf_length_m=max((lf.length_m for lf in leaves), default=_NAN),
        convex_hull_volume_m3=hull_volume,
        projected_area_xy_m2=projected_area_xy(above, cell=cell),
        stem_count=len(stems),
        stem_height_m=stem_height,
        leaf_count=n_leaves,
        leaf_area_m2=float(sum(lf.area_m2 for lf in leaves)) if leaves else _NAN,
        lamina_count=len(leaves),
        leaf_lengths_m=tuple(lf.length_m for lf in leaves),
        leaf_widths_m=tuple(lf.width_m for lf in leaves),
        leaf_areas_m2=tuple(lf.area_m2 for lf in leaves),
        leaf_inclinations_deg=tuple(lf.inclination_deg for lf in leaves),
        leaf_counts_over_grids=grid_counts,
        leaf_areas_over_grids_m2=grid_areas,
        stem_heights_over_grids_m=grid_stem_heights,
        heights_over_grids_m=heights,
        height_beam_gap_m=beam_gap,
        notes=tuple(notes),
    ), seg


def traits_from_mesh(
    vertices_turntable: Any,
    faces: Any,
    *,
    n_samples: int = 300_000,
    rng: np.random.Generator | int | None = None,
    settings: TraitSettings | None = None,
) -> PlantTraits:
    """Traits of the true mesh, measured the way a cloud is measured.

    Height and convex-hull volume are exact (top vertex; hull of the surface clipped
    at ``base_z + ground_clearance``, as for a cloud). Stems, leaves and projected
    area run the cloud pipeline on ``n_samples`` uniform surface samples (plus the
    vertices): the result is the method's own answer on a perfect, dense scan, so
    comparing a scan against it isolates the scanner's error from the method's bias
    (compare against ``traits_from_truth`` for the total).

    Args:
        vertices_turntable: (v, 3) float64, metres, turntable frame.
        faces: (f, 3) integer.
        n_samples: surface samples (>= 1).
        rng: ``numpy.random.Generator`` or int seed (None: seed 0).
        settings: extraction settings (defaults if None).

    Returns:
        PlantTraits.
    """
    s = settings or TraitSettings()
    v, f = metrics._as_mesh(vertices_turntable, faces)
    samples, _ = metrics.sample_surface(v, f, n_samples, rng=rng)
    from_samples = extract_traits(np.vstack([samples, v]), settings=s)
    above = _mesh_points_above(v, f, s.base_z + s.ground_clearance)
    return dataclasses.replace(
        from_samples,
        height_m=float(v[:, 2].max() - s.base_z),
        convex_hull_volume_m3=convex_hull_volume(above) if len(above) else _NAN,
    )


def _mesh_points_above(vertices: np.ndarray, faces: np.ndarray, z: float) -> np.ndarray:
    """Vertices at or above ``z`` plus the points where edges cross ``z``: the hull of
    these is exactly the hull of the mesh surface clipped at ``z``."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    cross = (a[:, 2] - z) * (b[:, 2] - z) < 0
    a, b = a[cross], b[cross]
    t = (z - a[:, 2]) / (b[:, 2] - a[:, 2])
    return np.vstack([vertices[vertices[:, 2] >= z], a + t[:, None] * (b - a)])


def _num(truth: Mapping[str, Any], key: str, where: str = "truth") -> float:
    value = truth.get(key)
    if value is None:
        return _NAN
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}[{key!r}] must be a number, got {value!r}") from None


def true_leaf_groups(leaves: Any) -> tuple[int, ...]:
    """Each truth lamina's leaf, numbered 0.. in order: laminae that give the same
    integer ``petiole`` are the leaflets of one compound leaf; one without it is a leaf.

    Args:
        leaves: the truth's ``leaves`` list (dicts).

    Returns:
        One group per lamina; the number of distinct groups is the leaf count.

    Raises:
        ValueError: a ``petiole`` that is not an integer.
    """
    number: dict[Any, int] = {}
    out = []
    for i, lf in enumerate(leaves):
        petiole = lf.get("petiole") if isinstance(lf, Mapping) else None
        if petiole is not None and (isinstance(petiole, bool) or not isinstance(petiole, (int, np.integer))):
            raise ValueError(f"truth['leaves'][{i}]['petiole'] must be an integer, got {petiole!r}")
        out.append(number.setdefault(("lamina", i) if petiole is None else ("petiole", int(petiole)), len(number)))
    return tuple(out)


def traits_from_truth(truth: Mapping[str, Any]) -> PlantTraits:
    """Traits from a bundled plant's exact-traits JSON (already parsed into a dict).

    Expected keys (metres): ``height_m`` (required), ``stems`` (list of ``index``,
    ``base_xy_m``, ``diameter_m``), ``stem_diameter_m``, ``stem_distances_m`` (list of
    ``stems`` [i, j], ``distance_m``), ``leaves`` (list of ``index``, ``length_m``,
    ``width_m``, and ``petiole``, an integer, for the leaflets of compound leaves: laminae
    with the same ``petiole`` are one leaf, a lamina without it is a leaf of its own).
    Missing optional keys give NaN. Aggregates follow
    :class:`PlantTraits` definitions, recomputed from the lists so that cloud and
    truth use one definition; where the file's own aggregate (``stem_diameter_m``,
    ``mean_stem_distance_m``, ``leaf_width_m``, ``leaf_length_m``) disagrees, a
    warning is logged and the recomputed value kept.

    Args:
        truth: the parsed JSON object.

    Returns:
        PlantTraits.

    Raises:
        ValueError: when ``height_m`` is missing or a value is not a number.
    """
    if not isinstance(truth, Mapping):
        raise ValueError(f"truth must be a dict parsed from the traits JSON, got {type(truth).__name__}")
    if "height_m" not in truth:
        logger.warning("truth lacks 'height_m' (keys present: %s): height is not compared",
                       sorted(truth))
    stems = tuple(
        Stem(
            index=int(st.get("index", i)),
            center_xy_m=(float(st["base_xy_m"][0]), float(st["base_xy_m"][1])),
            diameter_m=_num(st, "diameter_m", f"truth['stems'][{i}]"),
            height_m=_num(st, "height_m", f"truth['stems'][{i}]"),
        )
        for i, st in enumerate(truth.get("stems") or ())
    )
    if truth.get("stem_distances_m"):
        pairs = tuple(
            StemDistance(stems=(int(p["stems"][0]), int(p["stems"][1])), distance_m=float(p["distance_m"]))
            for p in truth["stem_distances_m"]
        )
        _, _, mean_nn = stem_distances(stems) if len(stems) >= 2 else ((), _NAN, _NAN)
        mean_pair = float(np.mean([p.distance_m for p in pairs]))
    else:
        pairs, mean_pair, mean_nn = stem_distances(stems)
    laminae = list(truth.get("leaves") or ())
    groups = true_leaf_groups(laminae)
    leaves = tuple(
        Leaf(
            index=int(lf.get("index", i)),
            length_m=_num(lf, "length_m", f"truth['leaves'][{i}]"),
            width_m=_num(lf, "width_m", f"truth['leaves'][{i}]"),
            group=groups[i],
        )
        for i, lf in enumerate(laminae)
    )
    traits = PlantTraits(
        height_m=_num(truth, "height_m"),
        stems=stems,
        stem_diameter_m=float(np.mean([st.diameter_m for st in stems])) if stems else _num(truth, "stem_diameter_m"),
        stem_distances=pairs,
        mean_stem_distance_m=mean_pair,
        mean_nearest_stem_distance_m=mean_nn,
        leaves=leaves,
        leaf_width_m=max((lf.width_m for lf in leaves), default=_num(truth, "leaf_width_m")),
        leaf_length_m=max((lf.length_m for lf in leaves), default=_num(truth, "leaf_length_m")),
        convex_hull_volume_m3=_num(truth, "convex_hull_volume_m3"),
        projected_area_xy_m2=_num(truth, "projected_area_xy_m2"),
        stem_count=len(stems),
        stem_height_m=max((_num(st, "height_m") for st in truth.get("stems") or ()), default=_NAN),
        leaf_count=len(set(groups)),
        leaf_area_m2=_num(truth, "leaf_area_m2"),
        lamina_count=len(leaves),
        leaf_lengths_m=tuple(lf.length_m for lf in leaves),
        leaf_widths_m=tuple(lf.width_m for lf in leaves),
    )
    for key, ours in (
        ("stem_diameter_m", traits.stem_diameter_m),
        ("mean_stem_distance_m", traits.mean_stem_distance_m),
        ("leaf_width_m", traits.leaf_width_m),
        ("leaf_length_m", traits.leaf_length_m),
    ):
        theirs = _num(truth, key)
        both = math.isfinite(theirs) and math.isfinite(ours)
        if both and not math.isclose(theirs, ours, rel_tol=1e-6, abs_tol=1e-9):
            logger.warning(
                "truth[%r] = %.6g differs from %.6g recomputed from its lists by the "
                "PlantTraits definition; using %.6g",
                key, theirs, ours, ours,
            )
    return traits


# --------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class TraitError:
    """Error of one trait, as in the paper's Tables I and II.

    Attributes:
        trait: name, e.g. ``"height_m"`` or ``"stem[1].diameter_m"``.
        estimate: S, from the cloud.
        reference: R, from the truth.
        absolute_error: ``|S - R|``, in the trait's unit (metres for lengths).
        relative_error: ``|S - R| / |R|`` as a fraction (x100 for the paper's %);
            NaN when R is 0 or either value is NaN.
        unit: ``"m"``, ``"m^2"`` or ``"m^3"``.
    """

    trait: str
    estimate: float
    reference: float
    absolute_error: float
    relative_error: float
    unit: str


def trait_error(trait: str, estimate: float, reference: float, *, unit: str = "m") -> TraitError:
    """Absolute and relative error of one trait: ``|S - R|`` and ``|S - R| / |R|``."""
    s, r = float(estimate), float(reference)
    ae = abs(s - r)
    re = ae / abs(r) if r != 0 and math.isfinite(ae) else _NAN
    return TraitError(trait=trait, estimate=s, reference=r, absolute_error=ae, relative_error=re, unit=unit)


@dataclasses.dataclass(frozen=True)
class TraitComparison:
    """Errors of every trait present in both the estimate and the reference.

    Attributes:
        errors: one per trait; per-stem diameters after matching stems by centre.
        n_stems: (estimate, reference) stem counts.
        n_leaves: (estimate, reference) leaf counts.
    """

    errors: tuple[TraitError, ...]
    n_stems: tuple[int, int]
    n_leaves: tuple[int, int]

    def __getitem__(self, trait: str) -> TraitError:
        for e in self.errors:
            if e.trait == trait:
                return e
        raise KeyError(f"no error for {trait!r}; available: {[e.trait for e in self.errors]}")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (NaN becomes None)."""
        return metrics._to_jsonable(self)


_SCALARS = (
    ("height_m", "m"),
    ("stem_diameter_m", "m"),
    ("mean_stem_distance_m", "m"),
    ("mean_nearest_stem_distance_m", "m"),
    ("leaf_width_m", "m"),
    ("leaf_length_m", "m"),
    ("convex_hull_volume_m3", "m^3"),
    ("projected_area_xy_m2", "m^2"),
    ("stem_height_m", "m"),
    ("leaf_area_m2", "m^2"),
)


def compare_traits(estimate: PlantTraits, reference: PlantTraits) -> TraitComparison:
    """Errors of ``estimate`` (S, from a cloud) against ``reference`` (R, the truth).

    Scalar traits are compared when both are finite. Stems are matched one-to-one by
    their centres (Hungarian assignment on XY distance, ``scipy.optimize
    .linear_sum_assignment``); each matched pair adds ``stem[i].diameter_m``,
    ``stem[i].center_offset_m`` (reference index i; the offset has reference 0, so
    its relative error is NaN) and, where both give it, ``stem[i].height_m`` (a
    tiller's own height: ``stem_height_m`` compares only the tallest's). Leaves are
    not matched one by one.

    Args:
        estimate: traits from a cloud.
        reference: traits from the truth.

    Returns:
        TraitComparison.
    """
    errors = []
    for name, unit in _SCALARS:
        s, r = getattr(estimate, name), getattr(reference, name)
        if math.isfinite(s) and math.isfinite(r):
            errors.append(trait_error(name, s, r, unit=unit))
    if estimate.stems and reference.stems:
        ce = np.array([st.center_xy_m for st in estimate.stems])
        cr = np.array([st.center_xy_m for st in reference.stems])
        cost = np.linalg.norm(ce[:, None] - cr[None], axis=2)
        rows, cols = optimize.linear_sum_assignment(cost)
        for i, j in sorted(zip(rows, cols), key=lambda t: reference.stems[t[1]].index):
            ref = reference.stems[j]
            errors.append(trait_error(f"stem[{ref.index}].diameter_m", estimate.stems[i].diameter_m, ref.diameter_m))
            errors.append(trait_error(f"stem[{ref.index}].center_offset_m", cost[i, j], 0.0))
            if math.isfinite(estimate.stems[i].height_m) and math.isfinite(ref.height_m):
                errors.append(trait_error(f"stem[{ref.index}].height_m", estimate.stems[i].height_m, ref.height_m))
    for name in ("stem_count", "leaf_count", "lamina_count"):
        s_val, r_val = getattr(estimate, name), getattr(reference, name)
        if r_val:
            errors.append(trait_error(name, s_val, r_val, unit="1"))
    return TraitComparison(
        errors=tuple(errors),
        n_stems=(len(estimate.stems), len(reference.stems)),
        n_leaves=(len(estimate.leaves), len(reference.leaves)),
    )
