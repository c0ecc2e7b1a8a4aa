"""Trait accuracy on procedural plants with exact traits (issue 13 targets).

Scans maize, wheat (tillers), rosettes of 12 and 30 leaves, a trifoliate dicot and three
3-leaf plants (maize, rosette, bean) with the pipeline and prints, per plant,
estimate/truth (error) for height, leaf count and leaf area, with the issue's targets,
then the stems found and their mean diameter (marked when noise hides it):
ideal 0.5 deg: 2 %, 20 %, 20 %; realistic 1 deg: 5 %, 40 %, 35 %. Leaves are counted
as a botanist counts them, a compound leaf once (the dicot's 8 trifoliate leaves), with
the laminae (its 24 leaflets) beside them where the two differ. A second line per
plant says how many found laminae are true laminae (IoU > 0.5 of their points, each
point's truth the leaf of its nearest mesh face, on a realistic scan of the face its beam
hit; :mod:`plantsim.evaluation.organ_match`):
a count can be right with leaves split and others merged, an area with leaf bases
lost to the stem and noise widening the rest. A third line reads the found leaves of
which 60 % or more of the points are one true leaf's against that leaf: the median (and
range) of their length and width errors, and how far above the true leaf's insertion
their midrib starts. On a realistic scan that line says why an area is right or wrong:
the lower part of a maize leaf rises along the stem in the noisy stem's column, and
until its base was read from the beams (segmentation._leaf_bases_from_beams) the
3-leaf maize's two leaves that are mostly one true leaf's started 125-127 mm above
their insertions and read 27-48 % short, while the noise widened them +5..+16 %; they
now start 14-50 mm above and read -22..+9 %. A fourth line measures the true leaves alone
(:func:`plantsim.evaluation.traits.measure_labelled_leaves`, each from its base on the
mesh): the leaf area's error with the segmentation taken out.

    python scripts/traits_accuracy.py            # both settings
    python scripts/traits_accuracy.py --step 2   # a quick look at 2 deg
    python scripts/traits_accuracy.py --range-filter   # realistic scans denoised first
    python scripts/traits_accuracy.py --fit-rig  # plants the default rig warns about on the
                                                 # rig --fit-rig picks (the rosettes)
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np

from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import scan_beam_gaps, scan_range_noise, truth_in_turntable
from plantsim.evaluation.organ_match import match_leaves, procedural_leaf_labels
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_dicot, make_maize, make_rosette, make_wheat
from plantsim.rig.fit import fit_rig, rig_fit_warnings
from plantsim.scan.config import RangeFilter, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from traits_area_bound import leaf_bases  # scripts/ is on the path when a script runs

TARGETS = {"ideal": (0.02, 0.20, 0.20), "realistic": (0.05, 0.40, 0.35)}


def _err(estimate: float, truth: float, target: float) -> str:
    rel = abs(estimate - truth) / truth
    flag = "ok" if rel <= target else "MISS"
    return f"{estimate:.4g}/{truth:.4g} ({100 * rel:.0f}% {flag})"


def _mm(value: float) -> str:
    return "none" if value != value else f"{1e3 * value:.1f}"


def _leaf_by_leaf(est: "traits.PlantTraits", seg, plant) -> str:
    """The found leaves mostly (60 % or more of their points) one true leaf's, against it."""
    truth = procedural_leaf_labels(seg.points, plant, range_noise_m=seg.range_noise_m)
    length, width, base = [], [], []
    for lf in est.leaves:
        lab = truth[seg.leaf_label == lf.index]
        if not (lab >= 0).any():
            continue
        k = int(np.bincount(lab[lab >= 0]).argmax())
        if np.mean(lab == k) < 0.6:
            continue
        true_leaf = plant.traits["leaves"][k]
        length.append(100 * (lf.length_m / true_leaf["length_m"] - 1))
        width.append(100 * (lf.width_m / true_leaf["width_m"] - 1))
        base.append(1e3 * (seg.leaf_midribs[lf.index][0, 2] - true_leaf["insertion_height_m"]))
    if not length:
        return "leaf by leaf: no found lamina is 60 % or more one true leaf's"

    def spread(values: list, unit: str) -> str:
        return f"{np.median(values):+.0f}{unit} ({min(values):+.0f}..{max(values):+.0f})"

    return (f"leaf by leaf: {len(length)} of {len(est.leaves)} found laminae are 60 % or more one true leaf's: "
            f"length {spread(length, ' %')}, width {spread(width, ' %')}, "
            f"midrib base {spread(base, ' mm')} from the true insertion")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=float, help="one step for both settings (default 0.5 ideal, 1 realistic)")
    parser.add_argument("--range-filter", action="store_true",
                        help="denoise the realistic scans' ranges first (plantsim.cloud.denoise, default window)")
    parser.add_argument("--fit-rig", action="store_true",
                        help="scan each plant the default rig warns about on the rig plantsim.rig.fit.fit_rig "
                             "picks for it, as `plantsim scan --fit-rig` does (the rosettes: LiDAR raised)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    plants = (("maize 9 leaves", make_maize(seed=0)), ("wheat 4 tillers", make_wheat(seed=0)),
              ("rosette 12 leaves", make_rosette(seed=1, n_leaves=12)),
              ("rosette 30 leaves", make_rosette(seed=2, n_leaves=30)),
              ("dicot 8 trifoliate leaves (24 laminae)", make_dicot(seed=0)),
              # The smallest leaf count, on three species shapes.
              ("maize 3 leaves", make_maize(seed=2, n_leaves=3)),
              ("rosette 3 leaves", make_rosette(seed=0, n_leaves=3)),
              ("bean 3 simple leaves", make_dicot(seed=1, n_leaves=3, leaflets=1)))
    for setting, default_step in (("ideal", 0.5), ("realistic", 1.0)):
        step = args.step or default_step
        t_h, t_n, t_a = TARGETS[setting]
        for name, pl in plants:
            t0 = time.perf_counter()
            config = RunConfig(ideal=setting == "ideal", scan=StepScan(step_deg=step))
            if args.range_filter and setting == "realistic":
                config = config.replace(range_filter=RangeFilter(enabled=True))
            plant = plant_from_arrays(pl.vertices_m, pl.faces)
            fitted = ""
            if args.fit_rig and rig_fit_warnings(plant, config.rig, config.lidar):
                rig, _ = fit_rig(plant, config.rig, config.lidar)
                config = config.replace(rig=rig)
                fitted = (f" (fitted rig: LiDAR {rig.lidar_distance_m:.3f} m out, "
                          f"{rig.lidar_height_m:.3f} m up, tilt {rig.tilt_deg:g} deg)")
            result = run_scan(config, plant=plant)
            pts = result.cloud.plant_only().points_turntable
            noise = scan_range_noise(result)[0]
            est, tr = traits.extract_traits(pts, range_noise_m=noise, beam_gaps_m=scan_beam_gaps(result)), pl.traits
            # Leaves as a botanist counts them: a compound leaf (laminae on one petiole) once.
            true_leaves = len(set(traits.true_leaf_groups(tr["leaves"])))
            laminae = (f" (laminae {est.lamina_count}/{len(tr['leaves'])})"
                       if (est.lamina_count, len(tr["leaves"])) != (est.leaf_count, true_leaves) else "")
            unresolved = [lf for lf in est.leaves if lf.width_resolved is False]
            label = setting + ("+filter" if "range_filter" in result.parts else "")
            print(f"{label:16s} {step:g} deg  {name:18s} n={len(pts):7d}  "
                  f"height {_err(est.height_m, tr['height_m'], t_h)}  "
                  f"leaves {_err(est.leaf_count, true_leaves, t_n)}{laminae}  "
                  f"area {_err(est.leaf_area_m2, tr['leaf_area_m2'], t_a)}"
                  + (f" (widths read the noise on {len(unresolved)}/{est.leaf_count} leaves, "
                     f"{100 * sum(lf.area_m2 for lf in unresolved) / est.leaf_area_m2:.0f} % of the area)"
                     if unresolved else "") + "  "
                  f"stems {est.stem_count}/{len(tr['stems'])} "
                  f"diameter {_mm(est.stem_diameter_m)}/{_mm(tr['stem_diameter_m'])} mm"
                  f"{' (unresolved: upper bound)' if est.stems and not any(s.diameter_resolved for s in est.stems) else ''}"
                  ", "
                  f"height {_mm(est.stem_height_m)}/{_mm(max(st['height_m'] for st in tr['stems']))} mm  "
                  f"{time.perf_counter() - t0:.1f} s{fitted}", flush=True)
            counts = est.leaf_counts_over_grids
            areas = [100 * (a / tr["leaf_area_m2"] - 1) for a in est.leaf_areas_over_grids_m2 if a == a]
            stem_heights = [h for h in est.stem_heights_over_grids_m if h == h]
            heights = [100 * (h / tr["height_m"] - 1) for h in est.heights_over_grids_m]
            print(f"{'':16s} {'':7s}  over {len(counts)} shifted grids: height {min(heights):+.1f}..{max(heights):+.1f} %, "
                  f"leaves {min(counts)}-{max(counts)}"
                  + (f", area {min(areas):+.0f}..{max(areas):+.0f} %" if areas else "")
                  + (f", stem height {_mm(min(stem_heights))}-{_mm(max(stem_heights))} mm" if stem_heights else ""),
                  flush=True)
            if len(tr["stems"]) > 1:
                # Each stem's own height, matched to the truth's by centre (turntable frame).
                truth_here = traits.traits_from_truth(truth_in_turntable(tr, plant.T_turntable_mesh))
                own = [e for e in traits.compare_traits(est, truth_here).errors
                       if e.trait.startswith("stem[") and e.trait.endswith("].height_m")]
                print(f"{'':16s} {'':7s}  each stem's height: "
                      + ", ".join(f"{_mm(e.estimate)}/{_mm(e.reference)}" for e in own) + " mm", flush=True)
            seg = traits.segment_for_traits(pts, range_noise_m=noise)
            match = match_leaves(seg.leaf_label, procedural_leaf_labels(seg.points, pl, range_noise_m=seg.range_noise_m),
                                 n_true_leaves=len(pl.traits["leaves"]))
            print(f"{'':16s} {'':7s}  leaves matched: {match.summary()}", flush=True)
            # The same measures on the true leaves alone: the area's error less the segmentation's.
            alone = traits.measure_labelled_leaves(
                pts, procedural_leaf_labels(pts, pl, range_noise_m=None if setting == "ideal" else noise),
                leaf_bases_m=leaf_bases(pl, plant.T_turntable_mesh),
                range_noise_m=None if setting == "ideal" else noise)
            print(f"{'':16s} {'':7s}  true leaves measured alone: {alone.leaf_count} leaves, "
                  f"area {_err(alone.leaf_area_m2, tr['leaf_area_m2'], t_a)}", flush=True)
            print(f"{'':16s} {'':7s}  {_leaf_by_leaf(est, seg, pl)}", flush=True)


if __name__ == "__main__":
    main()
