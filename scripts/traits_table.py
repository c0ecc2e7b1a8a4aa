"""The traits table of docs/traits.md: every trait, its truth, ideal and realistic scans.

Plants: the bundled maize and wheat and a procedural bean-like dicot (exact truth from
the generator, ``plantsim.plant.procedural``), scanned on the default rig; and the
seed-rig meshes given by path (no organ labels: their only truth is the paper's hand
measurements, Tables I and II, shown beside), scanned on the original rig's geometry.
Ideal = noiseless sensor at 0.5 deg steps; realistic = the URG-04LX sensor model at
1 deg. Every cell is ``value (relative error)`` (angles: the difference in degrees); "no truth" where the truth is not
known, "not found" where the cloud method found nothing (e.g. no stem), "<= ... (upper
bound)" for a stem diameter the noise hides, with the method's own notes listed under
the table.

Usage:
    python scripts/traits_table.py [--seed-rig ../shared/seed-rig] [--write docs/traits.md]

``--write`` replaces the block between the ``traits-table`` markers in that file.
Takes a few minutes (ten scans and their trait extraction).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))
sys.path.insert(0, str(REPO_ROOT / "scripts"))

from plantsim.evaluation.evaluate import scan_beam_gaps, scan_range_noise  # noqa: E402
from plantsim.evaluation.traits import convex_hull_volume, extract_traits, true_leaf_groups  # noqa: E402
from plantsim.plant.mesh import load_plant, plant_from_arrays  # noqa: E402
from plantsim.plant.procedural import make_dicot, make_maize, make_wheat  # noqa: E402
from plantsim.scan.config import RunConfig  # noqa: E402
from plantsim.scan.pipeline import run_scan  # noqa: E402
from plantsim.scan.schedule import StepScan  # noqa: E402

BEGIN, END = "<!-- traits-table:begin -->", "<!-- traits-table:end -->"
SETTINGS = (("ideal", True, 0.5), ("realistic", False, 1.0))

# (key, label, unit scale, unit). Keys are PlantTraits fields or derived below.
TRAITS = (
    ("height_m", "height", 1e3, "mm"),
    ("stem_count", "stem count", 1, ""),
    ("stem_diameter_m", "stem diameter", 1e3, "mm"),
    ("stem_height_m", "stem height", 1e3, "mm"),
    # Several stems: the shortest one's own height (Stem.height_m); stem_height_m is the
    # tallest's, and a culm read far short hides behind it.
    ("shortest_stem_height_m", "stem height (shortest stem)", 1e3, "mm"),
    ("mean_stem_distance_m", "distance between stems", 1e3, "mm"),
    ("leaf_count", "leaf count", 1, ""),
    ("lamina_count", "lamina count (leaflets apart)", 1, ""),
    ("leaf_area_m2", "leaf area", 1e4, "cm^2"),
    ("leaf_length_m", "leaf length (longest)", 1e3, "mm"),
    ("leaf_width_m", "leaf width (widest)", 1e3, "mm"),
    ("median_leaf_width_m", "leaf width (median)", 1e3, "mm"),
    ("mean_leaf_inclination_deg", "leaf inclination (mean)", 1, "deg"),
    ("convex_hull_volume_m3", "convex hull volume", 1e6, "cm^3"),
    ("projected_area_xy_m2", "projected area", 1e4, "cm^2"),
)

# The paper's Tables I and II (seed-rig README): R, S at 1 deg, S at 0.5 deg, in mm.
PAPER = {
    ("wheat", "stem_diameter_m"): (4.00, 5.00, 4.20),
    ("wheat", "mean_stem_distance_m"): (42.00, 47.00, 42.0),
    ("wheat", "height_m"): (555.00, 442.00, 490.0),
    ("maize", "height_m"): (417.00, 411.00, 412.69),
    ("maize", "stem_diameter_m"): (12.50, 12.00, 12.00),
    ("maize", "median_leaf_width_m"): (18.60, 15.78, 16.00),
}


def _nan_median(values) -> float:
    values = [v for v in values if math.isfinite(v)]
    return float(np.median(values)) if values else math.nan


def _nan_mean(values) -> float:
    values = [v for v in values if math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan


def truth_of(plant) -> dict:
    """Exact traits of a procedural plant, keyed as TRAITS."""
    t = plant.traits
    v = plant.vertices_m
    return {
        "height_m": t["height_m"], "stem_count": len(t["stems"]), "stem_diameter_m": t["stem_diameter_m"],
        "stem_height_m": max(s["height_m"] for s in t["stems"]),
        "shortest_stem_height_m": min(s["height_m"] for s in t["stems"]) if len(t["stems"]) > 1 else math.nan,
        "mean_stem_distance_m": t["mean_stem_distance_m"] if t["mean_stem_distance_m"] is not None else math.nan,
        # A compound leaf once (laminae on one petiole), as the cloud's leaf_count.
        "leaf_count": len(set(true_leaf_groups(t["leaves"]))), "lamina_count": len(t["leaves"]),
        "leaf_area_m2": t["leaf_area_m2"],
        "leaf_length_m": t["leaf_length_m"], "leaf_width_m": t["leaf_width_m"],
        "median_leaf_width_m": _nan_median([lf["width_m"] for lf in t["leaves"]]),
        "mean_leaf_inclination_deg": _nan_mean([lf["inclination_deg"] for lf in t["leaves"]]),
        # The hull of the mesh's vertices (every plant vertex stands above the ground).
        "convex_hull_volume_m3": convex_hull_volume(v),
        "projected_area_xy_m2": math.nan,   # no exact value: the cloud's is rasterised
    }


def estimate_of(points, range_noise_m=None, beam_gaps_m=None) -> tuple[dict, tuple[str, ...]]:
    """Traits of a cloud, keyed as TRAITS, and the method's notes."""
    e = extract_traits(points, range_noise_m=range_noise_m, beam_gaps_m=beam_gaps_m)
    out = {key: float(getattr(e, key)) for key, *_ in TRAITS if hasattr(e, key)}
    out["median_leaf_width_m"] = _nan_median(getattr(e, "leaf_widths_m", ()))
    own = [st.height_m for st in e.stems if math.isfinite(st.height_m)]
    out["shortest_stem_height_m"] = min(own) if len(own) > 1 else math.nan
    out["mean_leaf_inclination_deg"] = _nan_mean(getattr(e, "leaf_inclinations_deg", ()))
    # A stem whose diameter the noise hides reads its noisy column's width, an upper bound:
    # the plant's diameter is one where no stem's diameter was read.
    out["stem_diameter_upper_bound"] = bool(e.stems) and not any(st.diameter_resolved for st in e.stems)
    # Leaves whose width the range noise alone reads 45 % of (Leaf.width_resolved False).
    unresolved = [lf for lf in e.leaves if lf.width_resolved is False]
    out["unresolved_leaves"] = (len(unresolved), len(e.leaves),
                                sum(lf.area_m2 for lf in unresolved) / e.leaf_area_m2 if unresolved else 0.0)
    return out, tuple(getattr(e, "notes", ()))


def _scan(config: RunConfig, plant) -> tuple[dict, tuple[str, ...], int, float]:
    t0 = time.perf_counter()
    result = run_scan(config, plant=plant)
    points = result.cloud.plant_only().points_turntable
    try:
        estimate, notes = estimate_of(points, scan_range_noise(result)[0], scan_beam_gaps(result))
    except Exception as exc:  # noqa: BLE001 - any failure of the method is a finding, not a stop
        # The method failing on one cloud is a row of "not found" and a note naming the error.
        estimate, notes = {}, (f"trait extraction failed: {type(exc).__name__}: {exc}",)
    return estimate, notes, len(points), time.perf_counter() - t0


def _cell(value, truth, scale, key) -> str:
    if value is None or not math.isfinite(value):
        return "not found" if key != "mean_stem_distance_m" else "n/a"
    shown = f"{value * scale:.4g}"
    if truth is None or not math.isfinite(truth):
        return shown
    if key.endswith("_deg"):
        # An angle near 0 has no useful relative error: the difference in degrees.
        return f"{shown} ({value - truth:+.1f} deg)"
    if truth == 0:
        return shown
    return f"{shown} ({100 * abs(value - truth) / abs(truth):.1f} %)"


# Leaf traits read from the widths: marked where the range noise alone reads 45 % of a
# leaf's width or more (plantsim.evaluation.traits.Leaf.width_resolved).
UNRESOLVED_MARKED = ("leaf_area_m2", "leaf_width_m", "median_leaf_width_m")


def _unresolved(cell: str, unresolved, key: str) -> str:
    if not unresolved or not unresolved[0]:
        return cell
    k, n, share = unresolved
    if key == "leaf_area_m2":
        return f"{cell} ({100 * share:.0f} % of it on {k} of {n} leaves whose widths the noise reads)"
    return f"{cell} ({k} of {n} leaves' widths read the noise)"


def rows_for(name: str, truth: dict | None, scans: dict, paper_name: str | None) -> list[str]:
    rows = []
    for key, label, scale, unit in TRAITS:
        r = truth.get(key) if truth else None
        paper = PAPER.get((paper_name, key)) if paper_name else None
        if r is not None and not math.isfinite(r) and key in ("mean_stem_distance_m", "shortest_stem_height_m"):
            continue   # one stem: no distance, no shortest
        if key == "shortest_stem_height_m" and r is None and not any(
                math.isfinite(scans[s][0].get(key, math.nan)) for s, *_ in SETTINGS if s in scans):
            continue   # no truth, and no scan found several stems
        if (r is None or not math.isfinite(r)) and paper is not None:
            r = paper[0] / 1e3 if unit == "mm" else paper[0]
            truth_text = f"{paper[0]:.4g} (paper R)"
        elif r is None or not math.isfinite(r):
            truth_text = "no truth"
        else:
            truth_text = f"{r * scale:.4g}"
        paper_text = (f"{paper[1]:.4g} / {paper[2]:.4g}" if paper else "")
        cells = [_cell(scans[s][0].get(key), r, scale, key) if s in scans else "not run" for s, *_ in SETTINGS]
        if key == "stem_diameter_m":
            cells = [f"<= {c} (upper bound)" if s in scans and scans[s][0].get("stem_diameter_upper_bound") else c
                     for c, (s, *_) in zip(cells, SETTINGS)]
        if key in UNRESOLVED_MARKED:
            cells = [_unresolved(c, scans[s][0].get("unresolved_leaves"), key) if s in scans else c
                     for c, (s, *_) in zip(cells, SETTINGS)]
        rows.append(f"| {name} | {label}{f' [{unit}]' if unit else ''} | {truth_text} | "
                    + " | ".join(cells) + f" | {paper_text} |")
    return rows


def build(seed_rig: Path | None) -> str:
    plants = [("maize (bundled)", make_maize(seed=0), None), ("wheat (bundled)", make_wheat(seed=0), None),
              ("dicot (bean-like, 8 trifoliate leaves)", make_dicot(seed=0), None)]
    lines = ["| plant | trait | truth | ideal 0.5 deg | realistic 1 deg | paper S 1 deg / 0.5 deg |",
             "|---|---|---|---|---|---|"]
    notes, timings = [], []
    for name, generated, _ in plants:
        placed = plant_from_arrays(generated.vertices_m, generated.faces)
        scans = {}
        for setting, ideal, step in SETTINGS:
            est, n, count, dt = _scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=step)), placed)
            scans[setting] = (est, n)
            timings.append(f"{name} {setting}: {count} points, {dt:.0f} s")
            notes += [f"{name}, {setting}: {note}" for note in n]
            print(timings[-1], file=sys.stderr, flush=True)
        lines += rows_for(name, truth_of(generated), scans, None)
    if seed_rig is not None:
        from validate_seed_rig import SEED_LIDAR, SEED_RIG, T_TURNTABLE_SEEDMESH

        for plant_name in ("maize", "wheat"):
            path = seed_rig / f"{plant_name}.stl"
            if not path.is_file():
                notes.append(f"seed-rig {plant_name}: {path} not found, row left out")
                continue
            placed = load_plant(path, T_turntable_mesh=T_TURNTABLE_SEEDMESH)
            scans = {}
            for setting, ideal, step in SETTINGS:
                # The original rig's geometry; its noiseless 726-beam sensor for the ideal
                # scan, the URG-04LX model for the realistic one.
                config = RunConfig(rig=SEED_RIG, ideal=ideal, scan=StepScan(step_deg=step),
                                   **({"lidar": SEED_LIDAR} if ideal else {}))
                est, n, count, dt = _scan(config, placed)
                scans[setting] = (est, n)
                timings.append(f"seed-rig {plant_name} {setting}: {count} points, {dt:.0f} s")
                notes += [f"seed-rig {plant_name}, {setting}: {note}" for note in n]
                print(timings[-1], file=sys.stderr, flush=True)
            lines += rows_for(f"seed-rig {plant_name}", None, scans, plant_name)
    lines.append("")
    lines.append("Notes of the trait method (per plant and scan):")
    lines.append("")
    lines += [f"- {note}" for note in notes] or ["- none"]
    lines.append("")
    lines.append("Scans: " + "; ".join(timings) + ".")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed-rig", type=Path, default=None,
                        help="folder holding the seed-rig maize.stl and wheat.stl (rows left out without it)")
    parser.add_argument("--write", type=Path, default=None,
                        help=f"Markdown file whose block between {BEGIN} and {END} is replaced")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    table = build(args.seed_rig)
    if args.write is None:
        sys.stdout.write(table)
        return 0
    text = args.write.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{args.write} has no {BEGIN} ... {END} block to replace")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    args.write.write_text(head + BEGIN + "\n" + table + END + tail, encoding="utf-8")
    print(f"wrote the table into {args.write}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
