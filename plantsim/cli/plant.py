"""``plantsim plant make KIND -o MESH``: a procedural plant with exact traits.

Writes the mesh (``.obj``: one object per organ, so ``plantsim scan MESH --evaluate``
also reads the organs; ``.stl``: binary, metres, z up) and its exact traits beside it
(``<mesh stem>.traits.json``, found by ``--evaluate``), then says whether the plant
fits the default rig. ``plantsim plant make KIND --list`` prints the parameters.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

# Generator and parameter class of each kind, by name in plantsim.plant.procedural.
KINDS = {"maize": ("make_maize", "MaizeParams"), "wheat": ("make_wheat", "WheatParams"),
         "rosette": ("make_rosette", "RosetteParams"), "dicot": ("make_dicot", "DicotParams")}
FORMATS = (".obj", ".stl")


def add_plant_commands(sub) -> None:
    """Registers ``plant make`` on the ``plantsim`` sub-parsers."""
    plant = sub.add_parser("plant", help="procedural plants with exact traits",
                           description=__doc__.splitlines()[0])
    plant_sub = plant.add_subparsers(dest="plant_command", required=True)
    make = plant_sub.add_parser("make", help="generate a plant mesh and its exact traits JSON",
                                description=__doc__.splitlines()[0])
    make.add_argument("kind", choices=sorted(KINDS), help="plant kind")
    make.add_argument("-o", "--output", type=Path, default=None,
                      help=f"mesh file to write ({', '.join(FORMATS)}); its traits go to <stem>.traits.json")
    make.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    make.add_argument("--set", dest="params", action="append", default=[], metavar="NAME=VALUE",
                      help="a generator parameter, e.g. --set n_leaves=12 (repeatable; see --list)")
    make.add_argument("--list", action="store_true", help="print the kind's parameters and defaults, and exit")
    make.set_defaults(func=cmd_plant_make)


def parse_params(items: list[str]) -> dict:
    """``["n_leaves=12", "leaflets=1"]`` -> ``{"n_leaves": 12, "leaflets": 1}`` (JSON values).

    Raises:
        ValueError: an item without ``=``.
    """
    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--set takes NAME=VALUE, got {item!r}")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        out[name.strip()] = value
    return out


def cmd_plant_make(args: argparse.Namespace) -> int:
    from plantsim.plant import procedural

    make_name, params_name = KINDS[args.kind]
    if args.list:
        for field in dataclasses.fields(getattr(procedural, params_name)):
            print(f"{field.name} = {field.default!r}")
        return 0
    if args.output is None or args.output.suffix.lower() not in FORMATS:
        print(f"plantsim plant make: give -o MESH ending in {' or '.join(FORMATS)}, got {args.output}",
              file=sys.stderr)
        return 2
    try:
        plant = getattr(procedural, make_name)(seed=args.seed, **parse_params(args.params))
    except ValueError as exc:
        print(f"plantsim plant make: {exc}", file=sys.stderr)
        return 2
    data = (procedural.to_labelled_obj_bytes(plant) if args.output.suffix.lower() == ".obj"
            else procedural.to_stl_bytes(plant))
    traits_path = args.output.with_suffix(".traits.json")
    args.output.write_bytes(data)
    traits_path.write_text(procedural.traits_to_json(plant), encoding="utf-8")
    t = plant.traits
    from plantsim.evaluation.traits import true_leaf_groups

    # Leaves as the traits count them: a compound leaf (laminae on one petiole) once.
    n_leaves, n_laminae = len(set(true_leaf_groups(t["leaves"]))), len(t["leaves"])
    print(f"wrote {args.output} ({len(plant.faces)} faces) and {traits_path}: height "
          f"{t['height_m'] * 1e3:.0f} mm, {len(t['stems'])} stem(s), {n_leaves} leaves"
          f"{f' ({n_laminae} laminae)' if n_laminae != n_leaves else ''}, "
          f"leaf area {t['leaf_area_m2'] * 1e4:.1f} cm^2")
    from plantsim.plant.mesh import plant_from_arrays
    from plantsim.rig.fit import rig_fit_warnings
    from plantsim.rig.geometry import RigGeometry
    from plantsim.sensor.spec import URG_04LX_UG01

    for warning in rig_fit_warnings(plant_from_arrays(plant.vertices_m, plant.faces), RigGeometry(),
                                    URG_04LX_UG01):
        print(f"default rig: {warning}")
    return 0
