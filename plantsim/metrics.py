"""Cloud-to-truth metrics: exact point-to-mesh distance, Chamfer, coverage.

plantsim knows the exact plant mesh, so every error of a scan can be measured.
Everything here is pure math on arrays: the cloud and the mesh must already be in
one frame (any frame, as long as it is the same for both); nothing reads files.

Point-to-mesh distance is exact (closest point on the nearest triangle, after
Ericson, *Real-Time Collision Detection*, 2005, sec. 5.1.5), found without
testing every triangle: triangles are grouped by their bounding radius ``R``
(largest centroid-to-vertex distance) into levels whose ``R`` differ by at most a
factor two, each level with a cKDTree of centroids. For a point ``p`` whose ``k``
nearest centroids in a level are tested exactly, every untested triangle of that
level lies at least ``d_k - R_max`` away (``d_k``: distance to the ``k``-th
centroid; triangle inequality), so once ``d_k - R_max >= best`` no untested
triangle can be closer. Points that fail the test are re-queried with ``2k``
until they pass or the whole level has been tested: the result is exact for
every point, whatever the mesh, and only the running time depends on it.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
import math
import os
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

logger = logging.getLogger(__name__)

# Point-triangle pairs evaluated at once: bounds the temporaries of the exact
# distance kernel to roughly 40 arrays of this many float64 (about 100 MB).
_PAIRS_PER_BLOCK = 1 << 18


# --------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------
def _as_points(points: Any, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}); need at least one point")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{name} holds {int(bad.sum())} non-finite rows (NaN or inf), first at row "
            f"{first}: {arr[first].tolist()}; drop misses (e.g. points[hit]) before measuring"
        )
    return arr


def _as_mesh(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (v, 3), got shape {v.shape}")
    if v.shape[0] == 0:
        raise ValueError(f"vertices is empty (shape {v.shape}); the mesh has no vertices")
    if not np.isfinite(v).all():
        raise ValueError("vertices holds non-finite values (NaN or inf)")
    f_raw = np.asarray(faces)
    if f_raw.ndim != 2 or f_raw.shape[1] != 3:
        raise ValueError(f"faces must have shape (f, 3), got shape {f_raw.shape}")
    if f_raw.shape[0] == 0:
        raise ValueError(f"faces is empty (shape {f_raw.shape}); the mesh has no triangles")
    if not np.issubdtype(f_raw.dtype, np.integer):
        raise ValueError(f"faces must hold integer vertex indices, got dtype {f_raw.dtype}")
    f = f_raw.astype(np.int64)
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError(
            f"faces index vertices 0..{v.shape[0] - 1}, got indices from {f.min()} to {f.max()}"
        )
    return v, f


# --------------------------------------------------------------------------
# exact point-triangle distance (vectorised)
# --------------------------------------------------------------------------
def _n_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", x, y)


def closest_point_on_triangles(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> np.ndarray:
    """Closest point on each triangle to each point, pairwise (row i with row i).

    Ericson, *Real-Time Collision Detection* (2005), sec. 5.1.5, vectorised: the
    Voronoi regions are tested in his order (vertex A, B, edge AB, vertex C, edge AC,
    edge BC, face), here by overwriting from the last to the first. Degenerate
    (zero-area) triangles fall back to the nearest of their three edges.

    Args:
        points: (m, 3) float64, metres, any frame.
        a, b, c: (m, 3) float64, metres, same frame: the triangles' corners.

    Returns:
        (m, 3) float64, metres, same frame: the closest point of triangle i to point i.
    """
    ab = b - a
    ac = c - a
    ap = points - a
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    bp = points - b
    d3 = _dot(ab, bp)
    d4 = _dot(ac, bp)
    cp = points - c
    d5 = _dot(ab, cp)
    d6 = _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        # Edge BC.
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        v = np.where(m, 1.0 - t, v)
        w = np.where(m, t, w)
        # Edge AC.
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        v = np.where(m, 0.0, v)
        w = np.where(m, t, w)
        # Vertex C.
        m = (d6 >= 0) & (d5 <= d6)
        v = np.where(m, 0.0, v)
        w = np.where(m, 1.0, w)
        # Edge AB.
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        v = np.where(m, t, v)
        w = np.where(m, 0.0, w)
        # Vertex B.
        m = (d3 >= 0) & (d4 <= d3)
        v = np.where(m, 1.0, v)
        w = np.where(m, 0.0, w)
        # Vertex A.
        m = (d1 <= 0) & (d2 <= 0)
        v = np.where(m, 0.0, v)
        w = np.where(m, 0.0, w)

    closest = a + ab * v[:, None] + ac * w[:, None]
    bad = ~np.isfinite(closest).all(axis=1)
    if bad.any():
        closest[bad] = _closest_on_edges(points[bad], a[bad], b[bad], c[bad])
    return closest


def _closest_on_segment(p: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
    d = s1 - s0
    dd = _dot(d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dd > 0, _dot(p - s0, d) / dd, 0.0)
    t = np.clip(t, 0.0, 1.0)
    return s0 + d * t[:, None]


def _closest_on_edges(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    cands = np.stack(
        [_closest_on_segment(p, a, b), _closest_on_segment(p, b, c), _closest_on_segment(p, c, a)]
    )
    d2 = ((cands - p[None]) ** 2).sum(axis=2)
    pick = np.argmin(d2, axis=0)
    return cands[pick, np.arange(p.shape[0])]


# --------------------------------------------------------------------------
# the index
# --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ClosestPoints:
    """Result of a point-to-mesh query.

    Attributes:
        distance: (n,) float64, metres: unsigned distance of each point to the mesh.
        closest_points: (n, 3) float64, metres, the mesh's frame: closest surface point.
        triangle_index: (n,) int64: row of ``faces`` holding the closest point (ties
            between triangles sharing an edge or vertex go to either).
    """

    distance: np.ndarray
    closest_points: np.ndarray
    triangle_index: np.ndarray


class MeshProximity:
    """Exact point-to-mesh distance queries against one triangle mesh.

    Build once per mesh and query many clouds; see the module docstring for the
    method and why it is exact.

    Args:
        vertices: (v, 3) float64, metres, any frame.
        faces: (f, 3) integer, rows of ``vertices``; zero-area triangles are allowed.
        level_ratio: ratio of the largest to the smallest bounding radius inside one
            level (> 1). Smaller ratios mean more trees but tighter bounds.

    Raises:
        ValueError: if the mesh is empty, malformed or non-finite.
    """

    def __init__(self, vertices: Any, faces: Any, *, level_ratio: float = 2.0) -> None:
        if not level_ratio > 1.0:
            raise ValueError(f"level_ratio must be > 1, got {level_ratio}")
        self.vertices, self.faces = _as_mesh(vertices, faces)
        tri = self.vertices[self.faces]
        self._a = np.ascontiguousarray(tri[:, 0])
        self._b = np.ascontiguousarray(tri[:, 1])
        self._c = np.ascontiguousarray(tri[:, 2])
        centroid = tri.mean(axis=1)
        radius = np.sqrt(((tri - centroid[:, None]) ** 2).sum(axis=2)).max(axis=1)
        positive = radius[radius > 0]
        base = float(np.median(positive)) if positive.size else 1.0
        # Level 0 holds R <= level_ratio * median(R); each further level a factor more.
        with np.errstate(divide="ignore"):
            lvl = np.ceil(np.log(np.maximum(radius, 1e-300) / (level_ratio * base)) / math.log(level_ratio))
        lvl = np.clip(lvl, 0, None).astype(np.int64)
        self._levels: list[tuple[cKDTree, np.ndarray, float]] = []
        for value in np.unique(lvl):
            ids = np.flatnonzero(lvl == value)
            self._levels.append((cKDTree(centroid[ids]), ids, float(radius[ids].max())))
        logger.debug(
            "MeshProximity: %d triangles in %d levels (sizes %s)",
            self.faces.shape[0],
            len(self._levels),
            [ids.size for _, ids, _ in self._levels],
        )

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    def query(
        self, points: Any, *, k: int = 6, chunk_size: int = 100_000, workers: int = -1
    ) -> ClosestPoints:
        """Exact unsigned distance of each point to the nearest triangle.

        Args:
            points: (n, 3) float64, metres, the mesh's frame.
            k: centroids tested first per point and level (doubled where not sufficient).
            chunk_size: points processed together; bounds memory.
            workers: threads, each working on its own chunk (-1: all cores).

        Returns:
            ClosestPoints with distance (n,), closest_points (n, 3), triangle_index (n,).

        Raises:
            ValueError: if ``points`` is empty, not (n, 3), or holds NaN/inf.
        """
        pts = _as_points(points)
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        if workers != -1 and workers < 1:
            raise ValueError(f"workers must be -1 (all cores) or >= 1, got {workers}")
        n = pts.shape[0]
        best = np.full(n, np.inf)
        best_sq = np.full(n, np.inf)
        best_tri = np.full(n, -1, dtype=np.int64)
        best_pt = np.empty((n, 3))
        slices = [slice(s, min(s + chunk_size, n)) for s in range(0, n, chunk_size)]
        n_threads = _n_cores() if workers == -1 else workers
        n_threads = max(1, min(n_threads, len(slices)))

        def run(sl: slice) -> None:
            # Chunks write disjoint slices, so threads need no lock; numpy and
            # cKDTree release the GIL in their inner loops.
            self._query_chunk(pts[sl], best_sq[sl], best_tri[sl], best_pt[sl], k, 1)

        if n_threads == 1:
            for sl in slices:
                run(sl)
        else:
            with concurrent.futures.ThreadPoolExecutor(max_workers=n_threads) as pool:
                list(pool.map(run, slices))
        np.sqrt(best_sq, out=best)
        return ClosestPoints(distance=best, closest_points=best_pt, triangle_index=best_tri)

    # All arrays passed in are views that are updated in place.
    def _query_chunk(self, pts, best_sq, best_tri, best_pt, k0, workers) -> None:
        for tree, ids, r_max in self._levels:
            m = ids.size
            todo = np.arange(pts.shape[0])
            if tree is not self._levels[0][0]:
                # Skip the level for points whose nearest centroid already proves
                # that no triangle of this level can beat the current best.
                d1, _ = tree.query(pts, k=1, workers=workers)
                todo = np.flatnonzero(d1 - r_max < np.sqrt(best_sq))
            k = min(k0, m)
            while todo.size:
                dk, jk = tree.query(pts[todo], k=k, workers=workers)
                dk = dk.reshape(todo.size, k)
                jk = jk.reshape(todo.size, k)
                self._test_pairs(pts, todo, ids[jk], best_sq, best_tri, best_pt)
                if k >= m:
                    break
                unresolved = dk[:, -1] - r_max < np.sqrt(best_sq[todo])
                todo = todo[unresolved]
                k = min(2 * k, m)

    def _test_pairs(self, pts, rows, tri_ids, best_sq, best_tri, best_pt) -> None:
        """Test points ``rows`` against their candidate triangles ``tri_ids`` (len(rows), k)."""
        kk = tri_ids.shape[1]
        step = max(1, _PAIRS_PER_BLOCK // kk)
        for s in range(0, rows.size, step):
            r = rows[s : s + step]
            t = tri_ids[s : s + step].ravel()
            p = np.repeat(pts[r], kk, axis=0)
            q = closest_point_on_triangles(p, self._a[t], self._b[t], self._c[t])
            d2 = ((q - p) ** 2).sum(axis=1).reshape(r.size, kk)
            j = np.argmin(d2, axis=1)
            dmin = d2[np.arange(r.size), j]
            better = dmin < best_sq[r]
            rb = r[better]
            best_sq[rb] = dmin[better]
            flat = np.arange(r.size)[better] * kk + j[better]
            best_tri[rb] = t[flat]
            best_pt[rb] = q[flat]


def point_to_mesh_distance(
    points: Any, vertices: Any, faces: Any, *, k: int = 6, chunk_size: int = 100_000
) -> ClosestPoints:
    """Exact unsigned distance of every point to a triangle mesh.

    Convenience wrapper of :class:`MeshProximity` for one query; build a
    ``MeshProximity`` yourself to measure several clouds against one mesh.

    Args:
        points: (n, 3) float64, metres, the same frame as ``vertices``.
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer, rows of ``vertices``.
        k: centroids tested first per point (doubled where not provably sufficient).
        chunk_size: points processed together; bounds memory.

    Returns:
        ClosestPoints: distance (n,) metres, closest_points (n, 3), triangle_index (n,).

    Raises:
        ValueError: empty or non-finite cloud; empty or malformed mesh.
    """
    pts = _as_points(points)
    return MeshProximity(vertices, faces).query(pts, k=k, chunk_size=chunk_size)


# --------------------------------------------------------------------------
# surface sampling
# --------------------------------------------------------------------------
def triangle_areas(vertices: Any, faces: Any) -> np.ndarray:
    """Area of every triangle.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer.

    Returns:
        (f,) float64, square metres.
    """
    v, f = _as_mesh(vertices, faces)
    tri = v[f]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def _rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer)):
        return np.random.default_rng(0 if rng is None else int(rng))
    raise ValueError(f"rng must be a numpy.random.Generator or an int seed, got {type(rng).__name__}")


def sample_surface(
    vertices: Any, faces: Any, n: int, *, rng: np.random.Generator | int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Draw points uniformly by area on a triangle mesh.

    Triangles are drawn with probability proportional to area, then a point uniformly
    inside each (the square-root parametrisation of Osada et al. 2002, eq. 1).

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer.
        n: number of samples (>= 1).
        rng: a ``numpy.random.Generator`` or an int seed (None: seed 0).

    Returns:
        points: (n, 3) float64, metres, the mesh's frame.
        triangle_index: (n,) int64, the triangle each sample lies on.

    Raises:
        ValueError: if ``n`` < 1 or the mesh has zero total area.
    """
    if int(n) < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    v, f = _as_mesh(vertices, faces)
    gen = _rng(rng)
    area = triangle_areas(v, f)
    total = area.sum()
    if not total > 0:
        raise ValueError("the mesh has zero total area; cannot sample its surface")
    tri_idx = gen.choice(f.shape[0], size=int(n), p=area / total)
    r1 = np.sqrt(gen.random(int(n)))
    r2 = gen.random(int(n))
    t = v[f[tri_idx]]
    pts = (
        (1 - r1)[:, None] * t[:, 0]
        + (r1 * (1 - r2))[:, None] * t[:, 1]
        + (r1 * r2)[:, None] * t[:, 2]
    )
    return pts, tri_idx.astype(np.int64)


# --------------------------------------------------------------------------
# summary
# --------------------------------------------------------------------------
def _to_jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_to_jsonable(x) for x in value]
    if isinstance(value, dict):
        return {k: _to_jsonable(x) for k, x in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN
    return value


@dataclasses.dataclass(frozen=True)
class HeightBand:
    """Coverage of one horizontal band of the mesh surface.

    Attributes:
        z_low: lower edge, metres (inclusive).
        z_high: upper edge, metres (exclusive, except the last band).
        area_m2: estimated mesh surface area inside the band.
        n_samples: surface samples that fell in the band.
        coverage: share of the band's area within ``coverage_distance`` of the cloud
            (NaN when no sample fell in the band).
    """

    z_low: float
    z_high: float
    area_m2: float
    n_samples: int
    coverage: float


@dataclasses.dataclass(frozen=True)
class CloudMeshMetrics:
    """How far a cloud lies from its true mesh and how much of the mesh it covers.

    Distances are metres. "cloud->mesh" is the exact distance of each cloud point to
    the nearest triangle; "mesh->cloud" is the distance of each uniform surface
    sample to its nearest cloud point.

    Attributes:
        n_points: cloud points measured.
        median, p95, p99, max, mean, rms: of the cloud->mesh distance.
        mesh_to_cloud_mean: mean mesh->cloud distance (over surface samples).
        mesh_to_cloud_p95: 95th percentile of the mesh->cloud distance.
        chamfer: symmetric Chamfer distance, the mean of the two directed means:
            ``(mean cloud->mesh + mean mesh->cloud) / 2`` (unsquared, metres).
        coverage_distance: the ``d`` of coverage, metres.
        coverage: share of the mesh area within ``coverage_distance`` of a cloud point.
        coverage_stderr: binomial standard error of ``coverage`` from the sample count,
            ``sqrt(c (1 - c) / n_surface_samples)``.
        n_surface_samples: area-weighted surface samples used for the mesh->cloud side.
        mesh_area_m2: total mesh area.
        band_height: width of the height bands, metres.
        bands: coverage per band of z, from the mesh's lowest vertex up.
    """

    n_points: int
    median: float
    p95: float
    p99: float
    max: float
    mean: float
    rms: float
    mesh_to_cloud_mean: float
    mesh_to_cloud_p95: float
    chamfer: float
    coverage_distance: float
    coverage: float
    coverage_stderr: float
    n_surface_samples: int
    mesh_area_m2: float
    band_height: float
    bands: tuple[HeightBand, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (NaN becomes None)."""
        return _to_jsonable(self)


def cloud_mesh_metrics(
    points: Any,
    vertices: Any,
    faces: Any,
    *,
    coverage_distance: float = 0.002,
    band_height: float = 0.05,
    n_surface_samples: int = 200_000,
    rng: np.random.Generator | int | None = None,
    proximity: MeshProximity | None = None,
) -> CloudMeshMetrics:
    """Measure a cloud against its true mesh.

    Coverage is estimated from ``n_surface_samples`` points drawn uniformly by area:
    each sample is covered when a cloud point lies within ``coverage_distance``. The
    estimator is unbiased with standard error ``sqrt(c (1 - c) / n)`` (at most
    ``0.5 / sqrt(n)``: 0.0011 for the default 200,000); per band the error grows as the
    band holds fewer samples (see ``HeightBand.n_samples``).

    Args:
        points: (n, 3) float64, metres, the same frame as ``vertices``; bands are
            along that frame's z.
        vertices: (v, 3) float64, metres.
        faces: (f, 3) integer.
        coverage_distance: ``d`` in metres (> 0).
        band_height: width of the z bands in metres (> 0).
        n_surface_samples: surface samples for coverage and mesh->cloud (>= 1).
        rng: ``numpy.random.Generator`` or int seed for the surface samples (None: 0).
        proximity: a prebuilt ``MeshProximity`` of this same mesh, to reuse.

    Returns:
        CloudMeshMetrics.

    Raises:
        ValueError: empty or non-finite cloud; empty mesh; non-positive options.
    """
    pts = _as_points(points)
    v, f = _as_mesh(vertices, faces)
    if not coverage_distance > 0:
        raise ValueError(f"coverage_distance must be > 0 metres, got {coverage_distance}")
    if not band_height > 0:
        raise ValueError(f"band_height must be > 0 metres, got {band_height}")
    if int(n_surface_samples) < 1:
        raise ValueError(f"n_surface_samples must be >= 1, got {n_surface_samples}")
    prox = proximity if proximity is not None else MeshProximity(v, f)
    d = prox.query(pts).distance

    samples, _ = sample_surface(v, f, int(n_surface_samples), rng=rng)
    d_back, _ = cKDTree(pts).query(samples, k=1, workers=-1)
    covered = d_back <= coverage_distance
    cov = float(covered.mean())
    ns = samples.shape[0]
    area = float(triangle_areas(v, f).sum())

    z0 = float(v[:, 2].min())
    z1 = float(v[:, 2].max())
    n_bands = max(1, int(math.ceil((z1 - z0) / band_height - 1e-9)))
    band = np.clip(((samples[:, 2] - z0) // band_height).astype(np.int64), 0, n_bands - 1)
    counts = np.bincount(band, minlength=n_bands)
    hits = np.bincount(band, weights=covered.astype(np.float64), minlength=n_bands)
    bands = []
    for i in range(n_bands):
        c = int(counts[i])
        bands.append(
            HeightBand(
                z_low=z0 + i * band_height,
                z_high=z0 + (i + 1) * band_height,
                area_m2=area * c / ns,
                n_samples=c,
                coverage=float(hits[i] / c) if c else float("nan"),
            )
        )
    mean_fwd = float(d.mean())
    mean_back = float(d_back.mean())
    return CloudMeshMetrics(
        n_points=int(pts.shape[0]),
        median=float(np.median(d)),
        p95=float(np.percentile(d, 95)),
        p99=float(np.percentile(d, 99)),
        max=float(d.max()),
        mean=mean_fwd,
        rms=float(np.sqrt(np.mean(d**2))),
        mesh_to_cloud_mean=mean_back,
        mesh_to_cloud_p95=float(np.percentile(d_back, 95)),
        chamfer=0.5 * (mean_fwd + mean_back),
        coverage_distance=float(coverage_distance),
        coverage=cov,
        coverage_stderr=float(math.sqrt(cov * (1 - cov) / ns)),
        n_surface_samples=int(ns),
        mesh_area_m2=area,
        band_height=float(band_height),
        bands=tuple(bands),
    )
