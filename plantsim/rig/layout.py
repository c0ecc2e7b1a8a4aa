"""The rig's geoms without MuJoCo: what ``mjcf/rig.xml`` holds, placed by a RigGeometry.

A kinematic scan needs from the scene only where each surface is, what it is
(rig, turntable, plant) and whether it turns; it needs neither physics nor
MuJoCo's compiler. This module reads the subset of MJCF that plantsim's own rig
file uses (nested default classes setting ``group``; bodies with ``pos`` and
``quat``, at most a hinge joint; primitive geoms with ``type``, ``size``,
``pos``, ``quat``, ``class``, ``group``) into plain arrays, and places the parts
the rig geometry sizes (:func:`rig_placement`, the same numbers
:func:`plantsim.rig.scene.build_spec` writes into MuJoCo's spec). Anything else
in the file is refused with :class:`LayoutError`, and the scene then falls back
to MuJoCo's compiled model: the layout is never a guess.

Geom ids follow MuJoCo's order (bodies depth first, each body's geoms in file
order; the plant's body is the turntable's last child), so hits name the same
geoms whichever caster found them. ``tests/test_rig_layout.py`` compares every
geom's type, size, pose, group and id with MuJoCo's compiled model for several
rig geometries.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from plantsim.errors import PlantSimError
from plantsim.rig.geometry import RigGeometry

# MuJoCo's geom type names; the casters of plantsim.sensor.primitives handle these.
PRIMITIVE_TYPES = ("plane", "sphere", "cylinder", "box")
N_GROUPS = 6  # mujoco.mjNGROUP (a test checks it)

# Post behind the sensor, from the bench top up to the sensor's underside.
POST_BEHIND_M = 0.04
POST_RADIUS_M = 0.01
SENSOR_HALF_HEIGHT_M = 0.025
BENCH_HALF_THICKNESS_M = 0.01


class LayoutError(PlantSimError):
    """The rig file uses MJCF that this reader does not handle (MuJoCo's model is used instead)."""


@dataclasses.dataclass(frozen=True)
class Geom:
    """One geom of the scene, base frame with the turntable at angle 0.

    Attributes:
      name: the geom's name ("plant" for the plant's mesh).
      type: a MuJoCo geom type name ("box", "cylinder", ..., "mesh" for the plant).
      size: (3,) float64, MuJoCo's geom_size (half sizes; cylinder: radius, half height, 0).
      pos_base: (3,) float64, metres.
      R_base_geom: (3, 3) float64, the geom's axes in the base frame (columns).
      group: MuJoCo geom group (0 rig, 1 turntable, 2 plant, 3 the sensor's body).
      body: name of the body the geom belongs to ("world" for the fixed rig).
      turning: whether it turns with the table.
    """

    name: str
    type: str
    size: np.ndarray
    pos_base: np.ndarray
    R_base_geom: np.ndarray
    group: int
    body: str
    turning: bool


@dataclasses.dataclass(frozen=True)
class RigLayout:
    """The scene's geoms in MuJoCo's id order, and its bodies.

    Attributes:
      geoms: every geom, index = MuJoCo's geom id.
      bodies: body names, index = MuJoCo's body id ("world" first).
    """

    geoms: tuple[Geom, ...]
    bodies: tuple[str, ...]

    def body_id(self, name: str) -> int:
        return self.bodies.index(name)

    def geom_id(self, name: str) -> int:
        return [g.name for g in self.geoms].index(name)

    @property
    def turning(self) -> np.ndarray:
        """(ngeom,) bool: the geoms that turn with the table."""
        return np.array([g.turning for g in self.geoms], dtype=bool)

    @property
    def group(self) -> np.ndarray:
        """(ngeom,) int: each geom's group."""
        return np.array([g.group for g in self.geoms], dtype=np.int64)


def rig_placement(rig: RigGeometry, T_base_lidar: np.ndarray) -> dict:
    """What the rig geometry sets in the rig file: sizes and positions, base frame, metres.

    The one source of these numbers for both MuJoCo's spec
    (:func:`plantsim.rig.scene.build_spec`) and :func:`rig_layout`.

    Returns:
      ``{"geoms": {name: {"size": (3,) with NaN where the file's value stays,
      "pos": (3,)}}, "lidar_body": {"pos": (3,), "R": (3, 3)}}``.
    """
    bench_top_z = -rig.disk_thickness_m - rig.pedestal_height_m
    x_lo, x_hi = -rig.disk_radius_m - 0.2, rig.lidar_distance_m + 0.15
    yaw = math.radians(rig.yaw_deg)
    post_xy = T_base_lidar[:2, 3] + POST_BEHIND_M * np.array([math.cos(yaw), math.sin(yaw)])
    post_top_z = rig.lidar_height_m - SENSOR_HALF_HEIGHT_M
    half = max((post_top_z - bench_top_z) / 2, 1e-3)
    nan = math.nan
    return {
        "geoms": {
            "disk": {"size": np.array([rig.disk_radius_m, rig.disk_thickness_m / 2, 0.0]),
                     "pos": np.array([0.0, 0.0, -rig.disk_thickness_m / 2])},
            "pedestal": {"size": np.array([nan, rig.pedestal_height_m / 2, nan]),
                         "pos": np.array([0.0, 0.0, -rig.disk_thickness_m - rig.pedestal_height_m / 2])},
            "bench": {"size": np.array([(x_hi - x_lo) / 2, max(0.3, rig.disk_radius_m + 0.1),
                                        BENCH_HALF_THICKNESS_M]),
                      "pos": np.array([(x_hi + x_lo) / 2, 0.0, bench_top_z - BENCH_HALF_THICKNESS_M])},
            "lidar_post": {"size": np.array([POST_RADIUS_M, half, 0.0]),
                           "pos": np.array([post_xy[0], post_xy[1], bench_top_z + half])},
        },
        "lidar_body": {"pos": np.array(T_base_lidar[:3, 3], dtype=np.float64),
                       "R": np.array(T_base_lidar[:3, :3], dtype=np.float64)},
    }


def _floats(text: str | None, n: int, what: str) -> np.ndarray | None:
    if text is None:
        return None
    values = [float(v) for v in text.split()]
    if len(values) != n:
        raise LayoutError(f"{what}: expected {n} numbers, got {text!r}")
    return np.array(values, dtype=np.float64)


def quat_to_R(quat: np.ndarray) -> np.ndarray:
    """(4,) w x y z quaternion (normalised here, as MuJoCo does) -> (3, 3) rotation."""
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


_GEOM_ATTRS = {"name", "class", "type", "size", "pos", "quat", "group", "rgba", "contype", "conaffinity"}
_BODY_ATTRS = {"name", "pos", "quat"}
_BODY_CHILDREN = {"geom", "body", "joint", "inertial", "site"}
_SIZE_COUNT = {"plane": 3, "sphere": 1, "cylinder": 2, "box": 3}


@dataclasses.dataclass
class _Node:
    name: str
    pos: np.ndarray
    R: np.ndarray
    geoms: list
    children: list
    turns: bool


def _read_defaults(root: ET.Element) -> dict:
    """Class name -> geom group, through nested <default class="..."> blocks."""
    groups: dict[str, int] = {}

    def walk(element: ET.Element, inherited: int) -> None:
        group = inherited
        geom = element.find("geom")
        if geom is not None and geom.get("group") is not None:
            group = int(geom.get("group"))
        name = element.get("class", "main")
        groups[name] = group
        for child in element.findall("default"):
            walk(child, group)

    for default in root.findall("default"):
        walk(default, 0)
    return groups


def _read_body(element: ET.Element, name: str, groups: dict, *, turns: bool) -> _Node:
    extra = set(element.attrib) - _BODY_ATTRS
    if extra:
        raise LayoutError(f"body {name!r}: attributes {sorted(extra)} are not read without MuJoCo")
    pos = _floats(element.get("pos"), 3, f"body {name} pos")
    quat = _floats(element.get("quat"), 4, f"body {name} quat")
    node = _Node(name=name, pos=np.zeros(3) if pos is None else pos,
                 R=np.eye(3) if quat is None else quat_to_R(quat), geoms=[], children=[], turns=turns)
    for child in element:
        if child.tag not in _BODY_CHILDREN:
            raise LayoutError(f"body {name!r}: <{child.tag}> is not read without MuJoCo")
        if child.tag == "joint":
            axis = _floats(child.get("axis"), 3, "joint axis")
            if child.get("type", "hinge") != "hinge" or axis is None or not np.allclose(axis, [0, 0, 1]) \
                    or child.get("pos") not in (None, "0 0 0") or name != "turntable":
                raise LayoutError(f"body {name!r}: only the turntable's hinge about +Z is read without MuJoCo")
            node.turns = True
        elif child.tag == "geom":
            extra = set(child.attrib) - _GEOM_ATTRS
            if extra:
                raise LayoutError(f"geom {child.get('name')!r}: attributes {sorted(extra)} are not read "
                                  f"without MuJoCo")
            gtype = child.get("type", "sphere")
            if gtype not in PRIMITIVE_TYPES:
                raise LayoutError(f"geom {child.get('name')!r}: type {gtype!r} is not cast without MuJoCo")
            size = np.zeros(3)
            values = _floats(child.get("size"), _SIZE_COUNT[gtype], f"geom {child.get('name')} size")
            if values is not None:
                size[:len(values)] = values
            group = int(child.get("group", groups.get(child.get("class", "main"), 0)))
            gpos = _floats(child.get("pos"), 3, f"geom {child.get('name')} pos")
            gquat = _floats(child.get("quat"), 4, f"geom {child.get('name')} quat")
            node.geoms.append(dict(name=child.get("name", ""), type=gtype, size=size, group=group,
                                   pos=np.zeros(3) if gpos is None else gpos,
                                   R=np.eye(3) if gquat is None else quat_to_R(gquat)))
        elif child.tag == "body":
            node.children.append(_read_body(child, child.get("name", ""), groups, turns=node.turns))
    return node


@functools.lru_cache(maxsize=4)
def _read_rig_file(path: str) -> _Node:
    root = ET.parse(path).getroot()
    compiler = root.find("compiler")
    if compiler is None or compiler.get("angle") != "radian":
        raise LayoutError(f"{path}: the reader wants <compiler angle=\"radian\">")
    worldbody = root.find("worldbody")
    if worldbody is None:
        raise LayoutError(f"{path}: no <worldbody>")
    return _read_body(worldbody, "world", _read_defaults(root), turns=False)


def rig_file() -> Path:
    """The rig file the scene includes (``mjcf/rig.xml``, via ``mjcf/scene.xml``)."""
    from plantsim.resources import data_path

    scene = ET.parse(data_path("mjcf/scene.xml")).getroot()
    includes = [e.get("file") for e in scene.iter("include")]
    bodies = [e for e in scene.find("worldbody") if e.tag != "light"] if scene.find("worldbody") is not None else []
    if includes != ["rig.xml"] or bodies:
        raise LayoutError("mjcf/scene.xml must include rig.xml and add only lights to read without MuJoCo")
    return data_path("mjcf/rig.xml")


def rig_layout(rig: RigGeometry, *, with_plant: bool) -> RigLayout:
    """The scene's geoms as :func:`plantsim.rig.scene.build_scene` would compile them.

    Args:
      rig: the rig geometry.
      with_plant: whether the scene holds the plant (a mesh geom on its own body,
        the turntable's last child).

    Raises:
      LayoutError: the rig file uses MJCF this reader does not handle.
    """
    world = _read_rig_file(str(rig_file()))
    placement = rig_placement(rig, rig.T_base_lidar())
    set_geoms = placement["geoms"]
    found = set()
    bodies, geoms = [], []

    def visit(node: _Node, pos: np.ndarray, R: np.ndarray) -> None:
        if node.name == "lidar":
            pos, R = placement["lidar_body"]["pos"], placement["lidar_body"]["R"]
        elif node.name != "world":
            pos, R = pos + R @ node.pos, R @ node.R
        bodies.append(node.name)
        own = []
        for g in node.geoms:
            size, gpos = g["size"].copy(), g["pos"]
            if g["name"] in set_geoms:
                found.add(g["name"])
                new = set_geoms[g["name"]]
                size = np.where(np.isnan(new["size"]), size, new["size"])
                gpos = new["pos"]
            own.append(Geom(name=g["name"], type=g["type"], size=size, pos_base=pos + R @ gpos,
                            R_base_geom=R @ g["R"], group=g["group"], body=node.name, turning=node.turns))
        pending.append(own)
        for child in node.children:
            visit(child, pos, R)
        if node.name == "turntable" and with_plant:
            bodies.append("plant")
            pending.append([Geom(name="plant", type="mesh", size=np.zeros(3), pos_base=pos.copy(),
                                 R_base_geom=R.copy(), group=2, body="plant", turning=True)])

    pending: list[list[Geom]] = []
    visit(world, np.zeros(3), np.eye(3))
    missing = set(set_geoms) - found
    if missing or "turntable" not in bodies or "lidar" not in bodies:
        raise LayoutError(f"the rig file lacks {sorted(missing) or 'the turntable or lidar body'}")
    for own in pending:
        geoms.extend(own)
    return RigLayout(geoms=tuple(geoms), bodies=tuple(bodies))
