"""Leaf area with a perfect segmentation: is the method or the segmentation short?

For each procedural plant (exact organs), an ideal 0.5-degree scan and a realistic 1-degree
one; every point is given its true leaf (:mod:`plantsim.evaluation.organ_match`: the leaf of
its nearest mesh face, and on the realistic scan of the face its beam hit, since the range
noise moves a point along its beam and its nearest face is where the noise put it) and each
true leaf's points are measured alone (:func:`plantsim.evaluation.traits.measure_labelled_leaves`:
the per-leaf measures :func:`plantsim.evaluation.traits.extract_traits` uses, the ribbon between
the margins along a midrib, on the realistic scan with each cross-section's width read across
its beams where they can; the midrib from the leaf's base on the mesh).
Printed per plant and scan: the truth, the area ``extract_traits`` reads with its own
segmentation, and the area the true leaves read. Where the true leaves read as far off as
the found ones, the error is what the scan sees and how the ribbon reads it, not how the
cloud is cut into leaves. Flat plants are also scanned from the rig
:func:`plantsim.rig.fit.fit_rig` raises over them (leaves seen from above, not edge-on).

    python scripts/traits_area_bound.py                       # five plants, both scans
    python scripts/traits_area_bound.py --plants rosette12 --settings ideal --step-deg 1
"""

from __future__ import annotations

import argparse
import dataclasses
import logging

import numpy as np

from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import scan_range_noise
from plantsim.evaluation.organ_match import procedural_leaf_labels
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import PART_LEAF
from plantsim.rig.fit import fit_rig
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from traits_separability import PLANTS  # the five plants of the trait tests (scripts/ is on the path)

DEFAULT_STEP = {"ideal": 0.5, "realistic": 1.0}


def leaf_bases(plant, T_turntable_mesh: np.ndarray) -> np.ndarray:
    """(k, 3) each true leaf's base in the turntable frame: its first vertex in the
    generator's arrays, a corner of the row of vertices it starts with at its insertion
    (the generators build each leaf from its base row up), placed as the scan placed the
    plant (the placed mesh's own vertex order need not be the generator's)."""
    n_leaves = len(plant.traits["leaves"])
    first = np.full(n_leaves, np.iinfo(np.int64).max)
    leaf_faces = np.flatnonzero(plant.face_part == PART_LEAF)
    np.minimum.at(first, plant.face_organ[leaf_faces], plant.faces[leaf_faces].min(axis=1))
    base_mesh = plant.vertices_m[first]
    return base_mesh @ T_turntable_mesh[:3, :3].T + T_turntable_mesh[:3, 3]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=sorted(PLANTS), default=list(PLANTS))
    parser.add_argument("--settings", nargs="+", choices=sorted(DEFAULT_STEP), default=list(DEFAULT_STEP))
    parser.add_argument("--step-deg", type=float, help="one step for every scan (default 0.5 ideal, 1 realistic)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    print("leaf area: truth / found leaves / true leaves (relative error)")
    for setting in args.settings:
        step = args.step_deg or DEFAULT_STEP[setting]
        for name in args.plants:
            plant = PLANTS[name]()
            placed = plant_from_arrays(plant.vertices_m, plant.faces)
            if len(placed.faces) != len(plant.faces):
                raise SystemExit(f"{name}: placing dropped faces, the organ labels no longer line up")
            config = RunConfig(ideal=setting == "ideal", scan=StepScan(step_deg=step))
            rigs = [("default rig", config.rig)]
            fitted, _ = fit_rig(placed, config.rig, config.lidar)
            if fitted.lidar_height_m > placed.vertices_turntable[:, 2].max():
                rigs.append((f"fitted rig ({fitted.lidar_distance_m:.2f} m out, {fitted.lidar_height_m:.2f} m up)",
                             fitted))
            truth = plant.traits["leaf_area_m2"]
            bases = leaf_bases(plant, placed.T_turntable_mesh)
            for rig_name, rig in rigs:
                result = run_scan(dataclasses.replace(config, rig=rig), plant=placed)
                points = result.cloud.plant_only().points_turntable
                noise = None if setting == "ideal" else scan_range_noise(result)[0]
                found = traits.extract_traits(points, range_noise_m=noise).leaf_area_m2
                labels = procedural_leaf_labels(points, plant, range_noise_m=noise)
                true = traits.measure_labelled_leaves(points, labels, leaf_bases_m=bases,
                                                      range_noise_m=noise).leaf_area_m2
                print(f"{setting:9s} {step:g} deg  {name:10s} {rig_name:38s} {1e4 * truth:7.1f} cm^2 / "
                      f"{1e4 * found:7.1f} ({100 * (found / truth - 1):+.0f} %) / {1e4 * true:7.1f} "
                      f"({100 * (true / truth - 1):+.0f} %)", flush=True)


if __name__ == "__main__":
    main()
