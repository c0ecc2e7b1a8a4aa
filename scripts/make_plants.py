"""Regenerates the bundled procedural plants (maize, wheat) into assets/.

Usage:
    python scripts/make_plants.py [OUT_DIR]

Writes <name>.stl (binary, metres, Z up) and <name>.traits.json for each plant, each
atomically (temporary file in OUT_DIR, then os.replace). Running it twice gives
byte-identical files. OUT_DIR defaults to the repository's assets/ directory.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    # Lets the script run from a checkout without installing plantsim.
    sys.path.insert(0, str(REPO_ROOT))

from plantsim.plant.procedural import make_maize, make_wheat, to_stl_bytes, traits_to_json

DEFAULT_OUT_DIR = REPO_ROOT / "assets"
# The bundled plants: name -> (generator, seed). Parameters are the generators' defaults.
PLANTS = {"maize": (make_maize, 0), "wheat": (make_wheat, 0)}
MAX_STL_BYTES = 2_000_000


def _write_atomic(path: Path, data: bytes) -> None:
    """Writes data to path via a temporary file in the same directory and os.replace."""
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp_name, 0o644)  # mkstemp makes 0600; assets are ordinary readable files
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise


def write_plants(out_dir: Path) -> list[tuple[Path, int]]:
    """Generates every bundled plant and writes its STL and traits JSON into out_dir.

    Returns:
        (path, size in bytes) of each file written, in order.

    Raises:
        ValueError: An STL would reach MAX_STL_BYTES (nothing is written for that plant).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (generate, seed) in PLANTS.items():
        plant = generate(seed=seed)
        stl = to_stl_bytes(plant)
        if len(stl) >= MAX_STL_BYTES:
            raise ValueError(
                f"{name}.stl would be {len(stl)} bytes, over the {MAX_STL_BYTES}-byte limit; "
                "lower stem_rings, leaf_segments or leaf_width_segments")
        traits = traits_to_json(plant).encode("utf-8")
        for path, data in ((out_dir / f"{name}.stl", stl),
                           (out_dir / f"{name}.traits.json", traits)):
            _write_atomic(path, data)
            written.append((path, len(data)))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", type=Path, default=DEFAULT_OUT_DIR,
                        help=f"directory to write into (default: {DEFAULT_OUT_DIR})")
    args = parser.parse_args(argv)
    for path, size in write_plants(args.out_dir):
        note = f" (< {MAX_STL_BYTES} bytes limit)" if path.suffix == ".stl" else ""
        print(f"wrote {path} {size} bytes{note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
