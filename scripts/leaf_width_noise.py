"""Can this sensor resolve these leaves' widths? Leaf by leaf, on a realistic scan of a procedural plant.

Scans a procedural plant with the realistic sensor, segments the cloud as ``plantsim traits``
does, matches the found leaves to the true ones (each point's truth the leaf of its nearest
mesh face, :mod:`plantsim.evaluation.organ_match`) and prints per found leaf:

- ``width``: the width ``plantsim traits`` reports (per midrib node the 2nd-98th percentile
  extent across the midrib, 90th percentile over the outer four fifths of the nodes);
- ``sqrt(12 var)``: the same, read as a uniform strip from each node's variance across the midrib;
- ``less noise``: that strip width after taking away the share of the variance the sensor's
  range noise floor puts across the midrib, ``mean((sigma0 d_i . u)^2)`` with ``d_i`` each
  point's beam direction (from the rig and the angle each point was reconstructed at) and
  ``sigma0`` the preset's noise floor (``LidarSpec.range_sigma_m``). The noise is at least
  the floor, so this is an upper bound on what a known-noise correction can recover; it is
  a difference of two variances, and where the noise's share dwarfs the strip's the 90th
  percentile over the nodes reads it high as well (28 % on an analytic 10 mm strip under
  10 mm noise, 2000 points a node: ``tests/test_leaf_width_noise.py``);
- the true width of the leaf holding most of the found leaf's points, and that share.

A URG-04LX's range noise (a 10 mm floor) lies along each beam, and a beam crossing a
narrow leaf at a slant moves the point within the leaf's plane: the width reads the noise.

    python scripts/leaf_width_noise.py --plant wheat
    python scripts/leaf_width_noise.py --plant maize --step 0.5
"""

from __future__ import annotations

import argparse
import logging

import numpy as np
from scipy.spatial import cKDTree

from plantsim.cloud.reconstruct import base_to_turntable
from plantsim.evaluation import traits
from plantsim.evaluation.organ_match import procedural_leaf_labels
from plantsim.evaluation.segmentation import node_frames
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_dicot, make_maize, make_rosette, make_wheat
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

PLANTS = {"maize": lambda: make_maize(seed=0), "wheat": lambda: make_wheat(seed=0),
          "rosette": lambda: make_rosette(seed=1, n_leaves=12), "dicot": lambda: make_dicot(seed=0)}


def strip_widths_m(leaf_points: np.ndarray, beam_dirs: np.ndarray, midrib: np.ndarray, link_m: float,
                   sigma_m: float) -> tuple[float, float]:
    """90th percentile over the outer four fifths of the nodes of ``sqrt(12 var)`` across the
    midrib, raw and less the noise floor's share; (NaN, NaN) with no node of 8 points."""
    tangent, _, _, node = node_frames(leaf_points, midrib, link=link_m)
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(midrib, axis=0), axis=1))]
    raw, less = [], []
    for j in np.flatnonzero(along >= 0.2 * along[-1]):
        member = node == j
        if member.sum() < 8:
            continue
        q = leaf_points[member] - leaf_points[member].mean(axis=0)
        q -= np.outer(q @ tangent[j], tangent[j])
        across = np.linalg.svd(q, full_matrices=False)[2][0]
        var = float(np.var(q @ across))
        noise_var = float(np.mean((sigma_m * (beam_dirs[member] @ across)) ** 2))
        raw.append(np.sqrt(12.0 * var))
        less.append(np.sqrt(12.0 * max(var - noise_var, 0.0)))
    if not raw:
        return float("nan"), float("nan")
    return float(np.percentile(raw, 90)), float(np.percentile(less, 90))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plant", choices=sorted(PLANTS), default="wheat")
    parser.add_argument("--step", type=float, default=1.0, help="turntable step, degrees (default 1)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    plant = PLANTS[args.plant]()
    config = RunConfig(ideal=False, scan=StepScan(step_deg=args.step))
    result = run_scan(config, plant=plant_from_arrays(plant.vertices_m, plant.faces))
    cloud = result.cloud.plant_only()
    lidar_base = np.repeat(result.raw.T_base_lidar[:3, 3][None], len(cloud), axis=0)
    origin_turntable = base_to_turntable(lidar_base, cloud.turntable_angle_rad)
    beam = cloud.points_turntable - origin_turntable
    beam /= np.linalg.norm(beam, axis=1)[:, None]

    seg = traits.segment_for_traits(cloud.points_turntable)
    found = traits.extract_traits(cloud.points_turntable)
    _, row = cKDTree(cloud.points_turntable).query(seg.points)  # segmentation keeps a subset
    beam_seg = beam[row]
    truth = procedural_leaf_labels(seg.points, plant)
    true_width = [leaf["width_m"] for leaf in plant.traits["leaves"]]
    sigma_m = config.lidar.range_sigma_m
    print(f"{args.plant}, realistic {args.step:g} deg ({config.lidar.name}, noise floor "
          f"{1e3 * sigma_m:.1f} mm along the beam; the cloud's noise across its surfaces "
          f"{1e3 * seg.scale.noise_m:.1f} mm): {len(found.leaves)} leaves found")
    print("leaf  width  sqrt(12 var)  less noise   true  share of its points")
    for i, midrib in enumerate(seg.leaf_midribs):
        member = seg.leaf_label == i
        raw, less = strip_widths_m(seg.points[member], beam_seg[member], midrib, seg.link_m, sigma_m)
        labels, counts = np.unique(truth[member], return_counts=True)
        major = int(labels[np.argmax(counts)])
        true = f"{1e3 * true_width[major]:5.1f}" if major >= 0 else " stem"
        print(f"{i:4d}  {1e3 * found.leaves[i].width_m:5.1f}  {1e3 * raw:12.1f}  {1e3 * less:10.1f}  "
              f"{true}  {counts.max() / member.sum():.2f}")
    print("widths in mm; 'stem': most of the found leaf's points are no leaf's (a tiller, an ear, a petiole)")


if __name__ == "__main__":
    main()
