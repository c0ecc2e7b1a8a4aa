"""Can misses (gap fraction) recover the leaf area no beam reaches? A voxel study.

LiDAR leaf-area methods correct for occlusion with the beams that pass through the
canopy: voxel-based canopy profiling (Hosoi & Omasa 2006, IEEE TGRS 44:3610) counts, per
horizontal layer, the voxels a beam hit and those it only passed through, and gives the
voxels no beam entered the layer's share of hits. Here, per procedural plant, one
pipeline scan; every beam (returns and misses, from the LiDAR's origin at its line's
turntable angle) is walked through a voxel grid over the plant (steps of a third of a
voxel); then:

- hidden: the share of the plant's convex hull (voxel centres) that no beam entered;
- raster: the area of the voxels holding plant points, each ``voxel^2 / |n|_1`` (``n``
  the unit normal of its points' 12-neighbour plane fits: the voxels a plane crosses
  per unit area), against the plant's true leaf area (the stems are counted too);
- corrected: each layer's raster area times (entered + hidden) / entered voxels of the
  hull in that layer, the canopy-profiling extrapolation.

The printed figures say whether the hidden surface lies in voxels no beam enters (then
the correction recovers it) or in voxels beams do enter beside it (then it cannot).

    python scripts/traits_gap_fraction.py                      # ideal 0.5 deg, 4 and 8 mm voxels
    python scripts/traits_gap_fraction.py --plants rosette12 --realistic
"""

from __future__ import annotations

import argparse
import dataclasses
import logging

import numpy as np
from scipy.spatial import Delaunay

from plantsim.cloud.reconstruct import base_to_turntable, reconstruct
from plantsim.evaluation import traits
from plantsim.evaluation.knn import NeighbourIndex
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.scene import HitClass
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import BeamStatus
from traits_separability import PLANTS


def beams_turntable(result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every beam's origin and end (its return, or ``range_max_m`` for a miss) in the
    turntable frame, and whether it returned from the plant."""
    raw = result.raw
    ok = raw.status == BeamStatus.OK
    every = dataclasses.replace(raw, range_m=np.where(ok, raw.range_m, result.config.lidar.range_max_m),
                                status=np.full_like(raw.status, BeamStatus.OK))
    cloud = reconstruct(every)
    origin_base = np.broadcast_to(np.asarray(raw.T_base_lidar)[:3, 3], cloud.points_turntable.shape)
    origin = base_to_turntable(origin_base, cloud.turntable_angle_rad)
    plant = ok[cloud.scan_index, cloud.beam_index] & (cloud.hit_class == HitClass.PLANT)
    return origin, cloud.points_turntable, plant


def study(origin: np.ndarray, end: np.ndarray, plant_pts: np.ndarray, voxel_m: float
          ) -> tuple[float, float, float]:
    """(hidden share of the hull, raster area m^2, corrected area m^2)."""
    lo, hi = plant_pts.min(axis=0) - voxel_m, plant_pts.max(axis=0) + voxel_m
    shape = np.ceil((hi - lo) / voxel_m).astype(int)
    d = end - origin
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / u, (hi - origin) / u
    t_in = np.nanmax(np.minimum(t1, t2), axis=1)
    t_out = np.minimum(np.nanmin(np.maximum(t1, t2), axis=1), length - 1e-9)
    inside_box = t_out > t_in
    o, uu, a, b = origin[inside_box], u[inside_box], t_in[inside_box], t_out[inside_box]
    step = voxel_m / 3.0
    n = np.ceil((b - a) / step).astype(int) + 1
    entered = np.zeros(shape, dtype=bool)
    for chunk in np.array_split(np.arange(len(o)), max(1, len(o) // 20_000)):
        nn = n[chunk]
        rep = np.repeat(chunk, nn)
        k = np.arange(nn.sum()) - np.repeat(np.cumsum(nn) - nn, nn)
        p = o[rep] + uu[rep] * np.minimum(a[rep] + k * step, b[rep])[:, None]
        idx = np.clip(np.floor((p - lo) / voxel_m).astype(int), 0, shape - 1)
        entered[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    pidx = np.clip(np.floor((plant_pts - lo) / voxel_m).astype(int), 0, shape - 1)
    entered[tuple(pidx.T)] = True
    _, nb = NeighbourIndex(plant_pts).query(plant_pts, k=12)
    q = plant_pts[nb] - plant_pts[nb].mean(axis=1, keepdims=True)
    normal = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))[1][:, :, 0]
    occupied, member = np.unique(np.ravel_multi_index(tuple(pidx.T), shape), return_inverse=True)
    l1 = np.bincount(member, weights=np.abs(normal).sum(axis=1)) / np.bincount(member)
    layer_area = np.bincount(np.unravel_index(occupied, shape)[2], weights=voxel_m ** 2 / l1,
                             minlength=shape[2])
    centres = np.stack(np.meshgrid(*[lo[j] + voxel_m * (np.arange(shape[j]) + 0.5) for j in range(3)],
                                   indexing="ij"), axis=-1).reshape(-1, 3)
    hull = (Delaunay(plant_pts).find_simplex(centres) >= 0).reshape(shape)
    hull[tuple(pidx.T)] = True
    seen, hidden = (entered & hull).sum(axis=(0, 1)), (~entered & hull).sum(axis=(0, 1))
    corrected = float(np.sum(np.where(seen > 0, layer_area * (seen + hidden) / np.maximum(seen, 1), 0.0)))
    return float(hidden.sum() / max(seen.sum() + hidden.sum(), 1)), float(layer_area.sum()), corrected


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=list(PLANTS), default=list(PLANTS))
    parser.add_argument("--realistic", action="store_true", help="realistic 1-degree scans (default ideal 0.5)")
    parser.add_argument("--voxels-mm", type=float, nargs="+", default=[4.0, 8.0])
    args = parser.parse_args()
    logging.getLogger("plantsim").setLevel(logging.ERROR)
    ideal, step = (False, 1.0) if args.realistic else (True, 0.5)
    print(f"{'ideal' if ideal else 'realistic'} {step:g}-degree scans, default rig")
    for name in args.plants:
        plant = PLANTS[name]()
        result = run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=step)),
                          plant=plant_from_arrays(plant.vertices_m, plant.faces))
        origin, end, hit_plant = beams_turntable(result)
        pts = end[hit_plant]
        pts = pts[traits._above_mask(pts, traits.TraitSettings())]
        truth = plant.traits["leaf_area_m2"]
        for voxel_mm in args.voxels_mm:
            hidden, raster, corrected = study(origin, end, pts, 1e-3 * voxel_mm)
            print(f"{name:10s} voxel {voxel_mm:g} mm: hull hidden from every beam {100 * hidden:.0f} %; "
                  f"leaf area {truth:.4f} m^2, raster {raster:.4f} ({100 * (raster / truth - 1):+.0f} %), "
                  f"corrected {corrected:.4f} ({100 * (corrected / truth - 1):+.0f} %)", flush=True)


if __name__ == "__main__":
    main()
