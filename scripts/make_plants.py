"""Regenerates the bundled procedural plants (maize, wheat) into assets/, and optionally
more procedural plants with organ labels.

Usage:
    python scripts/make_plants.py [OUT_DIR] [--extra EXTRA_DIR]

Writes <name>.stl (binary, metres, Z up) and <name>.traits.json for each plant, each
atomically (temporary file in OUT_DIR, then os.replace). Running it twice gives
byte-identical files. OUT_DIR defaults to the repository's assets/ directory.
``--extra`` also writes the plants of ``EXTRA_PLANTS`` (a bean-like dicot, a branched
one, rosettes, touching-leaf maize) as labelled OBJ (one object per organ, read back by
``plantsim scan X.obj --evaluate``) with their <name>.obj.traits.json.
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

from plantsim.plant.procedural import (make_dicot, make_maize, make_rosette, make_wheat,  # noqa: E402
                                      to_labelled_obj_bytes, to_stl_bytes, traits_to_json)

DEFAULT_OUT_DIR = REPO_ROOT / "assets"
# The bundled plants: name -> (generator, seed). Parameters are the generators' defaults.
PLANTS = {"maize": (make_maize, 0), "wheat": (make_wheat, 0)}
MAX_STL_BYTES = 2_000_000
# Other plants with exact organs: name -> (generator, seed, parameters).
EXTRA_PLANTS = {
    "dicot": (make_dicot, 0, {}),
    "dicot-branched": (make_dicot, 1, {"n_leaves": 12, "n_branches": 2, "leaves_per_branch": 2}),
    "dicot-simple-30": (make_dicot, 2, {"n_leaves": 30, "leaflets": 1}),
    "dicot-touching": (make_dicot, 3, {"n_leaves": 10, "leaflets": 1, "stem_length": 0.12,
                                       "leaflet_length": 0.11, "leaflet_width": 0.08,
                                       "phyllotaxy_deg": 30.0, "lowest_node_fraction": 0.5}),
    "rosette-12": (make_rosette, 1, {"n_leaves": 12}),
    "rosette-30": (make_rosette, 2, {"n_leaves": 30}),
    "maize-3": (make_maize, 3, {"n_leaves": 3}),
    "maize-touching": (make_maize, 4, {"n_leaves": 12, "phyllotaxy_deg": 10.0, "phyllotaxy_jitter_deg": 0.0}),
}


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


def write_extra_plants(out_dir: Path) -> list[tuple[Path, int]]:
    """Writes every plant of EXTRA_PLANTS as labelled OBJ plus its traits JSON into out_dir.

    Returns:
        (path, size in bytes) of each file written, in order.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (generate, seed, params) in EXTRA_PLANTS.items():
        plant = generate(seed=seed, **params)
        for path, data in ((out_dir / f"{name}.obj", to_labelled_obj_bytes(plant)),
                           (out_dir / f"{name}.obj.traits.json", traits_to_json(plant).encode("utf-8"))):
            _write_atomic(path, data)
            written.append((path, len(data)))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", type=Path, default=DEFAULT_OUT_DIR,
                        help=f"directory to write into (default: {DEFAULT_OUT_DIR})")
    parser.add_argument("--extra", type=Path, default=None,
                        help="also write the labelled procedural plants of EXTRA_PLANTS into this directory")
    args = parser.parse_args(argv)
    for path, size in write_plants(args.out_dir):
        note = f" (< {MAX_STL_BYTES} bytes limit)" if path.suffix == ".stl" else ""
        print(f"wrote {path} {size} bytes{note}")
    if args.extra is not None:
        for path, size in write_extra_plants(args.extra):
            print(f"wrote {path} {size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
