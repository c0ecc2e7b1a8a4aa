"""Procedural plants (maize, wheat, rosette, broad-leaved dicot) whose traits are exact
by construction.

The generator builds a plant from parameters and a seed, in the plant frame: Z up,
the base of the (main) stem at the origin, the lowest point of the mesh at z = 0.
Every trait it reports is computed from the very vertices it returns, so a
reconstruction or trait-extraction algorithm can be scored against exact ground truth.

Definitions used by the traits (``ProceduralPlant.traits``):

- Stem diameter: the *circumscribed* diameter of the stem's polygonal tube at its base,
  i.e. the diameter of the circle through the bottom ring's vertices. The inscribed
  diameter is smaller by the factor ``cos(pi / stem_sides)`` (0.995 for 32 sides).
- Stem top and height: the upper end of the organ axis: the centre of the stem's top cap
  (maize), the apex of the ear (wheat). The plant height is the maximum z of the mesh.
- Stem distances: between stem axes at z = 0 (the centres of the bottom rings).
- Leaf length: the length of the polyline through the leaf's midrib vertices, collar to
  tip. Midrib steps are unit tangents times a constant step, so it equals the arc length
  of the generating curve up to rounding.
- Leaf width: the largest chord between the two margin vertices of one cross-section.
- Leaf area: the summed area of the leaf's triangles (one side of the open sheet).
- Leaf inclination: the angle above the horizontal of the chord from the leaf's first
  midrib vertex (collar) to its tip, degrees (positive: tip above the collar), the
  definition ``plantsim.evaluation.traits`` uses on clouds.
- Dicot leaves: every lamina is a leaf in ``leaves`` (a trifoliate leaf adds three);
  petioles and branches are neither stem nor leaf (``PART_PETIOLE``, ``PART_BRANCH``).

Leaves are single open sheets (no thickness); stems and ears are closed tubes.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import struct
from typing import Any

import numpy as np

_LOG = logging.getLogger(__name__)

PART_STEM = 0
PART_LEAF = 1
PART_EAR = 2
PART_PETIOLE = 3
PART_BRANCH = 4
# Names of the part labels, for exporters and labelled-mesh readers.
PART_NAMES = {PART_STEM: "stem", PART_LEAF: "leaf", PART_EAR: "ear", PART_PETIOLE: "petiole",
              PART_BRANCH: "branch"}

# A leaf that would reach below this height has its droop reduced (leaves rest above the pot).
_GROUND_CLEARANCE = 0.002  # m
_DROOP_SHRINK = 0.85
_DROOP_ATTEMPTS = 40
# Leaves start slightly inside the stem surface so no gap shows at the collar.
_COLLAR_INSET = 0.9
# The ear starts this far inside the top of its stem, so the two closed tubes overlap.
_EAR_OVERLAP = 0.003  # m
# Significant digits kept in the traits JSON (about a nanometre on a plant): far below any
# physical meaning, far above last-bit differences between numpy trig builds on other CPUs.
_JSON_DIGITS = 9


# --------------------------------------------------------------------------- validation


def _as_int(name: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    try:
        converted = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}") from None
    if converted != value or not lo <= converted <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return converted


def _as_float(name: str, value: Any, lo: float, hi: float, unit: str, *, lo_open: bool = False) -> float:
    left = "(" if lo_open else "["
    expected = f"a number in {left}{lo}, {hi}] {unit}".rstrip()
    if isinstance(value, bool):
        raise ValueError(f"{name} must be {expected}, got {value!r}")
    try:
        converted = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {expected}, got {value!r}") from None
    inside = (lo < converted if lo_open else lo <= converted) and converted <= hi
    if not (math.isfinite(converted) and inside):
        raise ValueError(f"{name} must be {expected}, got {value!r}")
    return converted


def _set(obj: Any, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


def _validate_common(p: Any) -> None:
    """Checks the fields MaizeParams and WheatParams share; converts them in place."""
    _set(p, "stem_length", _as_float("stem_length", p.stem_length, 0.05, 3.0, "m"))
    _set(p, "stem_diameter", _as_float("stem_diameter", p.stem_diameter, 0.0, 0.1, "m", lo_open=True))
    _set(p, "stem_top_diameter",
         _as_float("stem_top_diameter", p.stem_top_diameter, 0.0, 0.1, "m", lo_open=True))
    if p.stem_top_diameter > p.stem_diameter:
        raise ValueError(
            f"stem_top_diameter must not exceed stem_diameter ({p.stem_diameter} m), "
            f"got {p.stem_top_diameter}")
    if p.stem_diameter * 5 > p.stem_length:
        raise ValueError(
            f"stem_diameter must be at most stem_length / 5 ({p.stem_length / 5} m), got {p.stem_diameter}")
    _set(p, "stem_sides", _as_int("stem_sides", p.stem_sides, 24, 256))
    _set(p, "stem_rings", _as_int("stem_rings", p.stem_rings, 2, 1000))
    _set(p, "leaf_length", _as_float("leaf_length", p.leaf_length, 0.0, 2.0, "m", lo_open=True))
    _set(p, "leaf_width", _as_float("leaf_width", p.leaf_width, 0.0, 0.3, "m", lo_open=True))
    if p.leaf_width >= p.leaf_length:
        raise ValueError(f"leaf_width must be less than leaf_length ({p.leaf_length} m), got {p.leaf_width}")
    _set(p, "leaf_collar_fraction",
         _as_float("leaf_collar_fraction", p.leaf_collar_fraction, 0.0, 1.0, "", lo_open=True))
    _set(p, "leaf_insertion_angle_deg",
         _as_float("leaf_insertion_angle_deg", p.leaf_insertion_angle_deg, 1.0, 80.0, "deg"))
    _set(p, "leaf_tip_angle_deg",
         _as_float("leaf_tip_angle_deg", p.leaf_tip_angle_deg, 1.0, 170.0, "deg"))
    if p.leaf_tip_angle_deg < p.leaf_insertion_angle_deg:
        raise ValueError(
            f"leaf_tip_angle_deg must be at least leaf_insertion_angle_deg "
            f"({p.leaf_insertion_angle_deg} deg), got {p.leaf_tip_angle_deg}")
    _set(p, "leaf_angle_jitter_deg",
         _as_float("leaf_angle_jitter_deg", p.leaf_angle_jitter_deg, 0.0, 30.0, "deg"))
    _set(p, "leaf_twist_deg", _as_float("leaf_twist_deg", p.leaf_twist_deg, 0.0, 360.0, "deg"))
    _set(p, "leaf_curl_deg", _as_float("leaf_curl_deg", p.leaf_curl_deg, 0.0, 90.0, "deg"))
    _set(p, "leaf_fold", _as_float("leaf_fold", p.leaf_fold, 0.0, 1.0, ""))
    _set(p, "leaf_wave_amplitude",
         _as_float("leaf_wave_amplitude", p.leaf_wave_amplitude, 0.0, 0.05, "m"))
    _set(p, "leaf_wave_length",
         _as_float("leaf_wave_length", p.leaf_wave_length, 0.0, 1.0, "m", lo_open=True))
    _set(p, "phyllotaxy_deg", _as_float("phyllotaxy_deg", p.phyllotaxy_deg, 0.0, 360.0, "deg"))
    _set(p, "phyllotaxy_jitter_deg",
         _as_float("phyllotaxy_jitter_deg", p.phyllotaxy_jitter_deg, 0.0, 90.0, "deg"))
    _set(p, "size_jitter", _as_float("size_jitter", p.size_jitter, 0.0, 0.3, ""))
    _set(p, "leaf_segments", _as_int("leaf_segments", p.leaf_segments, 4, 1000))
    _set(p, "leaf_width_segments", _as_int("leaf_width_segments", p.leaf_width_segments, 2, 64))
    if p.leaf_width_segments % 2:
        raise ValueError(
            "leaf_width_segments must be even (the midrib is the middle column of vertices), "
            f"got {p.leaf_width_segments}")
    _set(p, "lowest_leaf_fraction",
         _as_float("lowest_leaf_fraction", p.lowest_leaf_fraction, 0.0, 1.0, "", lo_open=True))
    _set(p, "highest_leaf_fraction",
         _as_float("highest_leaf_fraction", p.highest_leaf_fraction, 0.0, 1.0, "", lo_open=True))
    if p.highest_leaf_fraction < p.lowest_leaf_fraction:
        raise ValueError(
            f"highest_leaf_fraction must be at least lowest_leaf_fraction ({p.lowest_leaf_fraction}), "
            f"got {p.highest_leaf_fraction}")


# ------------------------------------------------------------------------- parameters


@dataclasses.dataclass(frozen=True, kw_only=True)
class MaizeParams:
    """Parameters of a young maize plant (one stem, distichous strap leaves).

    Lengths are in metres, angles in degrees (``_deg``). Per-leaf sizes follow a
    profile over the leaf's rank (largest a little above mid-height, as in a young
    plant) scaled so the largest leaf has ``leaf_length`` and ``leaf_width``, then
    jittered by ``size_jitter``.

    Attributes:
        n_leaves: Number of leaves, 1-30.
        stem_length: Arc length of the stem axis, base to top cap, m.
        stem_diameter: Circumscribed stem diameter at the base, m.
        stem_top_diameter: Circumscribed stem diameter at the top, m (linear taper).
        stem_lean_deg: Largest lean of the stem top from vertical; the stem is a circular
            arc, vertical at its base, leaning by a random fraction of this.
        stem_sides: Sides of the stem polygon, 24-256.
        stem_rings: Rings of vertices along the stem, base and top included.
        leaf_length: Length of the longest leaf (before jitter), m.
        leaf_width: Maximum width of the widest leaf (before jitter), m.
        leaf_collar_fraction: Width at the collar over the leaf's maximum width.
        leaf_insertion_angle_deg: Midrib angle from vertical at the collar, lowest leaf;
            upper leaves are more erect.
        leaf_tip_angle_deg: Midrib angle from vertical at the tip, lowest leaf (above 90
            the tip points down); upper leaves arch less.
        leaf_angle_jitter_deg: Uniform jitter of the insertion angle.
        leaf_twist_deg: Largest twist of a leaf about its midrib, collar to tip.
        leaf_curl_deg: Largest sideways turn of the midrib, collar to tip.
        leaf_fold: Rise of the margins over the midrib, as a fraction of the half-width.
        leaf_wave_amplitude: Amplitude of the margin undulation, m.
        leaf_wave_length: Wavelength of the margin undulation along the leaf, m.
        phyllotaxy_deg: Azimuth between successive leaves (180 = distichous).
        phyllotaxy_jitter_deg: Uniform jitter of each leaf's azimuth.
        size_jitter: Relative uniform jitter of leaf lengths, widths and droops.
        leaf_segments: Segments along each leaf (rows of vertices, plus the tip).
        leaf_width_segments: Segments across each leaf; even, so a column is the midrib.
        lowest_leaf_fraction: Insertion of the lowest leaf, as a fraction of stem_length.
        highest_leaf_fraction: Insertion of the highest leaf, as a fraction of stem_length.
    """

    n_leaves: int = 9
    stem_length: float = 0.42
    stem_diameter: float = 0.014
    stem_top_diameter: float = 0.008
    stem_lean_deg: float = 3.0
    stem_sides: int = 32
    stem_rings: int = 40
    leaf_length: float = 0.40
    leaf_width: float = 0.052
    leaf_collar_fraction: float = 0.35
    leaf_insertion_angle_deg: float = 35.0
    leaf_tip_angle_deg: float = 125.0
    leaf_angle_jitter_deg: float = 5.0
    leaf_twist_deg: float = 40.0
    leaf_curl_deg: float = 10.0
    leaf_fold: float = 0.12
    leaf_wave_amplitude: float = 0.0015
    leaf_wave_length: float = 0.05
    phyllotaxy_deg: float = 180.0
    phyllotaxy_jitter_deg: float = 12.0
    size_jitter: float = 0.08
    leaf_segments: int = 80
    leaf_width_segments: int = 10
    lowest_leaf_fraction: float = 0.06
    highest_leaf_fraction: float = 0.90

    def __post_init__(self) -> None:
        _set(self, "n_leaves", _as_int("n_leaves", self.n_leaves, 1, 30))
        _set(self, "stem_lean_deg", _as_float("stem_lean_deg", self.stem_lean_deg, 0.0, 30.0, "deg"))
        _validate_common(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class WheatParams:
    """Parameters of a wheat plant at heading (tillers, narrow leaves, an ear on each).

    Lengths are in metres, angles in degrees (``_deg``). Tiller 0 (the main stem)
    stands at the origin; the others stand around it at ``tiller_spacing`` and lean
    outwards. Leaf sizes follow a profile over the leaf's rank on its tiller.

    Attributes:
        n_tillers: Number of tillers (stems), 1-8.
        tiller_spacing: Distance of the other tillers' bases from the main stem's base, m.
        tiller_splay_deg: Lean of the outer tillers' tops from vertical, outwards.
        stem_length: Arc length of the main stem, base to the ear, m; other tillers are
            86-97 % of it.
        stem_diameter: Circumscribed stem diameter at the base, m.
        stem_top_diameter: Circumscribed stem diameter below the ear, m (linear taper).
        stem_sides: Sides of the stem polygon, 24-256.
        stem_rings: Rings of vertices along each stem, base and top included.
        leaves_per_tiller: Leaves on each tiller, 1-8 (the top one is the flag leaf).
        leaf_length: Length of the longest leaf (before jitter), m.
        leaf_width: Maximum width of the widest leaf (before jitter), m.
        ear_length: Length of the ear (spike), m.
        ear_width: Width of the ear across its two rows of spikelets, m.
        ear_thickness: Thickness of the ear, m.
        ear_spikelets: Spikelets on each side of the ear (a zig-zag of bulges).
        ear_sides: Sides of the ear's cross-section polygon.
        ear_rings: Rings of vertices along the ear (its two apexes are extra vertices).
        (other fields): as in MaizeParams.
    """

    n_tillers: int = 4
    tiller_spacing: float = 0.035
    tiller_splay_deg: float = 8.0
    stem_length: float = 0.47
    stem_diameter: float = 0.004
    stem_top_diameter: float = 0.0032
    stem_sides: int = 24
    stem_rings: int = 30
    leaves_per_tiller: int = 4
    leaf_length: float = 0.20
    leaf_width: float = 0.010
    leaf_collar_fraction: float = 0.7
    leaf_insertion_angle_deg: float = 30.0
    leaf_tip_angle_deg: float = 140.0
    leaf_angle_jitter_deg: float = 6.0
    leaf_twist_deg: float = 90.0
    leaf_curl_deg: float = 15.0
    leaf_fold: float = 0.10
    leaf_wave_amplitude: float = 0.0
    leaf_wave_length: float = 0.05
    phyllotaxy_deg: float = 180.0
    phyllotaxy_jitter_deg: float = 15.0
    size_jitter: float = 0.06
    leaf_segments: int = 50
    leaf_width_segments: int = 4
    lowest_leaf_fraction: float = 0.06
    highest_leaf_fraction: float = 0.68
    ear_length: float = 0.08
    ear_width: float = 0.012
    ear_thickness: float = 0.008
    ear_spikelets: int = 18
    ear_sides: int = 16
    ear_rings: int = 48

    def __post_init__(self) -> None:
        _set(self, "n_tillers", _as_int("n_tillers", self.n_tillers, 1, 8))
        _set(self, "tiller_splay_deg",
             _as_float("tiller_splay_deg", self.tiller_splay_deg, 0.0, 45.0, "deg"))
        _set(self, "leaves_per_tiller", _as_int("leaves_per_tiller", self.leaves_per_tiller, 1, 8))
        _set(self, "ear_length", _as_float("ear_length", self.ear_length, 0.0, 0.5, "m", lo_open=True))
        _set(self, "ear_width", _as_float("ear_width", self.ear_width, 0.0, 0.1, "m", lo_open=True))
        _set(self, "ear_thickness",
             _as_float("ear_thickness", self.ear_thickness, 0.0, 0.1, "m", lo_open=True))
        _set(self, "ear_spikelets", _as_int("ear_spikelets", self.ear_spikelets, 1, 100))
        _set(self, "ear_sides", _as_int("ear_sides", self.ear_sides, 6, 256))
        _set(self, "ear_rings", _as_int("ear_rings", self.ear_rings, 2, 1000))
        _validate_common(self)
        _set(self, "tiller_spacing",
             _as_float("tiller_spacing", self.tiller_spacing, 0.0, 0.5, "m", lo_open=True))
        # Bases may move by size_jitter; keep the tubes apart at the base.
        min_spacing = 2.0 * self.stem_diameter / (1.0 - self.size_jitter)
        if self.n_tillers > 1 and self.tiller_spacing < min_spacing:
            raise ValueError(
                f"tiller_spacing must be at least {min_spacing:.4g} m so the stems do not touch "
                f"(2 x stem_diameter / (1 - size_jitter)), got {self.tiller_spacing}")


# ------------------------------------------------------------------------------ result


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class ProceduralPlant:
    """A generated plant: mesh, part labels and exact traits.

    Attributes:
        name: "maize", "wheat", "rosette" or "dicot".
        vertices_m: (n, 3) float64, metres, plant frame (Z up, main stem base at the
            origin, lowest point at z = 0). Read-only.
        faces: (m, 3) int64 vertex indices; stems and ears are wound outwards, leaves
            towards their upper (adaxial) side. Read-only.
        face_part: (m,) int64, PART_STEM (0), PART_LEAF (1), PART_EAR (2), PART_PETIOLE (3)
            or PART_BRANCH (4). Read-only.
        face_organ: (m,) int64, the stem index for stem and ear faces, the leaf index for
            leaf faces, the petiole's (petiolate leaf's) index for petiole faces, the
            branch index for branch faces. Read-only.
        traits: Exact traits, in the JSON schema written by ``traits_to_json``.
        params: The parameters the plant was made from.
    """

    name: str
    vertices_m: np.ndarray
    faces: np.ndarray
    face_part: np.ndarray
    face_organ: np.ndarray
    traits: dict
    params: MaizeParams | WheatParams | RosetteParams | DicotParams


# ------------------------------------------------------------------------ geometry core


def _arc_axis(s: np.ndarray, length: float, lean: float, azimuth: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit tangents of a stem axis: a circular arc, vertical at its base.

    The tangent turns from vertical by lean * s / length towards ``azimuth``.

    Args:
        s: (k,) float64, arc length from the base, m.
        length: Arc length of the whole axis, m.
        lean: Angle of the top tangent from vertical, rad.
        azimuth: Direction of the lean in the XY plane, rad from +X.

    Returns:
        points: (k, 3) float64, m, relative to the base.
        tangents: (k, 3) float64, unit.
    """
    angle = lean * s / length
    if lean == 0.0:
        horizontal = np.zeros_like(s)
        vertical = s.astype(np.float64)
    else:
        radius = length / lean
        horizontal = 2.0 * radius * np.sin(0.5 * angle) ** 2  # = R (1 - cos angle), stable
        vertical = radius * np.sin(angle)
    direction = np.array([math.cos(azimuth), math.sin(azimuth)])
    points = np.column_stack([horizontal * direction[0], horizontal * direction[1], vertical])
    tangents = np.column_stack(
        [np.sin(angle) * direction[0], np.sin(angle) * direction[1], np.cos(angle)])
    return points, tangents


def _tube(rings: np.ndarray, bottom: np.ndarray, top: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube from rings of vertices and a pole vertex at each end.

    Args:
        rings: (k, sides, 3) float64, m; each ring counter-clockwise about the axis
            direction (bottom to top).
        bottom: (3,) float64, m, the bottom pole (cap centre or apex).
        top: (3,) float64, m, the top pole.

    Returns:
        vertices: (k * sides + 2, 3) float64, m: the rings in order, then bottom, top.
        faces: (2 * sides * k, 3) int64, wound outwards.
    """
    k, sides, _ = rings.shape
    vertices = np.concatenate([rings.reshape(-1, 3), bottom[None], top[None]])
    a = np.arange(sides)
    a2 = (a + 1) % sides
    i = np.arange(k - 1)[:, None] * sides
    v00, v01 = i + a, i + a2
    v10, v11 = v00 + sides, v01 + sides
    side = np.concatenate([
        np.stack([v00, v01, v11], axis=-1).reshape(-1, 3),
        np.stack([v00, v11, v10], axis=-1).reshape(-1, 3),
    ])
    bottom_index, top_index = k * sides, k * sides + 1
    last = (k - 1) * sides
    caps = np.concatenate([
        np.column_stack([np.full(sides, bottom_index), a2, a]),
        np.column_stack([np.full(sides, top_index), last + a, last + a2]),
    ])
    return vertices, np.concatenate([side, caps]).astype(np.int64)


def _frames(tangents: np.ndarray, azimuth: float) -> tuple[np.ndarray, np.ndarray]:
    """Ring frames of a planar stem arc: (b, n, t) right-handed, b fixed and horizontal.

    Args:
        tangents: (k, 3) float64, unit tangents of an arc leaning towards ``azimuth``.
        azimuth: The arc's lean direction, rad.

    Returns:
        b: (k, 3) float64, unit, horizontal, perpendicular to the arc's plane.
        n: (k, 3) float64, unit, cross(t, b).
    """
    b = np.tile([-math.sin(azimuth), math.cos(azimuth), 0.0], (len(tangents), 1))
    return b, np.cross(tangents, b)


def _stem(base_xy: np.ndarray, length: float, lean: float, azimuth: float,
          radius_base: float, radius_top: float, sides: int, n_rings: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stem tube along a leaning arc; returns vertices, faces and the axis top point."""
    s = np.linspace(0.0, length, n_rings)
    axis, tangents = _arc_axis(s, length, lean, azimuth)
    axis = axis + np.array([base_xy[0], base_xy[1], 0.0])
    b, n = _frames(tangents, azimuth)
    radius = radius_base + (radius_top - radius_base) * s / length
    alpha = 2.0 * np.pi * np.arange(sides) / sides
    ring_dirs = (np.cos(alpha)[None, :, None] * b[:, None, :]
                 + np.sin(alpha)[None, :, None] * n[:, None, :])
    rings = axis[:, None, :] + radius[:, None, None] * ring_dirs
    # The base ring lies in z = 0 exactly: its tangent is vertical, b and n horizontal.
    rings[0, :, 2] = 0.0
    vertices, faces = _tube(rings, axis[0], axis[-1])
    return vertices, faces, axis[-1]


def _ear(start: np.ndarray, direction: np.ndarray, b: np.ndarray, length: float, width: float,
         thickness: float, spikelets: int, sides: int, n_rings: int, roll: float
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wheat spike: a closed spindle with alternating spikelet bulges on two rows.

    Args:
        start: (3,) float64, m, the bottom apex.
        direction: (3,) float64, unit, the ear axis.
        b: (3,) float64, unit, perpendicular to ``direction``; rolled by ``roll`` rad
            to give the plane of the two spikelet rows.

    Returns:
        vertices, faces as ``_tube``, and the top apex (3,) float64, m.
    """
    n = np.cross(direction, b)
    b_rows = math.cos(roll) * b + math.sin(roll) * n
    n_rows = np.cross(direction, b_rows)
    t = np.arange(1, n_rings + 1) / (n_rings + 1)
    envelope = (4.0 * t * (1.0 - t)) ** 0.3 * (1.0 - 0.2 * t)
    alpha = 2.0 * np.pi * np.arange(sides) / sides
    cos_a, sin_a = np.cos(alpha), np.sin(alpha)
    # Spikelets alternate between the two rows: half a period apart (pi) on either side.
    side_phase = np.where(cos_a < 0.0, np.pi, 0.0)
    bulge = 1.0 + 0.15 * np.sin(2.0 * np.pi * spikelets * t[:, None] + side_phase[None, :])
    half_width = 0.5 * width / 1.15 * envelope[:, None] * bulge
    half_thick = 0.5 * thickness * envelope[:, None] * np.ones_like(bulge)
    centres = start + (t * length)[:, None] * direction
    rings = (centres[:, None, :]
             + (half_width * cos_a)[..., None] * b_rows
             + (half_thick * sin_a)[..., None] * n_rows)
    top = start + length * direction
    vertices, faces = _tube(rings, start, top)
    return vertices, faces, top


def _width_profile(t: np.ndarray, collar: float, peak: float, tip_power: float) -> np.ndarray:
    """Leaf width over its maximum, collar (t = 0) to tip (t = 1, width 0)."""
    rise = collar + (1.0 - collar) * np.sin(0.5 * np.pi * np.clip(t / peak, 0.0, 1.0))
    fall = 1.0 - np.clip((t - peak) / (1.0 - peak), 0.0, 1.0) ** tip_power
    return np.where(t < peak, rise, fall)


@dataclasses.dataclass(frozen=True)
class _LeafShape:
    base: np.ndarray        # (3,) m, first midrib vertex
    azimuth: float          # rad
    length: float           # m
    width: float            # m, maximum of the profile
    theta0: float           # rad from vertical at the collar
    droop: float            # rad added to theta0 at the tip
    curl: float             # rad of azimuth drift, collar to tip
    twist: float            # rad about the midrib, collar to tip
    fold: float
    wave_amplitude: float   # m
    wave_length: float      # m
    wave_phase: tuple       # rad, (left margin, right margin)
    collar: float
    peak: float
    tip_power: float
    segments: int
    width_segments: int


def _leaf(shape: _LeafShape, droop_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """An open leaf sheet: rows of vertices across a drooping midrib, then the tip.

    Returns:
        vertices: (segments * (width_segments + 1) + 1, 3) float64, m, plant frame;
            row-major (row i = cross-section at s = i * length / segments, column
            width_segments / 2 is the midrib), the tip last.
        faces: (m, 3) int64, wound towards the upper side.
    """
    n_rows, n_cols = shape.segments, shape.width_segments + 1
    ds = shape.length / n_rows
    droop = shape.droop * droop_scale

    def direction(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta = shape.theta0 + droop * t ** 1.5
        phi = shape.azimuth + shape.curl * t
        return theta, phi

    # Midrib: constant steps of length ds along unit tangents taken mid-step, so the
    # polyline's length is exactly the leaf length.
    theta_m, phi_m = direction((np.arange(n_rows) + 0.5) / n_rows)
    steps = ds * np.column_stack(
        [np.sin(theta_m) * np.cos(phi_m), np.sin(theta_m) * np.sin(phi_m), np.cos(theta_m)])
    midrib = shape.base + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])

    t_row = np.arange(n_rows) / n_rows
    theta_r, phi_r = direction(t_row)
    tangent = np.column_stack(
        [np.sin(theta_r) * np.cos(phi_r), np.sin(theta_r) * np.sin(phi_r), np.cos(theta_r)])
    across = np.column_stack([np.sin(phi_r), -np.cos(phi_r), np.zeros(n_rows)])  # horizontal
    up = np.cross(across, tangent)
    psi = shape.twist * t_row
    across_t = np.cos(psi)[:, None] * across + np.sin(psi)[:, None] * up
    up_t = np.cross(across_t, tangent)

    half = 0.5 * shape.width * _width_profile(t_row, shape.collar, shape.peak, shape.tip_power)
    u = np.linspace(-1.0, 1.0, n_cols)
    phase = np.where(u < 0.0, shape.wave_phase[0], shape.wave_phase[1])
    wave = (shape.wave_amplitude * (half / (0.5 * shape.width))[:, None] * np.abs(u)[None, :] ** 3
            * np.sin(2.0 * np.pi * (t_row * shape.length)[:, None] / shape.wave_length + phase[None, :]))
    offset_across = half[:, None] * u[None, :]
    offset_up = shape.fold * half[:, None] * u[None, :] ** 2 + wave
    grid = (midrib[:n_rows, None, :]
            + offset_across[..., None] * across_t[:, None, :]
            + offset_up[..., None] * up_t[:, None, :])
    grid[:, n_cols // 2] = midrib[:n_rows]  # the midrib column, exactly
    vertices = np.concatenate([grid.reshape(-1, 3), midrib[-1:]])

    i = np.arange(n_rows - 1)[:, None] * n_cols
    j = np.arange(n_cols - 1)[None, :]
    v00, v01 = i + j, i + j + 1
    v10, v11 = v00 + n_cols, v01 + n_cols
    last = (n_rows - 1) * n_cols + np.arange(n_cols - 1)
    tip = np.full(n_cols - 1, n_rows * n_cols)
    faces = np.concatenate([
        np.stack([v00, v01, v11], axis=-1).reshape(-1, 3),
        np.stack([v00, v11, v10], axis=-1).reshape(-1, 3),
        np.column_stack([last, last + 1, tip]),
    ])
    return vertices, faces.astype(np.int64)


def _grounded_leaf(shape: _LeafShape, index: int) -> tuple[np.ndarray, np.ndarray]:
    """``_leaf``, with its droop reduced until it stays above the ground clearance."""
    scale = 1.0
    for _ in range(_DROOP_ATTEMPTS):
        vertices, faces = _leaf(shape, scale)
        if vertices[:, 2].min() >= _GROUND_CLEARANCE:
            if scale != 1.0:
                _LOG.debug("leaf %d: droop scaled by %.3f to stay above the ground", index, scale)
            return vertices, faces
        scale *= _DROOP_SHRINK
    raise ValueError(
        f"leaf {index} reaches below z = {_GROUND_CLEARANCE} m even without droop; "
        "raise lowest_leaf_fraction or lower leaf_insertion_angle_deg or leaf_twist_deg")


def _triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


# --------------------------------------------------------------------------- assembly


class _Builder:
    """Collects organ meshes into one vertex/face list with part and organ labels."""

    def __init__(self) -> None:
        self._vertices: list[np.ndarray] = []
        self._faces: list[np.ndarray] = []
        self._part: list[np.ndarray] = []
        self._organ: list[np.ndarray] = []
        self._count = 0

    def add(self, vertices: np.ndarray, faces: np.ndarray, part: int, organ: int) -> np.ndarray:
        """Adds a block; returns its faces re-indexed into the whole mesh."""
        shifted = faces + self._count
        self._vertices.append(vertices)
        self._faces.append(shifted)
        self._part.append(np.full(len(faces), part, dtype=np.int64))
        self._organ.append(np.full(len(faces), organ, dtype=np.int64))
        self._count += len(vertices)
        return shifted

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.concatenate(self._vertices), np.concatenate(self._faces),
                np.concatenate(self._part), np.concatenate(self._organ))


def _leaf_traits(index: int, stem: int, vertices: np.ndarray, faces: np.ndarray,
                 shape: _LeafShape) -> dict:
    n_rows, n_cols = shape.segments, shape.width_segments + 1
    grid = vertices[:-1].reshape(n_rows, n_cols, 3)
    midrib = np.concatenate([grid[:, n_cols // 2], vertices[-1:]])
    chord = midrib[-1] - midrib[0]
    return {
        "index": index,
        "stem": stem,
        "insertion_height_m": float(midrib[0, 2]),
        "length_m": float(np.linalg.norm(np.diff(midrib, axis=0), axis=1).sum()),
        "width_m": float(np.linalg.norm(grid[:, 0] - grid[:, -1], axis=1).max()),
        "area_m2": float(_triangle_areas(vertices, faces).sum()),
        "inclination_deg": float(np.degrees(np.arctan2(chord[2], np.hypot(chord[0], chord[1])))),
    }


def _finish(name: str, seed: int, params: Any, builder: _Builder,
            stems: list[dict], leaves: list[dict]) -> ProceduralPlant:
    vertices, faces, part, organ = builder.arrays()
    bases = np.array([s["base_xy_m"] for s in stems])
    pairs, nearest = [], []
    if len(stems) > 1:
        dist = np.linalg.norm(bases[:, None] - bases[None], axis=-1)
        for i in range(len(stems)):
            for j in range(i + 1, len(stems)):
                pairs.append({"stems": [i, j], "distance_m": float(dist[i, j])})
        np.fill_diagonal(dist, np.inf)
        nearest = dist.min(axis=1)
    traits = {
        "name": name,
        "generator": f"plantsim.plant.procedural.make_{name}",
        "seed": seed,
        "params": dataclasses.asdict(params),
        "units": "m",
        "up": "z",
        "height_m": float(vertices[:, 2].max()),
        "stem_diameter_m": float(np.mean([s["diameter_m"] for s in stems])),
        "stems": stems,
        "stem_distances_m": pairs,
        # Two aggregates, named for what they are (plantsim.evaluation.traits uses the same):
        # the mean over all pairs, and the mean distance to the nearest other stem.
        "mean_stem_distance_m": (float(np.mean([p["distance_m"] for p in pairs]))
                                 if len(stems) > 1 else None),
        "mean_nearest_stem_distance_m": float(np.mean(nearest)) if len(stems) > 1 else None,
        "leaves": leaves,
        "leaf_width_m": max(leaf["width_m"] for leaf in leaves),
        "leaf_length_m": max(leaf["length_m"] for leaf in leaves),
        "leaf_area_m2": float(sum(leaf["area_m2"] for leaf in leaves)),
        "n_vertices": int(len(vertices)),
        "n_faces": int(len(faces)),
    }
    for array in (vertices, faces, part, organ):
        array.setflags(write=False)
    return ProceduralPlant(name=name, vertices_m=vertices, faces=faces, face_part=part,
                           face_organ=organ, traits=traits, params=params)


def _make_params(cls: type, params: dict) -> Any:
    names = [field.name for field in dataclasses.fields(cls)]
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise ValueError(f"unknown {cls.__name__} field(s) {unknown}; valid names: {', '.join(names)}")
    return cls(**params)


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _leaf_rank_angles(p: Any, q: float, u_angle: float, u_droop: float,
                      erect: float, arch: float) -> tuple[float, float]:
    """Insertion angle and droop of a leaf at rank q (0 lowest, 1 highest), rad."""
    theta0_low = math.radians(p.leaf_insertion_angle_deg)
    theta0 = theta0_low * (1.0 - erect * q) + math.radians(p.leaf_angle_jitter_deg) * u_angle
    theta0 = max(theta0, math.radians(1.0))
    droop = (math.radians(p.leaf_tip_angle_deg) - theta0_low) * (1.0 - arch * q)
    return theta0, droop * (1.0 + p.size_jitter * u_droop)


# ---------------------------------------------------------------------------- plants


@dataclasses.dataclass(frozen=True)
class _MainStem:
    """The one leaning, tapering main stem of a maize or a dicot (its mesh already built).

    Attributes:
        length, lean, lean_azimuth: the stem's arc (metres, radians).
        first_azimuth: the azimuth of the first leaf, radians.
        r_base, r_top: radius at the base and the top, metres.
        truth: the plant's ``stems`` truth record (one stem).
    """

    length: float
    lean: float
    lean_azimuth: float
    first_azimuth: float
    r_base: float
    r_top: float
    truth: list

    def node(self, fraction: float) -> tuple[np.ndarray, float]:
        """The axis point (3,) and the stem's radius at ``fraction`` of its length."""
        axis, _ = _arc_axis(np.array([self.length * fraction]), self.length, self.lean, self.lean_azimuth)
        return axis[0], self.r_base + (self.r_top - self.r_base) * fraction


def _main_stem(builder: "_Builder", p: Any, rng: np.random.Generator) -> _MainStem:
    """Draws the stem's lean and the first leaf's azimuth (three numbers from ``rng``, in that
    order), adds the stem's mesh to ``builder`` and returns it (``p``: the plant's
    parameters with ``stem_length``, ``stem_lean_deg``, diameters, sides and rings)."""
    lean = math.radians(p.stem_lean_deg) * rng.uniform()
    lean_azimuth = rng.uniform(0.0, 2.0 * np.pi)
    first_azimuth = rng.uniform(0.0, 2.0 * np.pi)
    r_base, r_top = 0.5 * p.stem_diameter, 0.5 * p.stem_top_diameter
    stem_vertices, stem_faces, top = _stem(np.zeros(2), p.stem_length, lean, lean_azimuth,
                                           r_base, r_top, p.stem_sides, p.stem_rings)
    builder.add(stem_vertices, stem_faces, PART_STEM, 0)
    truth = [{"index": 0, "base_xy_m": [0.0, 0.0], "diameter_m": 2.0 * r_base,
              "height_m": float(top[2]), "top_xyz_m": [float(c) for c in top]}]
    return _MainStem(p.stem_length, lean, lean_azimuth, first_azimuth, r_base, r_top, truth)


def make_maize(*, seed: int = 0, **params: Any) -> ProceduralPlant:
    """Generates a young maize plant: one tapering stem with distichous strap leaves.

    Args:
        seed: Seed of the ``numpy.random.default_rng`` that draws the jitter.
        **params: Fields of ``MaizeParams`` to override.

    Returns:
        The plant, with exact traits (see the module docstring for their definitions).

    Raises:
        ValueError: An unknown or invalid parameter, or a negative seed.
    """
    seed = _check_seed(seed)
    p: MaizeParams = _make_params(MaizeParams, params)
    rng = np.random.default_rng(seed)
    builder = _Builder()
    stem = _main_stem(builder, p, rng)
    n = p.n_leaves
    u = rng.uniform(-1.0, 1.0, size=(7, n))
    wave_phase = rng.uniform(0.0, 2.0 * np.pi, size=(n, 2))

    leaves = []
    for k in range(n):
        q = k / (n - 1) if n > 1 else 0.5
        # Young maize: leaves grow longer and wider up to a little above mid-rank.
        length_factor = 0.45 + 0.55 * math.exp(-((q - 0.6) / 0.35) ** 2)
        width_factor = 0.42 + 0.58 * math.exp(-((q - 0.6) / 0.4) ** 2)
        fraction = p.lowest_leaf_fraction + (p.highest_leaf_fraction - p.lowest_leaf_fraction) * q ** 1.5
        node, r_here = stem.node(fraction)
        azimuth = (stem.first_azimuth + k * math.radians(p.phyllotaxy_deg)
                   + math.radians(p.phyllotaxy_jitter_deg) * u[0, k])
        base = node + _COLLAR_INSET * r_here * np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
        theta0, droop = _leaf_rank_angles(p, q, u[1, k], u[2, k], erect=0.6, arch=0.55)
        shape = _LeafShape(
            base=base, azimuth=azimuth,
            length=p.leaf_length * length_factor * (1.0 + p.size_jitter * u[3, k]),
            width=p.leaf_width * width_factor * (1.0 + p.size_jitter * u[4, k]),
            theta0=theta0, droop=droop,
            curl=math.radians(p.leaf_curl_deg) * u[5, k],
            twist=math.radians(p.leaf_twist_deg) * u[6, k],
            fold=p.leaf_fold, wave_amplitude=p.leaf_wave_amplitude,
            wave_length=p.leaf_wave_length, wave_phase=tuple(wave_phase[k]),
            collar=p.leaf_collar_fraction, peak=0.4, tip_power=1.6,
            segments=p.leaf_segments, width_segments=p.leaf_width_segments)
        vertices, faces = _grounded_leaf(shape, k)
        builder.add(vertices, faces, PART_LEAF, k)
        leaves.append(_leaf_traits(k, 0, vertices, faces, shape))
    return _finish("maize", seed, p, builder, stem.truth, leaves)


def make_wheat(*, seed: int = 0, **params: Any) -> ProceduralPlant:
    """Generates a wheat plant at heading: tillers with narrow leaves and an ear each.

    Args:
        seed: Seed of the ``numpy.random.default_rng`` that draws the jitter.
        **params: Fields of ``WheatParams`` to override.

    Returns:
        The plant, with exact traits (see the module docstring for their definitions).

    Raises:
        ValueError: An unknown or invalid parameter, or a negative seed.
    """
    seed = _check_seed(seed)
    p: WheatParams = _make_params(WheatParams, params)
    rng = np.random.default_rng(seed)
    n_tillers, n_leaves = p.n_tillers, p.leaves_per_tiller
    first_azimuth = rng.uniform(0.0, 2.0 * np.pi)
    tiller_u = rng.uniform(-1.0, 1.0, size=(6, n_tillers))
    leaf_u = rng.uniform(-1.0, 1.0, size=(8, n_tillers, n_leaves))
    wave_phase = rng.uniform(0.0, 2.0 * np.pi, size=(n_tillers, n_leaves, 2))

    builder = _Builder()
    stems, leaves = [], []
    slot = 2.0 * np.pi / max(n_tillers - 1, 1)
    for i in range(n_tillers):
        if i == 0:
            base_xy = np.zeros(2)
            length = p.stem_length
            lean = math.radians(p.tiller_splay_deg) * 0.3 * (0.5 + 0.5 * tiller_u[0, i])
            lean_azimuth = np.pi * tiller_u[1, i]
        else:
            azimuth = first_azimuth + (i - 1) * slot + 0.25 * slot * tiller_u[1, i]
            distance = p.tiller_spacing * (1.0 + p.size_jitter * tiller_u[2, i])
            base_xy = distance * np.array([math.cos(azimuth), math.sin(azimuth)])
            length = p.stem_length * (0.915 + 0.055 * tiller_u[3, i])
            lean = math.radians(p.tiller_splay_deg) * (0.85 + 0.15 * tiller_u[0, i])
            lean_azimuth = azimuth + 0.2 * tiller_u[4, i]
        r_base = 0.5 * p.stem_diameter * (1.0 + 0.5 * p.size_jitter * tiller_u[5, i])
        r_top = r_base * p.stem_top_diameter / p.stem_diameter
        stem_vertices, stem_faces, stem_top = _stem(base_xy, length, lean, lean_azimuth,
                                                    r_base, r_top, p.stem_sides, p.stem_rings)
        builder.add(stem_vertices, stem_faces, PART_STEM, i)

        _, top_tangent = _arc_axis(np.array([length]), length, lean, lean_azimuth)
        direction = top_tangent[0]
        b, _ = _frames(top_tangent, lean_azimuth)
        ear_length = p.ear_length * (1.0 + p.size_jitter * tiller_u[3, i])
        ear_vertices, ear_faces, apex = _ear(
            stem_top - _EAR_OVERLAP * direction, direction, b[0], ear_length, p.ear_width,
            p.ear_thickness, p.ear_spikelets, p.ear_sides, p.ear_rings,
            roll=float(np.pi * tiller_u[4, i]))
        builder.add(ear_vertices, ear_faces, PART_EAR, i)
        stems.append({"index": i, "base_xy_m": [float(c) for c in base_xy],
                      "diameter_m": float(2.0 * r_base), "height_m": float(apex[2]),
                      "top_xyz_m": [float(c) for c in apex]})

        leaf_azimuth0 = np.pi * leaf_u[0, i, 0]
        for k in range(n_leaves):
            index = len(leaves)
            q = k / (n_leaves - 1) if n_leaves > 1 else 1.0
            # Wheat at heading: the penultimate leaf is the longest, the flag leaf the widest.
            length_factor = 0.65 + 0.35 * math.exp(-((q - 0.7) / 0.4) ** 2)
            width_factor = 0.75 + 0.25 * q
            fraction = (p.lowest_leaf_fraction
                        + (p.highest_leaf_fraction - p.lowest_leaf_fraction) * q ** 1.3)
            s_insert = length * fraction
            axis, _ = _arc_axis(np.array([s_insert]), length, lean, lean_azimuth)
            azimuth = (leaf_azimuth0 + k * math.radians(p.phyllotaxy_deg)
                       + math.radians(p.phyllotaxy_jitter_deg) * leaf_u[1, i, k])
            r_here = r_base + (r_top - r_base) * fraction
            base = (axis[0] + np.array([base_xy[0], base_xy[1], 0.0])
                    + _COLLAR_INSET * r_here * np.array([math.cos(azimuth), math.sin(azimuth), 0.0]))
            theta0, droop = _leaf_rank_angles(p, q, leaf_u[2, i, k], leaf_u[3, i, k],
                                              erect=0.3, arch=0.35)
            shape = _LeafShape(
                base=base, azimuth=azimuth,
                length=p.leaf_length * length_factor * (1.0 + p.size_jitter * leaf_u[4, i, k]),
                width=p.leaf_width * width_factor * (1.0 + p.size_jitter * leaf_u[5, i, k]),
                theta0=theta0, droop=droop,
                curl=math.radians(p.leaf_curl_deg) * leaf_u[6, i, k],
                twist=math.radians(p.leaf_twist_deg) * leaf_u[7, i, k],
                fold=p.leaf_fold, wave_amplitude=p.leaf_wave_amplitude,
                wave_length=p.leaf_wave_length, wave_phase=tuple(wave_phase[i, k]),
                collar=p.leaf_collar_fraction, peak=0.25, tip_power=2.5,
                segments=p.leaf_segments, width_segments=p.leaf_width_segments)
            vertices, faces = _grounded_leaf(shape, index)
            builder.add(vertices, faces, PART_LEAF, index)
            leaves.append(_leaf_traits(index, i, vertices, faces, shape))
    return _finish("wheat", seed, p, builder, stems, leaves)


# -------------------------------------------------------------------------- exporters


@dataclasses.dataclass(frozen=True, kw_only=True)
class RosetteParams:
    """A rosette (lettuce, Arabidopsis, spinach): broad leaves radiating from a short crown.

    Leaves spiral at the golden angle, the outer (older) ones longer, flatter and
    wider; neighbours overlap when ``n_leaves`` is large, as in a real rosette.
    Lengths in metres, angles in degrees.
    """

    n_leaves: int = 12
    crown_height: float = 0.02        # m, the short stem (hypocotyl + crown)
    crown_diameter: float = 0.008     # m
    leaf_length: float = 0.12         # m, the outermost leaf
    leaf_width: float = 0.06          # m, the outermost leaf's widest chord
    outer_angle_deg: float = 70.0     # from vertical at the collar, outermost leaf
    inner_angle_deg: float = 25.0     # from vertical at the collar, innermost leaf
    droop_deg: float = 25.0           # added towards the tip
    size_jitter: float = 0.1          # relative
    leaf_segments: int = 24
    leaf_width_segments: int = 8
    stem_sides: int = 24

    def __post_init__(self) -> None:
        _set(self, "n_leaves", _as_int("n_leaves", self.n_leaves, 1, 60))
        for name, hi in (("crown_height", 0.5), ("crown_diameter", 0.1), ("leaf_length", 2.0),
                         ("leaf_width", 1.0)):
            _set(self, name, _as_float(name, getattr(self, name), 0.0, hi, "m", lo_open=True))
        for name in ("outer_angle_deg", "inner_angle_deg", "droop_deg"):
            _set(self, name, _as_float(name, getattr(self, name), 0.0, 89.0, "deg"))
        _set(self, "size_jitter", _as_float("size_jitter", self.size_jitter, 0.0, 0.5, ""))
        _set(self, "leaf_segments", _as_int("leaf_segments", self.leaf_segments, 4, 400))
        _set(self, "leaf_width_segments", _as_int("leaf_width_segments", self.leaf_width_segments, 2, 64))
        _set(self, "stem_sides", _as_int("stem_sides", self.stem_sides, 6, 128))
        if self.leaf_width_segments % 2:
            raise ValueError(f"leaf_width_segments must be even (the midrib is the middle column), "
                             f"got {self.leaf_width_segments}")


GOLDEN_ANGLE_DEG = 137.50776405003785


def make_rosette(*, seed: int = 0, **params: Any) -> ProceduralPlant:
    """Generates a rosette plant: a short crown and broad spiralled leaves.

    Leaf k (0 outermost) leaves the crown top at azimuth ``k * 137.5 deg`` (golden
    angle, with jitter), length and width falling from the outermost to 45 % of it
    for the innermost, collar angle from ``outer_angle_deg`` to ``inner_angle_deg``.
    Broad elliptic blades (widest at 45 % of the length, short petiole-like collar).

    Args:
        seed: Seed of the ``numpy.random.default_rng`` that draws the jitter.
        **params: Fields of ``RosetteParams`` to override.

    Returns:
        The plant, with exact traits (module docstring definitions; stem = the crown).

    Raises:
        ValueError: An unknown or invalid parameter, or a negative seed.
    """
    seed = _check_seed(seed)
    p: RosetteParams = _make_params(RosetteParams, params)
    rng = np.random.default_rng(seed)
    n = p.n_leaves
    u = rng.uniform(-1.0, 1.0, size=(5, n))
    builder = _Builder()
    r = 0.5 * p.crown_diameter
    stem_vertices, stem_faces, top = _stem(np.zeros(2), p.crown_height, 0.0, 0.0, r, r, p.stem_sides, 3)
    builder.add(stem_vertices, stem_faces, PART_STEM, 0)
    stems = [{"index": 0, "base_xy_m": [0.0, 0.0], "diameter_m": 2.0 * r,
              "height_m": float(top[2]), "top_xyz_m": [float(c) for c in top]}]
    first = rng.uniform(0.0, 2.0 * np.pi)
    leaves = []
    for k in range(n):
        q = k / (n - 1) if n > 1 else 0.0          # 0 outermost, 1 innermost
        size = (1.0 - 0.55 * q)
        azimuth = first + k * math.radians(GOLDEN_ANGLE_DEG) + math.radians(8.0) * u[0, k]
        theta0 = math.radians(p.outer_angle_deg + (p.inner_angle_deg - p.outer_angle_deg) * q
                              + 5.0 * u[1, k])
        theta0 = min(max(theta0, math.radians(1.0)), math.radians(88.0))
        # The collars stack up the crown's top few millimetres, inner leaves higher.
        z = p.crown_height * (0.8 + 0.2 * q)
        base = np.array([0.9 * r * math.cos(azimuth), 0.9 * r * math.sin(azimuth), z])
        shape = _LeafShape(
            base=base, azimuth=azimuth,
            length=p.leaf_length * size * (1.0 + p.size_jitter * u[2, k]),
            width=p.leaf_width * size * (1.0 + p.size_jitter * u[3, k]),
            theta0=theta0, droop=math.radians(p.droop_deg) * (1.0 - 0.5 * q) * (1.0 + p.size_jitter * u[4, k]),
            curl=0.0, twist=0.0, fold=0.05, wave_amplitude=0.0, wave_length=1.0, wave_phase=(0.0, 0.0),
            collar=0.08, peak=0.45, tip_power=2.0,
            segments=p.leaf_segments, width_segments=p.leaf_width_segments)
        vertices, faces = _grounded_leaf(shape, k)
        builder.add(vertices, faces, PART_LEAF, k)
        leaves.append(_leaf_traits(k, 0, vertices, faces, shape))
    return _finish("rosette", seed, p, builder, stems, leaves)



# ----------------------------------------------------------------------------- dicot


@dataclasses.dataclass(frozen=True, kw_only=True)
class DicotParams:
    """A broad-leaved dicot (bean, soybean, pepper): an upright stem with petiolate leaves.

    The main stem carries its leaves one per node, spiralled by ``phyllotaxy_deg``; each
    leaf is a petiole ending in one lamina (``leaflets=1``, a simple leaf) or, past a
    short rachis, a terminal leaflet with two lateral leaflets at the petiole's end
    (``leaflets=3``, trifoliate as in bean and soybean). Optional branches rise from the
    axils of the lowest nodes and carry ``leaves_per_branch`` leaves each. Leaf sizes
    follow a profile over the node's rank (the middle leaves largest, the youngest at
    the top smallest). Every lamina is a leaf of the traits (``leaves``).

    Touching leaves: short internodes (``stem_length`` small for ``n_leaves``), large
    laminae (``leaflet_length``/``leaflet_width``) and a small ``phyllotaxy_deg`` stack
    the laminae over each other, so their surfaces touch or overlap in projection.

    Attributes:
        n_leaves: Petiolate leaves on the whole plant, 1-30 (laminae: ``leaflets`` each).
        leaflets: 1 (simple leaves) or 3 (trifoliate).
        stem_length: Arc length of the main stem, base to apex, m.
        stem_diameter: Circumscribed stem diameter at the base, m.
        stem_top_diameter: Circumscribed stem diameter at the apex, m (linear taper).
        stem_lean_deg: Largest lean of the stem top from vertical (random fraction of it).
        stem_sides: Sides of the stem polygon, 24-256.
        stem_rings: Rings of vertices along the stem.
        lowest_node_fraction: Height of the lowest node, fraction of stem_length.
        highest_node_fraction: Height of the highest node, fraction of stem_length.
        phyllotaxy_deg: Azimuth between successive nodes (137.5 = golden angle).
        phyllotaxy_jitter_deg: Uniform jitter of each node's azimuth.
        petiole_length: Petiole length of the largest leaf, m (rachis not included).
        petiole_diameter: Petiole diameter, m.
        petiole_angle_deg: Petiole angle from vertical, lowest leaf (upper ones 30 % more erect).
        rachis_length: Of a trifoliate leaf: petiole extension to the terminal leaflet, m.
        leaflet_length: Lamina length of the largest (terminal) leaflet, m.
        leaflet_width: Lamina width of the largest (terminal) leaflet, m.
        lateral_leaflet_scale: Lateral leaflet size over the terminal one's.
        lateral_leaflet_angle_deg: Azimuth of the lateral leaflets from the petiole's.
        leaf_angle_deg: Lamina midrib angle from vertical at its base (90 horizontal).
        leaf_droop_deg: Added to leaf_angle_deg towards the lamina tip.
        leaf_angle_jitter_deg: Uniform jitter of leaf_angle_deg.
        leaf_fold: Rise of the lamina margins over the midrib, fraction of the half-width.
        leaf_twist_deg: Largest twist of a lamina about its midrib.
        n_branches: Branches from the axils of the lowest nodes, 0-4.
        branch_angle_deg: Branch angle from vertical.
        branch_length_fraction: Branch length over stem_length.
        branch_diameter: Branch diameter, m.
        leaves_per_branch: Leaves on each branch (counted in n_leaves).
        size_jitter: Relative uniform jitter of petiole and lamina sizes and droops.
        leaf_segments: Segments along each lamina.
        leaf_width_segments: Segments across each lamina; even (the midrib is a column).
        petiole_sides: Sides of the petiole and branch polygons.
    """

    n_leaves: int = 8
    leaflets: int = 3
    stem_length: float = 0.30
    stem_diameter: float = 0.007
    stem_top_diameter: float = 0.004
    stem_lean_deg: float = 3.0
    stem_sides: int = 24
    stem_rings: int = 30
    lowest_node_fraction: float = 0.3
    highest_node_fraction: float = 0.97
    phyllotaxy_deg: float = GOLDEN_ANGLE_DEG
    phyllotaxy_jitter_deg: float = 8.0
    petiole_length: float = 0.07
    petiole_diameter: float = 0.0025
    petiole_angle_deg: float = 50.0
    rachis_length: float = 0.02
    leaflet_length: float = 0.085
    leaflet_width: float = 0.055
    lateral_leaflet_scale: float = 0.85
    lateral_leaflet_angle_deg: float = 65.0
    leaf_angle_deg: float = 80.0
    leaf_droop_deg: float = 20.0
    leaf_angle_jitter_deg: float = 8.0
    leaf_fold: float = 0.08
    leaf_twist_deg: float = 10.0
    n_branches: int = 0
    branch_angle_deg: float = 35.0
    branch_length_fraction: float = 0.45
    branch_diameter: float = 0.004
    leaves_per_branch: int = 2
    size_jitter: float = 0.08
    leaf_segments: int = 16
    leaf_width_segments: int = 8
    petiole_sides: int = 8

    def __post_init__(self) -> None:
        _set(self, "n_leaves", _as_int("n_leaves", self.n_leaves, 1, 30))
        _set(self, "leaflets", _as_int("leaflets", self.leaflets, 1, 3))
        if self.leaflets == 2:
            raise ValueError("leaflets must be 1 (simple leaves) or 3 (trifoliate), got 2")
        _set(self, "stem_length", _as_float("stem_length", self.stem_length, 0.05, 3.0, "m"))
        for name in ("stem_diameter", "stem_top_diameter", "petiole_diameter", "branch_diameter"):
            _set(self, name, _as_float(name, getattr(self, name), 0.0, 0.1, "m", lo_open=True))
        if self.stem_top_diameter > self.stem_diameter:
            raise ValueError(f"stem_top_diameter must not exceed stem_diameter ({self.stem_diameter} m), "
                             f"got {self.stem_top_diameter}")
        if self.stem_diameter * 5 > self.stem_length:
            raise ValueError(f"stem_diameter must be at most stem_length / 5 ({self.stem_length / 5} m), "
                             f"got {self.stem_diameter}")
        _set(self, "stem_lean_deg", _as_float("stem_lean_deg", self.stem_lean_deg, 0.0, 30.0, "deg"))
        _set(self, "stem_sides", _as_int("stem_sides", self.stem_sides, 24, 256))
        _set(self, "stem_rings", _as_int("stem_rings", self.stem_rings, 2, 1000))
        for name in ("lowest_node_fraction", "highest_node_fraction"):
            _set(self, name, _as_float(name, getattr(self, name), 0.0, 1.0, "", lo_open=True))
        if self.highest_node_fraction < self.lowest_node_fraction:
            raise ValueError(f"highest_node_fraction must be at least lowest_node_fraction "
                             f"({self.lowest_node_fraction}), got {self.highest_node_fraction}")
        _set(self, "phyllotaxy_deg", _as_float("phyllotaxy_deg", self.phyllotaxy_deg, 0.0, 360.0, "deg"))
        _set(self, "phyllotaxy_jitter_deg",
             _as_float("phyllotaxy_jitter_deg", self.phyllotaxy_jitter_deg, 0.0, 90.0, "deg"))
        for name, hi in (("petiole_length", 0.5), ("leaflet_length", 0.5), ("leaflet_width", 0.5)):
            _set(self, name, _as_float(name, getattr(self, name), 0.0, hi, "m", lo_open=True))
        _set(self, "rachis_length", _as_float("rachis_length", self.rachis_length, 0.0, 0.2, "m"))
        if self.leaflet_width >= self.leaflet_length:
            raise ValueError(f"leaflet_width must be less than leaflet_length ({self.leaflet_length} m), "
                             f"got {self.leaflet_width}")
        if self.petiole_diameter * 4 > self.petiole_length:
            raise ValueError(f"petiole_diameter must be at most petiole_length / 4 "
                             f"({self.petiole_length / 4} m), got {self.petiole_diameter}")
        _set(self, "lateral_leaflet_scale",
             _as_float("lateral_leaflet_scale", self.lateral_leaflet_scale, 0.2, 1.5, ""))
        _set(self, "lateral_leaflet_angle_deg",
             _as_float("lateral_leaflet_angle_deg", self.lateral_leaflet_angle_deg, 10.0, 120.0, "deg"))
        _set(self, "petiole_angle_deg", _as_float("petiole_angle_deg", self.petiole_angle_deg, 0.0, 85.0, "deg"))
        _set(self, "leaf_angle_deg", _as_float("leaf_angle_deg", self.leaf_angle_deg, 10.0, 110.0, "deg"))
        _set(self, "leaf_droop_deg", _as_float("leaf_droop_deg", self.leaf_droop_deg, 0.0, 60.0, "deg"))
        _set(self, "leaf_angle_jitter_deg",
             _as_float("leaf_angle_jitter_deg", self.leaf_angle_jitter_deg, 0.0, 30.0, "deg"))
        _set(self, "leaf_fold", _as_float("leaf_fold", self.leaf_fold, 0.0, 1.0, ""))
        _set(self, "leaf_twist_deg", _as_float("leaf_twist_deg", self.leaf_twist_deg, 0.0, 90.0, "deg"))
        _set(self, "n_branches", _as_int("n_branches", self.n_branches, 0, 4))
        _set(self, "branch_angle_deg", _as_float("branch_angle_deg", self.branch_angle_deg, 5.0, 80.0, "deg"))
        _set(self, "branch_length_fraction",
             _as_float("branch_length_fraction", self.branch_length_fraction, 0.05, 1.0, ""))
        _set(self, "leaves_per_branch", _as_int("leaves_per_branch", self.leaves_per_branch, 1, 10))
        _set(self, "size_jitter", _as_float("size_jitter", self.size_jitter, 0.0, 0.3, ""))
        _set(self, "leaf_segments", _as_int("leaf_segments", self.leaf_segments, 4, 400))
        _set(self, "leaf_width_segments", _as_int("leaf_width_segments", self.leaf_width_segments, 2, 64))
        if self.leaf_width_segments % 2:
            raise ValueError(f"leaf_width_segments must be even (the midrib is the middle column), "
                             f"got {self.leaf_width_segments}")
        _set(self, "petiole_sides", _as_int("petiole_sides", self.petiole_sides, 6, 64))
        on_stem = self.n_leaves - self.n_branches * self.leaves_per_branch
        if on_stem < max(self.n_branches, 1):
            raise ValueError(
                f"n_leaves must be at least n_branches * (leaves_per_branch + 1) = "
                f"{self.n_branches * (self.leaves_per_branch + 1)} (each branch rises from a leaf's "
                f"axil on the main stem), got {self.n_leaves}; lower n_branches or leaves_per_branch")


def _rod(start: np.ndarray, end: np.ndarray, radius: float, sides: int
         ) -> tuple[np.ndarray, np.ndarray]:
    """A straight closed tube (petiole, branch) from ``start`` to ``end``, m."""
    axis = end - start
    t = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    b = np.cross(helper, t)
    b /= np.linalg.norm(b)
    n = np.cross(t, b)
    alpha = 2.0 * np.pi * np.arange(sides) / sides
    ring = radius * (np.cos(alpha)[:, None] * b + np.sin(alpha)[:, None] * n)
    rings = np.stack([start + ring, end + ring])
    return _tube(rings, start, end)


def _polar(theta: float, azimuth: float) -> np.ndarray:
    """Unit vector at ``theta`` rad from vertical towards ``azimuth`` rad from +X."""
    return np.array([math.sin(theta) * math.cos(azimuth), math.sin(theta) * math.sin(azimuth),
                     math.cos(theta)])


def make_dicot(*, seed: int = 0, **params: Any) -> ProceduralPlant:
    """Generates a broad-leaved dicot: an upright stem, petioles and flat ovate laminae.

    Node k of the main stem (0 lowest) sits at a height between
    ``lowest_node_fraction`` and ``highest_node_fraction`` of the stem, its leaf at
    azimuth ``k * phyllotaxy_deg`` (with jitter). Branches rise from the axils of the
    lowest ``n_branches`` nodes, leaning ``branch_angle_deg`` towards their node's leaf
    (offset by a quarter turn so the two do not coincide) and carry their leaves
    along their upper half. Laminae are ovate (widest at 35 % of their length, tapering
    to an acute tip) and nearly flat.

    Args:
        seed: Seed of the ``numpy.random.default_rng`` that draws the jitter.
        **params: Fields of ``DicotParams`` to override.

    Returns:
        The plant, with exact traits (see the module docstring), plus ``petioles``
        (per leaf: ``index``, ``axis`` ("stem" or "branch"), ``axis_index``,
        ``length_m`` including the rachis, ``leaves``: its laminae's indices) and
        ``branches`` (``index``, ``node``, ``base_xyz_m``, ``length_m``, ``diameter_m``).

    Raises:
        ValueError: An unknown or invalid parameter, or a negative seed.
    """
    seed = _check_seed(seed)
    p: DicotParams = _make_params(DicotParams, params)
    rng = np.random.default_rng(seed)
    builder = _Builder()
    stem = _main_stem(builder, p, rng)
    n = p.n_leaves
    u = rng.uniform(-1.0, 1.0, size=(6, n))
    blade_u = rng.uniform(-1.0, 1.0, size=(5, n, 3))
    branch_u = rng.uniform(-1.0, 1.0, size=(2, max(p.n_branches, 1)))

    # Where each leaf attaches: (axis point, axis radius, azimuth, rank q, axis kind, axis index).
    n_stem_leaves = n - p.n_branches * p.leaves_per_branch
    attachments = []
    for k in range(n_stem_leaves):
        q = k / (n_stem_leaves - 1) if n_stem_leaves > 1 else 0.5
        fraction = p.lowest_node_fraction + (p.highest_node_fraction - p.lowest_node_fraction) * q
        node, radius = stem.node(fraction)
        azimuth = (stem.first_azimuth + k * math.radians(p.phyllotaxy_deg)
                   + math.radians(p.phyllotaxy_jitter_deg) * u[0, k])
        attachments.append((node, radius, azimuth, q, "stem", 0))
    branches = []
    for i in range(p.n_branches):
        node_point, node_radius, node_azimuth, q_node = attachments[i][:4]
        azimuth = node_azimuth + 0.5 * np.pi * (1.0 if i % 2 == 0 else -1.0) + 0.2 * branch_u[0, i]
        direction = _polar(math.radians(p.branch_angle_deg) * (1.0 + 0.1 * branch_u[1, i]), azimuth)
        length = p.branch_length_fraction * p.stem_length
        radius = 0.5 * min(p.branch_diameter, 2.0 * node_radius)
        start = node_point
        end = start + length * direction
        vertices, faces = _rod(start, end, radius, p.petiole_sides)
        builder.add(vertices, faces, PART_BRANCH, i)
        branches.append({"index": i, "node": i, "base_xyz_m": [float(c) for c in start],
                         "length_m": length, "diameter_m": 2.0 * radius})
        for j in range(p.leaves_per_branch):
            f = 0.5 + 0.5 * (j + 1) / p.leaves_per_branch
            leaf_azimuth = (azimuth + (j + 1) * math.radians(p.phyllotaxy_deg)
                            + math.radians(p.phyllotaxy_jitter_deg) * u[0, len(attachments)])
            attachments.append((start + f * length * direction, radius, leaf_azimuth,
                                min(q_node + 0.3 + 0.2 * j, 1.0), "branch", i))

    leaves, petioles = [], []
    for k, (point, axis_radius, azimuth, q, axis_kind, axis_index) in enumerate(attachments):
        # The middle leaves are the largest, the young top ones the smallest.
        size = (0.55 + 0.45 * math.exp(-((q - 0.45) / 0.4) ** 2)) * (1.0 + p.size_jitter * u[1, k])
        petiole_theta = math.radians(p.petiole_angle_deg) * (1.0 - 0.3 * q) * (1.0 + 0.1 * u[2, k])
        direction = _polar(petiole_theta, azimuth)
        petiole_length = p.petiole_length * size
        total = petiole_length + (p.rachis_length * size if p.leaflets == 3 else 0.0)
        start = point + _COLLAR_INSET * axis_radius * np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
        end = start + total * direction
        vertices, faces = _rod(start, end, 0.5 * p.petiole_diameter, p.petiole_sides)
        builder.add(vertices, faces, PART_PETIOLE, k)
        blades = [("terminal", end, azimuth, 1.0)]
        if p.leaflets == 3:
            fork = start + petiole_length * direction
            spread = math.radians(p.lateral_leaflet_angle_deg)
            blades += [("lateral", fork, azimuth + spread, p.lateral_leaflet_scale),
                       ("lateral", fork, azimuth - spread, p.lateral_leaflet_scale)]
        indices = []
        for b, (role, base, blade_azimuth, scale) in enumerate(blades):
            index = len(leaves)
            jitter = blade_u[:, k, b]
            # Each lamina starts a petiole radius out along its own azimuth (a short
            # petiolule), so the three leaflets of a trifoliate leaf share no point.
            base = base + 0.5 * p.petiole_diameter * np.array(
                [math.cos(blade_azimuth), math.sin(blade_azimuth), 0.0])
            shape = _LeafShape(
                base=base, azimuth=blade_azimuth + 0.1 * jitter[0],
                length=p.leaflet_length * size * scale * (1.0 + 0.5 * p.size_jitter * jitter[1]),
                width=p.leaflet_width * size * scale * (1.0 + 0.5 * p.size_jitter * jitter[2]),
                theta0=math.radians(p.leaf_angle_deg + p.leaf_angle_jitter_deg * jitter[3]),
                droop=math.radians(p.leaf_droop_deg) * (1.0 + p.size_jitter * jitter[4]),
                curl=0.0, twist=math.radians(p.leaf_twist_deg) * jitter[0],
                fold=p.leaf_fold, wave_amplitude=0.0, wave_length=1.0, wave_phase=(0.0, 0.0),
                collar=0.04, peak=0.35, tip_power=1.4,
                segments=p.leaf_segments, width_segments=p.leaf_width_segments)
            vertices, faces = _grounded_leaf(shape, index)
            builder.add(vertices, faces, PART_LEAF, index)
            traits = _leaf_traits(index, 0, vertices, faces, shape)
            traits.update({"petiole": k, "leaflet": role})
            leaves.append(traits)
            indices.append(index)
        petioles.append({"index": k, "axis": axis_kind, "axis_index": axis_index,
                         "length_m": float(total), "diameter_m": p.petiole_diameter, "leaves": indices})
    plant = _finish("dicot", seed, p, builder, stem.truth, leaves)
    plant.traits["petioles"] = petioles
    plant.traits["branches"] = branches
    return plant


def _round_floats(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.{_JSON_DIGITS}g}")
    if isinstance(value, dict):
        return {key: _round_floats(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_round_floats(item) for item in value]
    return value


def traits_to_json(plant: ProceduralPlant) -> str:
    """The plant's traits as JSON text: indent 2, sorted keys, 9 significant digits.

    Rounding to 9 digits keeps the text identical across machines whose trig
    functions differ in the last bit; it is far below any physical resolution.
    """
    return json.dumps(_round_floats(plant.traits), indent=2, sort_keys=True, allow_nan=False) + "\n"


def to_stl_bytes(plant: ProceduralPlant) -> bytes:
    """The plant's mesh as binary STL (float32, metres, plant frame; 50 bytes a face).

    The 80-byte header names the plant and seed and never starts with "solid", so no
    reader mistakes the file for ASCII STL.
    """
    header = (f"plantsim procedural {plant.name} seed={plant.traits['seed']} units=m up=z"
              .encode("ascii").ljust(80, b" ")[:80])
    tri = plant.vertices_m[plant.faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    records = np.zeros(len(tri), dtype=[("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)),
                                        ("attribute", "<u2")])
    records["normal"] = normals
    records["vertices"] = tri
    return header + struct.pack("<I", len(tri)) + records.tobytes()


def to_labelled_obj_bytes(plant: ProceduralPlant) -> bytes:
    """The plant's mesh as Wavefront OBJ with one object per organ (metres, plant frame).

    Objects are named ``<part>_<organ>`` (``stem_0``, ``leaf_3``, ``petiole_2``,
    ``ear_1``, ``branch_0``), so :func:`plantsim.plant.labels.read_labelled_parts` and
    ``plantsim scan MESH --evaluate`` read stems and leaves from the file itself.
    Coordinates are written with 17 significant digits (float64 round trip).
    """
    lines = [f"# plantsim procedural {plant.name} seed={plant.traits['seed']} units=m up=z"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in plant.vertices_m.tolist()]
    keys = np.stack([plant.face_part, plant.face_organ], axis=1)
    order = np.lexsort((plant.face_organ, plant.face_part))
    last = None
    for i in order:
        key = (int(keys[i, 0]), int(keys[i, 1]))
        if key != last:
            lines.append(f"o {PART_NAMES[key[0]]}_{key[1]}")
            last = key
        a, b, c = plant.faces[i] + 1
        lines.append(f"f {a} {b} {c}")
    return ("\n".join(lines) + "\n").encode("ascii")
