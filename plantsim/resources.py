"""Where the rig files (mjcf/) and bundled plants (assets/) are.

In a source checkout (or an editable install) they sit at the repository root;
a wheel carries them in ``plantsim/_data``.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def data_path(relative: str) -> Path:
    """Path of a shipped file, e.g. ``data_path("mjcf/scene.xml")``."""
    for root in (_PACKAGE_DIR / "_data", _PACKAGE_DIR.parent):
        candidate = root / relative
        if candidate.exists():
            return candidate
    raise FileNotFoundError(
        f"plantsim data file {relative!r} not found in {_PACKAGE_DIR / '_data'} or "
        f"{_PACKAGE_DIR.parent}; reinstall plantsim")


# The bundled meshes: two procedural plants and the calibration target
# (plantsim.plant.target), all metres, Z up.
BUNDLED_PLANTS = ("maize", "wheat", "calibration-target")


def bundled_plant_path(name: str) -> Path:
    """Path of a bundled mesh ("maize", "wheat" or "calibration-target"), metres, Z up."""
    if name not in BUNDLED_PLANTS:
        raise ValueError(f"unknown bundled plant {name!r}; choose one of {', '.join(BUNDLED_PLANTS)}")
    return data_path(f"assets/{name}.stl")
