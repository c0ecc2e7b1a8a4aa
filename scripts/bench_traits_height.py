"""What reading the traits with the range noise costs (the height: traits.beam_median_points; the widths: traits.across_beam_width).

Usage:
    PYTHONPATH=. python scripts/bench_traits_height.py [--runs 3]

Given each point's range noise, ``extract_traits`` moves the points that can reach the
top along their beams before reading the height, and reads each leaf cross-section's
width where its beams meet the leaf, on each of the shifted grids whose leaf areas it
compares (since 2026-11-24). Per realistic 1-degree scan (the
procedural 9-leaf maize, 4-tiller wheat and 3-leaf bean on the default rig; the 12-leaf
and 30-leaf rosettes on the rig ``fit_rig`` picks, looking down, where the noise's band
covers most of a flat plant and nearly every point is moved), ``extract_traits`` with
and without the noise, alternating, each the median of ``--runs`` runs, and their
ratio. On a shared machine compare the ratios only.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics

from benchkit import median_time

from plantsim.evaluation import traits
from plantsim.evaluation.evaluate import scan_range_noise
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_dicot, make_maize, make_rosette, make_wheat
from plantsim.rig.fit import fit_rig
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

PLANTS = (("maize 9 leaves", lambda: make_maize(seed=0), False),
          ("wheat 4 tillers", lambda: make_wheat(seed=0), False),
          ("bean 3 simple leaves", lambda: make_dicot(seed=1, n_leaves=3, leaflets=1), False),
          ("rosette 12 leaves, fitted rig", lambda: make_rosette(seed=1, n_leaves=12), True),
          ("rosette 30 leaves, fitted rig", lambda: make_rosette(seed=2, n_leaves=30), True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    logging.getLogger("plantsim").setLevel(logging.ERROR)
    print(f"load average {os.getloadavg()[0]:.2f}; median of {args.runs} runs")
    for name, make, fitted in PLANTS:
        pl = make()
        plant = plant_from_arrays(pl.vertices_m, pl.faces)
        config = RunConfig(ideal=False, scan=StepScan(step_deg=1.0))
        if fitted:
            config = config.replace(rig=fit_rig(plant, config.rig, config.lidar)[0])
        result = run_scan(config, plant=plant)
        points = result.cloud.plant_only().points_turntable
        noise = scan_range_noise(result)[0]
        without, with_noise = [], []
        for _ in range(args.runs):
            without.append(median_time(lambda: traits.extract_traits(points), 1)[0])
            t, est = median_time(lambda: traits.extract_traits(points, range_noise_m=noise), 1)
            with_noise.append(t)
        t0, t1 = statistics.median(without), statistics.median(with_noise)
        moved = next((n.split(" read with the ")[1].split(" points")[0] for n in est.notes
                      if n.startswith("height:") and "moved along their beams" in n), "0")
        across = sum(1 for lf in est.leaves if lf.width_across_beams_share > 0)
        print(f"{name:30s} {len(points):7,d} points: {t0:.2f} s without the noise, {t1:.2f} s with "
              f"({t1 / t0:.2f}x; {moved} points moved; widths read across the beams on {across} of "
              f"{len(est.leaves)} leaves)", flush=True)


if __name__ == "__main__":
    main()
