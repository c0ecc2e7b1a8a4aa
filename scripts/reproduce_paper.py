"""Reproduce the paper's Tables I and II with plantsim, automatically.

    PYTHONPATH=. python scripts/reproduce_paper.py ../shared/seed-rig [-o docs/paper_reproduction.md]

Scans the original tool's two meshes (``wheat.stl``, ``maize.stl``) with the
original rig's geometry (``scripts/validate_seed_rig.py``: LiDAR 0.3575 m from
the axis and 0.105 m above the disk top, 726 beams over +-130 degrees, no noise, as
the Gazebo sensor had) at 1 and 0.5 degrees, extracts the paper's parameters from
each cloud with :func:`plantsim.traits.extract_traits` (no hand measurement), and
prints our table beside the paper's (``../shared/seed-rig/README.md``).

Two references: the paper's R, hand-measured in CloudCompare, and ours, the same
extraction run on 300,000 exact samples of the mesh surface
(:func:`plantsim.traits.traits_from_mesh`; its height is the mesh's top vertex).
Our S is compared against both. Parameters:

- wheat: stem diameter (mean over the stems of each one's ring above its basal
  flare), distance between stems (mean over all pairs of stem axes at their bases;
  the mean nearest-neighbour distance is printed too), plant height (the robust
  top above the disk top, knowing the sensor is noise-free and how far apart its
  beams pass at the top, half of which is added, as ``plantsim traits`` knows from a
  scan's sidecar);
- maize: plant height, stem diameter, leaf width (the widest detected leaf, the
  library's definition; the median over detected leaves, closer to the one leaf a
  person picks; and that median over the leaves 5 mm wide or more, which sets the
  tassel's thin branches aside).

The seed-rig files carry no licence: this script reads them where they are and
copies nothing. Writes the Markdown table (with a sentence on each difference)
to ``-o`` when given.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from validate_seed_rig import SEED_LIDAR, SEED_OUTPUT_DISK_TOP_Z, SEED_RIG, T_TURNTABLE_SEEDMESH  # noqa: E402

from plantsim.scan.config import PlantOptions, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.evaluation.evaluate import scan_beam_gaps, scan_range_noise
from plantsim.evaluation.traits import PlantTraits, extract_traits, traits_from_mesh

STEPS_DEG = (1.0, 0.5)

# The paper's Tables I and II (seed-rig README): R and S in mm.
PAPER = {
    ("wheat", "stem diameter"): (4.00, 5.00, 4.20),
    ("wheat", "distance between stems"): (42.00, 47.00, 42.0),
    ("wheat", "plant height"): (555.00, 442.00, 490.0),
    ("maize", "plant height"): (417.00, 411.00, 412.69),
    ("maize", "stem diameter"): (12.50, 12.00, 12.00),
    ("maize", "leaf width"): (18.60, 15.78, 16.00),
}


# Tip branches narrower than this are not leaves a person would measure: on the maize
# mesh they are its tassel's branches (0.7-4 mm wide, 450-540 mm above the disk).
LEAF_MIN_WIDTH_M = 0.005


def median_leaf_width(traits: PlantTraits, min_width_m: float = 0.0) -> float:
    widths = [lf.width_m for lf in traits.leaves if math.isfinite(lf.width_m) and lf.width_m >= min_width_m]
    return float(np.median(widths)) if widths else math.nan


def narrow_branches(traits: PlantTraits) -> int:
    return sum(1 for lf in traits.leaves if math.isfinite(lf.width_m) and lf.width_m < LEAF_MIN_WIDTH_M)


# Our parameter for each of the paper's, in metres: (row label, function of PlantTraits).
OURS = {
    ("wheat", "stem diameter"): [("stem diameter", lambda t: t.stem_diameter_m)],
    ("wheat", "distance between stems"): [
        ("distance between stems (all pairs)", lambda t: t.mean_stem_distance_m),
        ("distance to the nearest stem", lambda t: t.mean_nearest_stem_distance_m)],
    ("wheat", "plant height"): [("plant height", lambda t: t.height_m)],
    ("maize", "plant height"): [("plant height", lambda t: t.height_m)],
    ("maize", "stem diameter"): [("stem diameter", lambda t: t.stem_diameter_m)],
    ("maize", "leaf width"): [("leaf width (widest leaf)", lambda t: t.leaf_width_m),
                              ("leaf width (median leaf)", median_leaf_width),
                              ("leaf width (median leaf 5 mm wide or more)",
                               lambda t: median_leaf_width(t, LEAF_MIN_WIDTH_M))],
}


def seed_config(mesh: Path, step_deg: float) -> RunConfig:
    """The original rig (geometry, noiseless 726-beam sensor) scanning one seed mesh."""
    T = tuple(tuple(float(x) for x in row) for row in T_TURNTABLE_SEEDMESH)
    return RunConfig(plant=PlantOptions(mesh=str(mesh), T_turntable_mesh=T), rig=SEED_RIG,
                     lidar=SEED_LIDAR, scan=StepScan(step_deg=step_deg), ideal=True)


def measure(seed_rig: Path, plant: str) -> dict:
    """Traits of one seed mesh: from the mesh, and from a scan at each step."""
    out = {}
    for step in STEPS_DEG:
        t = time.perf_counter()
        result = run_scan(seed_config(seed_rig / f"{plant}.stl", step))
        points = result.cloud.plant_only().points_turntable
        # As `plantsim traits` reads a scan's cloud with its sidecar: knowing the sensor's noise
        # (none) and how far apart its beams pass at the top.
        out[step] = extract_traits(points, settings=None, range_noise_m=scan_range_noise(result)[0],
                                   beam_gaps_m=scan_beam_gaps(result))
        out[f"time {step}"] = time.perf_counter() - t
        out[f"points {step}"] = len(points)
        out[f"top {step}"] = float(points[:, 2].max()) if len(points) else math.nan
    out["mesh"] = traits_from_mesh(result.plant.vertices_turntable, result.plant.faces, rng=0)
    return out


def _err(s: float, r: float) -> str:
    return f"{abs(s - r) / r:.1%}" if math.isfinite(s) and r else "n/a"


def _mm(x: float) -> str:
    return f"{x * 1e3:.2f}" if math.isfinite(x) else "n/a"


def table(measured: dict) -> list[list[str]]:
    """Rows: plant, parameter, paper R, paper S 1 and 0.5 deg (error), our R, our S at
    1 and 0.5 deg (error against our R / against the paper's R)."""
    rows = []
    for (plant, parameter), (r_paper, s1, s05) in PAPER.items():
        m = measured[plant]
        for k, (label, get) in enumerate(OURS[(plant, parameter)]):
            r_ours = get(m["mesh"])
            ours = [get(m[step]) for step in STEPS_DEG]
            paper = [f"{s1:.2f} ({_err(s1, r_paper)})", f"{s05:.2f} ({_err(s05, r_paper)})"] if k == 0 \
                else ["", ""]
            rows.append([plant if k == 0 else "", label, f"{r_paper:.2f}" if k == 0 else "", *paper,
                         _mm(r_ours)] + [f"{_mm(s)} ({_err(s, r_ours)} / {_err(s, r_paper / 1e3)})"
                                         for s in ours])
    return rows


HEADER = ["plant", "parameter", "R paper [mm]", "S paper 1° [mm] (err)", "S paper 0.5° [mm] (err)",
          "R ours, mesh [mm]", "S ours 1° [mm] (err vs our R / vs paper R)",
          "S ours 0.5° [mm] (err vs our R / vs paper R)"]


def original_output_top_m(seed_rig: Path, plant: str) -> float:
    """Height above the disk top of the original tool's highest point (NaN without its file)."""
    path = seed_rig / f"{plant}_scan_1deg.txt"
    if not path.is_file():
        return math.nan
    table_ = np.loadtxt(path, delimiter="\t", ndmin=2)
    return float(np.nanmax(table_[:, 2]) - SEED_OUTPUT_DISK_TOP_Z)


def notes(measured: dict, seed_rig: Path) -> list[str]:
    """One sentence (or two) on each difference, with this run's numbers."""
    w, m = measured["wheat"], measured["maize"]
    w05, m1, m05 = w[0.5], m[1.0], m[0.5]
    pairs = ", ".join(f"{p.distance_m * 1e3:.1f}" for p in w["mesh"].stem_distances)
    widest = max((p.distance_m for p in w["mesh"].stem_distances), default=math.nan)
    pct = lambda s, r: abs(s - r) / r * 100  # noqa: E731
    gate = {p: original_output_top_m(seed_rig, p) for p in ("wheat", "maize")}
    w1, wd = w[1.0], [w[1.0].stem_diameter_m * 1e3, w05.stem_diameter_m * 1e3]
    top = max(m05.leaves, key=lambda lf: lf.length_m)
    return [
        f"**Wheat, stem diameter.** Our scans read {min(wd):.2f}-{max(wd):.2f} mm, within "
        f"{max(pct(d / 1e3, w['mesh'].stem_diameter_m) for d in wd):.1f} % of the same fit on the mesh and "
        f"{max(pct(d / 1e3, 0.004) for d in wd):.1f} % of the paper's R; the paper's 25 % at 1 degree comes "
        "from the original tool's misplaced points (a mirror image, beam angles scaled by 0.93, a "
        "sensor distance 7.5 mm short: points 2-8 mm off the mesh), not from the step.",
        f"**Wheat, distance between stems.** The mesh's three stems stand {pairs} mm apart at their bases "
        f"(mean {w['mesh'].mean_stem_distance_m * 1e3:.1f} mm), and our scans give the same distances to "
        f"{max(abs(t.mean_stem_distance_m - w['mesh'].mean_stem_distance_m) for t in (w1, w05)) * 1e3:.1f} mm; "
        f"the paper's 42 mm is closest to the widest pair ({widest * 1e3:.1f} mm), so it reads as one "
        "hand-picked pair (perhaps higher up, where the tillers splay), not a mean.",
        "**Wheat, plant height.** The original tool drops points beyond a hand-set range (not recorded; "
        f"its 1-degree wheat file stops {gate['wheat'] * 1e3:.0f} mm above the disk), which cuts off the "
        "ears: the likely reason for the paper's S being 20 % and 12 % short. "
        f"Without a gate we read {w1.height_m * 1e3:.1f} and {w05.height_m * 1e3:.1f} mm, "
        f"{(w['mesh'].height_m - w1.height_m) * 1e3:.1f} and {(w['mesh'].height_m - w05.height_m) * 1e3:.1f} mm "
        f"under the mesh's top vertex ({w['mesh'].height_m * 1e3:.1f} mm). The highest points lie "
        f"{(w['mesh'].height_m - w['top 1.0']) * 1e3:.1f} and {(w['mesh'].height_m - w['top 0.5']) * 1e3:.1f} mm "
        "under it, but the height is the top voxel holding two points (so that one stray point cannot set "
        "it), and the beams hit the ears' thin tips too sparsely to put two points in a voxel there, most "
        "of all at 1 degree. "
        f"The paper's R (555 mm) is {(w['mesh'].height_m - 0.555) * 1e3:.1f} mm below the mesh's top; the paper "
        "does not say where it measures from.",
        f"**Maize, plant height.** The mesh rises {m['mesh'].height_m * 1e3:.0f} mm above the disk top and "
        f"our scans read {m1.height_m * 1e3:.0f} and {m05.height_m * 1e3:.0f} mm; the paper's R (417 mm) "
        f"and S (411-413 mm) measure something else (its base and top are not recorded): the original "
        f"1-degree file stops {gate['maize'] * 1e3:.0f} mm above the disk, so its S cannot be the full "
        "height above the disk either.",
        f"**Maize, stem diameter.** The stem's ring above its basal flare reads "
        f"{m['mesh'].stem_diameter_m * 1e3:.1f} mm on the mesh; the paper's 12.5 mm was measured at a height "
        f"it does not give. Our scans read {m1.stem_diameter_m * 1e3:.1f} and {m05.stem_diameter_m * 1e3:.1f} mm, "
        f"{pct(m1.stem_diameter_m, m['mesh'].stem_diameter_m):.0f} and "
        f"{pct(m05.stem_diameter_m, m['mesh'].stem_diameter_m):.0f} % over the mesh, most likely because "
        "the scan samples the ring unevenly (densely where beams meet the stem head-on, sparsely at "
        "grazing angles) where the mesh samples are uniform; this was not isolated further.",
        "**Maize, leaf width.** The library's leaf width is the widest detected leaf, and on this plant "
        "that is not one leaf: the stem's path is lost where the upper leaves wrap it, so the longest "
        f"detected \"leaf\" ({top.length_m * 1e3:.0f} mm at 0.5 degrees) is the plant's upper part, stem, top "
        f"leaves and tassel together, and the widest reads {m1.leaf_width_m * 1e3:.0f} and "
        f"{m05.leaf_width_m * 1e3:.0f} mm. The median over detected leaves is the figure comparable to the "
        "one leaf a person measures, once the tassel's branches are set aside: the mesh's samples show "
        f"{narrow_branches(m['mesh'])} tip branches under {LEAF_MIN_WIDTH_M * 1e3:.0f} mm wide at the top "
        f"(the 1- and 0.5-degree scans count {narrow_branches(m1)} and {narrow_branches(m05)}: beams rarely "
        "hit them, and a branch with fewer points than spacings along it is not counted), which pull "
        f"the mesh's median down to {median_leaf_width(m['mesh']) * 1e3:.1f} mm. Over the leaves "
        f"{LEAF_MIN_WIDTH_M * 1e3:.0f} mm wide or more the median is "
        f"{median_leaf_width(m['mesh'], LEAF_MIN_WIDTH_M) * 1e3:.1f} mm on the mesh and "
        f"{median_leaf_width(m1, LEAF_MIN_WIDTH_M) * 1e3:.1f} and "
        f"{median_leaf_width(m05, LEAF_MIN_WIDTH_M) * 1e3:.1f} mm in our scans: "
        f"{pct(median_leaf_width(m05, LEAF_MIN_WIDTH_M), 0.0186):.0f} % from the paper's R at 0.5 degrees, "
        "where the paper's own S was 14-15 % off.",
    ]


def markdown(rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def document(measured: dict, seed_rig: Path) -> str:
    """The Markdown page: how it was made, the table, a sentence on each difference."""
    times = ", ".join(f"{plant} {measured[plant][f'time {step}']:.1f} s at {step:g} deg"
                      for plant in ("wheat", "maize") for step in STEPS_DEG)
    return "\n".join([
        "# The paper's Tables I and II, reproduced",
        "",
        "Written by `PYTHONPATH=. python scripts/reproduce_paper.py ../shared/seed-rig "
        "-o docs/paper_reproduction.md`.",
        "",
        "The original tool's meshes (`maize.stl`, `wheat.stl`, with their turntable disk) are scanned "
        "with the original rig's geometry (LiDAR 0.3575 m from the axis and 0.105 m above the disk "
        "top, 726 beams over +-130 degrees, no noise: the Gazebo sensor) at 1 and 0.5 degrees; the "
        "paper's parameters are extracted from the plant points by `plantsim.traits.extract_traits` "
        "with its default settings, with no hand measurement. R paper is the paper's hand measurement "
        "in CloudCompare; R ours is the same extraction on 300,000 exact samples of the mesh surface "
        "(`traits_from_mesh`; height: the top vertex above the disk top). Errors are |S - R| / R; "
        "ours are given against our R, then against the paper's R.",
        "",
        markdown(table(measured)),
        "## The differences",
        "",
        *[f"- {note}" for note in notes(measured, seed_rig)],
        "",
        f"Scan and trait times (load, build, cast, reconstruct, extract the traits on 9 grids; one shared machine): {times}. The paper reports "
        "about 40 minutes per scan.",
        "",
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("seed_rig", type=Path, help="path to ../shared/seed-rig")
    parser.add_argument("-o", "--output", type=Path, help="also write the Markdown table here")
    args = parser.parse_args()
    for plant in ("wheat", "maize"):
        if not (args.seed_rig / f"{plant}.stl").is_file():
            sys.exit(f"reproduce_paper: no {plant}.stl in {args.seed_rig}")
    measured = {}
    for plant in ("wheat", "maize"):
        measured[plant] = measure(args.seed_rig, plant)
        m = measured[plant]
        print(f"{plant}: " + "; ".join(
            f"{step:g} deg: {m[f'points {step}']:,} plant points in {m[f'time {step}']:.1f} s"
            for step in STEPS_DEG) + f"; stems found {[len(m[s].stems) for s in STEPS_DEG]}, "
            f"in the mesh {len(m['mesh'].stems)}", file=sys.stderr)
    text = document(measured, args.seed_rig)
    print(text)
    if args.output:
        args.output.write_text(text, encoding="utf-8")

if __name__ == "__main__":
    main()
