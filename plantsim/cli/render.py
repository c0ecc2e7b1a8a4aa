"""``plantsim render``: a picture of the rig, the plant, the LiDAR's fan and a cloud."""

from __future__ import annotations

import argparse
from pathlib import Path

_CLOUD_SUFFIXES = (".las", ".laz", ".pcd", ".txt", ".xyz", ".pts", ".e57")


def _is_cloud(path: Path) -> bool:
    """Cloud formats by extension; a PLY is a cloud when it has no faces."""
    suffix = path.suffix.lower()
    if suffix in _CLOUD_SUFFIXES:
        return True
    if suffix == ".ply":
        head = path.read_bytes()[:4096]
        end = head.find(b"end_header")
        header = head[:end if end >= 0 else len(head)].decode("ascii", "replace")
        return not any(line.split()[:2] == ["element", "face"] and line.split()[2] != "0"
                       for line in header.splitlines() if len(line.split()) >= 3)
    return False


def cmd_render(args: argparse.Namespace) -> int:
    from plantsim.cloud.export import check_output_path, read_cloud, write_atomic  # noqa: F401
    from plantsim.cloud.render import View, png_bytes, render_cloud, render_scene
    from plantsim.scan.config import config_from_dict, load_settings, merge
    from plantsim.scan.pipeline import load_configured_plant

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValueError(f"the picture is a PNG: give -o a .png path, got {out}")
    if not (out.parent if str(out.parent) else Path(".")).is_dir():
        raise FileNotFoundError(f"output folder does not exist: {out.parent}")
    # A TOML's mesh path is relative to it, a sidecar's as recorded (as plantsim scan reads them).
    data, base_dir = load_settings(args.config) if args.config else ({}, None)
    cloud = None
    mesh = args.plant
    draw_plant = not args.no_plant
    said = ""
    if args.input:
        source = Path(args.input)
        if not source.is_file():
            raise FileNotFoundError(f"not found: {source}")
        if _is_cloud(source):
            cloud = read_cloud(source)
            # The cloud's own scan: its rig, LiDAR and plant, from the sidecar beside it,
            # not the defaults (a wheat's cloud was drawn round the bundled maize).
            sidecar = source.with_name(source.name + ".json")
            if not args.config and sidecar.is_file():
                data, base_dir = load_settings(sidecar)
                said = f"; rig, LiDAR and plant from {sidecar.name}"
            elif not args.config and not mesh and draw_plant:
                if args.colour == "error":
                    raise ValueError("--colour error measures each point's distance to the plant's mesh, and "
                                     f"no sidecar ({sidecar.name}) says which mesh the cloud scanned: give "
                                     "--plant MESH (with --units/--up) or --config")
                draw_plant = False
                said = ("; no sidecar beside the cloud: the default rig, and no plant (its mesh is not "
                        "known: --plant MESH or --config draws it)")
        else:
            mesh = str(source)
    overrides = {}
    if mesh:
        overrides["plant"] = {"mesh": mesh}
    for key in ("units", "up"):
        if getattr(args, key):
            overrides.setdefault("plant", {})[key] = getattr(args, key)
    # A mesh given on the command line is relative to the working directory.
    config = config_from_dict(merge(data, overrides), base_dir=None if mesh else base_dir)
    plant = load_configured_plant(config) if draw_plant else None
    view = View(width=args.width, height=args.height, azimuth_deg=args.azimuth,
                elevation_deg=args.elevation, distance_m=args.distance)
    lidar = None if args.no_fan else config.lidar
    if cloud is None:
        image = render_scene(config.rig, plant, lidar=lidar, view=view)
        what = "the rig" + (" and the plant" if plant is not None else "")
    else:
        if args.plant_only:
            cloud = cloud.plant_only()
        image = render_cloud(cloud, config.rig, plant, lidar=lidar, colour=args.colour, view=view)
        what = f"{len(cloud):,} points by {args.colour}"
    write_atomic(out, png_bytes(image))
    print(f"wrote {out} ({what}, {view.width}x{view.height}{said})")
    return 0


def add_render_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    render = subparsers.add_parser(
        "render", help="draw the rig, the plant, the LiDAR's fan and a cloud to a PNG",
        description="Draws the scan scene with MuJoCo's offscreen renderer (EGL, else OSMesa; "
                    "MUJOCO_GL=egl|osmesa chooses). Given a cloud, its points are coloured by "
                    "class (plant green, turntable blue, rig grey) or by distance to the plant "
                    "mesh (--colour error, blue 0 -> red at the 95th percentile).")
    render.add_argument("input", nargs="?", metavar="MESH|CLOUD",
                        help="a plant mesh (STL/OBJ/PLY with faces) or a cloud "
                             "(LAS/LAZ/PLY/PCD/TXT/XYZ/PTS) from plantsim scan; default: the "
                             "configured plant alone")
    render.add_argument("-o", "--output", required=True, help="the PNG to write")
    render.add_argument("--config", help="TOML of the scan (rig, lidar, plant) as for plantsim scan, or a "
                        "scan's sidecar (.json); default for a cloud: the sidecar beside it")
    render.add_argument("--plant", metavar="MESH", help="the plant mesh drawn with a cloud "
                                                        "(default: the configured plant)")
    render.add_argument("--units", choices=["m", "cm", "mm"], help="the mesh file's unit")
    render.add_argument("--up", choices=["x", "y", "z"], help="the mesh file's up axis")
    render.add_argument("--colour", "--color", choices=["class", "error"], default="class",
                        help="colour points by class or by distance to the plant mesh")
    render.add_argument("--plant-only", action="store_true", help="draw only the plant's points")
    render.add_argument("--no-plant", action="store_true", help="do not draw the plant mesh")
    render.add_argument("--no-fan", action="store_true", help="do not draw the LiDAR's fan")
    render.add_argument("--width", type=int, default=960, help="pixels (default 960)")
    render.add_argument("--height", type=int, default=720, help="pixels (default 720)")
    render.add_argument("--azimuth", type=float, default=210.0, help="camera azimuth, degrees")
    render.add_argument("--elevation", type=float, default=-25.0, help="camera elevation, degrees")
    render.add_argument("--distance", type=float, help="camera distance, metres (default: fit)")
    render.set_defaults(func=cmd_render)
    return render
