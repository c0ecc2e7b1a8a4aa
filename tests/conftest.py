"""Shared in-memory fixtures: small meshes and a brute-force ray-triangle reference."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

REPO_ROOT = Path(__file__).resolve().parents[1]


def load_script(name: str):
    """The module of ``scripts/<name>.py`` (scripts are not a package), loaded fresh."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# The hardware tests: the emulators answer the drivers from threads of the test process.
_HARDWARE_MODULES = ("test_dxl_", "test_urg_", "test_rig_scan", "test_rig_urg")
# GIL switch interval for them, s (Python's default is 5 ms). See docs/servo-timing.md.
HARDWARE_SWITCH_INTERVAL_S = 0.0005


def turntable_first_hits(rng, cylinders=(), *, plates=(), sigma=0.012, n_angles=360, lidar=(0.35, 0.15),
                         beside_m=0.0, elev_deg=(-25.0, 50.0, 0.35), which=False):
    """A turntable scan ray-cast exactly: the first hits of a vertical fan (beams every
    ``elev_deg[2]`` degrees) from a LiDAR ``lidar[0]`` out and ``lidar[1]`` up (``beside_m``
    to the side of the axis) at each of ``n_angles`` turntable angles, on vertical
    cylinders (x, y, radius, height; from z = 0) and flat plates (origin, edge, edge);
    each moved along its beam by N(0, sigma). Returns points and noise vectors, and with
    ``which=True`` also each point's object (cylinders from 0, then plates)."""
    theta = np.radians(np.arange(n_angles) * 360.0 / n_angles)
    alpha = np.radians(np.arange(*elev_deg))
    th, al = (g.ravel() for g in np.meshgrid(theta, alpha, indexing="ij"))
    c, s = np.cos(-th), np.sin(-th)  # the plant turns by theta: the sensor by -theta
    sensor = np.column_stack([lidar[0] * c - beside_m * s, lidar[0] * s + beside_m * c, np.full_like(th, lidar[1])])
    d = np.column_stack([-np.cos(al) * c, -np.cos(al) * s, np.sin(al)])
    t_first = np.full(len(th), np.inf)
    obj = np.full(len(th), -1)
    for i, (x, y, r, h) in enumerate(cylinders):
        ox, oy = sensor[:, 0] - x, sensor[:, 1] - y
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = 2 * (ox * d[:, 0] + oy * d[:, 1])
        disc = b * b - 4 * a * (ox ** 2 + oy ** 2 - r ** 2)
        t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a), np.inf)
        z = sensor[:, 2] + t * d[:, 2]
        t = np.where((z >= 0) & (z <= h) & (t > 0), t, np.inf)
        obj[t < t_first] = i
        t_first = np.minimum(t_first, t)
    for j, (origin, e1, e2) in enumerate(plates):
        origin, e1, e2 = (np.asarray(v, dtype=np.float64) for v in (origin, e1, e2))
        n = np.cross(e1, e2)
        denom = d @ n
        t = ((origin - sensor) @ n) / np.where(np.abs(denom) > 1e-12, denom, np.nan)
        q = sensor + t[:, None] * d - origin
        u, v = np.linalg.solve(np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]]), np.vstack([q @ e1, q @ e2]))
        on = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1) & (t > 0)
        t = np.where(on, t, np.inf)
        obj[t < t_first] = len(cylinders) + j
        t_first = np.minimum(t_first, t)
    hit = np.isfinite(t_first)
    rng_m = t_first[hit] + rng.normal(0.0, sigma, hit.sum())
    out = sensor[hit] + rng_m[:, None] * d[hit], sigma * d[hit]
    return out + (obj[hit],) if which else out


def split_one_cup(split_step, pts, *, junction, cell_m, spacing_m, min_leaf_m):
    """Runs a cup split step (``segmentation._split_petals`` or ``_split_smooth_surfaces``)
    on ``pts`` as one found leaf, its midrib from ``junction`` to the points' mean and a
    base width the split must drop, on a clean cloud's voxel ``cell_m`` (level-set bins
    four voxels) and point spacing ``spacing_m``. Returns the step's return."""
    midrib = np.vstack([junction, pts.mean(axis=0)])
    return split_step(pts, np.zeros(len(pts), dtype=np.int64), [midrib], (0,), {0: np.ones(3)}, cell=cell_m,
                      bin_w=4 * cell_m, min_leaf=min_leaf_m, spacing=spacing_m)


def assert_cup_split_into(split, truth, n_leaves, *, min_share, junction):
    """Checks a cup split (``segmentation._split_petals``' or ``_split_smooth_surfaces``'
    return ``split``) against each point's true leaf ``truth`` (0..n_leaves - 1): every
    true leaf a found leaf of its own, holding ``min_share`` or more of its points, its
    midrib from ``junction``, and the merged leaf's base widths gone. Returns the midribs."""
    label, midribs, groups, base_widths, added = split
    assert added == n_leaves - 1 and len(midribs) == n_leaves
    assert sorted(set(groups)) == list(range(n_leaves))  # each a leaf of its own
    assert base_widths == {}  # the merged leaf's base widths were not its parts'
    found = []
    for i in range(n_leaves):
        counts = np.bincount(truth[label == i], minlength=n_leaves)
        assert counts.max() >= min_share * counts.sum(), counts
        found.append(int(counts.argmax()))
        assert np.allclose(midribs[i][0], junction)  # from the junction
    assert sorted(found) == list(range(n_leaves))
    return midribs


def brute_force_first_hit(origin: np.ndarray, dirs: np.ndarray, vertices: np.ndarray,
                          faces: np.ndarray) -> np.ndarray:
    """Möller-Trumbore against every triangle: the obviously right reference.

    Returns (n,) distances, inf for a miss.
    """
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    e1, e2 = b - a, c - a
    out = np.full(len(dirs), np.inf)
    s = origin - a
    q = np.cross(s, e1)
    for k, d in enumerate(dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-18
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        u = np.einsum("ij,ij->i", s, p) * inv
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", q, e2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if hit.any():
            out[k] = t[hit].min()
    return out


def point_triangle_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact unsigned distance from each point to the nearest triangle (brute force)."""
    tri = trimesh.Trimesh(vertices, faces, process=False)
    from trimesh.triangles import closest_point

    best = np.full(len(points), np.inf)
    triangles = tri.triangles
    for i, p in enumerate(points):
        cp = closest_point(triangles, np.repeat(p[None], len(triangles), axis=0))
        best[i] = np.linalg.norm(cp - p, axis=1).min()
    return best


@pytest.fixture
def box_mesh():
    """A 40 x 60 x 120 mm box mesh (exact planar faces), centred at the origin."""
    m = trimesh.creation.box(extents=[0.04, 0.06, 0.12])
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.fixture(autouse=True)
def _emulator_threads_get_the_gil(request):
    """In the hardware tests, hand the GIL over every 0.5 ms instead of every 5 ms.

    An emulator thread that has bytes to answer waits for the GIL while another
    thread of the process runs Python (the servo emulator's physics, the URG
    emulator's cast, the encoder poller, the scan): one exchange needs several
    handovers, each up to the switch interval. Measured with two busy loops and a
    pure-Python thread beside a bus-clock emulator (1000 reads): the worst round trip
    136 ms at 5 ms, 23 ms at 0.5 ms, 33 ms with the emulator in its own process.
    The drivers' scheduler allowances (0.3-2 s in these tests) keep their margin.
    """
    if not request.module.__name__.rpartition(".")[2].startswith(_HARDWARE_MODULES):
        yield
        return
    previous = sys.getswitchinterval()
    sys.setswitchinterval(HARDWARE_SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(previous)


@pytest.fixture
def emulator():
    """A Dynamixel emulator (ID 1) on its bus clock: the exchanges, not the wall clock, move its time."""
    from plantsim.hardware.dynamixel.emulator import DynamixelEmulator

    with DynamixelEmulator(ids=(1,), clock="bus") as emu:
        yield emu


@pytest.fixture
def cylinder(tmp_path):
    """A 5 cm radius, 0.3 m tall 64-sided cylinder written as an STL; its path."""
    import trimesh

    path = tmp_path / "cylinder.stl"
    trimesh.creation.cylinder(radius=0.05, height=0.3, sections=64).export(path)
    return str(path)
