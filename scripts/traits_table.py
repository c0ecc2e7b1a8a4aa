"""Prints the traits table of docs/traits.md: bundled plants, truth vs ideal 0.5 deg and
realistic 1 deg scans, relative errors.

Usage:
    python scripts/traits_table.py
(The seed-rig meshes carry no organ labels or truth file; their rows are the paper's
Tables I and II, see docs/traits.md.)
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))

from plantsim.evaluation.traits import extract_traits  # noqa: E402
from plantsim.scan.config import config_from_dict  # noqa: E402
from plantsim.scan.pipeline import run_scan  # noqa: E402

KEYS = ("height_m", "stem_count", "stem_diameter_m", "stem_height_m", "leaf_count", "leaf_area_m2",
        "leaf_width_m", "leaf_length_m")


def truth_of(t: dict) -> dict:
    return {"height_m": t["height_m"], "stem_count": len(t["stems"]),
            "stem_diameter_m": t["stem_diameter_m"],
            "stem_height_m": max(s["height_m"] for s in t["stems"]),
            "leaf_count": len(t["leaves"]), "leaf_area_m2": t["leaf_area_m2"],
            "leaf_width_m": t["leaf_width_m"], "leaf_length_m": t["leaf_length_m"]}


def cell(v, r):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    err = abs(v - r) / abs(r) * 100 if r else float("nan")
    return f"{v:.4g} ({err:.1f} %)"


def main() -> int:
    print("| plant | trait | truth | ideal 0.5 deg | realistic 1 deg |")
    print("|---|---|---|---|---|")
    for plant in ("maize", "wheat"):
        truth = truth_of(json.loads((REPO_ROOT / "assets" / f"{plant}.traits.json").read_text()))
        got = {}
        for label, ideal, step in (("ideal", True, 0.5), ("realistic", False, 1.0)):
            cfg = config_from_dict({"plant": {"bundled": plant}, "scan": {"step_deg": step},
                                    "ideal": ideal, "sensor": "ideal" if ideal else "realistic"})
            got[label] = extract_traits(run_scan(cfg).cloud.plant_only().points_turntable).to_dict()
        for k in KEYS:
            print(f"| {plant} | {k} | {truth[k]:.4g} | {cell(got['ideal'][k], truth[k])} | "
                  f"{cell(got['realistic'][k], truth[k])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
