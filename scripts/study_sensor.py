"""Study: how far a realistic URG-04LX cloud lies from the true plant, vs an ideal one.

Scans a plant twice through the ordinary pipeline (``--ideal`` and the default
sensor model), keeps the points on the plant and prints the distribution of
their distance to the mesh surface; saves a PNG of both clouds side by side,
coloured by that distance.

    PYTHONPATH=. python scripts/study_sensor.py [mesh] [--up z] [--step-deg 1] [--png out.png]

The mesh defaults to the bundled ``assets/maize.stl``; the original tool's
maize works too: ``../shared/seed-rig/maize.stl --up y``.

Point-to-mesh distance: exact point-triangle distances (trimesh) to the
triangles owning the nearest surface samples (a 2 mm barycentric grid in a
cKDTree), certified exact per point (the nearest triangle provably among the
candidates). The project's exact module is plantsim.evaluation.metrics.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from plantsim.scan.config import PlantOptions, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan


def surface_samples(triangles: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A barycentric grid on every triangle, n = ceil(longest edge / spacing) steps.

    Every point of a triangle is within ``spacing_m`` of one of its samples.

    Returns:
      samples (s, 3) float64 metres, triangle index (s,) int64.
    """
    edges = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2).max(axis=1)
    steps = np.maximum(1, np.ceil(edges / spacing_m)).astype(int)
    samples, owner = [], []
    for n in np.unique(steps):
        ids = np.nonzero(steps == n)[0]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        bary = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n  # (g, 3)
        samples.append(np.einsum("gk,tkd->tgd", bary, triangles[ids]).reshape(-1, 3))
        owner.append(np.repeat(ids, len(bary)))
    return np.concatenate(samples), np.concatenate(owner)


def point_to_mesh_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *,
                           spacing_m: float = 0.002, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each point to a triangle mesh (exact up to float rounding).

    Candidates are the triangles owning the k surface samples nearest to a
    point; the result is exact when the k-th sample is farther than the best
    distance plus the sample spacing (the nearest triangle then has a sample
    among them). Points that fail are retried once with 4k samples; for those
    still failing (far from the surface) the true distance lies in
    [min(best, k-th sample distance - spacing), best], and ``gap`` is the
    width of that bracket (0 where certified).

    Args:
      points: (n, 3) float64 metres.
      vertices: (m, 3) float64 metres, same frame.
      faces: (f, 3) int vertex indices.

    Returns:
      distance (n,) float64 metres (an upper bound where not certified),
      gap (n,) float64 metres.
    """
    import trimesh

    triangles = vertices[faces]
    samples, owner = surface_samples(triangles, spacing_m)
    tree = cKDTree(samples)
    best = np.full(len(points), np.inf)
    gap = np.zeros(len(points))
    todo = np.arange(len(points))
    for _ in range(2):
        k = min(k, len(samples))
        sample_dist, idx = tree.query(points[todo], k=k)
        sample_dist, idx = sample_dist.reshape(len(todo), k), idx.reshape(len(todo), k)
        for lo in range(0, len(todo), 20000):  # bounded memory
            part = slice(lo, lo + 20000)
            cand, pts = owner[idx[part]], points[todo[part]]
            pts_rep = np.repeat(pts, k, axis=0)
            closest = trimesh.triangles.closest_point(triangles[cand.ravel()], pts_rep)
            d = np.linalg.norm(closest - pts_rep, axis=1).reshape(len(pts), k).min(axis=1)
            best[todo[part]] = np.minimum(best[todo[part]], d)
        lower = np.minimum(best[todo], sample_dist[:, -1] - spacing_m)
        gap[todo] = best[todo] - np.maximum(lower, 0.0)
        todo = todo[gap[todo] > 0]
        k *= 4
    return best, gap


def describe(name: str, distance_m: np.ndarray, gap_m: np.ndarray) -> None:
    mm = distance_m * 1000
    q = np.percentile(mm, [50, 90, 99])
    print(f"{name:10s} {len(mm):8,d} {mm.mean():7.2f} {np.sqrt((mm ** 2).mean()):7.2f} "
          f"{q[0]:7.2f} {q[1]:7.2f} {q[2]:7.2f} {mm.max():8.2f} {(mm > 10).mean() * 100:7.2f} "
          f"{(gap_m == 0).mean() * 100:6.1f} {gap_m.max() * 1000:6.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="assets/maize.stl")
    parser.add_argument("--up", default="z", help="the mesh's up axis (bundled: z, seed rig: y)")
    parser.add_argument("--units", default="m")
    parser.add_argument("--step-deg", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--png", default="study_sensor.png", help="picture of both clouds")
    args = parser.parse_args(argv)
    if not Path(args.mesh).is_file():
        print(f"study_sensor: mesh not found: {args.mesh} (the bundled plants come with the "
              f"'plants' branch; try ../shared/seed-rig/maize.stl --up y)", file=sys.stderr)
        return 2

    results = {}
    for label, ideal in (("ideal", True), ("realistic", False)):
        config = RunConfig(plant=PlantOptions(mesh=args.mesh, up=args.up, units=args.units),
                           scan=StepScan(step_deg=args.step_deg), ideal=ideal, seed=args.seed)
        result = run_scan(config)
        cloud = result.cloud.plant_only()
        plant = result.plant
        dist, gap = point_to_mesh_distance(cloud.points_turntable, plant.vertices_turntable,
                                                 plant.faces)
        results[label] = (cloud, dist, gap, result)

    raw = results["realistic"][3].raw
    print(f"plant {args.mesh}: {results['ideal'][3].plant.n_faces:,} triangles; "
          f"{raw.n_lines} lines x {raw.n_beams} beams, seed {args.seed}")
    print(f"realistic beams by status: {raw.counts()['by_status']}")
    print("point-to-mesh distance of the plant points, mm (> 10 mm: share of points farther "
          "than 10 mm, %; cert: share with the nearest triangle proven, %; gap: the largest "
          "uncertainty of the others, mm)")
    print(f"{'cloud':10s} {'points':>8s} {'mean':>7s} {'rms':>7s} {'median':>7s} {'p90':>7s} "
          f"{'p99':>7s} {'max':>8s} {'> 10 mm':>7s} {'cert':>6s} {'gap':>6s}")
    for label, (_, dist, gap, _) in results.items():
        describe(label, dist, gap)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 7), sharex=True, sharey=True,
                             layout="constrained")
    vmax = 30.0
    for ax, (label, (cloud, dist, _, _)) in zip(axes, results.items()):
        p = cloud.points_turntable
        order = np.argsort(dist)
        sc = ax.scatter(p[order, 0], p[order, 2], c=np.minimum(dist[order] * 1000, vmax), s=0.3,
                        cmap="viridis", vmin=0, vmax=vmax, rasterized=True)
        ax.set_title(f"{label}: {len(p):,} plant points\nmedian distance "
                     f"{np.median(dist) * 1000:.2f} mm, p90 {np.percentile(dist, 90) * 1000:.1f} mm")
        ax.set_xlabel("x, turntable frame (m)")
        ax.set_aspect("equal")
    axes[0].set_ylabel("z (m)")
    fig.colorbar(sc, ax=axes, shrink=0.8, label="distance to the mesh (mm, clipped at 30)")
    fig.suptitle("URG-04LX-UG01 on the turntable: ideal vs realistic sensor model (side view)")
    fig.savefig(args.png, dpi=150)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
