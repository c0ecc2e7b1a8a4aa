"""plantsim.metrics against obviously right references: brute force, spheres, planes."""

import json

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import metrics


def _brute_force_distance(points, vertices, faces):
    """Distance to the nearest triangle by the textbook case split, every triangle.

    Inside the triangle's prism: distance to its plane; otherwise the nearest of its
    three edges (clamped segment projection). Written independently of Ericson's
    region tests used by the library.
    """

    def seg(p, s0, s1):
        d = s1 - s0
        dd = d @ d
        t = np.zeros(len(p)) if dd == 0 else np.clip((p - s0) @ d / dd, 0, 1)
        return np.linalg.norm(p - (s0 + t[:, None] * d), axis=1)

    best = np.full(len(points), np.inf)
    for a, b, c in vertices[faces]:
        edge = np.minimum(np.minimum(seg(points, a, b), seg(points, b, c)), seg(points, c, a))
        n = np.cross(b - a, c - a)
        nn = n @ n
        if nn > 0:
            # Barycentric coordinates of the projection onto the plane.
            proj = points - ((points - a) @ n / nn)[:, None] * n
            lb = (np.cross(c - b, proj - b) @ n) / nn
            lc = (np.cross(a - c, proj - c) @ n) / nn
            la = 1 - lb - lc
            inside = (la >= 0) & (lb >= 0) & (lc >= 0)
            plane = np.abs((points - a) @ n) / np.sqrt(nn)
            edge = np.where(inside, plane, edge)
        best = np.minimum(best, edge)
    return best


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _random_mesh(rng, n_vertices=25, n_faces=40):
    v = rng.normal(size=(n_vertices, 3)) * 0.1
    f = rng.integers(0, n_vertices, size=(n_faces, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    return v, f


def test_random_mesh_matches_brute_force_including_edges_and_vertices():
    rng = np.random.default_rng(7)
    v, f = _random_mesh(rng)
    tri = v[f]
    near_vertices = v + rng.normal(size=v.shape) * 0.01
    near_edges = 0.5 * (tri[:, 0] + tri[:, 1]) + rng.normal(size=(len(f), 3)) * 0.01
    t = rng.random((len(f), 1))
    on_edges = tri[:, 1] + t * (tri[:, 2] - tri[:, 1])
    scattered = rng.normal(size=(500, 3)) * 0.2
    far = rng.normal(size=(20, 3)) * 3.0
    pts = np.vstack([near_vertices, near_edges, on_edges, scattered, far, v])
    got = metrics.point_to_mesh_distance(pts, v, f, chunk_size=100)
    want = _brute_force_distance(pts, v, f)
    np.testing.assert_allclose(got.distance, want, rtol=0, atol=1e-12)
    # The returned closest point and triangle are consistent with the distance.
    np.testing.assert_allclose(
        np.linalg.norm(got.closest_points - pts, axis=1), got.distance, atol=1e-12
    )
    for i in rng.choice(len(pts), 50, replace=False):
        tri_i = got.triangle_index[i]
        one = _brute_force_distance(pts[i : i + 1], v, f[tri_i : tri_i + 1])
        assert one[0] == pytest.approx(got.distance[i], abs=1e-12)


@pytest.fixture(scope="module")
def mixed_sizes():
    """A small sphere under one huge triangle, points near and around, brute-forced once."""
    rng = np.random.default_rng(3)
    small = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    big_v = np.array([[-2.0, -2.0, 0.3], [2.0, -2.0, 0.3], [0.0, 2.0, 0.3]])
    v = np.vstack([small.vertices, big_v])
    n = len(small.vertices)
    f = np.vstack([small.faces, [[n, n + 1, n + 2]]])
    near, _ = metrics.sample_surface(v[:n], small.faces, 600, rng=1)
    pts = np.vstack([rng.normal(size=(600, 3)) * 0.2, near + rng.normal(size=near.shape) * 0.003])
    return v, f, pts, _brute_force_distance(pts, v, f)


@pytest.mark.parametrize(
    "options",
    [
        {},  # defaults: the big triangle sits in a coarser grid
        {"max_box_cells": 1},  # every point searches the coarsest copies
        {"max_cells_per_triangle": 1},  # many grid levels
        {"cell_size": 0.002},  # fine grid: many cells per triangle and per point
        {"cell_size": 5.0},  # one cell holds everything
        {"max_box_cells": 8, "cell_size": 0.001},  # deep pyramids
    ],
)
def test_mixed_triangle_sizes_are_exact_on_every_search_path(mixed_sizes, options):
    v, f, pts, want = mixed_sizes
    prox = metrics.MeshProximity(v, f, backend="grid", **options)
    got = prox.query(pts, chunk_size=300)
    np.testing.assert_allclose(got.distance, want, atol=1e-12)
    if not options:
        assert len(prox._pyramids) >= 2  # the big triangle really sits in a coarser grid


def test_small_batches_and_chunks_change_nothing(mixed_sizes, monkeypatch):
    v, f, pts, want = mixed_sizes
    monkeypatch.setattr(metrics, "_CELLS_PER_BATCH", 7)
    monkeypatch.setattr(metrics, "_PAIRS_PER_BLOCK", 5)
    got = metrics.MeshProximity(v, f, cell_size=0.01, backend="grid").query(pts, chunk_size=37, workers=2)
    np.testing.assert_allclose(got.distance, want, atol=1e-12)


def test_degenerate_triangles_are_measured_as_segments():
    v = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [0.0, 1, 0]])
    f = np.array([[0, 1, 2]])  # collinear: a segment from x=0 to x=2
    pts = np.array([[1.0, 1.0, 0.0], [3.0, 0.0, 0.0], [-1.0, 0.0, 1.0]])
    got = metrics.point_to_mesh_distance(pts, v, f)
    np.testing.assert_allclose(got.distance, [1.0, 1.0, np.sqrt(2)], atol=1e-12)


def test_surface_samples_of_a_sphere_are_on_the_mesh(sphere):
    v, f = sphere
    pts, tri = metrics.sample_surface(v, f, 20_000, rng=1)
    got = metrics.point_to_mesh_distance(pts, v, f)
    assert got.distance.max() < 1e-12


@pytest.mark.parametrize("shift", [0.001, 0.01, 0.3])
def test_shift_along_the_face_normal_is_the_distance(sphere, shift):
    # For a convex polyhedron a point pushed outward along its face's normal has
    # that face point as nearest point, so the distance is exactly the push.
    v, f = sphere
    pts, tri = metrics.sample_surface(v, f, 5_000, rng=2)
    t = v[f[tri]]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.sign(np.einsum("ij,ij->i", n, pts))[:, None]  # outward
    got = metrics.point_to_mesh_distance(pts + shift * n, v, f)
    np.testing.assert_allclose(got.distance, shift, rtol=1e-9)
    np.testing.assert_allclose(got.closest_points, pts, atol=1e-9)


def _plane(size=1.0, n=20, vertical=False):
    g = np.linspace(0, size, n + 1)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    if vertical:
        v = v[:, [0, 2, 1]]  # the plane x-z, z from 0 to size
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.vstack([np.column_stack([a.ravel(), b.ravel(), c.ravel()]),
                   np.column_stack([a.ravel(), c.ravel(), d.ravel()])])
    return v, f


def test_chamfer_of_identical_sets_is_zero():
    v, f = _plane()
    cloud, _ = metrics.sample_surface(v, f, 50_000, rng=5, by_triangle=True)
    m = metrics.cloud_mesh_metrics(cloud, v, f, n_surface_samples=50_000, rng=5)
    assert m.chamfer < 1e-12
    assert m.coverage == 1.0
    assert m.max < 1e-12


def test_coverage_of_a_half_sampled_plane_is_about_half():
    v, f = _plane()
    g = np.arange(0, 0.5 + 1e-9, 0.002)
    h = np.arange(0, 1 + 1e-9, 0.002)
    xx, yy = np.meshgrid(g, h, indexing="ij")
    cloud = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    d = 0.005
    m = metrics.cloud_mesh_metrics(cloud, v, f, coverage_distance=d, n_surface_samples=50_000, rng=0)
    # Covered: x <= 0.5 + d, i.e. 0.505 of the area; 4 standard errors of slack.
    assert m.coverage == pytest.approx(0.5 + d, abs=4 * m.coverage_stderr)
    assert 0 < m.coverage_stderr < 0.5 / np.sqrt(m.n_surface_samples) + 1e-12
    assert m.mesh_area_m2 == pytest.approx(1.0)
    assert m.median == 0.0


def test_height_bands_see_the_missing_top():
    v, f = _plane(vertical=True)
    g = np.arange(0, 1 + 1e-9, 0.002)
    h = np.arange(0, 0.5 + 1e-9, 0.002)
    xx, zz = np.meshgrid(g, h, indexing="ij")
    cloud = np.column_stack([xx.ravel(), np.zeros(xx.size), zz.ravel()])
    m = metrics.cloud_mesh_metrics(
        cloud, v, f, coverage_distance=0.003, band_height=0.25, n_surface_samples=50_000, rng=0
    )
    assert len(m.bands) == 4
    cov = [b.coverage for b in m.bands]
    assert cov[0] == 1.0 and cov[1] > 0.98 and cov[2] < 0.02 and cov[3] == 0.0
    assert sum(b.area_m2 for b in m.bands) == pytest.approx(1.0)
    # Only the cloud's top row, at z = 0.5 exactly, opens the third band.
    assert [b.n_points for b in m.bands][2:] == [len(g), 0]
    assert sum(b.n_points for b in m.bands) == len(cloud)
    assert m.bands[0].median == 0.0 and np.isnan(m.bands[3].median)
    assert m.bands[0].z_low == 0.0 and m.bands[-1].z_high == pytest.approx(1.0)


def test_summary_statistics_of_a_known_offset(sphere):
    v, f = sphere
    pts, tri = metrics.sample_surface(v, f, 4_000, rng=3)
    n = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    offsets = np.where(np.arange(len(pts)) % 2 == 0, 0.001, 0.003)
    # Push along the radial direction: close to the face normal on a fine sphere,
    # so the distance is within a hair of the offset (checked loosely).
    m = metrics.cloud_mesh_metrics(pts + offsets[:, None] * n, v, f, n_surface_samples=10_000)
    assert m.mean == pytest.approx(0.002, rel=0.01)
    assert m.rms == pytest.approx(np.sqrt(0.5 * (0.001**2 + 0.003**2)), rel=0.01)
    assert m.max == pytest.approx(0.003, rel=0.01)
    assert m.chamfer == pytest.approx(0.5 * (m.mean + m.mesh_to_cloud_mean))


def test_same_seed_same_metrics_and_json_round_trip(sphere):
    v, f = sphere
    pts, _ = metrics.sample_surface(v, f, 3_000, rng=9)
    a = metrics.cloud_mesh_metrics(pts, v, f, n_surface_samples=5_000, rng=np.random.default_rng(4))
    b = metrics.cloud_mesh_metrics(pts, v, f, n_surface_samples=5_000, rng=np.random.default_rng(4))
    assert a == b
    d = a.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert set(d) >= {"median", "p95", "p99", "max", "mean", "rms", "chamfer", "coverage", "bands"}


def test_sample_surface_is_deterministic_and_area_weighted():
    v, f = _plane(n=2)
    a, ta = metrics.sample_surface(v, f, 1000, rng=11)
    b, tb = metrics.sample_surface(v, f, 1000, rng=11)
    assert np.array_equal(a, b) and np.array_equal(ta, tb)
    assert np.all((a[:, :2] >= 0) & (a[:, :2] <= 1))


@pytest.mark.parametrize("by_triangle", [False, True])
def test_samples_fall_by_area_and_uniformly_inside_each_triangle(by_triangle):
    # Areas 0.5, 1.5 (three times as large) and 0 (degenerate): 1/4, 3/4, none.
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 1], [5, 0, 1], [2, 1, 1],
                  [0, 0, 2], [1, 0, 2], [2, 0, 2]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    n = 40_000
    pts, tri = metrics.sample_surface(v, f, n, rng=4, by_triangle=by_triangle)
    counts = np.bincount(tri, minlength=3)
    assert counts[2] == 0
    sigma = np.sqrt(n * 0.25 * 0.75)
    assert abs(counts[0] - n / 4) < 5 * sigma and abs(counts[1] - 3 * n / 4) < 5 * sigma
    # On their triangle, and uniform inside it: the mean is the centroid
    # (standard error about 0.3 / sqrt(count) of the triangle's size).
    assert metrics.point_to_mesh_distance(pts, v, f).distance.max() < 1e-12
    for t in (0, 1):
        mean = pts[tri == t].mean(axis=0)
        np.testing.assert_allclose(mean, v[f[t]].mean(axis=0), atol=5 * 1.5 / np.sqrt(counts[t]))
    assert np.all(np.diff(tri) >= 0) if by_triangle else np.any(np.diff(tri) < 0)


def test_validation_errors_say_what_arrived(sphere):
    v, f = sphere
    with pytest.raises(ValueError, match=r"points is empty \(shape \(0, 3\)\)"):
        metrics.point_to_mesh_distance(np.zeros((0, 3)), v, f)
    bad = np.zeros((5, 3))
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"points holds 1 non-finite rows .* first at row 3"):
        metrics.cloud_mesh_metrics(bad, v, f)
    with pytest.raises(ValueError, match=r"points must have shape \(n, 3\), got shape \(4, 2\)"):
        metrics.point_to_mesh_distance(np.zeros((4, 2)), v, f)
    with pytest.raises(ValueError, match=r"faces is empty"):
        metrics.point_to_mesh_distance(np.zeros((1, 3)), v, np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match=r"vertices is empty"):
        metrics.MeshProximity(np.zeros((0, 3)), f)
    with pytest.raises(ValueError, match=r"faces index vertices 0\.\.2, got indices from 0 to 5"):
        metrics.MeshProximity(np.zeros((3, 3)), [[0, 1, 5]])
    with pytest.raises(ValueError, match=r"faces must hold integer"):
        metrics.MeshProximity(np.zeros((3, 3)), [[0.0, 1.0, 2.0]])
    with pytest.raises(ValueError, match=r"coverage_distance must be > 0 metres, got 0"):
        metrics.cloud_mesh_metrics(np.zeros((1, 3)), v, f, coverage_distance=0)
    other = metrics.MeshProximity(*_plane())
    with pytest.raises(ValueError, match=r"proximity was built for another mesh"):
        metrics.cloud_mesh_metrics(np.zeros((1, 3)), v, f, proximity=other)
    with pytest.raises(ValueError, match=r"rng must be a numpy.random.Generator or an int seed"):
        metrics.sample_surface(v, f, 10, rng="seed")


def test_libigl_backend_matches_the_reference_grid_kernel():
    pytest.importorskip("igl", reason="libigl not installed (pip install libigl)")
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(5)
    pts = rng.normal(0, 0.06, (3000, 3))
    reference = metrics.MeshProximity(v, f, backend="grid").query(pts)
    seen = []
    fast = metrics.MeshProximity(v, f, backend="igl")
    assert fast.backend == "igl"
    got = fast.query(pts, chunk_size=1000, progress=lambda done, total: seen.append((done, total)))
    np.testing.assert_allclose(got.distance, reference.distance, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got.closest_points, reference.closest_points, atol=1e-12)
    assert seen == [(1000, 3000), (2000, 3000), (3000, 3000)]


def test_grid_backend_reports_progress_and_unknown_backend_is_refused():
    v, f = _plane()
    seen = []
    metrics.MeshProximity(v, f, backend="grid").query(
        np.zeros((10, 3)) + 0.1, chunk_size=4, workers=1,
        progress=lambda done, total: seen.append((done, total)))
    assert seen == [(4, 10), (8, 10), (10, 10)]
    with pytest.raises(ValueError, match="backend must be 'auto', 'igl' or 'grid', got 'embree'"):
        metrics.MeshProximity(v, f, backend="embree")
