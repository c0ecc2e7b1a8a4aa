"""Writes the calibration target's mesh, assets/calibration-target.stl (binary STL, metres, Z up).

    python scripts/make_target.py [OUT_DIR]

The target is described in plantsim/plant/target.py (sizes, how to build and place it);
running this twice gives byte-identical files, and a test checks the committed asset.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

from plantsim.plant.target import CALIBRATION_TARGET, target_stl_bytes  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", type=Path, default=REPO_ROOT / "assets")
    args = parser.parse_args()
    path = args.out_dir / "calibration-target.stl"
    data = target_stl_bytes(CALIBRATION_TARGET)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    print(f"wrote {path} ({len(data):,} bytes)")


if __name__ == "__main__":
    main()
