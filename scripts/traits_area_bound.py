"""Leaf area with a perfect segmentation: is the method or the segmentation short?

For each procedural plant (exact organs), one ideal 0.5-degree scan; every point is given
its true leaf (the leaf of its nearest mesh face, :mod:`plantsim.evaluation.organ_match`)
and each true leaf's points are measured alone by the same per-leaf measures
:func:`plantsim.evaluation.traits.extract_traits` uses (the ribbon between the margins
along a midrib; the midrib here the centroids of level sets of the geodesic distance from
the leaf's point nearest the turntable axis, bins of four voxels as in the segmentation:
a rosette leaf's base, since its leaves grow outward from the axis; not a leaflet's or
a drooping leaf's, so the rosettes only).
Printed per plant: the truth, the area ``extract_traits`` reads with its own segmentation,
and the area the true leaves read. Where the true leaves read as short as the found ones,
the shortfall is what the scan sees and how the ribbon reads it, not how the cloud is cut
into leaves. Flat plants are also scanned from the rig :func:`plantsim.rig.fit.fit_rig`
raises over them (leaves seen from above, not edge-on).

    python scripts/traits_area_bound.py                       # rosettes of 12 and 30 leaves
    python scripts/traits_area_bound.py --plants rosette12 --step-deg 1
"""

from __future__ import annotations

import argparse
import dataclasses
import logging

import numpy as np
from scipy.sparse import csgraph

from plantsim.evaluation import traits
from plantsim.evaluation.organ_match import procedural_leaf_labels
from plantsim.evaluation.segmentation import _graph, voxel_centroids
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.fit import fit_rig
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from traits_separability import PLANTS as TEST_PLANTS

# The five plants of the trait tests (scripts/ is on the path when a script runs); here
# the rosettes, whose leaves grow outward from the axis.
PLANTS = {name: make for name, make in TEST_PLANTS.items() if name.startswith("rosette")}


def true_leaf_area(points: np.ndarray, true_label: np.ndarray, n_leaves: int,
                   seg: "traits.segmentation.Segmentation") -> float:
    """Sum over the true leaves of the ribbon area of each one's points alone."""
    v = seg.scale.voxel_m
    total = 0.0
    for k in range(n_leaves):
        lp = points[true_label == k]
        if len(lp) < 10:
            continue
        nodes, _ = voxel_centroids(lp, v)
        graph = _graph(nodes, 2.0 * v, spacing=seg.scale.spacing_m)
        dist = csgraph.dijkstra(graph, directed=False, indices=int(np.argmin(np.hypot(nodes[:, 0], nodes[:, 1]))))
        level = (dist / (4.0 * v)).astype(np.int64)
        midrib = np.array([nodes[level == b].mean(axis=0) for b in np.unique(level)])
        area = traits._leaf_measures(lp, midrib, link=seg.link_m)[2]
        total += 0.0 if np.isnan(area) else area
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=sorted(PLANTS), default=list(PLANTS))
    parser.add_argument("--step-deg", type=float, default=0.5)
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    print(f"ideal {args.step_deg:g}-degree scans: leaf area, truth / found leaves / true leaves (relative error)")
    for name in args.plants:
        plant = PLANTS[name]()
        placed = plant_from_arrays(plant.vertices_m, plant.faces)
        config = RunConfig(ideal=True, scan=StepScan(step_deg=args.step_deg))
        rigs = [("default rig", config.rig)]
        fitted, _ = fit_rig(placed, config.rig, config.lidar)
        if fitted.lidar_height_m > placed.vertices_turntable[:, 2].max():
            rigs.append((f"fitted rig ({fitted.lidar_distance_m:.2f} m out, {fitted.lidar_height_m:.2f} m up)", fitted))
        truth = plant.traits["leaf_area_m2"]
        for rig_name, rig in rigs:
            result = run_scan(dataclasses.replace(config, rig=rig), plant=placed)
            points = result.cloud.plant_only().points_turntable
            found = traits.extract_traits(points).leaf_area_m2
            seg = traits.segment_for_traits(points)
            true = true_leaf_area(seg.points, procedural_leaf_labels(seg.points, plant),
                                  len(plant.traits["leaves"]), seg)
            print(f"{name:10s} {rig_name:38s} {1e4 * truth:7.1f} cm^2 / {1e4 * found:7.1f} "
                  f"({100 * (found / truth - 1):+.0f} %) / {1e4 * true:7.1f} ({100 * (true / truth - 1):+.0f} %)",
                  flush=True)


if __name__ == "__main__":
    main()
