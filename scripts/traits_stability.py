"""How far the traits move when the cloud moves by a micrometre.

A point cloud is read to finite precision: a LAS file keeps coordinates on a 0.01 mm grid,
another build of the ray caster may differ in the last bits of a float. Traits are measured
on the LAS grid (``plantsim.evaluation.traits.on_file_grid``), so the cloud as scanned and
its LAS file read the same; a jitter larger than the grid's half step (1 um) still moves
points across it. For each procedural plant (exact truth), one ideal 0.5-degree and one
realistic 1-degree scan; the traits of the cloud as scanned, of the same cloud rounded to
the LAS grid (``plantsim.cloud.export.LAS_SCALE_M``), and of the cloud moved by a uniform
+-1 um jitter (three seeds). Printed per plant and setting: height, leaf count and leaf
area (relative errors) for each, their range, and the range the shifted voxel grids read
on the cloud as scanned (``PlantTraits.leaf_counts_over_grids``: the segmentation's own
uncertainty).

    python scripts/traits_stability.py                 # all five plants, about 2 min
    python scripts/traits_stability.py --plants maize --jitter-um 0.1
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from plantsim.cloud.export import LAS_SCALE_M
from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import scan_beam_gaps, scan_range_noise
from plantsim.plant.mesh import plant_from_arrays
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from traits_separability import PLANTS as TEST_PLANTS

PLANTS = TEST_PLANTS  # the five plants of the trait tests (scripts/ is on the path when a script runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=sorted(PLANTS), default=list(PLANTS))
    parser.add_argument("--jitter-um", type=float, default=1.0, help="half-width of the uniform jitter, micrometres")
    parser.add_argument("--seeds", type=int, default=3, help="jittered copies")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    print("cloud: as scanned | LAS grid | jittered (seeds 1..n); height / leaves / area against the truth")
    for name in args.plants:
        plant = PLANTS[name]()
        truth = plant.traits
        for setting, ideal, step in (("ideal 0.5 deg", True, 0.5), ("realistic 1 deg", False, 1.0)):
            result = run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=step)),
                              plant=plant_from_arrays(plant.vertices_m, plant.faces))
            points = result.cloud.plant_only().points_turntable
            noise, gaps = scan_range_noise(result)[0], scan_beam_gaps(result)
            clouds = [points, np.round(points / LAS_SCALE_M) * LAS_SCALE_M]
            clouds += [points + np.random.default_rng(seed).uniform(-1e-6, 1e-6, points.shape) * args.jitter_um
                       for seed in range(1, args.seeds + 1)]
            rows = []
            for cloud in clouds:
                t = traits.extract_traits(cloud, range_noise_m=noise, beam_gaps_m=gaps)
                rows.append((100 * (t.height_m / truth["height_m"] - 1), t.leaf_count,
                             100 * (t.leaf_area_m2 / truth["leaf_area_m2"] - 1)))
                if len(rows) == 1:
                    grid_counts = t.leaf_counts_over_grids
                    grid_areas = [100 * (x / truth["leaf_area_m2"] - 1) for x in t.leaf_areas_over_grids_m2
                                  if np.isfinite(x)]
            h, n, a = (np.array(col, dtype=float) for col in zip(*rows))
            print(f"{name:10s} {setting:16s} height {' '.join(f'{x:+.1f}' for x in h)} % | "
                  f"leaves {' '.join(str(int(x)) for x in n)} /{len(set(traits.true_leaf_groups(truth['leaves'])))} | "
                  f"area {' '.join(f'{x:+.0f}' for x in a)} % | range: leaves {int(n.min())}-{int(n.max())}, "
                  f"area {a.min():+.0f}..{a.max():+.0f} % | over {len(grid_counts)} grids: leaves "
                  f"{min(grid_counts)}-{max(grid_counts)}, area "
                  f"{f'{min(grid_areas):+.0f}..{max(grid_areas):+.0f} %' if grid_areas else 'n/a'}", flush=True)


if __name__ == "__main__":
    main()
