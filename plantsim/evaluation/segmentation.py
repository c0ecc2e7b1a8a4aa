"""Organ segmentation of a plant point cloud: stems and individual leaves, cloud only.

Method: a level-set (Reeb-graph) skeleton of the geodesic distance from the plant's
base, as introduced for scattered points by Verroust & Lazarus (2000, "Extracting
skeletal curves from 3D scattered data", The Visual Computer 16:15-29) and used on
laser-scanned plants by Xu, Gossett & Chen (2007, "Knowledge and heuristic-based
modeling of laser-scanned trees", ACM TOG 26(4):19) and Delagrange et al. (2014,
"PypeTree", Sensors 14:4271-4289):

1. Scale. The point spacing ``h`` (from the distance to the 16th neighbour, the median
   over the surface's area, not over its points) and the noise
   ``sigma`` (RMS residual of local plane fits, Hoppe et al. 1992, at the most
   surface-like of a ladder of radii, Mitra & Nguyen 2003; :func:`estimate_scale`)
   are measured on the cloud; every length below is a multiple of
   ``v = max(2 h, 1.5 sigma)``, never a fixed millimetre figure.
2. Outliers: statistical outlier removal (Rusu et al. 2008): a point whose mean
   distance to its 8 neighbours exceeds the cloud's mean by 3 standard deviations
   is dropped, unless the cloud is clean (noise at most half its spacing) and the
   point's 12 neighbours lie on a plane: that is the sparse outer part of a leaf,
   far from the turntable's axis (:func:`kept_points`). The scale is measured on
   the points kept, that sparse surface included (a stem on the axis, seen from every
   turn, holds most of a small plant's points: the scale is the leaves' too).
3. Graph: points are merged into voxel centroids of side ``v``; centroids closer
   than ``2 v`` are joined (weight = distance). Components the occlusion cut off
   are bridged to the rest by their shortest link (Livny et al. 2010 join tree
   fragments the same way), so a leaf tip seen apart from its base stays one leaf;
   a component that is one straight scan line is bridged all along its length,
   from every node about as near the rest as its nearest one (hung by one end, it
   reached past its leaf's tip).
4. Roots: stems are found from the base up (:func:`find_stems`: compact XY clusters
   of thin slices that persist over several slices, each with a circle fit); given
   the range noise, stems beside the axis that it smears into streaks along the
   beams are found in their points' turn angles, which it leaves as scanned, and
   followed up to their tops (:func:`find_beam_stems`, :func:`track_beam_stem`: a
   noisy wheat's tillers), their points the stem's whatever the skeleton makes of
   them; the nodes near the stem bases in the lowest slice are the sources of a
   multi-source Dijkstra geodesic distance.
5. Level sets: nodes are binned by geodesic distance (bins of ``4 v``); connected
   pieces of one bin are the skeleton's nodes; a node's parent is the node holding
   the Dijkstra predecessor of its nearest member. The skeleton is a tree.
6. Organs: each stem follows the skeleton up from its root, always to the child
   whose centroid stays nearest the stem's (extrapolated) axis, while it stays
   within a few radii of it; the axis moves only through pieces that fit in the
   stem's column (its radius plus the noise band and a voxel; where the noise hides
   the ring, the noisy width measured at the base, which holds the noise already).
   A child lying wholly inside the stem's column is stem too, and the walk goes on from
   it: where a leaf wrapped round the stem hides bands of it from every view, the
   stem's level sets are half-rings side by side, and the stem's top lies above
   one of them. A noisy stem on the turntable's axis ends where the beams stop meeting
   it (:func:`beam_stem_top`: in a range image of turn angle and height, every beam
   crosses the axis), below where the walk up its column stops: a leaf rising steeply
   from its top lies in the noisy column too, and the walk went on up it (the
   realistic maizes' 0.42 m stems read 0.48-0.50 m); its points above go to the leaves
   they touch. It also ends where the beams meet, all round, leaves standing round it
   twice as far out as its own surface (:func:`cup_stem_top`, on slices of half a
   voxel: a rosette's crown, whose noisy column held its inner leaves; the realistic
   12-leaf rosette's 20 mm crown read 69 mm, and reads 18 mm). In the same range image
   a leaf standing in front of such a stem, or in its column above its top, is read
   from the cells' medians: the leaf's base, which
   rises in the noisy column for 10 cm or more on a maize, goes to the leaf, with its
   midrib and widths there (:func:`_leaf_bases_from_beams`). Every other tip whose
   branch (tip to the junction below it) is longer than ``min_leaf_length_m`` is a leaf tip, and so is a tip
   hanging from a stem piece that lies that far out of the stem's column: a
   noisy stem fills a column several
   centimetres wide whose level sets hold most of a short leaf (a bean's
   leaflets), leaving a branch of a bin or two past them; a leaf is the chain
   of nodes from its tip down to the stem, shared nodes going to the longer leaf;
   shorter spurs join the leaf they hang from, and so does a branch whose nodes
   lie along one straight line (a lone scan line of a leaf seen at a grazing
   angle, bridged to the graph apart from its leaf: a leaf is a surface;
   :func:`_is_line`). Stem pieces keep only the points
   within the stem's column round the axis the walk tracked;
   the rest, leaf bases wrapped round the stem, go to the leaf they touch.
7. Halves: a band along a leaf that no view sees (shaded by a leaf below) cuts the
   leaf lengthwise, and each half grows its own tip. Two leaves whose midribs run
   side by side, parallel, offset within both leaves' surfaces and for at least
   three times their distance apart are joined (:func:`_merge_split_leaves`);
   the joined leaf's width spans the hidden band. Compound leaves: a leaf whose chain
   meets another leaf's, not a stem, is a leaflet of that leaf when the junction lies
   out of every stem's column by a bin or more and the chain from the stem up to it
   narrows to a stalk (a petiole: a piece within an eighth of the branch's half-width,
   or half a voxel, of the line through it); ``Segmentation.leaf_group`` numbers the
   leaves, a compound leaf's leaflets sharing one (a maize leaf hanging from another's
   chain where the stem's walk stopped meets it on the axis; a rosette's leaf lying on
   another meets a lamina, not a stalk, except where occlusion leaves a strip of it).
8. Surfaces: a leaf holds at least one point per point spacing along its midrib (a
   sampled surface does); a branch with fewer is a trail of mixed pixels behind a
   leaf's edge, of strays, or a filament thinner than the spacing (a tassel branch),
   not counted (:func:`_drop_leaves_without_surface`). Given each point's range noise
   along its beam, a branch nearly all of whose points could be a stem's own hits,
   moved along their beams by the noise, and that ends within the stem's noise disc,
   is the stem's noise, not a leaf (:func:`stem_noise_points`,
   :func:`_drop_stem_noise_leaves`): its points go to the stem.
9. Grids: the voxel grid (step 3) and the level sets (step 5) start somewhere, and a
   branch near a threshold goes one way or the other with where they start (a tip near
   the shortest leaf, two halves near the merge rule): the ideal 30-leaf rosette reads 13
   to 25 leaves over 9 grids, the maize 9 to 11. :func:`segment_on_shifted_grids`
   segments on grids shifted by a fraction of a voxel and of a bin
   (:func:`shifted_grid_offsets`), sharing the steps no grid changes (outliers, scale,
   stems); traits read the median grid and its spread, as an averaged shifted histogram
   removes a histogram's dependence on its bins' origin (Scott 1985, "Averaged shifted
   histograms", Annals of Statistics 13:1024-1040).
10. Round the axis: given the range noise, on each grid after step 8. A turntable
   rig's beams lie in planes through its axis, so the noise moves each point along a
   line through the axis and leaves its azimuth about it. A rosette's leaves grow from
   the axis, where the noise spreads their bases into one disc and joins them into
   one leaf; beyond the disc, leaves apart in azimuth are apart in the points, and a
   leaf whose points there fall into groups that empty sectors part, each as long as
   a leaf, is that many leaves (:func:`_split_at_axis`). The realistic 3-leaf
   rosette read one leaf for three without it, and reads its three, each matched to
   its true leaf.
11. Cups, on a clean scan, after step 10: a rosette's inner leaves rise from the crown
   edge on edge, a cup the level sets hold as one leaf until near the tips (the ideal
   30-leaf rosette: two found leaves held twelve true ones). A leaf's tip is where it
   reaches farthest from its base, and round the axis the cup's reach from its junction
   has a lobe per leaf; a leaf whose outer half spans a quarter turn round the axis and
   whose reach has two lobes or more, each two spacings prominent and as long as a leaf,
   is cut at the valleys between them (:func:`_split_petals`). A part lying in another
   found leaf's sector is that leaf's piece, and a part that starts well out from the
   junction is a leaflet at the end of a stalk, not a leaf. The 30-leaf rosette reads
   21 leaves for 30 (15 before), 11 of its 23 laminae 60 % or more one true leaf's (7
   of 16). A noisy scan's reach is its noise's: step 10 reads those.
12. Cups by their surfaces, on a clean scan, after step 11: touching leaves meet at a
   crease, and a cup's points fall into smooth surfaces there by region growing with a
   smoothness constraint (Rabbani et al. 2006), the pieces of one leaf that the leaves
   in front of it cut apart joined where one quadric fits them as closely as each alone;
   each surface as long as a leaf, starting near the cup's base and reaching out from
   the axis, is a leaf (:func:`_split_smooth_surfaces`). The ideal 30-leaf rosette reads
   25 leaves for 30 (21 before; 17-31 over the grids), the 12-leaf one 14 (12), with 8 and
   9 laminae matched to a true leaf (3 and 6).
13. Fragments, on a clean scan: a found leaf with fewer nodes a spacing apart than a strip
   two nodes wide and a leaf long is no leaf's surface but a piece of the leaf it touches
   most, and joins it (:func:`_join_fragments`).

Validity: plants with thin stems and strap or broad leaves attached to them
(cereals, maize, seedlings), turntable frame with z up and the base at ``base_z``.
Leaves that touch over more than about a bin along their length, or that wrap the
stem (sheaths), merge until the level sets separate them: their bases are counted
with the stem and the leaf count falls by one for every pair that stays joined.
Range noise above about a tenth of the leaf width blurs neighbouring leaves into
one; leaves shorter than ``min_leaf_length_m`` are not counted. Mixed pixels with
little range noise (a footprint model without its noise) leave, besides the trails,
leaves split lengthwise: a realistic maize scanned without range noise reads 17 leaves
for 9.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import typing
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantsim.evaluation.knn import NeighbourIndex

logger = logging.getLogger(__name__)

__all__ = [
    "CloudScale", "Segmentation", "SegmentationSettings", "StemBase", "estimate_scale",
    "BeamStemTrack", "beam_stem_diameter", "beam_stem_top", "checked_range_noise", "cup_stem_top",
    "find_beam_stems", "find_stems", "kept_points",
    "node_frames", "on_beam_stem", "outlier_mask", "quadric_rms", "read_by_axis_beams", "track_beam_stem",
    "with_beam_stems",
    "segment_on_shifted_grids",
    "segment_organs", "shifted_grid_offsets", "stem_noise_points", "uniform_width", "voxel_centroids",
]


# --------------------------------------------------------------------------
# scale and outliers
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class CloudScale:
    """The length scales of a cloud, metres.

    Attributes:
        spacing_m: point spacing on the surface, ``r16 sqrt(pi / 16)`` with ``r16`` the
            distance to the 16th neighbour: its median over the surface's area (each
            point weighted by the area it stands for, ``r16^2``).
        noise_m: median RMS distance of 16-neighbourhoods from their best-fit plane.
        voxel_m: the working resolution ``max(2 spacing, 1.5 noise)``.
    """

    spacing_m: float
    noise_m: float
    voxel_m: float


def estimate_scale(points: np.ndarray, *, max_samples: int = 20_000, seed: int = 0,
                   workers: int = -1) -> CloudScale:
    """Point spacing and noise of a cloud (see the module docstring, step 1).

    Spacing: ``r16 sqrt(pi / 16)`` with ``r16`` the distance to the 16th neighbour (a
    surface of density ``16 / (pi r16^2)``), its median over the surface's area: each
    point weighs the area it stands for, ``pi r16^2 / 16``. A turntable sees the
    region near its axis on every turn, so a per-point statistic measures the stem:
    97 % of an ideal 3-leaf bean's points lie within 6 mm of the axis, and their 90th
    percentile read 0.14 mm for leaves sampled 1-2 mm apart (no leaf joined the
    stem). Weighted by area, a stem counts for its surface, and the spacing is that of
    the median square millimetre of the plant (a plane grid's spacing on a grid).

    Noise: multi-scale local plane fits (the residual of Hoppe et al. 1992, the
    scale chosen as in Mitra & Nguyen 2003, "Estimating surface normals in noisy
    point cloud data", SoCG): around sampled points, the covariance of the
    neighbours within radius ``R`` is taken for a ladder of radii from the 16th
    neighbour's distance up. Below the noise the ball is filled (smallest /
    middle eigenvalue near 1); well above it curvature and neighbouring organs
    raise the ratio again; the radius with the smallest median ratio is where the
    cloud looks most like a surface, and the median RMS residual there is the
    noise. The ladder starts at three spacings (and 16 neighbours). A fixed 16-point fit underestimates LiDAR noise several-fold: 16
    neighbours lie on one or two scan lines, inside the noise band, and a
    line's noise stays in its own scan plane. Valid while the noise is below the
    largest radius of the ladder (the 256th neighbour's distance on a 5,000-point
    subsample), i.e. up to about a quarter of the organ widths.

    Args:
        points: (n, 3) float64, metres, n >= 17.
        max_samples: neighbourhoods sampled for the spacing (deterministic subsample).
        seed: seed of the subsamples.
        workers: threads of the neighbour queries (-1: all cores; same answer).

    Returns:
        CloudScale.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 17:
        raise ValueError(f"estimating the point spacing needs at least 17 points, got {len(pts)}")
    rng = np.random.default_rng(seed)
    tree = NeighbourIndex(pts)
    idx = rng.choice(len(pts), size=min(max_samples, len(pts)), replace=False)
    # Scan lines pack points far closer along a line than between lines, so the
    # nearest neighbour understates the spacing: take the radius r16 holding 16
    # neighbours on a surface of density rho = 16 / (pi r16^2), spacing 1/sqrt(rho).
    d, _ = tree.query(pts[idx], k=17, workers=workers)
    spacing = _area_weighted_median(d[:, 16], d[:, 16] ** 2) * math.sqrt(math.pi / 16.0)
    noise = _noise_multiscale(pts, 3.0 * spacing, rng=rng, workers=workers, tree=tree)
    return CloudScale(spacing_m=spacing, noise_m=noise, voxel_m=max(2.0 * spacing, 1.5 * noise))


def _area_weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value below which half the total weight lies (the lower weighted median)."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order], dtype=np.float64)
    if not cum[-1] > 0:
        return float(np.median(values))  # all weights zero: duplicate points only
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def _noise_multiscale(pts: np.ndarray, r_min: float, *, rng: np.random.Generator, workers: int,
                      n_centres: int = 300, k: int = 256, sub: int = 5_000,
                      tree: NeighbourIndex | None = None) -> float:
    """RMS plane-fit residual at the most surface-like scale (estimate_scale's noise).

    Two ladders: small radii on the whole cloud, large radii on a subsample (which
    reaches farther with the same ``k``; second moments do not depend on density).
    ``tree``: a k-d tree of ``pts`` already built (else one is built).
    """
    best = (math.inf, 0.0)
    clouds = [pts]
    if len(pts) > sub:
        clouds.append(pts[rng.choice(len(pts), size=sub, replace=False)])
    for cloud in clouds:
        kk = min(k, len(cloud))
        centres = cloud[rng.choice(len(cloud), size=min(n_centres, len(cloud)), replace=False)]
        cloud_tree = tree if cloud is pts and tree is not None else NeighbourIndex(cloud)
        dist, nn = cloud_tree.query(centres, k=kk, workers=workers)
        nb = cloud[nn]
        # Below a few spacings a ball holds one or two scan lines: no plane to fit.
        lo = max(r_min, float(np.median(dist[:, 15])), 1e-9)
        hi = max(float(np.median(dist[:, -1])), lo)
        for radius in np.geomspace(lo, hi, 6):
            w = (dist <= radius).astype(np.float64)
            count = w.sum(axis=1)
            ok = count >= 16
            if ok.sum() < 20:
                continue
            wk, q, c = w[ok], nb[ok], count[ok][:, None]
            # Weighted means and covariances as batched matrix products (BLAS;
            # the same sums as einsum's "nk,nki,nkj->nij", 2.5x faster).
            mean = np.matmul(wk[:, None, :], q)[:, 0] / c
            q = q - mean[:, None, :]
            cov = np.matmul((q * wk[..., None]).transpose(0, 2, 1), q) / c[..., None]
            ev = np.linalg.eigvalsh(cov)
            ratio = float(np.median(ev[:, 0] / np.maximum(ev[:, 1], 1e-30)))
            if ratio < best[0]:
                best = (ratio, float(np.sqrt(max(np.median(ev[:, 0]), 0.0))))
    return best[1]


def outlier_mask(points: np.ndarray, *, k: int = 8, n_sigma: float = 3.0,
                 workers: int = -1) -> np.ndarray:
    """Statistical outlier removal (Rusu et al. 2008, "Towards 3D point cloud based
    object maps for household environments", RAS 56:927-941).

    Args:
        points: (n, 3) float64, metres.
        k: neighbours.
        n_sigma: a point is an outlier when its mean neighbour distance exceeds the
            cloud's mean by ``n_sigma`` standard deviations.
        workers: threads of the neighbour query (-1: all cores; same answer).

    Returns:
        (n,) bool, True for the points kept.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) <= k:
        return np.ones(len(pts), dtype=bool)
    d, _ = NeighbourIndex(pts).query(pts, k=k + 1, workers=workers)
    mean = d[:, 1:].mean(axis=1)
    return mean <= mean.mean() + n_sigma * mean.std()


def _sparse_surface(points: np.ndarray, flagged: np.ndarray, scale: CloudScale, *, k: int = 12,
                    planarity: float = 0.01, workers: int = -1) -> np.ndarray:
    """The flagged points that are the sparse part of a clean surface, not outliers.

    Statistical outlier removal assumes the mean neighbour distances of a cloud
    spread about one value. A turntable scan's do not: the turntable's steps sample
    a surface ``r dphi`` apart at a distance ``r`` from the axis, so a leaf's outer
    part is several times sparser than the stem, and on a noise-free cloud the
    points the rule drops are all on the plant (an ideal 0.5-degree maize lost the
    outer 76 mm of a 211 mm leaf, a dicot its leaflets' tips: a third of its leaf
    area). A flagged point is kept again when the cloud is clean (noise at most half
    its spacing) and the point continues a surface: its ``k`` nearest points lie on a
    plane (smallest eigenvalue of their covariance at most ``planarity`` of the sum,
    the surface variation of Pauly et al. 2002), the point lies on that plane (within
    three noise and a tenth of a spacing), and it is no sparser than they are (its
    mean distance to its 8 nearest at most twice theirs, as in the local outlier
    factor of Breunig et al. 2000). On a noisy cloud the flagged points are the
    noise's and the mixed pixels' (20 to 30 mm off the plant on the realistic
    procedural scans) and all go.

    Returns:
        (n,) bool, True for the flagged points kept again.
    """
    out = np.zeros(len(points), dtype=bool)
    bad = np.flatnonzero(flagged)
    if len(bad) == 0 or len(points) <= k + 1 or scale.noise_m > 0.5 * scale.spacing_m:
        return out
    index = NeighbourIndex(points)
    _, idx = index.query(points[bad], k=k + 1, workers=workers)
    nb = idx[:, 1:]  # the point itself comes first (duplicates aside: any twin is as good)
    centre = points[nb].mean(axis=1)
    q = points[nb] - centre[:, None]
    w, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    planar = w[:, 0] <= planarity * np.maximum(w.sum(axis=1), 1e-300)
    off_plane = np.abs(np.einsum("ni,ni->n", points[bad] - centre, vec[:, :, 0]))
    on_plane = off_plane <= 3.0 * scale.noise_m + 0.1 * scale.spacing_m
    who = np.unique(np.concatenate([bad, nb.ravel()]))
    d, _ = index.query(points[who], k=9, workers=workers)
    mean_d = np.zeros(len(points))
    mean_d[who] = d[:, 1:].mean(axis=1)
    dense_as_neighbours = mean_d[bad] <= 2.0 * np.median(mean_d[nb], axis=1)
    out[bad[planar & on_plane & dense_as_neighbours]] = True
    return out


def kept_points(points: np.ndarray, *, workers: int = -1) -> tuple[np.ndarray, CloudScale]:
    """The points the segmentation keeps, and the cloud's scale.

    :func:`outlier_mask`, then the flagged points that are the sparse part of a
    clean surface back (:func:`_sparse_surface`, judged with the scale of the points
    the removal keeps); the scale returned is estimated again on all the points kept.
    The removal's verdict follows the points, not the surface: on a small plant whose
    stem holds most of the points it flags most of the leaves, and a scale without
    them is the stem's.

    Args:
        points: (n, 3) float64, metres, n >= 17.
        workers: threads of the neighbour queries (-1: all cores; same answer).

    Returns:
        ((n,) bool, True for the points kept; CloudScale).
    """
    pts = np.asarray(points, dtype=np.float64)
    kept = outlier_mask(pts, workers=workers)
    scale = estimate_scale(pts[kept], workers=workers)
    rescued = _sparse_surface(pts, ~kept, scale, workers=workers)
    if not rescued.any():
        return kept, scale
    kept = kept | rescued
    return kept, estimate_scale(pts[kept], workers=workers)


def voxel_centroids(points: np.ndarray, cell: float,
                    grid_offset: Any = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Centroid of each occupied voxel of side ``cell`` and each point's voxel.

    ``grid_offset``: x, y, z fractions of ``cell`` the grid is shifted by (voxel faces
    where ``point + offset * cell`` is a multiple of ``cell``), as a shifted grid's
    voxels are (:attr:`SegmentationSettings.grid_offset`); zeros: anchored on the origin.

    Returns:
        (centroids (m, 3) float64, inverse (n,) int64 with points[i] in voxel inverse[i]).
    """
    shift = np.asarray(grid_offset, dtype=np.float64) * cell
    points = points + shift
    ijk = np.floor(points / cell).astype(np.int64)
    ijk -= ijk.min(axis=0)
    dims = ijk.max(axis=0) + 1
    if float(np.prod(dims, dtype=np.float64)) < 2.0**62:
        # One int64 key a voxel, ordered as the rows (i, j, k) are: the same voxels
        # and numbering as np.unique(ijk, axis=0), several times faster.
        _, inverse = np.unique((ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2],
                               return_inverse=True)
    else:
        _, inverse = np.unique(ijk, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    m = int(inverse.max()) + 1
    counts = np.bincount(inverse, minlength=m).astype(np.float64)
    centroids = np.column_stack(
        [np.bincount(inverse, weights=points[:, j], minlength=m) / counts for j in range(3)])
    return centroids - shift, inverse


# --------------------------------------------------------------------------
# stems from the base up
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StemBase:
    """A stem found at the base of a cloud.

    Attributes:
        center_xy_m: (x, y) of the stem axis near the base, metres.
        diameter_m: the stem's ring diameter above its basal flare
            (:func:`_diameter_above_flare`), metres; when the noise hides the ring
            (``diameter_resolved`` False), the median width of its column over the base
            slices.
        rms_residual_m: median radial RMS residual of those fits, metres.
        n_slices: slices the stem was found in.
        n_points: points in those slices.
        diameter_resolved: False when most of those slices were noise-dominated (no
            plausible circle, or one whose residual is over a quarter of its radius):
            the diameter is then the noisy column's width, an upper bound on the stem's.
        found_in_beams: True for a stem beside the axis that the range noise hides from
            the slices, found as a streak of turn angles (:func:`find_beam_stems`); its
            diameter is the turn angles it spans times its distance from the axis,
            resolved to a scanned step there, and ``rms_residual_m`` is NaN.
    """

    center_xy_m: tuple[float, float]
    diameter_m: float
    rms_residual_m: float
    n_slices: int
    n_points: int
    diameter_resolved: bool = True
    found_in_beams: bool = False


def _xy_clusters(xy: np.ndarray, link: float, min_points: int) -> list[np.ndarray]:
    """Single-linkage clusters of 2D points at ``link``, through an occupancy grid.

    Points in one square cell of side ``link / sqrt(2)`` are always linked, so only
    the occupied cells are clustered: two cells join when their points' centroids lie
    within ``link`` of each other. A dense stem slice holds thousands of points and
    millions of point pairs but a few dozen cells; the clusters are single linkage
    at ``link`` to within a cell (a gap narrower than a cell may be bridged).
    """
    if len(xy) == 0:
        return []
    cell = link / math.sqrt(2.0)
    ij = np.floor(xy / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    _, inv = np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1], return_inverse=True)
    inv = inv.reshape(-1)
    m = int(inv.max()) + 1
    counts = np.bincount(inv, minlength=m).astype(np.float64)
    centres = np.column_stack([np.bincount(inv, weights=xy[:, j], minlength=m) / counts
                               for j in range(2)])
    pairs = cKDTree(centres).query_pairs(link, output_type="ndarray")
    lab = _components(m, pairs)[inv]
    order = np.argsort(lab, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(lab[order])) + 1)
    return [g for g in groups if len(g) >= min_points]


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component label of each of ``n`` nodes joined by ``pairs`` (p, 2).

    The CSR matrix is built directly (edges grouped by row): a COO matrix would
    be summed and sorted per row first, the slow part on dense radius graphs.
    Labels are numbered by each component's lowest node, whatever the edge order.
    """
    order = np.argsort(pairs[:, 0])
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=n), out=indptr[1:])
    g = sparse.csr_matrix((np.ones(len(pairs)), pairs[order, 1], indptr), shape=(n, n))
    return csgraph.connected_components(g, directed=False)[1]


class _SliceFit(typing.NamedTuple):
    """One stem candidate in one base slice (:func:`find_stems`)."""

    slice_index: int
    centre_xy: np.ndarray
    diameter_m: float
    rms_residual_m: float
    n_points: int
    join_m: float          # other slices' centres within this are the same column
    unresolved: bool       # a fallback or a noise-filled disc, not a ring


def _robust_extent(xy: np.ndarray) -> float:
    """Twice the 95th-percentile distance from the median point: one stray point
    cannot make a stem look like a leaf."""
    return 2.0 * float(np.percentile(np.hypot(*(xy - np.median(xy, axis=0)).T), 95))


def _dense_core(xy: np.ndarray, radius: float, *, min_share: float = 0.5) -> np.ndarray | None:
    """The points of a slice cluster within ``radius`` of its densest place, if they hold
    at least ``min_share`` of it; else None.

    The centre starts at the cluster's median and is moved three times to the median
    of the points within ``radius`` of it (a trimmed-median mode seeker), so a leaf
    band joined to a noisy stem's disc drags it little while the disc holds most of
    the points.
    """
    c = np.median(xy, axis=0)
    core = xy
    for _ in range(3):
        core = xy[np.hypot(*(xy - c).T) <= radius]
        if len(core) < 6:
            return None
        c = np.median(core, axis=0)
    return core if len(core) >= min_share * len(xy) else None


def _plausible_circle(fit, extent: float, max_diameter_m: float) -> bool:
    """A slice's circle fit can be a stem: no wider than ``max_diameter_m``, and on an
    arc spanning at least half its radius (a short arc fits any large circle)."""
    return 2 * fit.radius <= max_diameter_m and fit.radius <= 2 * extent


def _ring_residual(fit) -> bool:
    """A ring's radial RMS residual is at most a quarter of its radius; a noise-filled
    disc's is not."""
    return fit.rms_residual <= 0.25 * fit.radius


def _rising_run(slices: list[int], min_slices: int) -> int:
    """How many of a column's base slices (their indices, ascending, from 1) make a stem
    rising from the base: it holds one of the two lowest and goes on up, at most one slice
    missing at a time, for ``min_slices`` or more; 0 when it does not."""
    run = 1
    while run < len(slices) and slices[run] - slices[run - 1] <= 2:
        run += 1
    return run if run >= min_slices and slices[0] <= 2 else 0


def find_stems(points: np.ndarray, *, base_z: float, scale: CloudScale, max_diameter_m: float,
               n_slices: int = 6, min_slices: int = 3) -> tuple[StemBase, ...]:
    """Stems found from the base up: compact clusters that persist over thin slices.

    The ``n_slices`` slices of thickness ``max(v, 3 mm)`` (``max(2 v, 3 mm)`` in a
    noisy cloud) start one slice above
    ``base_z`` (the lowest is skipped: soil and disk edges). In each slice the points
    are clustered in XY (single linkage at ``max(3 spacing, 2 noise)``); a cluster
    whose extent is at most ``max_diameter_m + 4 noise`` gets a circle fit (Kasa,
    then geometric; :func:`plantsim.evaluation.traits.fit_circle`). A fit wider than
    ``max_diameter_m`` or on too short an arc falls back to the cluster's mean and
    extent (a noise-dominated slice). In a noisy cloud (noise above half the spacing:
    range noise smears a thin stem into a disc centimetres wide, and the leaf bases
    it touches join it in the slice) a wider cluster is cut to its dense core,
    the points within ``max_diameter_m / 2 + 2 noise`` of its trimmed-median mode
    (:func:`_dense_core`), when that core holds half of it; the core is a fallback
    too. Circle fits whose centres lie within one diameter (at least two voxels) of
    each other across slices form a column, fallbacks within two voxels (a mean
    follows a leaf rising through the slices; a stem's stays put), one fit a slice
    (the nearest), two circles' diameters within a factor of two of each other. A
    column is a stem when it rises from the base: it holds one of the two lowest
    slices and goes on up, at most one slice missing at a time, for at least
    ``min_slices`` slices (a rosette's inner leaves, rising steeply from a crown 2 cm
    tall, are compact columns from the crown's top up). Its centre is the median over
    those slices; its diameter is read above the basal flare, its rings followed on up
    (:func:`_diameter_above_flare`). The diameter is unresolved (an upper bound:
    the median width over those slices) when most of them are fallbacks or circles whose RMS residual exceeds a quarter of
    their radius (a disc of noise, not a ring). A drooping leaf crosses few slices at one place, so
    it is not taken for a stem; with none found, "no stem" is the answer (an empty
    tuple), never a guess.

    Args:
        points: (n, 3) float64, metres, turntable frame.
        base_z: z of the plant base, metres.
        scale: the cloud's scale.
        max_diameter_m: widest plausible stem, metres.
        n_slices: slices examined.
        min_slices: slices a stem must appear in.

    Returns:
        Stems, sorted by x then y.
    """
    from plantsim.evaluation.traits import fit_circle  # circular import otherwise

    noisy = scale.noise_m > 0.5 * scale.spacing_m
    # A clean slice one voxel (two spacings) thick holds a ring; the centre of a
    # disc of noise needs twice the points. Thin slices resolve short stems (a
    # rosette's 2 cm crown).
    thickness = max((2.0 if noisy else 1.0) * scale.voxel_m, 0.003)
    link = max(3.0 * scale.spacing_m, 2.0 * scale.noise_m)
    fits: list[_SliceFit] = []
    for k in range(1, n_slices + 1):
        z0 = base_z + k * thickness
        sl = points[(points[:, 2] >= z0) & (points[:, 2] < z0 + thickness), :2]
        for g in _xy_clusters(sl, link, 6):
            xy = sl[g]
            extent = _robust_extent(xy)
            cored = extent > max_diameter_m + 4.0 * scale.noise_m
            if cored and not noisy:
                continue
            if cored:
                xy = _dense_core(xy, 0.5 * max_diameter_m + 2.0 * scale.noise_m)
                if xy is None:
                    continue
                extent = _robust_extent(xy)
            try:
                fit = fit_circle(xy)
            except ValueError:
                continue
            radius = fit.radius
            fallback = cored or not _plausible_circle(fit, extent, max_diameter_m)
            if fallback:
                radius = 0.5 * extent  # fall back to the extent (noise-dominated slice)
                centre = xy.mean(axis=0)
            else:
                centre = np.array(fit.center_xy)
            # A circle's centre may wander by its diameter between slices; a fallback's
            # is a mean, which a leaf band rising through the slices drags along with
            # it, so it must stay within two voxels to be one column.
            join = 2 * scale.voxel_m if fallback else max(2 * radius, 2 * scale.voxel_m)
            unresolved = fallback or not _ring_residual(fit)
            fits.append(_SliceFit(k, centre, 2 * radius, fit.rms_residual, len(g), join, unresolved))
    stems: list[StemBase] = []
    used = np.zeros(len(fits), dtype=bool)
    centres = np.array([f.centre_xy for f in fits]).reshape(-1, 2)
    for i, seed in enumerate(fits):
        if used[i]:
            continue
        dist = np.linalg.norm(centres - seed.centre_xy, axis=1)
        within = dist <= seed.join_m
        # One fit a slice: the nearest the seed's centre. Between two ring fits, the
        # diameters agree within a factor of two (a stem's section changes slowly;
        # the leaf bands round its top fit wide arcs and must not join its column).
        nearest: dict[int, tuple[float, int]] = {}
        for j in np.flatnonzero(within & ~used):
            f, d = fits[j], float(dist[j])
            rings = not (seed.unresolved or f.unresolved)
            if (d >= nearest.get(f.slice_index, (math.inf, -1))[0]
                    or rings and not 0.5 <= f.diameter_m / seed.diameter_m <= 2.0):
                continue
            nearest[f.slice_index] = (d, int(j))
        # A stem rises from the base: its column holds one of the two lowest slices
        # and goes on up without a gap of more than one slice (a leaf may hide one).
        # A leaf rising steeply from a crown above the base (rosettes) is a compact
        # column too, but only from the crown's top up; leaf bands stacked higher
        # are not the column it starts.
        slices = sorted(nearest)
        run = _rising_run(slices, min_slices)
        if not run:
            continue
        nearest = {k: nearest[k] for k in slices[:run]}
        slices = set(nearest)
        # The column takes every fit within its join (none seeds another column);
        # its centre and diameter come from its one fit a slice.
        used[within] = True
        column = [fits[j] for _, j in nearest.values()]
        c = np.median(np.array([f.centre_xy for f in column]), axis=0)
        resolved = 2 * sum(f.unresolved for f in column) < len(column)
        diameter = float(np.median([f.diameter_m for f in column]))
        if resolved:
            diameter = _diameter_above_flare(points, base_z, c, column, thickness=thickness, link=link,
                                             max_diameter_m=max_diameter_m)
        stems.append(StemBase(center_xy_m=(float(c[0]), float(c[1])),
                              diameter_m=diameter,
                              rms_residual_m=float(np.median([f.rms_residual_m for f in column])),
                              n_slices=len(slices), n_points=int(sum(f.n_points for f in column)),
                              diameter_resolved=resolved))
    stems.sort(key=lambda s: s.center_xy_m)
    return tuple(stems)


# A stem's base flares into a root collar (a maize's from 25 mm to 14 mm over its
# lowest 25 mm, about two diameters); its diameter is read above it.
FLARE_DIAMETERS = 3.0


def _diameter_above_flare(points: np.ndarray, base_z: float, centre_xy: np.ndarray,
                          column: list[_SliceFit], *, thickness: float, link: float,
                          max_diameter_m: float) -> float:
    """A stem's diameter above its basal flare, metres.

    The stem's ring fits are followed on up from its base column, slice by slice,
    to ``FLARE_DIAMETERS`` times the column's median diameter above ``base_z``: in
    each slice the cluster (single linkage ``link``) nearest the stem's centre gets a
    circle fit, kept while it is a ring (RMS residual at most a quarter of its radius,
    on an arc spanning its radius) within a factor of two of the last ring's diameter
    and centred within one diameter of the stem's centre; two slices in a row without
    one end the climb (leaves leave the stem there). The diameter is the median of
    the rings in the upper half of the heights climbed, up to that height (thick base
    slices, on a sparse cloud, can reach past it): the flare, where a stem widens
    into its root collar, lies in the lower half (phenotyping measures stem diameter
    above the collar, not at the soil). A column whose rings stop at its base slices
    (a rosette's 2 cm crown) reads the median of the upper half of those.
    """
    from plantsim.evaluation.traits import fit_circle  # circular import otherwise

    rings = [(f.slice_index, f.diameter_m) for f in column if not f.unresolved]
    if not rings:
        return float(np.median([f.diameter_m for f in column]))
    top_z = base_z + FLARE_DIAMETERS * float(np.median([d for _, d in rings]))
    k, last, misses = max(f.slice_index for f in column), max(rings)[1], 0
    while misses < 2 and base_z + (k + 1) * thickness < top_z:
        k += 1
        z0 = base_z + k * thickness
        near = (np.abs(points[:, 2] - z0 - 0.5 * thickness) <= 0.5 * thickness) & (
            np.hypot(*(points[:, :2] - centre_xy).T) <= last + 2.0 * link)
        found = False
        sl = points[near, :2]
        groups = _xy_clusters(sl, link, 6) if len(sl) >= 6 else []
        if groups:
            g = min(groups, key=lambda g: float(np.hypot(*(sl[g].mean(axis=0) - centre_xy))))
            try:
                fit = fit_circle(sl[g])
            except ValueError:
                fit = None
            if fit is not None:
                d = 2 * fit.radius
                found = (_plausible_circle(fit, _robust_extent(sl[g]), max_diameter_m)
                         and _ring_residual(fit) and 0.5 <= d / last <= 2.0
                         and np.hypot(*(np.array(fit.center_xy) - centre_xy)) <= d)
        if found:
            rings.append((k, d))
            last, misses = d, 0
        else:
            misses += 1
    heights = (np.array([i for i, _ in rings], dtype=np.float64) + 0.5) * thickness
    diameters = np.array([d for _, d in rings])
    band = heights <= top_z - base_z  # base slices may reach past the flare band (thick slices)
    if band.any():
        heights, diameters = heights[band], diameters[band]
    upper = heights >= 0.5 * (heights.min() + heights.max())
    return float(np.median(diameters[upper]))


# --------------------------------------------------------------------------
# stems beside the axis that the range noise hides, found in the turn angles
# --------------------------------------------------------------------------
# A rig whose scan plane holds the turntable's axis casts every beam in a plane through
# it: the range noise moves a point along its beam, within that plane, and leaves its
# turn angle (its azimuth about the axis) as scanned. The beams are taken to lie in such
# planes when the median tangential component of their directions is under this.
_BEAM_PLANE_MAX_TANGENTIAL = 0.02
# A stem beside the axis under range noise is a streak of turn angles: a few angles
# wide (its diameter over its distance from the axis), its points spread along their
# beams (radially) as the noise spreads them. Its points lie within this many standard
# deviations of the radial noise of its axis.
BEAM_STEM_RADIAL_SIGMAS = 3.0
# Points beyond this many standard deviations of the radial noise from the axis are
# no stem's on the axis (its noise disc): a streak is looked for among them.
_BEAM_STEM_AXIS_SIGMAS = 2.5
# A streak holds at least this many points a slice; its points spread from their median
# distance from the axis no more than this times the radial noise does (plus a quarter of
# its arc: a leaf running out from the axis spreads as far as it runs); and it holds this
# many times the points the slice holds per turn angle beyond the axis's noise disc (its
# median over 5 deg sectors: the disc's tail, and leaves).
_BEAM_STEM_MIN_POINTS = 8
_BEAM_STEM_MAX_SPREAD = 1.6
_BEAM_STEM_BACKGROUND_TIMES = 3.0
# A streak's distance from the axis is that of its own points: its turn angles' points
# less those of the turn angles beside it (the noise of the stem on the axis, which fills
# every turn angle alike), at every distance; the median of the excess. Beyond the disc
# alone its points' median reads a stem inside it at the disc's edge: the seed rig's
# wheat culms 13-27 mm from the axis, under 16 mm of radial noise, read 45-47 mm, and
# their excess 15-27 mm; the procedural wheat's tillers 37-60 mm out read 37-59 mm. The
# excess must hold this share of the streak's turn angles' points (else it is the disc's
# noise), and the stem must stand beyond the axis's noise disc (_BEAM_STEM_AXIS_SIGMAS):
# inside it, its noise and the axis stem's are one disc, which hides its own points from
# the beams behind it, and the slices' stem is all that is read.
_BEAM_STEM_MIN_EXCESS = 0.2
# The slices a streak is looked for in, and followed up through, are this many voxels
# thick: twice find_stems' noisy slices, as a thin stem beside the axis is met by a few
# scanned turn angles only (a 4 mm culm 60 mm out by 4 of 1 deg), and each slice must
# hold _BEAM_STEM_MIN_POINTS of its points.
BEAM_STEM_SLICE_VOXELS = 4.0
# A stem leans at most this far from upright over the base slices, radially or round the
# axis (a procedural wheat's tillers lean 3-4 deg): a leaf rising steeply beside the axis
# is a streak too, but its distance from the axis grows slice by slice.
BEAM_STEM_MAX_LEAN_DEG = 20.0
# Its track up the plant ends after this many slices in a row without the streak.
_BEAM_STEM_MAX_MISSES = 3


class _TurnGeometry(typing.NamedTuple):
    """Where each point lies about the turntable's axis, and how its noise moves it."""

    azimuth: np.ndarray       # (n,) rad, each point's turn angle about the axis
    rho: np.ndarray           # (n,) m, its distance from the axis
    radial_sigma: np.ndarray  # (n,) m, its range noise's component away from the axis
    sigma_r: float            # m, the RMS of radial_sigma
    step: float               # rad, the spacing of the scanned turn angles


def _turn_geometry(points: np.ndarray, noise: np.ndarray) -> _TurnGeometry | None:
    """The points' turn angles and radial noise; None when a point has no noise or the
    beams do not lie in planes through the axis (their turn angles are then noisy too)."""
    sigma = np.linalg.norm(noise, axis=1)
    if not len(points) or not np.all(sigma > 0):
        return None
    phi = np.arctan2(points[:, 1], points[:, 0])
    rho = np.hypot(points[:, 0], points[:, 1])
    cos, sin = np.cos(phi), np.sin(phi)
    tangential = np.abs(-noise[:, 0] * sin + noise[:, 1] * cos) / sigma
    if float(np.median(tangential)) > _BEAM_PLANE_MAX_TANGENTIAL:
        return None
    radial = np.abs(noise[:, 0] * cos + noise[:, 1] * sin)
    sigma_r = float(np.sqrt(np.mean(radial ** 2)))
    # The scanned turn angles, from the points beyond the axis's noise disc (a point
    # near the axis, rounded to a file's grid, moves in turn angle): distinct values
    # 0.05 deg apart or more; the step is the median gap between them.
    far = rho > _BEAM_STEM_AXIS_SIGMAS * sigma_r
    angles = np.unique(np.round(np.degrees(phi[far]) / 0.05)) * 0.05
    gaps = np.diff(angles)
    gaps = gaps[gaps > 0.075]
    if not len(gaps):
        return None
    return _TurnGeometry(phi, rho, radial, sigma_r, math.radians(float(np.median(gaps))))


def _turn_offset(phi: np.ndarray, centre: float) -> np.ndarray:
    """Turn angles less ``centre``, wrapped to (-pi, pi]."""
    return (phi - centre + math.pi) % (2.0 * math.pi) - math.pi


def _on_axis(stem: StemBase) -> bool:
    """Whether the turntable's axis lies within half a stem's width of its centre."""
    return math.hypot(*stem.center_xy_m) <= 0.5 * stem.diameter_m


def read_by_axis_beams(stem: StemBase, noise_given: bool) -> bool:
    """Whether the beams through the turntable's axis read a stem (its top,
    :func:`beam_stem_top` and :func:`cup_stem_top`; its diameter,
    :func:`beam_stem_diameter`): a noisy stem, whose rings the noise hides, standing on
    the axis (within half its column's width), with each point's range noise given."""
    return noise_given and not stem.diameter_resolved and _on_axis(stem)


def with_beam_stems(stems: tuple[StemBase, ...], beside: tuple[StemBase, ...]) -> tuple[StemBase, ...]:
    """The stems the slices found (:func:`find_stems`) and those found in the turn angles
    (:func:`find_beam_stems`), sorted by x then y: a noisy column off the axis that
    the slices found (its diameter unresolved) gives way to a stem found in the turn
    angles within half its width of its centre, which reads its diameter."""
    def replaced(st: StemBase) -> bool:
        return not st.diameter_resolved and not _on_axis(st) and any(
            math.hypot(b.center_xy_m[0] - st.center_xy_m[0], b.center_xy_m[1] - st.center_xy_m[1])
            <= 0.5 * st.diameter_m for b in beside)

    return tuple(sorted([st for st in stems if not replaced(st)] + list(beside), key=lambda st: st.center_xy_m))


class _Streak(typing.NamedTuple):
    """One stem candidate in one slice: a streak of turn angles (:func:`find_beam_stems`)."""

    slice_index: int
    azimuth: float      # rad, its median turn angle
    rho: float          # m, its median distance from the axis
    diameter_m: float   # the turn angles it spans times its distance (:func:`_streak_diameter`)
    n_points: int
    width: float        # rad, the turn angles its points span (5th to 95th percentile, plus a step)


def _streak_diameter(phi: np.ndarray, rho: float, step: float) -> float:
    """A thin stem's diameter from the turn angles its points were scanned at:
    ``count x step x rho``, ``count`` the scanned angles holding a quarter of the
    fullest one's points or more (a stray point of another organ holds an angle alone).
    A stem of diameter d beside the axis meets on average ``d / (step rho)`` of the
    planes through it, whatever their phase: within ``step x rho`` of d on one slice,
    wider by the beam's footprint (a beam grazing its edge returns a point)."""
    _, counts = np.unique(np.round(phi / step), return_counts=True)
    return int(np.count_nonzero(counts >= 0.25 * counts.max())) * step * rho


def find_beam_stems(points: np.ndarray, noise: np.ndarray, *, base_z: float, scale: CloudScale,
                    max_diameter_m: float, stems: tuple[StemBase, ...] = (), n_slices: int = 6,
                    min_slices: int = 3) -> tuple[StemBase, ...]:
    """Stems beside the turntable's axis that the range noise hides from
    :func:`find_stems`, found in the turn angles of their points.

    A rig whose scan plane holds the axis casts each beam in a plane through it; the
    noise moves a point along its beam and leaves its turn angle as scanned. A thin
    stem ``rho`` from the axis is met by the planes within ``d / rho`` of its own
    angle: under range noise several times its diameter (a wheat tiller's 4 mm culm
    under the URG-04LX's 10-12 mm) its points fill a streak a few turn angles wide and
    centimetres long along the beams, which no slice's clusters in x, y hold as a
    compact column. In each of the ``n_slices`` base slices (``BEAM_STEM_SLICE_VOXELS``
    voxels thick, from one slice above ``base_z``), the points beyond the axis's noise
    disc (2.5 standard deviations of the radial noise) are grouped by turn angle (gaps
    of 2.5 scanned steps part them); a group is a streak when it holds 8 points or
    more, spans at most ``max_diameter_m`` and twice the radial noise in arc, its points
    spread from their median distance no more than 1.6 times the radial noise does
    (plus a quarter of its arc), and it holds three times the slice's background per
    turn angle (the median over 5 deg sectors) and 8 points more. Streaks within one
    diameter (plus a step) of each other in turn angle and 1.5 radial sigmas in
    distance form a column; a column is a stem as in :func:`find_stems` (it holds one of
    the two lowest slices and goes on up, at most one slice missing at a time, for
    ``min_slices`` or more) that leans under ``BEAM_STEM_MAX_LEAN_DEG`` radially and
    round the axis (least squares over its slices), and stands beyond the axis's noise
    disc: its distance is that of its own points over the base slices
    (:func:`_streak_distance`: its turn angles' points less those beside them, an
    excess of a fifth of them or more; a stem inside the disc shows only its tail
    beyond it, at the disc's edge). Its diameter is the median over the column of
    :func:`_streak_diameter`. None is added within half the width of a stem
    the slices found whose ring was resolved or which stands on the axis; one within a
    noisy column off the axis replaces it (:func:`with_beam_stems`).

    Needs beams in planes through the axis (:func:`_turn_geometry`); returns none
    otherwise, or without noise on every point.

    Args:
        points: (n, 3) float64 metres, turntable frame.
        noise: (n, 3) float64, each point's beam direction times its range noise's sigma.
        base_z, scale, max_diameter_m, n_slices, min_slices: as :func:`find_stems`.
        stems: the stems :func:`find_stems` found.

    Returns:
        StemBase per stem found (``found_in_beams`` True), sorted by x then y.
    """
    geo = _turn_geometry(points, noise)
    if geo is None:
        return ()
    thickness = max(BEAM_STEM_SLICE_VOXELS * scale.voxel_m, 0.003)
    outside = geo.rho > _BEAM_STEM_AXIS_SIGMAS * geo.sigma_r
    max_arc = min(max_diameter_m, 2.0 * geo.sigma_r)
    step_deg = math.degrees(geo.step)
    streaks: list[_Streak] = []
    for k in range(1, n_slices + 1):
        z0 = base_z + k * thickness
        s = np.flatnonzero(outside & (points[:, 2] >= z0) & (points[:, 2] < z0 + thickness))
        if len(s) < _BEAM_STEM_MIN_POINTS:
            continue
        deg = np.degrees(geo.azimuth[s])
        background = float(np.median(np.histogram(deg, bins=72, range=(-180.0, 180.0))[0])) / 5.0
        order = np.argsort(deg)
        s, deg = s[order], deg[order]
        # Start the circle at its widest gap, so no group is cut at +-180 deg.
        cut = int(np.argmax(np.diff(np.r_[deg, deg[0] + 360.0]))) + 1
        s, deg = np.r_[s[cut:], s[:cut]], np.r_[deg[cut:], deg[:cut] + 360.0]
        for g in np.split(np.arange(len(s)), np.flatnonzero(np.diff(deg) > 2.5 * step_deg) + 1):
            if len(g) < _BEAM_STEM_MIN_POINTS:
                continue
            idx = s[g]
            rho = float(np.median(geo.rho[idx]))
            width_deg = float(np.percentile(deg[g], 95) - np.percentile(deg[g], 5))
            arc = math.radians(width_deg + step_deg) * rho
            spread = float(np.std(geo.rho[idx]))
            expected = float(np.sqrt(np.mean(geo.radial_sigma[idx] ** 2)))
            dense = _BEAM_STEM_BACKGROUND_TIMES * background * (width_deg + step_deg) + _BEAM_STEM_MIN_POINTS
            if arc <= max_arc and spread <= _BEAM_STEM_MAX_SPREAD * expected + 0.25 * arc and len(g) >= dense:
                streaks.append(_Streak(k, math.radians(float(np.median(deg[g]))), rho,
                                       _streak_diameter(geo.azimuth[idx], rho, geo.step), len(g),
                                       math.radians(width_deg + step_deg)))
    found: list[StemBase] = []
    used = np.zeros(len(streaks), dtype=bool)
    for i, seed in enumerate(streaks):
        if used[i]:
            continue
        column = {seed.slice_index: i}
        for j, f in enumerate(streaks):
            if used[j] or f.slice_index in column:
                continue
            apart = abs(float(_turn_offset(np.array(f.azimuth), seed.azimuth))) * seed.rho
            if (apart <= max(seed.diameter_m, f.diameter_m) + geo.step * seed.rho
                    and abs(f.rho - seed.rho) <= 1.5 * geo.sigma_r):
                column[f.slice_index] = j
        slices = sorted(column)
        run = _rising_run(slices, min_slices)
        if not run:
            continue
        members = [streaks[column[k]] for k in slices[:run]]
        used[[column[k] for k in slices[:run]]] = True
        # A stem stands nearly upright; a leaf rising beside the axis leans out of the
        # slices' streaks by its own slope.
        z = np.array([m.slice_index for m in members], dtype=np.float64) * thickness
        rho_of = np.array([m.rho for m in members])
        across = _turn_offset(np.array([m.azimuth for m in members]), seed.azimuth) * seed.rho
        if max(abs(float(np.polyfit(z, rho_of, 1)[0])), abs(float(np.polyfit(z, across, 1)[0]))) > math.tan(
                math.radians(BEAM_STEM_MAX_LEAN_DEG)):
            continue
        azimuth = math.atan2(float(np.median([math.sin(m.azimuth) for m in members])),
                             float(np.median([math.cos(m.azimuth) for m in members])))
        diameter = float(np.median([m.diameter_m for m in members]))
        rho, share = _streak_distance(points, geo, azimuth, float(np.median([m.width for m in members])),
                                      z_m=(base_z + thickness, base_z + (n_slices + 1) * thickness))
        logger.debug("segmentation: streak at %.0f deg: %.0f mm from the axis, %.0f %% of its turn angles' "
                     "points over their flanks'", math.degrees(azimuth), 1e3 * rho, 100 * share)
        if share < _BEAM_STEM_MIN_EXCESS or not rho > _BEAM_STEM_AXIS_SIGMAS * geo.sigma_r:
            continue
        centre = (rho * math.cos(azimuth), rho * math.sin(azimuth))
        if any(math.hypot(centre[0] - st.center_xy_m[0], centre[1] - st.center_xy_m[1]) <= 0.5 * st.diameter_m
               and (st.diameter_resolved or _on_axis(st)) for st in stems):
            continue
        found.append(StemBase(center_xy_m=centre, diameter_m=diameter,
                              rms_residual_m=math.nan, n_slices=run,
                              n_points=int(sum(m.n_points for m in members)), found_in_beams=True))
    found.sort(key=lambda st: st.center_xy_m)
    return tuple(found)


def _streak_distance(points: np.ndarray, geo: _TurnGeometry, azimuth: float, width: float, *,
                     z_m: tuple[float, float]) -> tuple[float, float]:
    """A streak's distance from the axis, metres, and the share of its turn angles' points
    that are its own, between heights ``z_m``: its turn angles (within half its ``width``,
    rad, and a step of ``azimuth``) against those beside it (a step on, twice as wide:
    their points count half), in 2 mm bins of distance; the median of the excess, clipped
    at zero bin by bin."""
    half = 0.5 * width + geo.step
    rows = (points[:, 2] >= z_m[0]) & (points[:, 2] < z_m[1])
    off = np.abs(_turn_offset(geo.azimuth[rows], azimuth))
    dist = geo.rho[rows]
    own = off <= half
    beside = (off > half + geo.step) & (off <= 3.0 * half + geo.step)
    bins = np.arange(0.0, float(dist.max(initial=0.0)) + 0.004, 0.002)
    excess = np.clip(np.histogram(dist[own], bins)[0] - 0.5 * np.histogram(dist[beside], bins)[0], 0.0, None)
    total = float(excess.sum())
    if total <= 0.0:
        return math.nan, 0.0
    k = int(np.searchsorted(np.cumsum(excess), 0.5 * total))
    return float(0.5 * (bins[k] + bins[k + 1])), total / max(int(own.sum()), 1)


class BeamStemTrack(typing.NamedTuple):
    """A stem found in the turn angles (:func:`find_beam_stems`), followed up the plant
    (:func:`track_beam_stem`).

    Attributes:
        z_m: (k,) float64, the lower edge of each slice the stem's streak was found in,
            metres, ascending.
        azimuth_lo, azimuth_hi: (k,) float64 rad, the turn angles its streak spans there
            (unwrapped: ``azimuth_lo <= azimuth_hi``).
        rho_m: (k,) float64 metres, its distance from the axis there (its points' median).
        slice_m: the slices' thickness, metres.
        top_z_m: its top, metres: the highest of its points in its last slice.
    """

    z_m: np.ndarray
    azimuth_lo: np.ndarray
    azimuth_hi: np.ndarray
    rho_m: np.ndarray
    slice_m: float
    top_z_m: float

    def axis_track(self) -> np.ndarray:
        """(k, 3): z (slice middles), x, y of its axis, as the skeleton's walk tracks one."""
        mid = 0.5 * (self.azimuth_lo + self.azimuth_hi)
        return np.column_stack([self.z_m + 0.5 * self.slice_m, self.rho_m * np.cos(mid),
                                self.rho_m * np.sin(mid)])


def _in_band(geo: _TurnGeometry, rows: np.ndarray, rho: float) -> np.ndarray:
    """Of ``rows``, those whose distance from the axis is within BEAM_STEM_RADIAL_SIGMAS of
    their own radial noise of ``rho``: where a stem that far out puts its points."""
    return rows[np.abs(geo.rho[rows] - rho) <= BEAM_STEM_RADIAL_SIGMAS * geo.radial_sigma[rows]]


def _streak_run(geo: _TurnGeometry, rows: np.ndarray, azimuth: float, core: float) -> tuple[float, float]:
    """The run of scanned turn angles round ``azimuth`` that hold a point of ``rows``, as
    (lo, hi) offsets from it, rad: the steps within ``core`` of it, and on out either side
    to the first step that holds none."""
    steps = set(np.round(_turn_offset(geo.azimuth[rows], azimuth) / geo.step).astype(np.int64).tolist())
    reach = max(0, int(math.floor(core / geo.step)))
    lo, hi = -reach, reach
    while lo - 1 in steps:
        lo -= 1
    while hi + 1 in steps:
        hi += 1
    return (lo - 0.5) * geo.step, (hi + 0.5) * geo.step


def track_beam_stem(points: np.ndarray, noise: np.ndarray, stem: StemBase, *, base_z: float,
                    slice_m: float) -> BeamStemTrack | None:
    """Follow a stem found in the turn angles (:func:`find_beam_stems`) up the plant,
    slice by slice, to its top.

    In each slice ``slice_m`` thick, from the base up, the candidates are the points
    beyond the axis's noise disc whose distance from the axis lies within 3 standard
    deviations of their own radial noise of the stem's. Its core is those within
    half its diameter and a scanned step (``core``) of its turn angle; the slice holds
    the stem when the core holds 8 points or more. Its turn angle then moves to the
    core's median (by at most a step a slice: a stem leans slowly, and a leaf crossing
    the slice beside it must not carry it off), its distance to the core's median
    distance (by at most a radial sigma). Its streak there, whose points are the
    stem's, is the run of scanned turn angles holding candidates out from the core to
    an empty step each side (a wheat's ear, wider than its culm, is the culm's top),
    or the core alone where the run spans more than twice the core (a leaf crossing).
    Three slices in a row without it end it; its top is the highest of its points in
    the last slice that held it.

    Returns:
        The track, or None when the beams do not lie in planes through the axis or no
        slice holds the stem.
    """
    geo = _turn_geometry(points, noise)
    if geo is None:
        return None
    azimuth = math.atan2(stem.center_xy_m[1], stem.center_xy_m[0])
    rho = math.hypot(*stem.center_xy_m)
    outside = np.flatnonzero(geo.rho > _BEAM_STEM_AXIS_SIGMAS * geo.sigma_r)
    order = outside[np.argsort(points[outside, 2], kind="stable")]
    z_sorted = points[order, 2]
    rows: list[tuple[float, float, float, float]] = []
    top = math.nan
    misses, k = 0, 0
    while misses < _BEAM_STEM_MAX_MISSES and base_z + k * slice_m <= z_sorted[-1]:
        z0 = base_z + k * slice_m
        k += 1
        sl = _in_band(geo, order[np.searchsorted(z_sorted, z0):np.searchsorted(z_sorted, z0 + slice_m)], rho)
        core = (0.5 * stem.diameter_m + geo.step * rho) / max(rho, 1e-9)
        offset = _turn_offset(geo.azimuth[sl], azimuth)
        in_core = np.abs(offset) <= core
        if int(in_core.sum()) < _BEAM_STEM_MIN_POINTS:
            misses += 1
            continue
        misses = 0
        lo, hi = _streak_run(geo, sl, azimuth, core)
        if hi - lo > 4.0 * core:
            lo, hi = -core, core
        own = sl[(offset >= lo) & (offset <= hi)]
        rows.append((z0, azimuth + lo, azimuth + hi, rho))
        top = float(points[own, 2].max())
        azimuth += float(np.clip(np.median(offset[in_core]), -geo.step, geo.step))
        rho += float(np.clip(float(np.median(geo.rho[sl[in_core]])) - rho, -geo.sigma_r, geo.sigma_r))
    if not rows:
        return None
    z, lo, hi, r = (np.array(c, dtype=np.float64) for c in zip(*rows))
    return BeamStemTrack(z, lo, hi, r, slice_m, top)


def on_beam_stem(points: np.ndarray, noise: np.ndarray, track: BeamStemTrack, *,
                 axis_stem: bool = False) -> np.ndarray:
    """(n,) bool: the points of a tracked stem (:func:`track_beam_stem`): in a slice that
    held it, up to its top, within the turn angles its streak spans there and 3
    standard deviations of their own radial noise of its distance from the axis. With a
    stem on the axis (``axis_stem``), whose noise spreads its points out along the same
    beams, a point nearer the axis than half the stem's distance is the axis stem's: the
    likelier of the two under the same noise."""
    k = np.searchsorted(track.z_m, points[:, 2], side="right") - 1
    ok = (k >= 0) & (points[:, 2] <= track.top_z_m)
    k = np.clip(k, 0, len(track.z_m) - 1)
    ok &= points[:, 2] < track.z_m[k] + track.slice_m
    mid = 0.5 * (track.azimuth_lo + track.azimuth_hi)[k]
    phi = mid + _turn_offset(np.arctan2(points[:, 1], points[:, 0]), mid)
    ok &= (phi >= track.azimuth_lo[k]) & (phi <= track.azimuth_hi[k])
    phi_pts = np.arctan2(points[:, 1], points[:, 0])
    radial = np.abs(noise[:, 0] * np.cos(phi_pts) + noise[:, 1] * np.sin(phi_pts))
    rho = np.hypot(points[:, 0], points[:, 1])
    ok &= np.abs(rho - track.rho_m[k]) <= BEAM_STEM_RADIAL_SIGMAS * radial
    if axis_stem:
        ok &= rho > 0.5 * track.rho_m[k]
    return ok


# --------------------------------------------------------------------------
# skeleton and organs
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class SegmentationSettings:
    """Settings of :func:`segment_organs`. Lengths relative to the cloud's scale.

    Attributes:
        base_z: z of the plant base, metres (turntable frame).
        link_factor: graph edges join voxel centroids closer than this many voxels.
        bin_factor: level-set bin width, in voxels.
        min_leaf_fraction: a branch shorter than this fraction of the plant height
            (or 2 bins, whichever is longer) is a spur, not a leaf.
        max_stem_diameter_m: widest plausible stem, metres (a biological bound).
        grid_offset: where the voxel grid and the level sets start: the grid's x, y
            and z offset in voxels and the level sets' phase in bins, each in [0, 1)
            (zeros: the grid anchored on the origin, the first level set on the
            roots). The outcome depends on it (:func:`shifted_grid_offsets`).
    """

    base_z: float = 0.0
    link_factor: float = 2.0
    bin_factor: float = 4.0
    min_leaf_fraction: float = 0.10
    max_stem_diameter_m: float = 0.05
    grid_offset: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not math.isfinite(self.base_z):
            raise ValueError(f"base_z must be finite, got {self.base_z!r}")
        offset = tuple(self.grid_offset) if isinstance(self.grid_offset, (tuple, list, np.ndarray)) else ()
        if len(offset) != 4 or not all(isinstance(x, (int, float, np.floating)) and 0 <= x < 1 for x in offset):
            raise ValueError("grid_offset must be 4 numbers in [0, 1) (the voxel grid's x, y, z offset in "
                             f"voxels and the level sets' phase in bins), got {self.grid_offset!r}")
        object.__setattr__(self, "grid_offset", tuple(float(x) for x in offset))
        for name in ("link_factor", "bin_factor", "max_stem_diameter_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not 0 < self.min_leaf_fraction < 1:
            raise ValueError(f"min_leaf_fraction must be in (0, 1), got {self.min_leaf_fraction!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class Segmentation:
    """Organs of a cloud.

    Attributes:
        points: (n, 3) float64, metres, turntable frame: the cloud after outlier removal.
        kept: (N,) bool over the input cloud: the points in ``points``.
        stem_label: (n,) int64, stem index of each point or -1.
        leaf_label: (n,) int64, leaf index of each point or -1.
        stems: the stems found at the base.
        stem_tops_m: (s, 3) float64, metres: the top of each stem's skeleton path (its z
            where the beams say the stem ends below it, :func:`beam_stem_top`).
        leaf_midribs: per leaf, (k, 3) float64 metres: skeleton centroids from the
            junction with the stem (first) to the tip (last).
        scale: the cloud's scale.
        min_leaf_length_m: metres: the length a branch needed to be a leaf
            (``min_leaf_fraction`` of the height, at least two skeleton steps).
        link_m: metres: the skeleton graph's link (``link_factor`` voxels); points
            farther apart than this are not joined.
        sparse_branches: branches long enough to be leaves but holding fewer points
            than spacings along them (mixed-pixel trails, stray points, filaments
            thinner than the spacing): not counted, their points unlabelled.
        leaf_group: per leaf (lamina) of ``leaf_midribs``, the leaf it belongs to,
            numbered 0.. in order: the leaflets of one compound leaf share it (step 7
            of the module docstring); empty means each lamina is its own leaf.
        leaf_base_widths_m: per leaf (empty, or none given: none), the widths, metres, of
            the nodes its midrib starts with where the beams read its base in a noisy
            stem's column (:func:`_leaf_bases_from_beams`: the arc its cells span).
        stem_walk_tops_z_m: per stem, the z its skeleton walk reached where the beams say
            it ends lower (``stem_tops_m``; :func:`beam_stem_top`), NaN elsewhere; empty:
            none given.
        stem_noise_branches: branches long enough to be leaves whose points the range
            noise given spread from a stem (:func:`_drop_stem_noise_leaves`; step 8): not
            counted, their points the stem's. 0 without the range noise.
        axis_split_leaves: leaves found by splitting leaves merged round the axis by
            the range noise, by azimuth (:func:`_split_at_axis`; step 10): 0 without
            the range noise.
        petal_split_leaves: leaves found by splitting a cup of touching leaves round
            the axis at its tips (:func:`_split_petals`; step 11): 0 on a noisy scan.
        surface_split_leaves: leaves found by splitting a cup of touching leaves at
            the creases where their smooth surfaces meet (:func:`_split_smooth_surfaces`;
            step 12): 0 on a noisy scan.
        joined_leaves: found leaves too small for a leaf's surface, joined to the leaf
            they touch most (:func:`_join_fragments`; step 13): 0 on a noisy scan.
        stem_beam_top_refusals: per stem, why the beams through the turntable's axis
            do not end it (:func:`beam_stem_top`), one clause; '' where they do, or
            where its rings are resolved and the walk follows them. Where they do not,
            a noisy stem's top is where the walk up its column stopped, and a leaf
            rising in the column carries the walk on. Empty: none given.
        stem_tops_in_cup: per stem, whether the beams through the axis end it where
            they meet, all round, the leaves standing round it (:func:`cup_stem_top`: a
            rosette's crown), rather than where they pass the axis. Empty: none given.
        range_noise_m: (n, 3) float64, each of ``points``' range noise vector as given
            (``range_noise_m`` of :func:`segment_organs`, the kept points'); None when
            none was given or it is zero.
    """

    points: np.ndarray
    kept: np.ndarray
    stem_label: np.ndarray
    leaf_label: np.ndarray
    stems: tuple[StemBase, ...]
    stem_tops_m: np.ndarray
    leaf_midribs: tuple[np.ndarray, ...]
    scale: CloudScale
    min_leaf_length_m: float
    link_m: float
    sparse_branches: int
    leaf_group: tuple[int, ...] = ()
    stem_noise_branches: int = 0
    leaf_base_widths_m: tuple[np.ndarray, ...] = ()
    stem_walk_tops_z_m: tuple[float, ...] = ()
    axis_split_leaves: int = 0
    petal_split_leaves: int = 0
    surface_split_leaves: int = 0
    joined_leaves: int = 0
    stem_beam_top_refusals: tuple[str, ...] = ()
    stem_tops_in_cup: tuple[bool, ...] = ()
    range_noise_m: np.ndarray | None = None


def _graph(nodes: np.ndarray, link: float, *, spacing: float | None = None) -> sparse.csr_matrix:
    """Radius graph on the nodes, made connected by bridging components (shortest links).

    A component that is a lone scan line (:func:`_is_line`, with ``spacing`` given) is
    bridged from every node whose nearest other node lies within one ``link`` of its
    shortest bridge: a line that fell apart from its leaf runs beside it, and hung by
    one end it would reach past the leaf's tip and be taken for the leaf.
    """
    m = len(nodes)
    tree = cKDTree(nodes)
    pairs = tree.query_pairs(link, output_type="ndarray")
    rows, cols = [pairs[:, 0]], [pairs[:, 1]]
    vals = [np.maximum(np.linalg.norm(nodes[pairs[:, 0]] - nodes[pairs[:, 1]], axis=1), 1e-12)]
    k = min(32, m)
    dk, jk = tree.query(nodes, k=k) if m > 1 else (np.zeros((m, 1)), np.zeros((m, 1), int))
    for _ in range(64):
        g = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(m, m))
        n_comp, lab = csgraph.connected_components(g, directed=False)
        if n_comp == 1:
            break
        # Each component's shortest link to another component, among 32 neighbours
        # (then, for components with none, the nearest point of any other).
        other = lab[jk] != lab[:, None]
        dd = np.where(other, dk, np.inf)
        best = dd.argmin(axis=1)
        bd = dd[np.arange(m), best]
        order = np.lexsort((bd, lab))
        starts = np.r_[0, np.flatnonzero(np.diff(lab[order])) + 1, m]
        for a, group in zip(order[starts[:-1]], np.split(order, starts[1:-1])):
            line = spacing is not None and _is_line(nodes[group], spacing)
            # The shortest link among the 32 neighbours is the component's shortest
            # link only where no node's 32 neighbours end nearer than it. A thin leaf's
            # tip has few nodes of its own about it and finds a leaf 3 cm off while the
            # stem's dense nodes, 12 mm from that leaf's base, see only each other.
            # Bridged by the tip, the leaf is reached through it and split in two.
            exact = np.isfinite(bd[a]) and bd[a] <= dk[group, -1].min()
            if exact and not line:
                rows.append(np.array([a])); cols.append(np.array([jk[a, best[a]]]))
                vals.append(np.array([max(float(bd[a]), 1e-12)]))
                continue
            # A lone line (every node near enough), or no certain shortest link among
            # the 32 neighbours (the nearest node of any other).
            outside = np.flatnonzero(lab != lab[a])
            d, j = cKDTree(nodes[outside]).query(nodes[group])
            near = (d <= d.min() + link) if line else (np.arange(len(d)) == np.argmin(d))
            rows.append(group[near]); cols.append(outside[j[near]])
            vals.append(np.maximum(d[near], 1e-12))
    return sparse.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m)).tocsr()


def _is_line(branch_nodes: np.ndarray, spacing: float, *, min_nodes: int = 6) -> bool:
    """True when a branch's nodes lie along one straight line: their RMS distance from
    their principal axis is below the point spacing, over at least ``min_nodes`` nodes.

    A leaf is a surface. Where it is seen at a grazing angle (a rosette's outer leaves
    from a side-mounted LiDAR) its samples are scan lines a centimetre apart, and a
    short stretch of one line can fall apart from its leaf and be bridged to the
    graph as a branch of its own. Its nodes are one voxel wide and straight; a leaf's,
    even a narrow one's, spread across its width or bend along an arched midrib.
    """
    if len(branch_nodes) < min_nodes:
        return False
    q = branch_nodes - branch_nodes.mean(axis=0)
    sv = np.linalg.svd(q, compute_uv=False)
    return float(sv[1]) / math.sqrt(len(q)) < spacing


def _axis_xy_at(track: np.ndarray, z: Any) -> np.ndarray:
    """The x, y of a stem's tracked axis (``track``: rows z, x, y) at height(s) ``z``,
    interpolated in z and held constant beyond the track's ends: (2,) or (k, 2)."""
    tr = track[np.argsort(track[:, 0], kind="stable")]
    return np.stack([np.interp(z, tr[:, 0], tr[:, 1]), np.interp(z, tr[:, 0], tr[:, 2])], axis=-1)


def _column_radius(stem: StemBase, margin: float) -> float:
    """Radius of the column a stem's points fill round its axis, metres.

    A resolved stem's ring is the surface: its points lie within its radius plus
    ``margin`` (the noise band and a voxel). An unresolved stem's diameter is
    already the width of its noisy column (:class:`StemBase`), noise included:
    adding the band again took a 14 mm maize stem's column, 42 mm wide in a
    realistic scan, out to 37 mm from the axis, and the leaves' bases with it.
    """
    return 0.5 * stem.diameter_m + (margin if stem.diameter_resolved else 0.0)


def _out_of_column(point: np.ndarray, stem: StemBase, track: np.ndarray, margin: float) -> float:
    """How far a point lies out of a stem's column (:func:`_column_radius`): its
    horizontal distance from the axis the stem's walk tracked (at the point's height)
    less the column's radius."""
    axis = _axis_xy_at(track, point[2])
    return float(np.hypot(*(point[:2] - axis)) - _column_radius(stem, margin))


def _release_leaf_bases(pts: np.ndarray, stem_label: np.ndarray, leaf_label: np.ndarray,
                        stems: tuple[StemBase, ...], tracks: list[np.ndarray], *,
                        margin: float, link: float, tops_z: list[float] | None = None,
                        on_track: list[np.ndarray | None] | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Give the points of stem pieces that lie off the stem to the nearest leaf.

    A level set crossing the stem also holds the bases of the leaves wrapped round
    it, so whole pieces labelled stem swallow leaf area. A stem is a cylinder round
    the axis its skeleton walk tracked through compact pieces (``tracks``: z, x, y,
    interpolated in z; held constant beyond the ends), and only points within its column
    (:func:`_column_radius`; ``margin``: the noise band and a voxel), and below ``tops_z``
    (per stem, NaN for none: where the beams say it ends, :func:`beam_stem_top`), stay
    stem; a stem found in the turn angles keeps its track's points (``on_track``, per
    stem a mask or None: :func:`on_beam_stem`) and no others. The others take
    the label of their nearest leaf point when it lies within ``link`` (the graph's
    link widened by the noise band of both surfaces, ``2 link + 8 noise``), else no
    label (one k-d tree query, no loop over points).
    """
    stem_label, leaf_label = stem_label.copy(), leaf_label.copy()
    off = np.zeros(len(pts), dtype=bool)
    for si, st in enumerate(stems):
        m = np.flatnonzero(stem_label == si)
        if len(m) == 0:
            continue
        if on_track is not None and on_track[si] is not None:
            off[m[~on_track[si][m]]] = True
            continue
        axis_xy = _axis_xy_at(tracks[si], pts[m, 2])
        r = np.hypot(*(pts[m, :2] - axis_xy).T)
        off[m[r > _column_radius(st, margin)]] = True
        if tops_z is not None:
            off[m[pts[m, 2] > tops_z[si]]] = True
    leaf_pts = np.flatnonzero(leaf_label >= 0)
    if off.any() and len(leaf_pts):
        released = np.flatnonzero(off)
        # Only points touching a leaf join it; the rest (another organ's
        # fragments) leave the stem unlabelled. The search stops at ``link`` (no
        # neighbour: d is inf and j the tree's size), which the rule needs anyway.
        d, j = cKDTree(pts[leaf_pts]).query(pts[released], distance_upper_bound=link, workers=-1)
        stem_label[released] = -1
        near = d <= link
        leaf_label[released] = -1
        leaf_label[released[near]] = leaf_label[leaf_pts[j[near]]]
    return stem_label, leaf_label


def uniform_width(u: np.ndarray) -> float:
    """The width of a strip whose points ``u`` (offsets across it, n >= 2) sample it
    uniformly, from their 2nd-98th percentile extent.

    The extent is robust to a stray point but reads short: the k-th of n uniform
    samples on a width ``w`` lies at ``k w / (n + 1)`` on average (order statistics,
    e.g. David & Nagaraja 2003, "Order Statistics", 3rd ed., Wiley, section 3.1),
    and numpy's linearly interpolated percentiles are linear in the order
    statistics, so ``E[P98 - P2] = 0.96 w (n - 1) / (n + 1)``: 0.87 w for 20
    points, 0.95 w for 300 (checked by simulation in
    ``tests/test_traits.py``). The width returned is the extent divided by that
    factor: unbiased for a uniform strip. Noise across the strip widens it further;
    that is what :func:`plantsim.evaluation.traits.leaf_noise_width` checks.
    """
    u = np.asarray(u, dtype=np.float64)
    n = len(u)
    if n < 2:
        raise ValueError(f"a width needs at least 2 points across, got {n}")
    return float(_uniform_widths(np.sort(u), np.array([0]), np.array([n]))[0])


def _uniform_widths(u_sorted: np.ndarray, start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """:func:`uniform_width` of many groups at once: group ``g`` is
    ``u_sorted[start[g]:start[g] + count[g]]``, sorted ascending, ``count[g] >= 2``.
    Percentiles interpolated linearly between order statistics, as numpy's."""
    def percentile(p: float) -> np.ndarray:
        pos = p / 100.0 * (count - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, count - 1)
        frac = pos - lo
        return u_sorted[start + lo] * (1.0 - frac) + u_sorted[start + hi] * frac

    n = count.astype(np.float64)
    return (percentile(98.0) - percentile(2.0)) * (n + 1) / (0.96 * (n - 1))


def node_frames(leaf_pts: np.ndarray, midrib: np.ndarray, *, link: float | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per midrib node: unit tangent, unit normal (NaN with under 3 points) and width;
    and each point's node.

    A node's points are those nearest it; their spread across the tangent gives the
    in-plane axis (largest) and the normal; the width is read from the 2nd-98th
    percentile extent along the in-plane axis as the width of a strip sampled
    uniformly across (:func:`uniform_width`: the extent alone read the ideal maize's and
    wheat's widest leaves 6 % narrow).

    With ``link`` given, a cross-section that falls apart along that axis into runs
    more than ``link`` apart is read as the leaf's own run (the one holding the
    midrib's node) plus the runs lying in its plane (their centroid's offset within 25
    degrees of it, as in :func:`_merge_split_leaves`), measured across the own run's
    axis: a band of the leaf that no view sees leaves a gap in its plane, while another
    leaf crossing above or below it at a level set lies out of it (60-70 degrees on the
    ideal wheat, where it tripled a 9 mm leaf's width). A leaf crossing within the
    leaf's plane is not told apart.
    """
    seg = np.diff(midrib, axis=0)
    tangent = seg / np.maximum(np.linalg.norm(seg, axis=1), 1e-12)[:, None]
    tangent = np.vstack([tangent, tangent[-1:]])
    m = len(midrib)
    normal = np.full((m, 3), np.nan)
    width = np.zeros(m)
    if len(leaf_pts) == 0:
        return tangent, normal, width, np.zeros(0, dtype=np.int64)
    _, node = cKDTree(midrib).query(leaf_pts)
    # All nodes at once: each node's points about their centre, less their component
    # along the tangent; the in-plane axis is the principal axis of what is left.
    count = np.bincount(node, minlength=m)
    centre = np.column_stack([np.bincount(node, weights=leaf_pts[:, j], minlength=m) for j in range(3)])
    centre /= np.maximum(count, 1)[:, None]
    q = leaf_pts - centre[node]
    q -= np.einsum("ni,ni->n", q, tangent[node])[:, None] * tangent[node]
    cov = np.zeros((m, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(node, weights=q[:, a] * q[:, b], minlength=m)
    axis = np.linalg.eigh(cov)[1][:, :, 2]  # eigenvector of the largest eigenvalue
    ok = count >= 3
    normal[ok] = np.cross(tangent[ok], axis[ok])
    u = np.einsum("ni,ni->n", q, axis[node])
    order = np.lexsort((u, node))
    u_sorted, node_sorted = u[order], node[order]
    start = np.r_[0, np.cumsum(count)[:-1]]
    split = np.zeros(m, dtype=bool)  # cross-sections that fall apart into runs
    if link is not None:
        gap = (np.diff(u_sorted) > link) & (node_sorted[1:] == node_sorted[:-1])
        split[node_sorted[1:][gap]] = True
    plain = ok & ~split
    width[plain] = _uniform_widths(u_sorted, start[plain], count[plain])
    sin_plane = math.sin(math.radians(25.0))
    for i in np.flatnonzero(ok & split):
        members = order[start[i]:start[i] + count[i]]
        qi, ui = q[members], u[members]
        run = np.r_[0, np.cumsum(np.diff(ui) > link)]  # ui is sorted: runs in order
        foot = (midrib[i] - centre[i]) @ axis[i]
        home = run[np.argmin(np.abs(ui - foot))]
        own = qi[run == home]
        if len(own) >= 3:
            own_axis = np.linalg.svd(own - own.mean(axis=0), full_matrices=False)[2][0]
            own_normal = np.cross(tangent[i], own_axis)
            own_normal /= max(float(np.linalg.norm(own_normal)), 1e-12)
            keep = run == home
            for r in range(int(run.max()) + 1):
                if r == home:
                    continue
                other = qi[run == r]
                off = other.mean(axis=0) - own.mean(axis=0)
                if abs(float(off @ own_normal)) > sin_plane * float(np.linalg.norm(off)):
                    continue  # it lies above or below the leaf
                keep |= run == r
            ui = qi[keep] @ own_axis  # across the leaf's own run, not tilted by the other leaf
        width[i] = uniform_width(ui)
    return tangent, normal, width, node


def _nearest_on_polyline(polyline: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest point of a polyline (k >= 2 vertices) to each point, and its segment index."""
    a, seg = polyline[:-1], np.diff(polyline, axis=0)
    seg_len2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-24)
    t = np.clip(np.einsum("nij,ij->ni", points[:, None, :] - a[None], seg) / seg_len2, 0.0, 1.0)
    foot = a[None] + t[..., None] * seg[None]
    best = np.linalg.norm(points[:, None, :] - foot, axis=2).argmin(axis=1)
    return foot[np.arange(len(points)), best], best


def _merge_split_leaves(pts: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray], *,
                        bin_w: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Join leaves that are the two halves of one leaf, split along its length.

    When a band along a leaf is hidden from every view (a leaf below shades its
    middle), the level sets cut the leaf in two and each half grows its own tip.
    Two leaves are halves of one when, at 60 % of the shorter one's midrib nodes,
    the longer one's midrib runs beside it:

    - parallel, within 25 degrees;
    - level with it: the nearest point of the other midrib lies within half a bin
      along the midrib, plus the parallel tolerance over their distance;
    - offset within both leaves' surfaces, at most 25 degrees out of either (a
      leaf's cross-section is curved);
    - no farther apart than twice their two widths;

    and the stretch so run side by side is at least three times their distance
    apart (a leaf's halves are long and narrow; leaflets side by side are about
    as long as they are apart). Leaves stacked one above the other (offset along
    the normal) and leaflets that fan out from one point (not parallel) stay
    apart. The joined leaf keeps the longer one's midrib.
    """
    n = len(midribs)
    if n < 2:
        return leaf_label, midribs
    frames = [node_frames(pts[leaf_label == i], midribs[i])[:3] for i in range(n)]
    length = np.array([float(np.linalg.norm(np.diff(m, axis=0), axis=1).sum()) for m in midribs])
    trees = [cKDTree(m) for m in midribs]
    cos_par, sin_plane = math.cos(math.radians(25.0)), math.sin(math.radians(25.0))
    into = np.arange(n)

    def root(i: int) -> int:
        while into[i] != i:
            i = int(into[i])
        return i

    for b in np.argsort(length, kind="stable"):
        t_b, n_b, w_b = frames[b]
        ks = [k for k in range(1, len(midribs[b])) if np.isfinite(n_b[k, 0])]
        if len(ks) < 3:
            continue
        step_b = np.linalg.norm(np.diff(midribs[b], axis=0), axis=1)  # node k to k + 1 ...
        step_b = np.r_[step_b[:1], 0.5 * (step_b[:-1] + step_b[1:]), step_b[-1:]]  # ... as a node's share
        best = None
        for a in np.argsort(-length, kind="stable"):
            if a == b or length[a] < length[b] or root(int(a)) == root(int(b)):
                continue
            t_a, n_a, w_a = frames[a]
            foot, seg_a = _nearest_on_polyline(midribs[a], midribs[b][ks])
            _, near = trees[a].query(foot)
            run, apart = 0.0, []
            for k, f, i, j in zip(ks, foot, seg_a, near):
                off = f - midribs[b][k]
                along = float(off @ t_b[k])
                perp = off - along * t_b[k]
                d = float(np.linalg.norm(perp))
                if (abs(float(t_b[k] @ t_a[i])) < cos_par or abs(along) > 0.5 * bin_w + sin_plane * d
                        or d > 2.0 * (w_b[k] + w_a[j]) or d == 0.0):
                    continue
                if abs(float(perp @ n_b[k])) > sin_plane * d:
                    continue
                if np.isfinite(n_a[j, 0]) and abs(float(perp @ n_a[j])) > sin_plane * d:
                    continue
                run += step_b[k]
                apart.append(d)
            if len(apart) >= 0.6 * len(ks) and run >= 3.0 * float(np.median(apart)):
                best = int(a)
                break
        if best is not None:
            into[b] = root(best)
    roots = np.array([root(i) for i in range(n)])
    if (roots == np.arange(n)).all():
        return leaf_label, midribs
    keep = np.flatnonzero(roots == np.arange(n))
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[keep] = np.arange(len(keep))
    relabel = np.where(leaf_label >= 0, new_index[roots[np.maximum(leaf_label, 0)]], -1)
    logger.info("segmentation: %d leaves were halves of others (split lengthwise) and joined them",
                n - len(keep))
    return relabel, [midribs[i] for i in keep]


def _drop_leaves_without_surface(leaf_label: np.ndarray, midribs: list[np.ndarray], *, spacing: float,
                                 min_points: int = 3) -> tuple[np.ndarray, list[np.ndarray], int]:
    """Drop the leaves that are no sampled surface (their points stay unlabelled) and
    number the rest 0.. in order; also return how many were dropped.

    A leaf is a surface, and a surface one spacing wide or more holds at least one
    point per spacing along it: a branch holding fewer points than its midrib has
    spacings is a sparse trail, not a leaf. Such trails are mixed pixels strung out
    behind a leaf's edge where a beam's footprint spans the edge and a surface behind
    it (a footprint model or a real sensor with the range noise low enough not to
    blur them; a realistic maize scanned without range noise read 24 "leaves" for 9,
    7 of them trails of 11-41 points along 9-20 cm, all more than 3 mm off the mesh),
    or stray points the graph bridged, or a filament thinner than the spacing, which
    few scan lines cross (a branch of the seed rig maize's tassel: 25 points along
    56 mm at 1.25 mm spacing in an ideal 0.5-degree scan). Every leaf found in the
    ideal and realistic scans of ``tests/test_traits_procedural.py`` holds 1.39 points
    per spacing or more (a bean leaflet seen edge-on; measured 2026-11-23), and
    none of them is dropped.

    Also, a branch long enough to be a leaf can end up holding almost no points of its
    own when the nodes it shares go to a longer leaf: fewer than ``min_points`` span no
    surface, and such a "leaf" had no width or area (NaN), which made the plant's leaf
    area NaN.
    """
    counts = np.bincount(leaf_label[leaf_label >= 0], minlength=len(midribs))
    lengths = np.array([np.linalg.norm(np.diff(m, axis=0), axis=1).sum() for m in midribs])
    keep = np.flatnonzero((counts >= min_points) & (counts >= lengths / spacing))
    if len(keep) == len(midribs):
        return leaf_label, midribs, 0
    relabel = np.full(len(midribs) + 1, -1, dtype=np.int64)
    relabel[keep] = np.arange(len(keep))
    logger.debug("segmentation: %d leaf branches with fewer than %d points or fewer points than spacings "
                 "along them dropped", len(midribs) - len(keep), min_points)
    return relabel[leaf_label], [midribs[i] for i in keep], len(midribs) - len(keep)


# How far along its beam a stem's hit can be carried by the range noise, in the noise's
# standard deviations (stem_noise_points).
STEM_NOISE_GATE_SIGMAS = 3.0
# A branch is the stem's noise when at least this share of its points could be the stem's
# hits carried along their beams, and it ends within the stem's noise disc
# (_drop_stem_noise_leaves). Were every point a stem's hit, 99.7 % would lie within the
# 3-sigma gate; on the 9 grids of the realistic 1-degree scans of scripts/traits_accuracy.py
# the 3-leaf bean's noise lobes that read as leaves hold 90-100 % (0-23 % of their points
# on a true leaf), true leaves up to 89 % (94 % on the rig fit_rig picks for the maize).
STEM_NOISE_SHARE = 0.9


def stem_noise_points(points_turntable: Any, range_noise_m: Any, *, axis_xy_m: Any, radius_m: float,
                      z_range_m: tuple[float, float],
                      gate_sigmas: float = STEM_NOISE_GATE_SIGMAS) -> np.ndarray:
    """Which points could be hits on a stem, carried along their beams by the range noise.

    A range sensor's beam direction is exact (the encoder and the mirror set it) and its
    range is not, so a hit on a stem, however noisy, stays on the beam that made it: a
    point can be the stem's only if its beam's line meets the stem's column (a vertical
    cylinder of ``radius_m`` round ``axis_xy_m``) and the point lies within
    ``gate_sigmas`` of its own noise's standard deviation of where the beam enters it,
    between ``z_range_m``. A noisy stem (7 mm wide under 10 mm of noise) spreads its
    hits into a disc several centimetres wide round its axis, whose lobes the skeleton
    reads as short leaves (the realistic 3-leaf bean's two extra "leaves", 96 and 97 %
    of their points such); a leaf beside the stem has points whose beams miss the stem
    or that lie farther along them. A leaf the beams cross just in front of the stem,
    within the gate, cannot be told from it by its points alone.

    Args:
        points_turntable: (n, 3) float64, metres.
        range_noise_m: (n, 3) float64 metres, per point its beam's unit direction (away
            from the sensor) times its range noise's standard deviation
            (:func:`plantsim.evaluation.evaluate.range_noise_vectors`); a point with zero
            noise is no stem's noise.
        axis_xy_m: the column's axis, (2,) or per point (n, 2) (a leaning stem's axis at
            each point's height), metres.
        radius_m: the column's radius, metres (> 0).
        z_range_m: (lowest, highest) z of the stem, metres.
        gate_sigmas: how far along its beam a hit can be carried, in standard deviations.

    Returns:
        (n,) bool.
    """
    pts = _checked_points(points_turntable)
    noise = checked_range_noise(range_noise_m, pts)
    axis = np.broadcast_to(np.asarray(axis_xy_m, dtype=np.float64), (len(pts), 2))
    lo, hi = (float(z) for z in z_range_m)
    if not (math.isfinite(radius_m) and radius_m > 0 and math.isfinite(gate_sigmas) and gate_sigmas > 0):
        raise ValueError(f"radius_m and gate_sigmas must be > 0, got {radius_m!r} and {gate_sigmas!r}")
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi) or not np.all(np.isfinite(axis)):
        raise ValueError(f"z_range_m must be (low, high) with low <= high and the axis finite, got {z_range_m!r}")
    sigma = np.linalg.norm(noise, axis=1)
    d = noise / np.maximum(sigma, 1e-300)[:, None]
    ph, dh = pts[:, :2] - axis, d[:, :2]
    a = np.einsum("ij,ij->i", dh, dh)
    b = 2.0 * np.einsum("ij,ij->i", ph, dh)
    c = np.einsum("ij,ij->i", ph, ph) - radius_m * radius_m
    disc = b * b - 4.0 * a * c
    meets = (sigma > 0) & (a > 1e-12) & (disc >= 0)
    # Where the beam enters the column (the nearer root: the beam runs away from the sensor).
    t_in = np.where(meets, (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * np.maximum(a, 1e-12)), np.inf)
    z_in = pts[:, 2] + np.where(meets, t_in, 0.0) * d[:, 2]
    return meets & (np.abs(t_in) <= gate_sigmas * sigma) & (z_in >= lo) & (z_in <= hi)


# A stem whose base slices leave more of their cells open than this is too thin for its
# noise to be told from no stem (beam_stem_top): the beams read nothing. The maizes' 14 mm
# stems under 12 mm noise leave 1-3 % open, the 7 mm stems of the dicot and the bean
# 11-22 %, the wheat's 4 mm main culm 18-27 % (leaning 3.5 mm off the axis by its top, it
# leaves half its cells open from 160 mm up: it would read 0.18 m for 0.54).
BEAM_TOP_MAX_OPEN = 0.1


def beam_stem_top(points_turntable: Any, range_noise_m: Any, *, base_z: float, slice_m: float,
                  sector_deg: float = 3.0, max_miss_m: float) -> float:
    """The top of a stem on the turntable's axis: where the beams stop meeting it.

    Method: when the LiDAR's scan plane holds the turntable's axis (the rig's
    geometry: a 2D LiDAR aimed at the axis), every beam crosses the axis, and a point's
    turn angle and height are exact; only its distance along the beam is noisy. Each
    point's signed distance ``s`` from the axis towards the sensor and its turn angle
    (from its beam's direction, ``range_noise_m``) place it in a cell of a sector of
    ``sector_deg`` by a slice of ``slice_m``: a range image in turn angle and height.
    A beam that meets a stem on the axis, or a leaf in front of it, returns ``s > 0``; a
    beam that passes the axis returns ``s < 0`` (a leaf behind it) or nothing. A cell is
    open when it holds no point or the median ``s`` of its points is below 0 (the median
    over the cell's beams, as a range-image median filter reads a noisy surface). Up a
    stem few cells are open (a stem of radius ``R`` under noise ``sigma`` leaves a cell
    of ``n`` points open with the chance that a median of ``n`` draws falls ``R`` below
    its mean: 1-3 % on a 14 mm maize stem under 12 mm noise, 15-30 % on a 7 mm one);
    above its top the beams pass the axis wherever no leaf stands in front of it. The
    stem's own share of open cells is read in the 5 slices above its lowest, and its top
    is the bottom of the first slice of two in a row in which more than halfway from
    that share to all are open (on the realistic 1-degree scans of
    ``scripts/traits_accuracy.py``: the maizes' 0.42 m stems read 0.42-0.43 m, the
    walk up the noisy column read 0.48-0.50 m).

    Validity: a stem standing on the turntable's axis, thick for its noise (its base
    slices leave at most :data:`BEAM_TOP_MAX_OPEN` of their cells open), beams through
    the axis (their lines pass within ``max_miss_m`` of it, the median over the points)
    and each point's range noise given. NaN where it does not apply: no noise, beams
    that miss the axis, a stem too thin for its noise, or no stem on the axis.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame (the axis at x = y = 0).
        range_noise_m: (n, 3) float64 metres, per point its beam's unit direction (away
            from the sensor) times its range noise's standard deviation.
        base_z: z of the plant base, metres.
        slice_m: the slices' thickness, metres (> 0).
        sector_deg: the sectors' width, degrees (in (0, 90]).
        max_miss_m: how far from the axis the beams may pass, metres (>= 0).

    Returns:
        The stem's top z, metres, or NaN.
    """
    pts = _checked_points(points_turntable)
    noise = checked_range_noise(range_noise_m, pts)
    if not (math.isfinite(slice_m) and slice_m > 0 and math.isfinite(sector_deg) and 0 < sector_deg <= 90
            and math.isfinite(max_miss_m) and max_miss_m >= 0 and math.isfinite(base_z)):
        raise ValueError(f"slice_m must be > 0, sector_deg in (0, 90], max_miss_m >= 0 and base_z finite, got "
                         f"{slice_m!r}, {sector_deg!r}, {max_miss_m!r}, {base_z!r}")
    return _stem_top_in(_axis_range_image(pts, noise, base_z=base_z, slice_m=slice_m, sector_deg=sector_deg,
                                          max_miss_m=max_miss_m))


def _stem_top_in(image: "_RangeImage | None") -> float:
    """:func:`beam_stem_top` on a range image (None: NaN)."""
    return _stem_top_and_refusal(image)[0]


def _stem_top_and_refusal(image: "_RangeImage | None") -> tuple[float, str]:
    """:func:`beam_stem_top` on a range image, and why it reads no top: a clause a trait
    note can quote ('' when it reads one)."""
    if image is None:
        return math.nan, "the beams do not pass through the turntable's axis, or too few points were seen"
    if image.n_levels < 7:
        return math.nan, (f"the plant spans {image.n_levels} slices of {1e3 * image.slice_m:.0f} mm, too few "
                          "to read the stem's own share of open cells in the 5 slices above its lowest")
    base_z, slice_m = image.base_z, image.slice_m
    closed = np.zeros(image.n_levels * image.n_sectors, dtype=bool)
    closed[image.cells] = image.median_s >= 0.0
    open_share = 1.0 - closed.reshape(image.n_levels, image.n_sectors).mean(axis=1)
    own = float(np.median(open_share[1:6]))
    if own > BEAM_TOP_MAX_OPEN:
        return math.nan, (f"the beams pass the axis in {100 * own:.0f} % of the cells of the 5 slices above its "
                          f"lowest (more than {100 * BEAM_TOP_MAX_OPEN:.0f} %: a stem thin for its noise, or "
                          "shorter than those slices, cannot be told there from no stem)")
    above = open_share > 0.5 * (1.0 + own)
    for k in range(1, image.n_levels - 1):
        if above[k] and above[k + 1]:
            return base_z + k * slice_m, ""
    return base_z + image.n_levels * slice_m, ""


# A stem's top stands where the beams meet, over most of the turn, a surface more than
# twice as far in front of the axis as the stem's own (cup_stem_top): a stem does not
# double its width going up, and a leaf sheath wraps it tightly.
CUP_FRONT_FACTOR = 2.0
CUP_FRONT_SIGMAS = 3.0
# segment_organs reads cup_stem_top on slices of half a voxel, ended by runs a voxel tall.
CUP_SLICE_VOXELS = 0.5
CUP_RUN_VOXELS = 1.0


def cup_stem_top(points_turntable: Any, range_noise_m: Any, *, base_z: float, slice_m: float, run_m: float,
                 sector_deg: float = 3.0, max_miss_m: float) -> float:
    """The top of a stem on the turntable's axis where leaves stand round it: where the
    beams stop meeting the stem and meet, all round, the leaves in front of it.

    Method: the range image of :func:`beam_stem_top` (each point's signed distance
    ``s`` from the axis towards the sensor, in cells of turn angle by height; only the
    distance along a beam is noisy). Each slice's front is the median over its sectors
    of their cells' median ``s`` (an empty sector counts as open, past the axis): up a
    stem of radius ``R`` it reads about ``R``, whatever a leaf standing in front of it
    in a few sectors reads. The stem's own front ``s0`` is the median of the fronts of
    the 5 slices above its lowest. Where the beams meet, over most of the turn, a
    surface more than :data:`CUP_FRONT_FACTOR` times as far in front
    (``front > 2 s0 + 3 se``, ``se`` the front's standard error: 1.25 times the
    cells' median noise of their median over the root of the sectors), the stem has
    ended in a cup of leaves standing round the axis (a rosette's inner leaves round its
    crown). A stem does not double its width going up, and a sheath wraps it tightly:
    the realistic maize's fronts read 7-13 mm up its 14 mm stem, with its leaves in
    front of it in a quarter of the sectors. Such slices must run ``run_m`` tall
    (slices a few millimetres thin alias with the beams' rows at the axis: a thin
    stem's fronts swing by 6 mm from slice to slice). The cup's wall leaves the stem's
    surface at its top and widens upward, so where it stands twice as far out is above
    the top: the top is the bottom of that run taken down through the slices below it
    whose front still stands out of the stem's by 3 ``se``. Beams that pass the axis
    instead are :func:`beam_stem_top`'s.

    Validity: as :func:`beam_stem_top`'s, and a stem seen in front of the axis (``s0``
    at least 3 ``se``) spanning 6 slices or more above the lowest slice holding points
    (points below a ground clearance leave the slices under it empty); NaN otherwise,
    and where no such run stands above it. Ray-cast, an 8 mm crown 20 mm tall in a cup
    of 8 leaves rising at 50 deg from its top reads 17-19 mm under 5-10 mm of range noise
    (``tests/test_beam_stem_top.py``). On the realistic 1-degree scans of
    ``scripts/traits_accuracy.py`` (slices of half a voxel, runs of a voxel) the 12-leaf
    rosette's 20 mm crown reads 18 mm; no other plant's stem holds such a run.

    Args:
        points_turntable, range_noise_m, base_z, sector_deg, max_miss_m: as
            :func:`beam_stem_top`'s.
        slice_m: the slices' thickness, metres (> 0).
        run_m: how tall a run of slices in front ends the stem, metres (> 0).

    Returns:
        The stem's top z, metres, or NaN.
    """
    pts = _checked_points(points_turntable)
    noise = checked_range_noise(range_noise_m, pts)
    if not (math.isfinite(slice_m) and slice_m > 0 and math.isfinite(run_m) and run_m > 0
            and math.isfinite(sector_deg) and 0 < sector_deg <= 90
            and math.isfinite(max_miss_m) and max_miss_m >= 0 and math.isfinite(base_z)):
        raise ValueError(f"slice_m and run_m must be > 0, sector_deg in (0, 90], max_miss_m >= 0 and base_z "
                         f"finite, got {slice_m!r}, {run_m!r}, {sector_deg!r}, {max_miss_m!r}, {base_z!r}")
    return _cup_top_in(_axis_range_image(pts, noise, base_z=base_z, slice_m=slice_m, sector_deg=sector_deg,
                                         max_miss_m=max_miss_m), run_m)


def _slice_fronts(image: "_RangeImage") -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Per slice of a range image: its front (the median over the sectors of their
    cells' median ``s``, an empty sector counting as past the axis), the front's
    standard error, and the cells' median standard error (:func:`cup_stem_top`); and
    the lowest slice holding points (points below a ground clearance leave the slices
    under it empty)."""
    n, m = image.n_levels, image.n_sectors
    median = np.full(n * m, -np.inf)
    median[image.cells] = image.median_s
    front = np.median(median.reshape(n, m), axis=1)
    # A median of k draws has about 1.25 sigma / sqrt(k) of spread: per cell its noise's
    # over its points; per slice the cells' median of that over the root of the sectors
    # seen (the front's spread about the cells', a median's 1.25 left out: the thresholds
    # of cup_stem_top were read with it so).
    cell_se = np.full(n * m, np.nan)
    cell_se[image.cells] = _MEDIAN_SE * image.sigma_s / np.sqrt(image.count)
    cell_se = cell_se.reshape(n, m)
    seen = np.count_nonzero(np.isfinite(cell_se), axis=1)
    se, cell = np.full(n, np.inf), np.full(n, np.inf)
    ok = seen > 0
    cell[ok] = np.nanmedian(cell_se[ok], axis=1)
    se[ok] = cell[ok] / np.sqrt(seen[ok])
    return front, se, cell, int(image.cells[0]) // m


def _cup_top_in(image: "_RangeImage | None", run_m: float) -> float:
    """:func:`cup_stem_top` on a range image (None: NaN)."""
    if image is None:
        return math.nan
    n = image.n_levels
    front, se, _, lowest = _slice_fronts(image)
    # The stem's own front: the 5 slices above its lowest seen.
    if n - lowest < 7:
        return math.nan
    own = slice(lowest + 1, lowest + 6)
    s0 = float(np.median(front[own]))
    if not s0 >= CUP_FRONT_SIGMAS * float(np.median(se[own])):
        return math.nan
    cup = front > CUP_FRONT_FACTOR * s0 + CUP_FRONT_SIGMAS * se
    run = max(2, int(math.ceil(run_m / image.slice_m - 1e-9)))
    # The cup's wall leaves the stem's surface at its top and widens upward: found where
    # it stands twice as far out, it starts where its front first stood out of the
    # stem's by the front's noise.
    wider = front > s0 + CUP_FRONT_SIGMAS * se
    for k in range(lowest + 1, n - run + 1):
        if cup[k:k + run].all():
            while k > lowest + 1 and wider[k - 1]:
                k -= 1
            return image.base_z + k * image.slice_m
    return math.nan


def beam_stem_diameter(points_turntable: Any, range_noise_m: Any, *, base_z: float, top_z: float,
                       slice_m: float, sector_deg: float = 3.0, max_miss_m: float) -> float:
    """The diameter of a noisy stem on the turntable's axis, read from the beams that
    cross the axis; NaN where they cannot read it.

    Under range noise a stem's cross-section is a disc of noise centimetres wide, and no
    ring fits it (:func:`find_stems` then gives its column's width, an upper bound). But
    a beam that crosses the axis meets a stem standing on it at its front, a radius in
    front of the axis, whatever the turn angle: each point's distance ``s`` from the axis
    towards the sensor is its beam's return, noisy along the beam only. In the range
    image of :func:`beam_stem_top` (cells of ``sector_deg`` of turn by ``slice_m`` of
    height) each cell's median ``s`` reads the radius within its standard error
    (1.25 sigma / sqrt(points)), except where a leaf stands in front of the stem, which
    reads farther out: a maize's leaves rise in front of its stem in a quarter of the
    sectors, and the median over the sectors read its 14 mm stem 17-18 mm wide. Each
    slice's radius is the mode of its cells' medians instead: the median of those
    within 2 standard errors of the current value, repeated from the median over the
    sectors until it settles (a mean shift with a flat kernel, Fukunaga & Hostetler
    1975, on the median). The diameter is twice the median over the slices of the
    stem's lower half (above the lowest slice holding points, at least 3 slices wholly
    below ``top_z``): its upper half holds the leaves' bases in front of it (the whorl).

    On the realistic 1-degree scans of ``scripts/traits_accuracy.py`` (slices of half a
    voxel, the stems' tops as segmented): the maizes' 14 mm stems read 14.1 mm (their
    noisy columns 26-41 mm wide), the dicot's and the bean's 7 mm ones 7.0 and 6.4 mm
    (a beam's footprint, 3.5 mm at 0.35 m, overhangs a thin stem's edges and
    returns a mixed range from behind), the 12-leaf rosette's 8 mm crown 8.9 mm.

    Validity: as :func:`beam_stem_top`'s (a stem standing on the axis, beams through
    it, each point's range noise), a stem wider than the beam's footprint, at least 3
    slices tall, and seen in front of the axis: in half the slices or more, at least 3
    (a slice whose front lies past the axis is left out), and the radius at least 3
    times their standard error. NaN otherwise.

    Args:
        points_turntable, range_noise_m, base_z, sector_deg, max_miss_m: as
            :func:`beam_stem_top`'s.
        top_z: the stem's top z, metres.
        slice_m: the slices' thickness, metres (> 0).

    Returns:
        The diameter in metres, or NaN.
    """
    pts = _checked_points(points_turntable)
    noise = checked_range_noise(range_noise_m, pts)
    if not (math.isfinite(slice_m) and slice_m > 0 and math.isfinite(sector_deg) and 0 < sector_deg <= 90
            and math.isfinite(max_miss_m) and max_miss_m >= 0 and math.isfinite(base_z) and math.isfinite(top_z)):
        raise ValueError(f"slice_m must be > 0, sector_deg in (0, 90], max_miss_m >= 0 and base_z and top_z "
                         f"finite, got {slice_m!r}, {sector_deg!r}, {max_miss_m!r}, {base_z!r}, {top_z!r}")
    return _front_diameter_in(_axis_range_image(pts, noise, base_z=base_z, slice_m=slice_m, sector_deg=sector_deg,
                                                max_miss_m=max_miss_m), top_z)


# beam_stem_diameter: a slice's mode takes the cells' medians within this many standard
# errors of it, and settles within this many rounds.
_MODE_WINDOW_SE = 2.0
_MODE_ROUNDS = 20


def _front_diameter_in(image: "_RangeImage | None", top_z: float) -> float:
    """:func:`beam_stem_diameter` on a range image (None: NaN)."""
    if image is None:
        return math.nan
    n, m = image.n_levels, image.n_sectors
    front, se, cell_se, lowest = _slice_fronts(image)
    below_top = int(math.floor((top_z - image.base_z) / image.slice_m))  # slices wholly below it
    first, k = lowest + 1, min(below_top, n) - (lowest + 1)
    if k < 3:
        return math.nan
    use = np.arange(first, first + max(3, k // 2))
    # A slice whose beams pass the axis in most sectors sees no stem: by chance on a thin
    # stem (a cell's median of 3 points falls past a 3.5 mm radius under 10 mm of noise
    # 30 % of the time); in most of the slices, there is none.
    seen = use[front[use] > 0]
    if len(seen) < max(3, (len(use) + 1) // 2):
        return math.nan
    level = image.cells // m
    radii = []
    for j in seen:
        x = image.median_s[level == j]
        r = float(front[j])
        for _ in range(_MODE_ROUNDS):
            near = x[np.abs(x - r) <= _MODE_WINDOW_SE * cell_se[j]]
            if not len(near):
                break
            r_new = float(np.median(near))
            if r_new == r:
                break
            r = r_new
        radii.append(r)
    radius = float(np.median(radii))
    if not radius >= CUP_FRONT_SIGMAS * float(np.median(se[seen])):
        return math.nan
    return 2.0 * radius


# The standard error of the median of k normal draws is about sqrt(pi / 2) sigma / sqrt(k).
_MEDIAN_SE = math.sqrt(math.pi / 2.0)


class _RangeImage(typing.NamedTuple):
    """A turntable scan's points in cells of turn angle and height (:func:`_axis_range_image`)."""

    point: np.ndarray  # (m,) index into the points of each point used
    cell: np.ndarray  # (m,) its cell, level * n_sectors + sector
    cells: np.ndarray  # (c,) the occupied cells, ascending
    median_s: np.ndarray  # (c,) the median s of each
    count: np.ndarray  # (c,) points in each
    sigma_s: np.ndarray  # (c,) the median noise of s in each (sigma times the beam's horizontal part)
    n_levels: int
    n_sectors: int
    base_z: float  # the lowest slice's bottom, metres
    slice_m: float  # the slices' thickness, metres


def _beam_axis_distance(points_xy: np.ndarray, beam_xy: np.ndarray) -> np.ndarray:
    """How far from the turntable's axis (x = y = 0) each point's beam passes,
    horizontally: ``points_xy`` (n, 2) metres, ``beam_xy`` (n, 2) the beams' horizontal
    unit directions (either sense)."""
    return np.abs(points_xy[:, 0] * beam_xy[:, 1] - points_xy[:, 1] * beam_xy[:, 0])


def _axis_range_image(pts: np.ndarray, noise: np.ndarray, *, base_z: float, slice_m: float, sector_deg: float,
                      max_miss_m: float) -> _RangeImage | None:
    """The points of a scan whose beams cross the axis in cells of turn angle and height,
    with each cell's median distance from the axis towards the sensor; None where the
    beams do not cross the axis or the noise is not known (:func:`beam_stem_top`)."""
    sigma = np.linalg.norm(noise, axis=1)
    horizontal = np.hypot(noise[:, 0], noise[:, 1])
    use = np.flatnonzero((sigma > 0) & (horizontal > 0.1 * sigma) & (pts[:, 2] >= base_z))
    if len(use) < 100:
        return None
    towards = -noise[use, :2] / horizontal[use, None]  # the sensor's side, horizontal unit vector
    miss = _beam_axis_distance(pts[use, :2], towards)
    if float(np.median(miss)) > max_miss_m:
        return None
    s = np.einsum("ij,ij->i", pts[use, :2], towards)
    n_sectors = int(round(360.0 / sector_deg))
    sector = np.floor((np.degrees(np.arctan2(towards[:, 1], towards[:, 0])) % 360.0)
                      / (360.0 / n_sectors)).astype(np.int64) % n_sectors
    level = np.floor((pts[use, 2] - base_z) / slice_m).astype(np.int64)
    cell = level * n_sectors + sector
    order = np.lexsort((s, cell))
    cell_sorted, s_sorted = cell[order], s[order]
    starts = np.r_[0, np.flatnonzero(np.diff(cell_sorted)) + 1]
    counts = np.diff(np.r_[starts, len(cell_sorted)])
    median = 0.5 * (s_sorted[starts + (counts - 1) // 2] + s_sorted[starts + counts // 2])
    noise_sorted = horizontal[use][np.lexsort((horizontal[use], cell))]
    sigma_s = 0.5 * (noise_sorted[starts + (counts - 1) // 2] + noise_sorted[starts + counts // 2])
    return _RangeImage(point=use, cell=cell, cells=cell_sorted[starts], median_s=median, count=counts,
                       sigma_s=sigma_s, n_levels=int(level.max()) + 1, n_sectors=n_sectors, base_z=base_z,
                       slice_m=slice_m)


# A cell of the range image stands in front of a stem when its median distance from the
# axis exceeds the stem's by this many standard errors of a median (_leaf_bases_from_beams).
FRONT_SIGMAS = 3.0


def _leaf_bases_from_beams(image: _RangeImage, stem_label: np.ndarray, leaf_label: np.ndarray,
                           midribs: list[np.ndarray], *, top_z: float, column_m: float) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], dict[int, np.ndarray]]:
    """Give each leaf the base it has in a noisy stem's column, from the beams.

    A leaf leaving a noisy stem on the axis steeply (a maize leaf rises along its stem
    for 10 cm or more) lies in the stem's noisy column, where its points are stem or
    nothing to the skeleton: the leaf began where it left the column, 12-18 cm above its
    insertion, and read a quarter short. In the range image of turn angle and height
    (``image``, :func:`beam_stem_top`'s; the stem ends at ``top_z``) a cell holds the first hits of
    its beams, the stem's or those of a leaf standing in front of it, and its median
    distance from the axis towards the sensor reads which, although each point is 12 mm
    noisy: the stem's cells read its radius (the median over the cells on the
    sensor's side), a leaf's more, by :data:`FRONT_SIGMAS` standard errors of the median
    (``1.2533 sigma / sqrt(n)``) or more. Above the stem's top every cell within the
    column (``column_m`` plus that error) is a leaf's. Those cells, connected in turn
    angle and height, go to the leaf that holds most of the points of the cells they
    reach first (a breadth-first search from the cells whose points are mostly a
    leaf's); their points that are not a leaf's become that leaf's, and its midrib
    starts with their centres, one per slice below its first node past the junction
    (each at the cells' median distance, at the centre of their turn angles: the noise
    averaged out), and its width there is the arc the cells span in turn angle at that
    distance (the noise moves no point in turn angle). Returns (stem_label, leaf_label,
    midribs, {leaf: the widths of the nodes its midrib starts with}).
    """
    if not midribs:
        return stem_label, leaf_label, midribs, {}
    ns, n_cells = image.n_sectors, image.n_levels * image.n_sectors
    base_z, slice_m = image.base_z, image.slice_m
    below = image.cells < int(math.floor((top_z - base_z) / slice_m)) * ns
    on_stem = below & (image.median_s >= 0.0)
    if not on_stem.any():
        return stem_label, leaf_label, midribs, {}
    stem_s = float(np.median(image.median_s[on_stem]))
    error = FRONT_SIGMAS * 1.2533 * image.sigma_s / np.sqrt(image.count)
    leafy = (image.count >= 3) & np.where(below, image.median_s > stem_s + error,
                                         np.abs(image.median_s) <= column_m + error)
    # The leaf most of each cell's points are (at least half of them), if any.
    index_of = np.full(n_cells, -1, dtype=np.int64)
    index_of[image.cells] = np.arange(len(image.cells))
    labels = leaf_label[image.point]
    votes = np.zeros((len(image.cells), len(midribs) + 1))
    np.add.at(votes, (index_of[image.cell], np.where(labels >= 0, labels, len(midribs))), 1.0)
    owner = np.full(n_cells, -1, dtype=np.int64)
    held = leafy & (votes[:, :-1].sum(axis=1) >= 0.5 * image.count)
    owner[image.cells[held]] = votes[held, :-1].argmax(axis=1)
    is_leafy = np.zeros(n_cells, dtype=bool)
    is_leafy[image.cells[leafy]] = True
    frontier = image.cells[held]
    while len(frontier):
        level, sector = np.divmod(frontier, ns)
        reached = []
        for nb, ok in (((level - 1) * ns + sector, level > 0), ((level + 1) * ns + sector, level + 1 < image.n_levels),
                       (level * ns + (sector + 1) % ns, True), (level * ns + (sector - 1) % ns, True)):
            nb, src = nb[ok], frontier[ok]
            take = is_leafy[nb] & (owner[nb] < 0)
            nb, src = nb[take], src[take]
            nb, first = np.unique(nb, return_index=True)
            owner[nb] = owner[src[first]]
            reached.append(nb)
        frontier = np.unique(np.concatenate(reached))
    gained = (owner[image.cell] >= 0) & (labels < 0)
    if not gained.any():
        return stem_label, leaf_label, midribs, {}
    stem_label, leaf_label, midribs = stem_label.copy(), leaf_label.copy(), list(midribs)
    stem_label[image.point[gained]] = -1
    leaf_label[image.point[gained]] = owner[image.cell[gained]]
    base_widths: dict[int, np.ndarray] = {}
    cells = np.unique(image.cell[gained])
    for li in np.unique(owner[cells]):
        mine = cells[owner[cells] == li]
        k = index_of[mine]
        level, sector = np.divmod(mine, ns)
        phi = np.radians((sector + 0.5) * 360.0 / ns)
        x, y, w = image.median_s[k] * np.cos(phi), image.median_s[k] * np.sin(phi), image.count[k].astype(float)
        levels = np.unique(level)
        nodes = np.array([[np.average(x[level == lv], weights=w[level == lv]),
                           np.average(y[level == lv], weights=w[level == lv]),
                           base_z + (lv + 0.5) * slice_m] for lv in levels])
        # A cell whose median lies past the axis (above the stem's top) is the leaf at the
        # opposite turn angle.
        facing = np.where(image.median_s[k] >= 0.0, sector, (sector + ns // 2) % ns)
        widths = np.array([_arc_span(facing[level == lv], ns) * float(np.median(np.abs(image.median_s[k[level == lv]])))
                           for lv in levels])
        rib = midribs[li]
        past = rib[1:] if len(rib) > 1 else rib  # the junction, on the stem, gives way
        below_rib = nodes[:, 2] < past[0, 2]
        if below_rib.any():
            midribs[li] = np.vstack([nodes[below_rib], past])
            base_widths[int(li)] = widths[below_rib]
    return stem_label, leaf_label, midribs, base_widths


def _arc_span(sectors: np.ndarray, n_sectors: int) -> float:
    """The turn angle, radians, that a set of sectors (of ``n_sectors``) spans: the
    circle less its largest gap."""
    occupied = np.unique(sectors)
    gaps = np.diff(np.r_[occupied, occupied[0] + n_sectors]) - 1
    return float(n_sectors - int(gaps.max())) * 2.0 * math.pi / n_sectors


def _drop_stem_noise_leaves(pts: np.ndarray, noise: np.ndarray, stem_label: np.ndarray,
                            leaf_label: np.ndarray, midribs: list[np.ndarray], stems: tuple[StemBase, ...],
                            tracks: list[np.ndarray], stem_tops: list, *, base_z: float, margin: float,
                            reach: float) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], int]:
    """Give the leaves that are a stem's noise to the stem; number the rest 0.. in order.

    A leaf is a stem's noise when at least :data:`STEM_NOISE_SHARE` of its points could be
    the stem's hits carried along their beams (:func:`stem_noise_points`) and its tip (the
    last midrib node) lies within the stem's noise disc: the column's radius plus the gate
    (``STEM_NOISE_GATE_SIGMAS`` times the leaf's median noise) plus ``reach``. On the
    realistic scans the noise lobes end 1.1-1.4 times column and gate from the axis (the
    3-leaf bean's), the leaves with as large a share 1.7-3.7 times (maize leaves, whose
    sheaths lie along the stem: up to 94 % of their points within the gate, seen from the
    rig ``fit_rig`` picks for them).

    Each stem's column is :func:`_column_radius` (``margin``: a voxel; an unresolved stem's
    noisy width holds its noise already) round the axis its walk tracked, from
    ``base_z`` to its top piece's centroid plus ``reach`` (a bin: the top piece spans one).
    Returns (stem_label, leaf_label, midribs, leaves dropped)."""
    if not midribs or not stems:
        return stem_label, leaf_label, midribs, 0
    which = np.full(len(pts), -1, dtype=np.int64)
    for si in reversed(range(len(stems))):
        hit = stem_noise_points(pts, noise, axis_xy_m=_axis_xy_at(tracks[si], pts[:, 2]),
                                radius_m=_column_radius(stems[si], margin),
                                z_range_m=(base_z, float(stem_tops[si][2]) + reach))
        which[hit] = si
    counts = np.bincount(leaf_label[leaf_label >= 0], minlength=len(midribs))
    noisy = np.bincount(leaf_label[(leaf_label >= 0) & (which >= 0)], minlength=len(midribs))
    drop = (noisy >= STEM_NOISE_SHARE * np.maximum(counts, 1)) & (counts > 0)
    sigma = np.linalg.norm(noise, axis=1)
    owner = np.full(len(midribs), -1, dtype=np.int64)
    for i in np.flatnonzero(drop):
        own = which[leaf_label == i]
        # The stem most of the leaf's points could be the hits of; the branch must end
        # within that stem's noise disc (its column, the gate at the leaf's median noise,
        # and a bin: the tip is a level set's centroid). A leaf whose sheath lies along
        # the stem has most of its points in the disc too, but reaches out of it.
        si = int(np.bincount(own[own >= 0], minlength=len(stems)).argmax())
        tip = midribs[i][-1]
        disc = (_column_radius(stems[si], margin)
                + STEM_NOISE_GATE_SIGMAS * float(np.median(sigma[leaf_label == i])) + reach)
        if np.hypot(*(tip[:2] - _axis_xy_at(tracks[si], tip[2]))) <= disc:
            owner[i] = si
    drop &= owner >= 0
    if not drop.any():
        return stem_label, leaf_label, midribs, 0
    stem_label, leaf_label = stem_label.copy(), leaf_label.copy()
    for i in np.flatnonzero(drop):
        member = leaf_label == i
        stem_label[member] = owner[i]
        leaf_label[member] = -1
    keep = np.flatnonzero(~drop)
    relabel = np.full(len(midribs) + 1, -1, dtype=np.int64)
    relabel[keep] = np.arange(len(keep))
    logger.debug("segmentation: %d leaf branches are the stems' range noise", int(drop.sum()))
    return stem_label, relabel[leaf_label], [midribs[i] for i in keep], int(drop.sum())


# Leaves merged round the axis in the range noise are split by azimuth (_split_at_axis,
# step 10): a leaf's points beyond its noise disc (AXIS_DISC_SIGMAS of its median range
# noise, plus a voxel, from the axis) fall into several groups when sectors holding under
# AZIMUTH_GAP_SHARE of the smaller neighbour's peak density part them, and each group
# holds AZIMUTH_MIN_SHARE or more of those points. A group in whose sector another leaf
# holds AZIMUTH_PIECE_SHARE as many points beyond the disc is a piece of that leaf. The
# realistic 3-leaf rosette's three leaves, one leaf without the split, part at 0.1. On
# synthetic 3-leaf rosettes whose grids cut a leaf in two (tests/test_axis_split.py),
# the split reads 4-5 leaves without the piece rule, 4 on one of three at 1.0, and 3 on
# every grid at 0.5.
AXIS_DISC_SIGMAS = 2.0
AZIMUTH_GAP_SHARE = 0.1
AZIMUTH_MIN_SHARE = 0.1
AZIMUTH_PIECE_SHARE = 0.5


def _azimuth_groups(phi: np.ndarray, *, bandwidth: float, bins: int = 720) -> np.ndarray:
    """Group azimuths (radians) into the modes of their circular density (a Gaussian
    kernel of ``bandwidth`` radians) that empty sectors separate: the density between two
    groups falls below :data:`AZIMUTH_GAP_SHARE` of the smaller one's peak, and each
    group holds :data:`AZIMUTH_MIN_SHARE` of the points. Returns a group per azimuth
    (all 0: one group).

    The density's local maxima are merged until every valley left is that deep: the
    shallowest valley's lower peak goes first, and where every valley is deep but a group
    is too small, the smallest group's peak goes. A peak that goes joins the arcs on
    either side of it, whose valley is the lower of theirs."""
    width = 2 * math.pi / bins
    idx = np.floor((phi % (2 * math.pi)) / width).astype(np.int64) % bins
    hist = np.bincount(idx, minlength=bins).astype(np.float64)
    offset = (np.arange(bins) + bins // 2) % bins - bins // 2
    kernel = np.exp(-0.5 * (offset * width / bandwidth) ** 2)
    dens = np.real(np.fft.ifft(np.fft.fft(hist) * np.fft.fft(kernel / kernel.sum())))
    dens[dens < 1e-9 * dens.max()] = 0.0  # the transform's rounding in empty sectors
    peaks = np.flatnonzero((dens > np.roll(dens, 1)) & (dens >= np.roll(dens, -1)))
    if len(peaks) < 2:
        return np.zeros(len(phi), dtype=np.int64)
    # valley[k]: the lowest bin on the arc from peaks[k] to the next peak round.
    valley = np.empty(len(peaks), dtype=np.int64)
    for k, (a, b) in enumerate(zip(peaks, np.roll(peaks, -1))):
        arc = (a + np.arange((b - a) % bins + 1)) % bins
        valley[k] = arc[int(np.argmin(dens[arc]))]
    cum = np.r_[0.0, np.cumsum(hist)]
    peaks, valley = list(peaks), list(valley)

    def drop(j: int) -> None:
        # Peak j goes: the arcs before and after it join, at the lower of their valleys.
        before, after = valley[j - 1], valley[j]
        valley[j - 1] = before if dens[before] <= dens[after] else after
        del peaks[j], valley[j]

    while len(peaks) > 1:
        p = np.array(peaks)
        v = np.array(valley)
        nxt = np.roll(p, -1)
        share = dens[v] / np.maximum(np.minimum(dens[p], dens[nxt]), 1e-300)
        worst = int(np.argmax(share))
        if share[worst] >= AZIMUTH_GAP_SHARE:
            drop(worst if dens[p[worst]] < dens[nxt[worst]] else (worst + 1) % len(p))
            continue
        # Group k runs from valley[k - 1] (exclusive) to valley[k] (inclusive), round.
        lo, hi = np.roll(v, 1), v
        size = np.where(hi >= lo, cum[hi + 1] - cum[lo + 1], cum[-1] - cum[lo + 1] + cum[hi + 1])
        small = int(np.argmin(size))
        if size[small] >= AZIMUTH_MIN_SHARE * len(phi):
            break
        drop(small)
    if len(peaks) < 2:
        return np.zeros(len(phi), dtype=np.int64)
    bounds = np.sort(np.array(valley))
    return np.searchsorted(bounds, idx, side="left") % len(bounds)


def _midrib_of(points: np.ndarray, junction: np.ndarray, *, cell: float, bin_w: float,
               grid_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """A leaf's midrib from its points alone, as step 5 reads a branch: the centroids of
    the level sets (bins ``bin_w`` wide) of the geodesic distance over the voxel graph
    (side ``cell``) from the node nearest ``junction``; ``junction`` first. The voxels and
    the bins start where the grid's do (:attr:`SegmentationSettings.grid_offset`)."""
    nodes, _ = voxel_centroids(points, cell, np.asarray(grid_offset[:3], dtype=np.float64))
    if len(nodes) < 2:
        return np.vstack([junction, nodes])
    graph = _graph(nodes, 2.0 * cell)
    src = int(np.argmin(np.linalg.norm(nodes - junction, axis=1)))
    dist = csgraph.dijkstra(graph, directed=False, indices=src)
    level = np.floor(dist / bin_w + grid_offset[3]).astype(np.int64)
    chain = [nodes[level == k].mean(axis=0) for k in np.unique(level)]
    return np.vstack([junction] + chain)


def _mean_azimuth(phi: np.ndarray) -> float:
    """The circular mean of azimuths, radians (round the circle, not across it)."""
    return math.atan2(float(np.sin(phi).sum()), float(np.cos(phi).sum()))


def _nearest_in_azimuth(centres: np.ndarray, azimuth: float) -> int:
    """Index of the azimuth in ``centres`` nearest ``azimuth`` round the circle (radians)."""
    return int(np.argmin(np.abs((centres - azimuth + math.pi) % (2 * math.pi) - math.pi)))


def _sector_owner(phi_part: np.ndarray, phi_others: np.ndarray, label_others: np.ndarray) -> int:
    """The leaf a part cut from a leaf by azimuth belongs to: the leaf holding most of
    the other leaves' points (``phi_others``, ``label_others``) in the part's sector, when
    they number :data:`AZIMUTH_PIECE_SHARE` of the part's points (``phi_part``); -1 when
    they do not (the part is a leaf of its own). Azimuths in radians."""
    mid = _mean_azimuth(phi_part)
    dev = (phi_part - mid + math.pi) % (2 * math.pi) - math.pi
    off = (phi_others - mid + math.pi) % (2 * math.pi) - math.pi
    inside = (off >= dev.min()) & (off <= dev.max())
    if np.count_nonzero(inside) < AZIMUTH_PIECE_SHARE * len(phi_part):
        return -1
    return int(np.bincount(label_others[inside]).argmax())


def _apply_split(leaf_label: np.ndarray, midribs: list[np.ndarray], groups: list[int],
                 base_widths: dict[int, np.ndarray], li: int, member: np.ndarray, part: np.ndarray,
                 owner: np.ndarray, new: np.ndarray, ribs: list[np.ndarray]) -> int:
    """Split leaf ``li`` in place (steps 10 to 12): its points ``member`` by ``part``;
    the parts with an ``owner`` go to that leaf, the parts ``new`` (with midribs
    ``ribs``) are leaves, the first keeping ``li``, each other a new leaf of its own. The
    merged leaf's base widths were not its parts': they go. Returns the leaves added."""
    for k in np.flatnonzero(owner >= 0):
        leaf_label[member[part == k]] = owner[k]
    midribs[li] = ribs[0]
    base_widths.pop(li, None)
    for k, rib in zip(new[1:], ribs[1:]):
        leaf_label[member[part == k]] = len(midribs)
        midribs.append(rib)
        groups.append(max(groups) + 1)
    return len(new) - 1


def _split_at_axis(pts: np.ndarray, noise: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray],
                   groups: tuple[int, ...], base_widths: dict[int, np.ndarray], *, cell: float,
                   bin_w: float, min_leaf: float, spacing: float,
                   grid_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
                   ) -> tuple[np.ndarray, list[np.ndarray], tuple[int, ...], dict[int, np.ndarray], int]:
    """Split the leaves that are several leaves merged round the axis by the range noise
    (step 10). Returns the leaf labels, midribs, groups and base widths, and the number of
    leaves the splits added.

    A turntable rig's beams lie in planes through its axis, so the range noise moves a
    point along a line through the axis: its azimuth about the axis stays (or turns by
    180 deg where the noise carries it across). A beam that passes ``d`` from the axis
    moves a point at radius ``r`` by ``sigma d / r^2`` in azimuth. Round the axis, where
    a rosette's leaves grow from, the noise spreads every leaf's base into one disc and
    joins them into one leaf; beyond the disc (:data:`AXIS_DISC_SIGMAS` of the leaf's
    median noise, plus a voxel), the points whose azimuth the noise moves by under half
    the spacing there are where they were scanned, and leaves apart in azimuth are apart
    (:func:`_azimuth_groups`, bandwidth the spacing at the disc's edge). A group in
    whose sector another leaf holds :data:`AZIMUTH_PIECE_SHARE` as many points beyond the
    disc is a piece of that leaf (the grid cut the leaf in two, and the noise joined one
    half to its neighbours), and goes to it. The other groups are leaves when each one's
    midrib (:func:`_midrib_of`, from the merged leaf's junction) is as long as a leaf;
    the merged leaf's bases are no longer theirs, so its base widths go. The disc's
    points go with the group of their nearest point beyond it, a piece's with it, where
    several leaves are left (their bases); where one is, they stay with it: the disc is
    then a stem's noise (on the 3-leaf maize on the rig ``--fit-rig`` picks, 11,000 of
    its stem's points followed a piece to another leaf, and one grid read the leaf area
    +28 % for +7 %; -5 % since)."""
    sigma = np.linalg.norm(noise, axis=1)
    beam = noise / np.maximum(sigma, 1e-300)[:, None]
    beam_xy = beam[:, :2] / np.maximum(np.hypot(beam[:, 0], beam[:, 1]), 1e-12)[:, None]
    miss = _beam_axis_distance(pts[:, :2], beam_xy)
    r = np.hypot(pts[:, 0], pts[:, 1])
    phi = np.arctan2(pts[:, 1], pts[:, 0])
    leaf_label = leaf_label.copy()
    midribs = list(midribs)
    groups = list(groups) if groups else list(range(len(midribs)))
    base_widths = dict(base_widths)
    added = 0
    for li in range(len(midribs)):
        member = np.flatnonzero(leaf_label == li)
        disc = AXIS_DISC_SIGMAS * float(np.median(sigma[member])) + cell if len(member) else 0.0
        bandwidth = spacing / max(disc, 1e-12)
        exact = (r[member] > disc) & (sigma[member] * miss[member] <= 0.5 * bandwidth * r[member] ** 2)
        outer = member[exact]
        if len(outer) < 10:  # too few to part
            continue
        g = _azimuth_groups(phi[outer], bandwidth=bandwidth)
        n_g = int(g.max()) + 1
        if n_g < 2:
            continue
        part = np.empty(len(member), dtype=np.int64)
        part[exact] = g
        # A group in a sector where another leaf holds half as many points beyond the disc
        # (AZIMUTH_PIECE_SHARE) is a piece of that leaf, which the grid cut off into this
        # one: it goes to that leaf.
        others = np.flatnonzero((leaf_label >= 0) & (leaf_label != li) & (r > disc))
        owner = np.array([_sector_owner(phi[outer[g == k]], phi[others], leaf_label[others])
                          for k in range(n_g)], dtype=np.int64)
        new = np.flatnonzero(owner < 0)
        if not len(new):
            continue
        # The disc's points go with the group of their nearest point beyond it where the
        # leaf is several leaves (their bases); with one leaf and pieces of others, with
        # that leaf (a stem's noise there).
        kept = np.isin(g, new) if len(new) == 1 else np.ones(len(g), dtype=bool)
        if not exact.all():
            part[~exact] = g[kept][cKDTree(pts[outer[kept]]).query(pts[member[~exact]], workers=-1)[1]]
        ribs = [_midrib_of(pts[member[part == k]], midribs[li][0], cell=cell, bin_w=bin_w,
                           grid_offset=grid_offset) for k in new]
        if min(float(np.linalg.norm(np.diff(m, axis=0), axis=1).sum()) for m in ribs) < min_leaf:
            continue
        logger.debug("segmentation: leaf %d is %d leaves merged round the axis and %d pieces of others, "
                     "split by azimuth", li, len(new), n_g - len(new))
        added += _apply_split(leaf_label, midribs, groups, base_widths, li, member, part, owner, new, ribs)
    return leaf_label, midribs, tuple(groups), base_widths, added


# Step 11, petals round the axis (clean scans). A lobe of a leaf's reach over azimuth
# must rise PETAL_PROMINENCE_SPACINGS point spacings above the higher valley beside it:
# the sampling's own roughness is about a spacing (a bin's farthest point lies up to a
# spacing inside the surface's edge); at 1.5 the rosettes read the same. A leaf is
# looked at when its outer half occupies PETAL_MIN_ARC_DEG of azimuth bins round the
# axis (at 60 the ideal dicot's top trifoliate splits on one grid of 9; at 150 the
# 30-leaf rosette reads 19 leaves for 21). Runs of up to PETAL_GAP_BINS empty bins are
# bridged (a sampling gap; 1 to 6 read the same rosettes). A part starts where
# PETAL_START_PERCENTILE of its points lie nearer the junction (a few points of a stalk,
# whose azimuth says little near the axis, fall in every sector; a cone sampled evenly
# over its area, as a scan does not sample a cup, has 5 % of a petal's points within a
# fifth of its length). A part starting more than PETAL_BASE_SHARE of its reach farther
# out than the leaf's nearest point does not grow from the cup's base: a leaflet at the
# end of a stalk a fifth of the leaf's reach long. The ideal dicot's side leaflets start
# 0.40-0.50 of their reach out, its parts that hold the stalk 0.01-0.03; the rosettes'
# parts spread over 0-0.43 (at 0.25 the 30-leaf rosette reads 23, the dicot 8).
PETAL_PROMINENCE_SPACINGS = 2.0
PETAL_MIN_ARC_DEG = 90.0
PETAL_GAP_BINS = 3
PETAL_BASE_SHARE = 0.2
PETAL_START_PERCENTILE = 2.0


def _reach_profile(phi: np.ndarray, reach: np.ndarray, n_bins: int, *, half_width: Any = 0.0) -> np.ndarray:
    """Per azimuth bin (``n_bins`` round the circle, from 0 rad), the farthest ``reach`` of
    the points over it: a point covers the bins within ``half_width`` (radians, per point
    or one for all) of its azimuth, and at least its own. A point stands for the voxel of
    surface round it, which spans half a voxel over its radius either side: near the
    axis, where a bin a voxel wide at the median radius is narrower than the spacing
    between points, its farthest point would be the sampling's. Runs of up to
    :data:`PETAL_GAP_BINS` empty bins take the line between the bins either side,
    longer runs stay 0."""
    width = 2 * math.pi / n_bins
    half = np.broadcast_to(np.asarray(half_width, dtype=np.float64), phi.shape)
    lo = np.floor(((phi - half) % (2 * math.pi)) / width).astype(np.int64)
    span = np.minimum(np.floor(2 * half / width).astype(np.int64) + 1, n_bins)
    rows = np.repeat(np.arange(len(phi)), span)
    first = np.repeat(np.cumsum(span) - span, span)
    bins = (lo[rows] + np.arange(len(rows)) - first) % n_bins
    prof = np.zeros(n_bins)
    np.maximum.at(prof, bins, reach[rows])
    occupied = np.flatnonzero(prof > 0)
    if len(occupied) < 2:
        return prof
    runs = (np.roll(occupied, -1) - occupied) % n_bins
    for a, run in zip(occupied, runs):
        if 1 < run <= PETAL_GAP_BINS + 1:
            steps = np.arange(1, run)
            prof[(a + steps) % n_bins] = prof[a] + (prof[(a + run) % n_bins] - prof[a]) * steps / run
    return prof


def _reach_lobes(prof: np.ndarray, *, prominence: float, min_reach: float) -> tuple[np.ndarray, np.ndarray]:
    """The lobes of a circular reach profile (:func:`_reach_profile`): (bins of the peaks
    at least ``prominence`` above the higher of the valleys on either side and reaching
    ``min_reach``, in order round; the bin where each lobe's sector ends, the lowest
    between it and the next peak). Fewer than two peaks: both empty."""
    from scipy.signal import find_peaks

    n = len(prof)
    start = int(np.argmin(prof))
    line = np.roll(prof, -start)
    # Unrolled at its lowest bin and closed with it, padded with zeros so that a lobe
    # at either end is one.
    line = np.r_[0.0, line, line[0], 0.0]
    peaks, _ = find_peaks(line, prominence=prominence)
    peaks = peaks[line[peaks] >= min_reach] - 1
    if len(peaks) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    inner = line[1:-1]
    ends = np.array([a + int(np.argmin(inner[a:b + 1])) for a, b in zip(peaks, np.r_[peaks[1:], peaks[0] + n])])
    return (peaks + start) % n, (ends + start) % n


def _cup_bins(r: np.ndarray, phi: np.ndarray, junction: np.ndarray, cell: float
              ) -> tuple[np.ndarray, int, np.ndarray] | None:
    """Whether a leaf is a cup round the axis (steps 11 and 12): its points farther from
    the axis than its junction by a voxel (``cell``), the outer ones (radius ``r`` and
    azimuth ``phi``, radians), occupy :data:`PETAL_MIN_ARC_DEG` of azimuth bins a voxel
    wide at their median radius, counted on those beyond it. Returns (the outer mask,
    the number of bins, each outer point's bin), or None: no cup (or under 20 outer
    points)."""
    outer = r > float(np.hypot(junction[0], junction[1])) + cell
    if np.count_nonzero(outer) < 20:
        return None
    r_out = r[outer]
    # A cup wraps round the axis out to its rim, where any leaf's base spans a wide
    # angle seen from the axis beside it: the arc is that of its outer half, the
    # points beyond their median radius (a strip leaf 45 mm wide leaving a stem 6 mm
    # wide spans 150 deg from the axis, its outer half 20 deg).
    r_median = float(np.median(r_out))
    n_bins = max(int(2 * math.pi * r_median / cell), 8)
    b = np.floor((phi[outer] % (2 * math.pi)) / (2 * math.pi / n_bins)).astype(np.int64) % n_bins
    if len(np.unique(b[r_out >= r_median])) * 360.0 / n_bins < PETAL_MIN_ARC_DEG:
        return None
    return outer, n_bins, b


def _cups(pts: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray], cell: float):
    """The leaves that are cups round the axis (:func:`_cup_bins`; steps 11 and 12), among
    those found when the walk starts: (leaf, its points' indices, its junction, the cup's
    bins, every point's radius and azimuth), each read when the walk reaches it, after the
    splits of the leaves before it relabelled their points (a split's new leaves are not
    walked)."""
    r_all = np.hypot(pts[:, 0], pts[:, 1])
    phi_all = np.arctan2(pts[:, 1], pts[:, 0])
    for li in range(len(midribs)):
        member = np.flatnonzero(leaf_label == li)
        junction = midribs[li][0]
        cup = _cup_bins(r_all[member], phi_all[member], junction, cell)
        if cup is not None:
            yield li, member, junction, cup, r_all, phi_all


def _split_petals(pts: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray], groups: tuple[int, ...],
                  base_widths: dict[int, np.ndarray], *, cell: float, bin_w: float, min_leaf: float,
                  spacing: float, grid_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
                  ) -> tuple[np.ndarray, list[np.ndarray], tuple[int, ...], dict[int, np.ndarray], int]:
    """Split the leaves that are a cup of touching leaves round the axis, one per tip
    (step 11; clean scans). Returns the leaf labels, midribs, groups and base widths, and
    the number of leaves the splits added.

    A rosette's inner leaves rise from the crown side by side, edge on edge, a cup whose
    level sets do not part until near the tips: on the ideal 30-leaf rosette two found
    leaves held twelve true ones. Their tips still stand out: a leaf's tip is where it
    reaches farthest from its base (step 5 reads tips the same way), and round the axis
    the cup's reach, the distance from the junction of its farthest point in each
    azimuth bin (a voxel wide at the points' median radius, each point covering the
    bins its own voxel spans; :func:`_reach_profile`), has one lobe per leaf. A leaf
    whose outer half (its points beyond their median radius) occupies
    :data:`PETAL_MIN_ARC_DEG` of bins round the axis is cut at the valleys between the
    lobes (:func:`_reach_lobes`: :data:`PETAL_PROMINENCE_SPACINGS` above both valleys,
    each reaching a leaf's length); its points within a voxel of the junction's radius
    go with their nearest part. Then, as step 10 does:

    - A part in whose sector another leaf holds :data:`AZIMUTH_PIECE_SHARE` as many of
      the points in the part's span of radius and height is a piece of that leaf
      (:func:`_sector_owner`): a leaf lying beneath the cup, cut off by the grid.
    - A part whose points start (:data:`PETAL_START_PERCENTILE` of them nearer the
      junction) more than :data:`PETAL_BASE_SHARE` of its reach farther from the
      junction than the leaf's nearest point is no petal but a leaflet on a stalk, and
      so is a part holding fewer points than spacings along its reach (no surface, the
      rule of step 8): it goes with the petal nearest in azimuth. A leaf splits only
      into two petals or more, each with a midrib (:func:`_midrib_of`, from the
      junction) as long as a leaf.

    A noisy scan's reach is its noise's (the noise moves points along beams through the
    axis, and so mostly in reach): it is left to step 10."""
    leaf_label = leaf_label.copy()
    midribs = list(midribs)
    groups = list(groups) if groups else list(range(len(midribs)))
    base_widths = dict(base_widths)
    added = 0
    for li, member, junction, (outer, n_bins, b), r_all, phi_all in _cups(pts, leaf_label, midribs, cell):
        p_out, r_out, phi_out = pts[member[outer]], r_all[member[outer]], phi_all[member[outer]]
        d_out = np.linalg.norm(p_out - junction, axis=1)
        prof = _reach_profile(phi_out, d_out, n_bins,
                              half_width=0.5 * cell / r_out)
        peaks, ends = _reach_lobes(prof, prominence=PETAL_PROMINENCE_SPACINGS * spacing, min_reach=min_leaf)
        if len(peaks) < 2:
            continue
        # Part k runs from the valley before lobe k round to the one after it (exclusive).
        part_out = np.searchsorted((ends[:-1] - ends[-1]) % n_bins, (b - ends[-1]) % n_bins, side="right")
        n_p = len(peaks)
        others = np.flatnonzero((leaf_label >= 0) & (leaf_label != li) & (r_all > r_out.min()))
        owner = np.full(n_p, -1, dtype=np.int64)
        for k in range(n_p):
            pk, rk = p_out[part_out == k], r_out[part_out == k]
            if not len(pk):
                continue
            near = others[(r_all[others] >= rk.min()) & (r_all[others] <= rk.max())
                          & (pts[others, 2] >= pk[:, 2].min()) & (pts[others, 2] <= pk[:, 2].max())]
            owner[k] = _sector_owner(phi_out[part_out == k], phi_all[near], leaf_label[near])
        size = np.bincount(part_out, minlength=n_p)
        new = np.flatnonzero((owner < 0) & (size > 0))
        if len(new) < 2:
            continue
        # A petal grows from the cup's base, near the junction, and is a surface: as many
        # points as spacings along its reach (step 8's rule for a leaf).
        start = np.array([np.percentile(d_out[part_out == k], PETAL_START_PERCENTILE) for k in new])
        reach = prof[peaks[new]]
        petal = (start <= d_out.min() + PETAL_BASE_SHARE * reach) & (size[new] * spacing >= reach)
        if np.count_nonzero(petal) < 2:
            continue
        centre = np.array([_mean_azimuth(phi_out[part_out == k]) for k in new])
        for k, c in zip(new[~petal], centre[~petal]):
            part_out[part_out == k] = new[petal][_nearest_in_azimuth(centre[petal], c)]
        new = new[petal]
        part = np.empty(len(member), dtype=np.int64)
        part[outer] = part_out
        if not outer.all():
            part[~outer] = part_out[cKDTree(p_out).query(pts[member[~outer]], workers=-1)[1]]
        ribs = [_midrib_of(pts[member[part == k]], junction, cell=cell, bin_w=bin_w, grid_offset=grid_offset)
                for k in new]
        if min(float(np.linalg.norm(np.diff(m, axis=0), axis=1).sum()) for m in ribs) < min_leaf:
            continue
        logger.debug("segmentation: leaf %d is a cup of %d leaves round the axis, split at its tips",
                     li, len(new))
        added += _apply_split(leaf_label, midribs, groups, base_widths, li, member, part, owner, new, ribs)
    return leaf_label, midribs, tuple(groups), base_widths, added


# Step 12, cups by their smooth surfaces (clean scans, after step 11). Region growing with
# a smoothness constraint (Rabbani, van den Heuvel and Vosselman 2006, "Segmentation of
# point clouds using smoothness constraint", IAPRS 36(5):248-253) on nodes a point spacing
# apart: neighbours join a region while their normals (PCA within SMOOTH_NORMAL_SPACINGS)
# turn by under SMOOTH_ANGLE_DEG, and the region grows on from the nodes flatter than the
# SMOOTH_SEED_PERCENTILE of curvature (a crease's nodes join a region but do not carry it
# over the crease). Touching leaves meet at a crease, so their surfaces part where the
# level sets and the reach's lobes (step 11) do not. A leaf that a leaf in front hides in
# bands falls into pieces, each as smooth as the leaf, that one quadric height field fits
# as closely as each alone (:func:`quadric_rms`): regions of SMOOTH_SEED_NODES or more,
# within a leaf's length of each other, whose joint fit's RMS lies within
# SMOOTH_JOIN_SPACINGS of a spacing of their own pooled are one surface. On the ideal
# 8-leaf rosette (seed 3) a leaf's pieces fit jointly within 0.02-0.07 mm of their own,
# neighbouring leaves 0.3-1.9 mm apart, at a 1.6 mm spacing. A part is a leaf when it is
# as long as a leaf, a surface (as many points as spacings along its reach, and
# SMOOTH_WIDTH_NODES nodes per spacing of it), starts within SMOOTH_START_SHARE of its
# reach of the leaf's nearest point to the junction (a rosette's inner leaves, hidden near
# the crown and the junction the walk's top above it, show from 0-0.4 of their reach; a
# trifoliate's side leaflets from 0.55-0.86), and reaches out from the axis (its 95th
# percentile radius SMOOTH_SPREAD_SHARE of its reach or more: a blade rising 60 deg, 0.5;
# round its stem, 0.3). Then (step 13) a found leaf with fewer nodes than a strip
# SMOOTH_WIDTH_NODES wide and a leaf long is a fragment of the leaf it touches most.
SMOOTH_ANGLE_DEG = 10.0
SMOOTH_NORMAL_SPACINGS = 2.5
SMOOTH_SEED_PERCENTILE = 90.0
SMOOTH_SEED_NODES = 10
SMOOTH_JOIN_SPACINGS = 0.1
SMOOTH_START_SHARE = 0.45
SMOOTH_SPREAD_SHARE = 0.4
SMOOTH_WIDTH_NODES = 2.0


def quadric_rms(points: np.ndarray) -> float:
    """RMS distance of ``points`` ((n, 3), metres) from the quadric height field
    ``h = a + b x + c y + d x^2 + e x y + f y^2`` fitted by least squares in their
    principal frame (``h`` along the least principal axis): a smooth surface's pieces
    fit one such field as closely as each alone, two surfaces meeting at a crease or
    stacked apart do not. Infinite for fewer than 8 points (no residual to read)."""
    if len(points) < 8:
        return math.inf
    q = points - points.mean(axis=0)
    axes = np.linalg.eigh(q.T @ q)[1]
    x, y, h = q @ axes[:, 2], q @ axes[:, 1], q @ axes[:, 0]
    design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    coef = np.linalg.lstsq(design, h, rcond=None)[0]
    return float(np.sqrt(np.mean((design @ coef - h) ** 2)))


def _smooth_regions(points: np.ndarray, spacing: float, *, min_nodes: int, reach: float) -> np.ndarray:
    """Each point's smooth-surface region (step 12): region growing on nodes a spacing
    apart, the regions that are pieces of one surface (within ``reach`` of each other)
    joined (:func:`_join_region_pieces`), regions under ``min_nodes`` nodes given to the
    region they touch most (or the nearest). Returns (n,) int64 labels 0..k-1."""
    nodes, inverse = voxel_centroids(points, spacing)
    n = len(nodes)
    if n < 2:
        return np.zeros(len(points), dtype=np.int64)
    tree = cKDTree(nodes)
    # Normals and curvature (PCA) of each node's neighbours within the radius, at most
    # 32 of them (a disc of 2.5 spacings holds about 20).
    dist, near = tree.query(nodes, k=min(32, n), distance_upper_bound=SMOOTH_NORMAL_SPACINGS * spacing)
    dist, near = dist.reshape(n, -1), near.reshape(n, -1)
    weight = np.isfinite(dist).astype(np.float64)
    count = weight.sum(axis=1)
    gathered = np.concatenate([nodes, np.zeros((1, 3))])[np.minimum(near, n)]
    mean = (gathered * weight[:, :, None]).sum(axis=1) / count[:, None]
    q = (gathered - mean[:, None, :]) * weight[:, :, None]
    w, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    normals = vec[:, :, 0]
    curvature = np.where(count >= 4, w[:, 0] / np.maximum(w.sum(axis=1), 1e-300), 1.0)
    adjacent = tree.query_ball_point(nodes, 1.5 * spacing)
    cos_max = math.cos(math.radians(SMOOTH_ANGLE_DEG))
    flat = curvature <= np.percentile(curvature, SMOOTH_SEED_PERCENTILE)
    region = np.full(n, -1, dtype=np.int64)
    grown = 0
    for seed in np.argsort(curvature, kind="stable"):
        if region[seed] >= 0:
            continue
        region[seed] = grown
        front = [int(seed)]
        while front:
            i = front.pop()
            for j in adjacent[i]:
                if region[j] < 0 and abs(float(normals[i] @ normals[j])) >= cos_max:
                    region[j] = grown
                    if flat[j]:
                        front.append(j)
        grown += 1
    region = _join_region_pieces(nodes, region, spacing=spacing, reach=reach)
    # Small regions (a crease's nodes, a leaf's edge) go to the region they touch most.
    for _ in range(n):
        size = np.bincount(region)
        votes: dict[int, dict[int, int]] = {}
        for i in np.flatnonzero(size[region] < min_nodes):
            for j in adjacent[i]:
                if size[region[j]] >= min_nodes:
                    tally = votes.setdefault(int(region[i]), {})
                    tally[int(region[j])] = tally.get(int(region[j]), 0) + 1
        if not votes:
            break
        for r, tally in votes.items():
            region[region == r] = max(tally, key=tally.get)
    size = np.bincount(region)
    big = size[region] >= min_nodes
    if not big.any():
        return np.zeros(len(points), dtype=np.int64)
    if not big.all():
        region[~big] = region[big][cKDTree(nodes[big]).query(nodes[~big])[1]]
    return np.unique(region, return_inverse=True)[1].ravel()[inverse]


def _join_region_pieces(nodes: np.ndarray, region: np.ndarray, *, spacing: float, reach: float) -> np.ndarray:
    """Join the regions of :data:`SMOOTH_SEED_NODES` nodes or more, within ``reach`` of
    each other, whose joint quadric fit (:func:`quadric_rms`) lies within
    :data:`SMOOTH_JOIN_SPACINGS` of a spacing of their own fits' pooled RMS: the closest
    fitting pair first, until none is left (step 12). Returns the region labels."""
    region = region.copy()
    size = np.bincount(region)
    member = {int(r): np.flatnonzero(region == r) for r in np.flatnonzero(size >= SMOOTH_SEED_NODES)}
    if len(member) < 2:
        return region
    keys = np.array(sorted(member))
    lo = np.array([nodes[member[k]].min(axis=0) for k in keys])
    hi = np.array([nodes[member[k]].max(axis=0) for k in keys])
    boxes = np.all((lo[:, None, :] <= hi[None, :, :] + reach) & (lo[None, :, :] <= hi[:, None, :] + reach), axis=2)
    trees = {int(k): cKDTree(nodes[member[int(k)]]) for k in keys}
    rms = {r: quadric_rms(nodes[m]) for r, m in member.items()}
    tol = SMOOTH_JOIN_SPACINGS * spacing

    def excess(a: int, b: int) -> float:
        ma, mb = member[a], member[b]
        pooled = math.sqrt((len(ma) * rms[a] ** 2 + len(mb) * rms[b] ** 2) / (len(ma) + len(mb)))
        return quadric_rms(nodes[np.concatenate([ma, mb])]) - pooled - tol

    cost = {}
    for i, j in zip(*np.nonzero(np.triu(boxes, 1))):
        a, b = int(keys[i]), int(keys[j])
        small, big = (a, b) if len(member[a]) <= len(member[b]) else (b, a)
        if np.isfinite(trees[big].query(nodes[member[small]], distance_upper_bound=reach)[0]).any():
            cost[(a, b)] = excess(a, b)
    while cost:
        (a, b), worst = min(cost.items(), key=lambda kv: kv[1])
        if worst > 0:
            break
        member[a] = np.concatenate([member[a], member.pop(b)])
        rms[a] = quadric_rms(nodes[member[a]])
        rms.pop(b)
        region[region == b] = a
        touched = {r for pair in cost if a in pair or b in pair for r in pair} - {a, b}
        cost = {pair: c for pair, c in cost.items() if a not in pair and b not in pair}
        for r in touched:
            cost[(min(a, r), max(a, r))] = excess(min(a, r), max(a, r))
    return region


def _split_smooth_surfaces(pts: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray],
                           groups: tuple[int, ...], base_widths: dict[int, np.ndarray], *, cell: float,
                           bin_w: float, min_leaf: float, spacing: float,
                           grid_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
                           ) -> tuple[np.ndarray, list[np.ndarray], tuple[int, ...], dict[int, np.ndarray], int]:
    """Split the cups that are touching leaves' smooth surfaces meeting at creases (step
    12; clean scans). Returns the leaf labels, midribs, groups and base widths, and the
    number of leaves the splits added.

    A leaf is a cup, as step 11 reads one, when its outer half spans
    :data:`PETAL_MIN_ARC_DEG` round the axis. Its points fall into smooth-surface
    regions (:func:`_smooth_regions`; regions under a leaf's length of
    :data:`SMOOTH_WIDTH_NODES`-node strips go to their neighbours). A region is a leaf
    of its own when it is as long as a leaf (its midrib from the junction,
    :func:`_midrib_of`), a surface, starts within :data:`SMOOTH_START_SHARE` of its reach
    of the cup's nearest point to the junction and reaches out from the axis
    (:data:`SMOOTH_SPREAD_SHARE`); the other regions go with the leaf nearest in
    azimuth. A cup splits only into two leaves or more."""
    leaf_label = leaf_label.copy()
    midribs = list(midribs)
    groups_l = list(groups) if groups else list(range(len(midribs)))
    base_widths = dict(base_widths)
    min_nodes = int(SMOOTH_WIDTH_NODES * min_leaf / spacing)
    added = 0
    for li, member, junction, (outer, _, _), r_all, phi_all in _cups(pts, leaf_label, midribs, cell):
        part = _smooth_regions(pts[member], spacing, min_nodes=min_nodes, reach=min_leaf)
        n_p = int(part.max()) + 1
        if n_p < 2:
            continue
        d = np.linalg.norm(pts[member] - junction, axis=1)
        d_min = float(d[outer].min())
        ribs = [_midrib_of(pts[member[part == k]], junction, cell=cell, bin_w=bin_w, grid_offset=grid_offset)
                for k in range(n_p)]
        leaf_like = np.zeros(n_p, dtype=bool)
        for k in range(n_p):
            mine = part == k
            reach = float(d[mine].max())
            start = float(np.percentile(d[mine & outer], PETAL_START_PERCENTILE)) if (mine & outer).any() else math.inf
            leaf_like[k] = (float(np.linalg.norm(np.diff(ribs[k], axis=0), axis=1).sum()) >= min_leaf
                            and start <= d_min + SMOOTH_START_SHARE * reach
                            and np.count_nonzero(mine) * spacing >= reach
                            and len(voxel_centroids(pts[member[mine]], spacing)[0]) >= SMOOTH_WIDTH_NODES * reach / spacing
                            and float(np.percentile(r_all[member[mine]], 95)) >= SMOOTH_SPREAD_SHARE * reach)
        new = np.flatnonzero(leaf_like)
        if len(new) < 2:
            continue
        centre = np.array([_mean_azimuth(phi_all[member[part == k]]) for k in range(n_p)])
        for k in np.flatnonzero(~leaf_like):
            part[part == k] = new[_nearest_in_azimuth(centre[new], centre[k])]
        logger.debug("segmentation: leaf %d is a cup of %d smooth surfaces meeting at creases, split", li, len(new))
        added += _apply_split(leaf_label, midribs, groups_l, base_widths, li, member, part,
                              np.full(n_p, -1, dtype=np.int64), new, [ribs[k] for k in new])
    return leaf_label, midribs, tuple(groups_l), base_widths, added


def _join_fragments(pts: np.ndarray, leaf_label: np.ndarray, midribs: list[np.ndarray], groups: tuple[int, ...],
                    base_widths: dict[int, np.ndarray], *, min_leaf: float, spacing: float
                    ) -> tuple[np.ndarray, list[np.ndarray], tuple[int, ...], dict[int, np.ndarray], int]:
    """Give each found leaf too small to be a leaf's surface to the leaf it touches most
    (step 13; clean scans): fewer nodes a spacing apart than a strip
    :data:`SMOOTH_WIDTH_NODES` nodes wide and a leaf long, and nodes of a larger leaf
    within two spacings (a fragment left alone stays). Returns the leaf labels, midribs,
    groups and base widths (the larger leaf's), and the number of fragments joined."""
    n = len(midribs)
    nodes = [voxel_centroids(pts[leaf_label == i], spacing)[0] for i in range(n)]
    size = np.array([len(m) for m in nodes])
    whole = np.flatnonzero(size >= int(SMOOTH_WIDTH_NODES * min_leaf / spacing))
    into = np.arange(n)
    if n < 2 or not len(whole) or len(whole) == n:
        return leaf_label, list(midribs), groups, base_widths, 0
    owner = np.concatenate([np.full(size[k], k) for k in whole])
    tree = cKDTree(np.vstack([nodes[k] for k in whole]))
    for k in np.setdiff1d(np.arange(n), whole):
        d, j = tree.query(nodes[k], distance_upper_bound=2.0 * spacing)
        if np.isfinite(d).any():
            into[k] = int(np.bincount(owner[j[np.isfinite(d)]]).argmax())
    keep = np.unique(into)
    if len(keep) == n:
        return leaf_label, list(midribs), groups, base_widths, 0
    new_of = np.full(n, -1, dtype=np.int64)
    new_of[keep] = np.arange(len(keep))
    label = np.where(leaf_label >= 0, new_of[into[np.maximum(leaf_label, 0)]], -1)
    groups_l = list(groups) if groups else list(range(n))
    new_groups = np.unique([groups_l[k] for k in keep], return_inverse=True)[1].ravel()
    widths = {int(new_of[k]): w for k, w in base_widths.items() if into[k] == k}
    logger.debug("segmentation: %d found leaves too small for a leaf joined the leaves they touch", n - len(keep))
    return label, [midribs[k] for k in keep], tuple(int(g) for g in new_groups), widths, n - len(keep)


def _remap_parents(old_label: np.ndarray, new_label: np.ndarray, old_parent: list[int],
                   n_new: int) -> tuple[int, ...]:
    """Each new leaf's parent leaf (-1: it hangs from a stem or from nothing), from the
    chains' parents, after leaves were joined or dropped (labels ``old_label`` became
    ``new_label``): a chain's parent is its nearest ancestor that became another leaf."""
    n_old = len(old_parent)
    new_of_old = np.full(n_old, -1, dtype=np.int64)
    both = (old_label >= 0) & (new_label >= 0)
    new_of_old[old_label[both]] = new_label[both]
    parent = [-1] * n_new
    for i in range(n_old):
        j = int(new_of_old[i])
        if j < 0 or parent[j] >= 0:
            continue
        a = old_parent[i]
        while a >= 0 and int(new_of_old[a]) in (-1, j):
            a = old_parent[a]
        parent[j] = int(new_of_old[a]) if a >= 0 else -1
    return tuple(parent)


def shifted_grid_offsets(n: int) -> np.ndarray:
    """``n`` grid offsets for :attr:`SegmentationSettings.grid_offset`, spread evenly.

    The points 0 .. n - 1 of the Halton sequence in bases 2, 3, 5 and 7
    (``scipy.stats.qmc.Halton``, unscrambled; Halton 1960, "On the
    efficiency of certain quasi-random sequences of points in evaluating
    multi-dimensional integrals", Numerische Mathematik 2:84-90), which cover the unit
    cube of offsets and phases more evenly than random draws; the first is zeros (the
    grid anchored on the origin).

    Args:
        n: offsets, >= 1.

    Returns:
        (n, 4) float64 in [0, 1).
    """
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    from scipy.stats import qmc

    # Unscrambled, the sequence starts at its point 0, the origin.
    return qmc.Halton(d=4, scramble=False).random(int(n))


def checked_range_noise(range_noise_m: Any, points: np.ndarray) -> np.ndarray:
    """``range_noise_m`` as float64, one finite vector per point of ``points``
    ((n, 3), as :func:`plantsim.evaluation.evaluate.range_noise_vectors` gives them).

    Raises:
        ValueError: another shape, or a NaN or inf.
    """
    noise = np.asarray(range_noise_m, dtype=np.float64)
    if noise.shape != points.shape or not np.all(np.isfinite(noise)):
        raise ValueError(f"range_noise_m must be finite and shaped like points_turntable {points.shape}, "
                         f"got {noise.shape}")
    return noise


def _checked_points(points_turntable: Any) -> np.ndarray:
    raw = np.asarray(points_turntable, dtype=np.float64)
    if raw.ndim != 2 or raw.shape[1] != 3:
        raise ValueError(f"points_turntable must have shape (n, 3), got shape {raw.shape}")
    if not np.isfinite(raw).all():
        raise ValueError("points_turntable holds NaN or inf; drop misses before segmenting")
    return raw


def segment_organs(points_turntable: Any, *, settings: SegmentationSettings | None = None,
                   range_noise_m: Any = None) -> Segmentation:
    """Stems and leaves of a cloud (method in the module docstring).

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame (z up, base at
            ``settings.base_z``), plant points only, n >= 17.
        settings: SegmentationSettings (defaults if None).
        range_noise_m: optional (n, 3) float64 metres, per point its beam's unit
            direction times its range noise's standard deviation
            (:func:`plantsim.evaluation.evaluate.range_noise_vectors`): branches that
            are a stem's noise are then not leaves (step 8). None: the points alone.

    Returns:
        Segmentation.
    """
    return segment_on_shifted_grids(points_turntable, settings=settings,
                                    offsets=[(settings or SegmentationSettings()).grid_offset],
                                    range_noise_m=range_noise_m)[0]


def segment_on_shifted_grids(points_turntable: Any, *, settings: SegmentationSettings | None = None,
                             offsets: Any, range_noise_m: Any = None) -> tuple[Segmentation, ...]:
    """:func:`segment_organs` once for each grid offset, sharing what no grid changes.

    The outlier removal, the scale and the stems found at the base do not depend on
    the grid; the skeleton does: a voxel grid and level sets that start elsewhere
    cut the cloud elsewhere, and a branch near a threshold (a tip near the shortest
    leaf, two halves near the merge rule) goes the other way. The spread of the
    outcomes over offsets is the segmentation's own uncertainty
    (:func:`plantsim.evaluation.traits.extract_traits` reads the median).

    Args:
        points_turntable: as :func:`segment_organs`.
        settings: SegmentationSettings (defaults if None); its ``grid_offset`` must be
            zeros (the default) or the one offset given: the offsets say where the grids
            start.
        offsets: (k, 4) grid offsets (:attr:`SegmentationSettings.grid_offset`), k >= 1.
        range_noise_m: as :func:`segment_organs`'.

    Returns:
        k Segmentations, in the order of ``offsets``.
    """
    s = settings or SegmentationSettings()
    grids = [dataclasses.replace(s, grid_offset=tuple(o)) for o in np.asarray(offsets, dtype=np.float64)
             .reshape(-1, 4)]
    if not grids:
        raise ValueError("offsets must hold at least one grid offset")
    if any(s.grid_offset) and any(g.grid_offset != s.grid_offset for g in grids):
        raise ValueError(f"settings.grid_offset {s.grid_offset} and offsets both say where the grid starts: "
                         "leave settings.grid_offset at zeros and give the offsets")
    raw = _checked_points(points_turntable)
    noise = None if range_noise_m is None else checked_range_noise(range_noise_m, raw)
    kept, scale = kept_points(raw)
    pts = raw[kept]
    noise = None if noise is None or not np.any(noise != 0) else noise[kept]
    stems = find_stems(pts, base_z=s.base_z, scale=scale, max_diameter_m=s.max_stem_diameter_m)
    # Stems beside the axis that the range noise hides from the slices: in the turn angles.
    beam_tracks: dict[tuple[float, float], BeamStemTrack] = {}
    if noise is not None:
        beside = []
        for st in find_beam_stems(pts, noise, base_z=s.base_z, scale=scale,
                                  max_diameter_m=s.max_stem_diameter_m, stems=stems):
            track = track_beam_stem(pts, noise, st, base_z=s.base_z, slice_m=BEAM_STEM_SLICE_VOXELS * scale.voxel_m)
            if track is not None:
                beam_tracks[st.center_xy_m] = track
                beside.append(st)
        stems = with_beam_stems(stems, tuple(beside))
    tracks = [beam_tracks.get(st.center_xy_m) if st.found_in_beams else None for st in stems]
    # A stem found in the turn angles is its track's points (on_beam_stem), not a walk's;
    # no grid changes them.
    axis_stem = any(tr is None and _on_axis(st) for st, tr in zip(stems, tracks))
    on_track = [None if tr is None else on_beam_stem(pts, noise, tr, axis_stem=axis_stem) for tr in tracks]
    # A noisy stem on the axis ends where the beams stop meeting it (beam_stem_top), which
    # no grid changes; the walk up its noisy column goes on up the leaves rising in it.
    on_axis = [read_by_axis_beams(st, noise is not None) for st in stems]
    image = None
    if any(on_axis):
        image = _axis_range_image(pts, noise, base_z=s.base_z, slice_m=2.0 * scale.voxel_m, sector_deg=3.0,
                                  max_miss_m=0.25 * scale.spacing_m)
    top, why = _stem_top_and_refusal(image)
    in_cup = False
    if any(on_axis):
        # Leaves standing round the stem end it where the beams meet them all round
        # (cup_stem_top), read on slices of half a voxel: a rosette's crown is a few
        # voxels tall.
        cup = _cup_top_in(_axis_range_image(pts, noise, base_z=s.base_z, slice_m=CUP_SLICE_VOXELS * scale.voxel_m,
                                            sector_deg=3.0, max_miss_m=0.25 * scale.spacing_m),
                          CUP_RUN_VOXELS * scale.voxel_m)
        if math.isfinite(cup) and not cup >= top:
            top, why, in_cup = cup, "", True
    beam_tops = [top if axis else math.nan for axis in on_axis]
    refusals = tuple(_beam_top_refusal(st, noise is not None, axis, why) for st, axis in zip(stems, on_axis))
    cups = tuple(in_cup and axis for axis in on_axis)
    return tuple(dataclasses.replace(_segment_on_grid(pts, kept, scale, stems, g, noise, beam_tops, image, tracks,
                                                      on_track), stem_beam_top_refusals=refusals,
                                     stem_tops_in_cup=cups, range_noise_m=noise) for g in grids)


def _beam_top_refusal(stem: StemBase, noise_given: bool, on_axis: bool, why: str) -> str:
    """Why the beams through the axis do not end a stem whose noisy column hides its
    rings (:func:`beam_stem_top`; ``why`` the range image's own reason); '' where they
    do or its rings are resolved (the walk follows them)."""
    if stem.diameter_resolved:
        return ""
    if not noise_given:
        return "no range noise is given (or it is zero), so the beams' directions are not known"
    if not on_axis:
        return (f"it stands {1e3 * math.hypot(*stem.center_xy_m):.0f} mm off the turntable's axis, more than "
                "half its column's width, where the beams through the axis need not meet it")
    return why


def _segment_on_grid(pts: np.ndarray, kept: np.ndarray, scale: CloudScale, stems: tuple[StemBase, ...],
                     s: SegmentationSettings, noise: np.ndarray | None = None,
                     beam_tops: list[float] | None = None, image: _RangeImage | None = None,
                     tracks: list[BeamStemTrack | None] | None = None,
                     on_track: list[np.ndarray | None] | None = None) -> Segmentation:
    """The skeleton and organs of the kept points ``pts`` on one grid (``s.grid_offset``);
    ``tracks``: per stem, its track where it was found in the turn angles
    (:func:`track_beam_stem`), else None; ``on_track``: per such stem its points
    (:func:`on_beam_stem`), else None."""
    v = scale.voxel_m
    tracks = list(tracks) if tracks is not None else [None] * len(stems)
    on_track = list(on_track) if on_track is not None else [None] * len(stems)
    nodes, inverse = voxel_centroids(pts, v, s.grid_offset[:3])
    graph = _graph(nodes, s.link_factor * v, spacing=scale.spacing_m)
    # Roots: nodes in the lowest slices near each stem base (or the lowest nodes).
    z = nodes[:, 2]
    low = z <= s.base_z + 4.0 * max(2.0 * v, 0.003)
    roots = np.zeros(len(nodes), dtype=bool)
    for st in stems:
        near = np.hypot(nodes[:, 0] - st.center_xy_m[0], nodes[:, 1] - st.center_xy_m[1])
        roots |= low & (near <= st.diameter_m / 2 + 2 * v)
    if not roots.any():
        roots = z <= z.min() + 2.0 * v
    dist, pred, _ = csgraph.dijkstra(graph, directed=False, indices=np.flatnonzero(roots),
                                     min_only=True, return_predecessors=True)
    dist[~np.isfinite(dist)] = 0.0

    bin_w = s.bin_factor * v
    level = np.floor(dist / bin_w + s.grid_offset[3]).astype(np.int64)
    # Connected pieces of each level set: keep only the edges inside one bin.
    coo = graph.tocoo()
    same = level[coo.row] == level[coo.col]
    m = len(nodes)
    sub = sparse.coo_matrix((np.ones(int(same.sum())), (coo.row[same], coo.col[same])), shape=(m, m))
    _, piece = csgraph.connected_components(sub, directed=False)
    n_pieces = int(piece.max()) + 1
    counts = np.bincount(piece, minlength=n_pieces).astype(np.float64)
    centroid = np.column_stack([np.bincount(piece, weights=nodes[:, j], minlength=n_pieces) / counts
                                for j in range(3)])
    # Parent of a piece: the piece of the Dijkstra predecessor of its nearest node.
    order = np.lexsort((dist, piece))
    first = order[np.r_[0, np.flatnonzero(np.diff(piece[order])) + 1]]
    parent = np.full(n_pieces, -1, dtype=np.int64)
    has_pred = pred[first] >= 0
    parent[piece[first[has_pred]]] = piece[pred[first[has_pred]]]
    parent[parent == np.arange(n_pieces)] = -1
    piece_dist = np.zeros(n_pieces)
    np.maximum.at(piece_dist, piece, dist)
    spread = np.zeros(n_pieces)  # horizontal reach of each piece from its centroid
    np.maximum.at(spread, piece, np.hypot(*(nodes[:, :2] - centroid[piece, :2]).T))
    children: list[list[int]] = [[] for _ in range(n_pieces)]
    for c in np.flatnonzero(parent >= 0):
        children[parent[c]].append(int(c))

    height = float(pts[:, 2].max() - s.base_z)
    min_leaf = max(s.min_leaf_fraction * height, 2.0 * bin_w)

    # Stems: follow the skeleton up from each stem's root piece.
    by_piece = np.argsort(piece, kind="stable")
    piece_start = np.r_[0, np.cumsum(np.bincount(piece, minlength=n_pieces))]

    def piece_nodes(q: int) -> np.ndarray:
        """Indices of the nodes making up skeleton piece ``q``."""
        return by_piece[piece_start[q]:piece_start[q + 1]]

    # The column a stem's points fill round its axis: its radius plus the noise band and a voxel.
    column_margin = 2.5 * scale.noise_m + v
    is_stem_piece = np.full(n_pieces, -1, dtype=np.int64)
    stem_tops = []
    walk_top_z = [math.nan] * len(stems)  # where a walk went, when the beams end its stem lower
    axis_tracks: list[np.ndarray] = []  # per stem, (k, 3): z, x, y of its axis
    # A stem found in the turn angles holds the pieces most of whose points are its
    # track's, before any walk: the walk up a noisy stem on the axis, whose column its
    # neighbours' noise reaches, does not go on up theirs.
    point_piece = piece[inverse]
    point_count = np.bincount(point_piece, minlength=n_pieces)
    for si, mask in enumerate(on_track):
        if mask is not None:
            mine = np.bincount(point_piece[mask], minlength=n_pieces)
            is_stem_piece[(is_stem_piece < 0) & (2 * mine > point_count)] = si
    for si, st in enumerate(stems):
        if tracks[si] is not None:
            axis = tracks[si].axis_track()
            stem_tops.append([float(axis[-1, 1]), float(axis[-1, 2]), tracks[si].top_z_m])
            axis_tracks.append(axis)
            continue
        c0 = np.array(st.center_xy_m)
        root_pieces = np.unique(piece[roots & (np.hypot(nodes[:, 0] - c0[0], nodes[:, 1] - c0[1])
                                                 <= st.diameter_m / 2 + 2 * v)])
        if len(root_pieces) == 0:
            stem_tops.append([c0[0], c0[1], s.base_z])
            axis_tracks.append(np.array([[s.base_z, c0[0], c0[1]]]))
            continue
        reach = max(1.5 * st.diameter_m, 3.0 * v)
        column = _column_radius(st, column_margin)
        track = [(s.base_z, c0[0], c0[1])]
        start = int(root_pieces[np.argmin(centroid[root_pieces, 2])])
        is_stem_piece[start] = si
        top = start
        walks = [(start, c0.copy())]  # pieces to walk on from, each with its axis
        while walks:
            cur, axis_xy = walks.pop()
            if centroid[cur, 2] > centroid[top, 2]:
                top = cur
            kids = [k for k in children[cur] if is_stem_piece[k] < 0]
            if not kids:
                continue
            # The axis follows a leaning stem, but only through pieces that fit in
            # the stem's column: a piece holding a leaf's base has its centroid pulled
            # off the axis, and the pieces of a leaf rising from the stem's top are
            # wider than the column: the axis does not bend off up the leaf (it did
            # on a noisy maize, whose 0.42 m stem read 0.60 m).
            off = [float(np.linalg.norm(centroid[k, :2] - axis_xy)) for k in kids]
            best = int(np.argmin(off))
            if off[best] <= reach and centroid[kids[best], 2] > centroid[cur, 2] - bin_w:
                nxt = axis_xy
                # A noisy stem's top piece moves it only if it lies round it (the axis
                # within its reach of its centroid): the last level set of a noisy stem is
                # often a lobe of its noise disc, beside the axis, and the axis that followed
                # it 13-23 mm off left the stem's top points out of its column.
                lobe = (not st.diameter_resolved and not children[kids[best]]
                        and off[best] > spread[kids[best]])
                if spread[kids[best]] <= column and not lobe:
                    nxt = centroid[kids[best], :2].copy()
                    track.append((float(centroid[kids[best], 2]), nxt[0], nxt[1]))
                is_stem_piece[kids[best]] = si
                walks.append((kids[best], nxt))
            # A leaf wrapped round the stem, or one lying against it, hides a band of
            # the stem from every view: the stem's level sets fall into pieces side by
            # side (halves of its cross-section), each going on up. Every piece lying
            # wholly inside the stem's column is stem, and the walk goes on from each;
            # a leaf's base reaches out of the column.
            for k in kids:
                if is_stem_piece[k] >= 0:
                    continue
                members = nodes[piece_nodes(k), :2]
                if (centroid[k, 2] > centroid[cur, 2] - bin_w
                        and np.hypot(*(members - axis_xy).T).max() <= column):
                    is_stem_piece[k] = si
                    walks.append((k, axis_xy))
        top_xyz = centroid[top].tolist()
        if beam_tops is not None and math.isfinite(beam_tops[si]) and beam_tops[si] < top_xyz[2]:
            walk_top_z[si] = top_xyz[2]
            top_xyz[2] = float(beam_tops[si])
        stem_tops.append(top_xyz)
        axis_tracks.append(np.array(track))

    def piece_width(q: int, below: int) -> float:
        """How far piece ``q``'s nodes lie from the line through it towards ``below``."""
        along = centroid[q] - centroid[below]
        along /= max(float(np.linalg.norm(along)), 1e-300)
        offset = nodes[piece_nodes(q)] - centroid[q]
        return float(np.linalg.norm(offset - np.outer(offset @ along, along), axis=1).max())

    def on_stalk(junction: int, chain: list[int]) -> bool:
        """Whether a branch meeting another leaf's chain at ``junction`` is a leaflet of
        that leaf (step 7 of the module docstring): the junction lies out of every stem's
        column by a level-set bin or more, and the chain from the stem up to it narrows
        to a stalk: a piece whose nodes lie within an eighth of the branch's half-width
        (its widest piece's) of the line through it, or within half a voxel."""
        if junction < 0 or is_stem_piece[junction] >= 0 or owner[junction] < 0 or not stems:
            return False
        out = min(_out_of_column(centroid[junction], st, track, column_margin)
                  for st, track in zip(stems, axis_tracks))
        if out < bin_w:
            return False
        widths, q = [], int(parent[junction])
        while q >= 0 and is_stem_piece[q] < 0:
            below = int(parent[q])
            if below < 0:
                break
            widths.append(piece_width(q, below))
            q = below
        if not widths:
            return False
        branch = max(piece_width(c, int(parent[c])) for c in chain if parent[c] >= 0)
        return min(widths) <= max(0.5 * v, 0.125 * branch)

    # Leaves: tips with a long enough branch, walked down to the stem.
    tips = [p for p in range(n_pieces) if not children[p] and is_stem_piece[p] < 0]
    owner = np.full(n_pieces, -1, dtype=np.int64)
    leaf_chains: list[list[int]] = []
    chain_parent: list[int] = []
    for tip in sorted(tips, key=lambda p: -piece_dist[p]):
        chain = [tip]
        p = int(parent[tip])
        while p >= 0 and is_stem_piece[p] < 0 and owner[p] < 0:
            chain.append(p)
            p = int(parent[p])
        junction = p
        base_d = piece_dist[junction] if junction >= 0 else 0.0
        if piece_dist[tip] - base_d < min_leaf and not (
                junction >= 0 and is_stem_piece[junction] >= 0
                and _out_of_column(centroid[tip], stems[is_stem_piece[junction]], axis_tracks[is_stem_piece[junction]],
                                   column_margin) >= min_leaf):
            continue
        if _is_line(nodes[np.concatenate([piece_nodes(q) for q in chain])], scale.spacing_m):
            continue  # a scan line seen apart from its leaf: it joins what it hangs from
        li = len(leaf_chains)
        owner[chain] = li
        chain_parent.append(int(owner[junction]) if on_stalk(junction, chain) else -1)
        if junction >= 0:
            chain.append(junction)  # the midrib starts at the junction
        leaf_chains.append(chain[::-1])
    # Spurs and unowned pieces join the leaf (or stem) they hang from.
    for p in np.argsort(piece_dist):
        if owner[p] >= 0 or is_stem_piece[p] >= 0:
            continue
        q = int(parent[p])
        if q >= 0:
            owner[p] = owner[q]
            if is_stem_piece[q] >= 0 and owner[q] < 0:
                is_stem_piece[p] = is_stem_piece[q]
    stem_label = is_stem_piece[point_piece]
    leaf_label = np.where(stem_label >= 0, -1, owner[point_piece])
    for si, mask in enumerate(on_track):
        if mask is not None:
            stem_label[mask], leaf_label[mask] = si, -1
    if len(stems) and len(leaf_chains):
        stem_label, leaf_label = _release_leaf_bases(
            pts, stem_label, leaf_label, stems, axis_tracks, margin=column_margin,
            link=2 * s.link_factor * v + 8 * scale.noise_m,
            tops_z=[top[2] if math.isfinite(walk) else math.nan for top, walk in zip(stem_tops, walk_top_z)],
            on_track=on_track)
    midribs = [centroid[np.array(ch)] for ch in leaf_chains]
    chain_label = leaf_label
    leaf_label, midribs = _merge_split_leaves(pts, leaf_label, midribs, bin_w=bin_w)
    leaf_label, midribs, n_sparse = _drop_leaves_without_surface(leaf_label, midribs,
                                                                 spacing=scale.spacing_m)
    n_stem_noise = 0
    if noise is not None:
        stem_label, leaf_label, midribs, n_stem_noise = _drop_stem_noise_leaves(
            pts, noise, stem_label, leaf_label, midribs, stems, axis_tracks, stem_tops,
            base_z=s.base_z, margin=v, reach=bin_w)
    base_widths: dict[int, np.ndarray] = {}
    if image is not None and beam_tops is not None and midribs:
        # A noisy stem on the axis: its leaves' bases in its column, from the beams.
        for si, st in enumerate(stems):
            if math.isfinite(beam_tops[si]):
                stem_label, leaf_label, midribs, base_widths = _leaf_bases_from_beams(
                    image, stem_label, leaf_label, midribs, top_z=float(stem_tops[si][2]),
                    column_m=_column_radius(st, column_margin))
    # A lamina and those hanging from it are one leaf, numbered by its first lamina.
    parents = _remap_parents(chain_label, leaf_label, chain_parent, len(midribs))
    links = np.array([(i, p) for i, p in enumerate(parents) if p >= 0], dtype=np.int64).reshape(-1, 2)
    groups = tuple(int(g) for g in _components(len(midribs), links))
    n_axis_split = 0
    if noise is not None and midribs:
        leaf_label, midribs, groups, base_widths, n_axis_split = _split_at_axis(
            pts, noise, leaf_label, midribs, groups, base_widths, cell=v, bin_w=bin_w, min_leaf=min_leaf,
            spacing=scale.spacing_m, grid_offset=s.grid_offset)
    n_petals = 0
    if midribs and (noise is None or not np.any(noise)) and scale.noise_m <= 0.5 * scale.spacing_m:
        leaf_label, midribs, groups, base_widths, n_petals = _split_petals(
            pts, leaf_label, midribs, groups, base_widths, cell=v, bin_w=bin_w, min_leaf=min_leaf,
            spacing=scale.spacing_m, grid_offset=s.grid_offset)
    n_surface_split = n_joined = 0
    if midribs and (noise is None or not np.any(noise)) and scale.noise_m <= 0.5 * scale.spacing_m:
        leaf_label, midribs, groups, base_widths, n_surface_split = _split_smooth_surfaces(
            pts, leaf_label, midribs, groups, base_widths, cell=v, bin_w=bin_w, min_leaf=min_leaf,
            spacing=scale.spacing_m, grid_offset=s.grid_offset)
        leaf_label, midribs, groups, base_widths, n_joined = _join_fragments(
            pts, leaf_label, midribs, groups, base_widths, min_leaf=min_leaf, spacing=scale.spacing_m)
    logger.info("segmentation: %d points, spacing %.3g mm, noise %.3g mm, voxel %.3g mm, "
                "%d skeleton nodes, %d stems, %d leaves", len(pts), 1e3 * scale.spacing_m,
                1e3 * scale.noise_m, 1e3 * v, n_pieces, len(stems), len(midribs))
    return Segmentation(points=pts, kept=kept, stem_label=stem_label, leaf_label=leaf_label,
                        stems=stems, stem_tops_m=np.array(stem_tops, dtype=np.float64).reshape(-1, 3),
                        leaf_midribs=tuple(midribs), scale=scale, min_leaf_length_m=float(min_leaf),
                        link_m=float(s.link_factor * v), sparse_branches=n_sparse,
                        leaf_group=groups, stem_noise_branches=n_stem_noise, axis_split_leaves=n_axis_split,
                        petal_split_leaves=n_petals, surface_split_leaves=n_surface_split,
                        joined_leaves=n_joined,
                        leaf_base_widths_m=tuple(base_widths.get(i, np.zeros(0)) for i in range(len(midribs))),
                        stem_walk_tops_z_m=tuple(walk_top_z))
