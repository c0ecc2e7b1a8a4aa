"""Which faces of a plant mesh are stems and which are leaves, read from the mesh itself.

A mesh can say what its parts are in several ways; each is read into a list of
:class:`LabelledPart` (kind ``"stem"`` or ``"leaf"``, a name, the part's own vertices
and faces), from which :func:`plantsim.evaluation.evaluate.truth_from_labelled_mesh`
computes exact truth traits:

- **Named parts**: separate objects or groups (OBJ ``o``/``g``), scene nodes or
  geometries (GLB/glTF and any format trimesh loads as a scene). A name containing
  one of :data:`LEAF_NAMES` is a leaf, one of :data:`STEM_NAMES` a stem (leaf words
  first: "leaf_sheath_on_stem" is a leaf); other parts (pot, petiole, ear) are left out.
- **Integer labels**, per face or per vertex (PLY properties named in
  :data:`LABEL_PROPERTIES`, or arrays given in memory): ``stem_label`` (0) is the stem,
  every other label >= 1 one leaf, negative labels are left out (the convention of
  plant-organ datasets such as Pheno4D, whose 0 is soil, is served by
  ``stem_label=1, ignore_labels=(0,)``).
- **Colours**, per face or per vertex (PLY/OBJ/GLB colours, through trimesh): each
  colour is classed by :data:`PART_COLOURS_RGB` (plantsim's own palette) when it is
  one of those, else by a rule a person painting a plant would follow: a colour whose
  green channel exceeds red and blue by :data:`GREEN_MARGIN` is leaf, a grey (channels
  within :data:`GREY_SPREAD` of each other: white, black, unpainted) is left out, any
  other (brown, red, ...) is stem; ``legend`` overrides both. Leaves are then told
  apart by colour (one colour per leaf) and by connectivity (vertices welded by exact
  position): every connected patch of one colour is one part.

Vertex labels or colours become face labels by the majority of the face's three
vertices (the first vertex's on a three-way tie).

Nothing here guesses silently: a mesh with no usable labels gives an empty list, and
:func:`describe` says which rule was applied.
"""

from __future__ import annotations

import dataclasses
import io
import logging
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

_LOG = logging.getLogger(__name__)

# Part names that say what a labelled mesh's part is (case-insensitive substrings).
STEM_NAMES = ("stem", "stalk", "culm", "tiller", "trunk")
LEAF_NAMES = ("leaf", "leaves", "blade", "lamina", "leaflet")
# PLY face or vertex properties read as integer part labels.
LABEL_PROPERTIES = ("label", "part", "organ", "class", "scalar_label")
# plantsim's organ palette (sRGB 0-255): what plantsim writes, read back exactly.
PART_COLOURS_RGB = {
    "stem": (139, 69, 19),
    "leaf": (34, 139, 34),
    "ear": (218, 165, 32),
    "petiole": (128, 128, 0),
    "branch": (205, 133, 63),
}
# A colour is leaf-green when green exceeds both red and blue by this much (0-255).
GREEN_MARGIN = 20
# A colour is grey (not a label) when its channels lie within this of each other.
GREY_SPREAD = 24


@dataclasses.dataclass(frozen=True, eq=False)
class LabelledPart:
    """One stem or leaf of a labelled mesh.

    Attributes:
        kind: "stem" or "leaf".
        name: where it came from (object name, ``label=3``, ``rgb=(34, 139, 34)#2``).
        vertices: (n, 3) float64, the mesh's units and frame.
        faces: (m, 3) int64 indices into ``vertices`` (may leave vertices unused).
    """

    kind: str
    name: str
    vertices: np.ndarray
    faces: np.ndarray


def part_kind(name: str) -> str | None:
    """"leaf", "stem" or None from a part's name (see :data:`LEAF_NAMES`, :data:`STEM_NAMES`)."""
    low = name.lower()
    if any(word in low for word in LEAF_NAMES):
        return "leaf"
    if any(word in low for word in STEM_NAMES):
        return "stem"
    return None


def colour_kind(rgb: Iterable[int], legend: Mapping[tuple[int, int, int], str] | None = None) -> str | None:
    """"leaf", "stem" or None (left out) for one sRGB colour (0-255); see the module docstring."""
    key = tuple(int(c) for c in rgb)[:3]
    if legend is not None and key in legend:
        kind = legend[key]
        return None if kind in (None, "ignore") else kind
    for name, palette in PART_COLOURS_RGB.items():
        if key == palette:
            return name if name in ("stem", "leaf") else None
    r, g, b = key
    if max(key) - min(key) <= GREY_SPREAD:
        return None
    if g >= r + GREEN_MARGIN and g >= b + GREEN_MARGIN:
        return "leaf"
    return "stem"


def _check_legend(legend: Mapping | None) -> dict | None:
    if legend is None:
        return None
    out = {}
    for key, kind in legend.items():
        rgb = tuple(int(c) for c in key)
        if len(rgb) != 3 or not all(0 <= c <= 255 for c in rgb):
            raise ValueError(f"legend keys must be (r, g, b) colours with channels 0-255, got {key!r}")
        if kind not in ("stem", "leaf", "ignore", None):
            raise ValueError(f"legend values must be 'stem', 'leaf' or 'ignore', got {kind!r} for {key!r}")
        out[rgb] = kind
    return out


def _face_values(faces: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
    """Per-face value from per-vertex values (rows): the majority of the three vertices."""
    v = vertex_values[faces]  # (m, 3, ...)
    v = v.reshape(len(faces), 3, -1)
    same01 = (v[:, 0] == v[:, 1]).all(axis=1)
    same12 = (v[:, 1] == v[:, 2]).all(axis=1)
    out = v[:, 0].copy()
    # A face whose first vertex is the odd one out takes the other two's value.
    odd_first = ~same01 & same12
    out[odd_first] = v[odd_first, 1]
    return out.reshape((len(faces),) + vertex_values.shape[1:])


def _welded_components(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Connected component of each face, vertices welded by exact position: (m,) int64."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from plantsim.plant.mesh import unique_rows

    if len(faces) == 0:
        return np.zeros(0, dtype=np.int64)
    _, weld = unique_rows(np.ascontiguousarray(vertices, dtype=np.float64))
    f = weld[faces]
    n = int(weld.max()) + 1
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels[f[:, 0]].astype(np.int64)


def parts_from_face_labels(vertices: Any, faces: Any, face_labels: Any, *, stem_label: int = 0,
                           ignore_labels: Iterable[int] = ()) -> list[LabelledPart]:
    """Parts from one integer label per face: ``stem_label`` stem, other labels >= 0 one leaf each.

    Args:
        vertices: (n, 3) float, any units.
        faces: (m, 3) int.
        face_labels: (m,) int; negative labels and ``ignore_labels`` are left out.
        stem_label: the label of stem faces (every face with it is one stem part per
            connected patch, so the tillers of a plant labelled 0 stay apart).
        ignore_labels: labels that are neither stem nor leaf (soil, pot).

    Returns:
        The parts, stems first, then leaves by label.

    Raises:
        ValueError: shapes that do not match.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    labels = np.asarray(face_labels).reshape(-1)
    if len(labels) != len(f):
        raise ValueError(f"face_labels must have one label per face ({len(f)}), got {len(labels)}")
    if not np.issubdtype(labels.dtype, np.integer):
        rounded = np.rint(labels.astype(np.float64))
        if not np.array_equal(rounded, labels.astype(np.float64)):
            raise ValueError("face_labels must be integers (0 stem, k >= 1 leaf k)")
        labels = rounded.astype(np.int64)
    skip = set(int(k) for k in ignore_labels)
    parts = []
    stem_faces = f[labels == stem_label]
    if len(stem_faces):
        comp = _welded_components(v, stem_faces)
        for c in np.unique(comp):
            parts.append(LabelledPart("stem", f"label={stem_label}#{int(c)}", v, stem_faces[comp == c]))
    for k in np.unique(labels):
        if k < 0 or k == stem_label or int(k) in skip:
            continue
        parts.append(LabelledPart("leaf", f"label={int(k)}", v, f[labels == k]))
    return parts


def parts_from_colours(vertices: Any, faces: Any, face_rgb: Any, *,
                       legend: Mapping[tuple[int, int, int], str] | None = None) -> list[LabelledPart]:
    """Parts from one sRGB colour per face (0-255; alpha ignored); see the module docstring.

    Args:
        vertices: (n, 3) float.
        faces: (m, 3) int.
        face_rgb: (m, 3) or (m, 4) uint8-like colours.
        legend: {(r, g, b): "stem" | "leaf" | "ignore"}, overriding the default rule.

    Returns:
        The parts: one per connected patch of one colour, stems first. Empty when
        every face has one colour (a plain mesh, not a labelled one).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    rgb = np.asarray(face_rgb).reshape(len(f), -1)[:, :3].astype(np.int64)
    legend = _check_legend(legend)
    colours, inverse = np.unique(rgb, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(colours) < 2 and legend is None:
        return []
    stems, leaves = [], []
    for c, colour in enumerate(colours):
        kind = colour_kind(colour, legend)
        if kind is None:
            continue
        mine = f[inverse == c]
        comp = _welded_components(v, mine)
        for k in np.unique(comp):
            part = LabelledPart(kind, f"rgb={tuple(int(x) for x in colour)}#{int(k)}", v, mine[comp == k])
            (stems if kind == "stem" else leaves).append(part)
    return stems + leaves


# ------------------------------------------------------------------------ file readers


def _obj_parts(text: str) -> tuple[list[LabelledPart], np.ndarray | None, np.ndarray, np.ndarray]:
    """OBJ parts by ``o``/``g`` names, plus vertex colours (``v x y z r g b``) if every vertex has one.

    Returns:
        (named parts, vertex colours (n, 3) 0-255 or None, all vertices, all faces).
    """
    vertices: list[list[float]] = []
    colours: list[list[float]] = []
    faces_by_name: dict[str, list[list[int]]] = {}
    name = ""
    for line in text.splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == "v":
            vertices.append([float(x) for x in fields[1:4]])
            if len(fields) >= 7:
                colours.append([float(x) for x in fields[4:7]])
        elif fields[0] in ("o", "g"):
            name = " ".join(fields[1:])
        elif fields[0] == "f":
            idx = [int(tok.split("/")[0]) for tok in fields[1:]]
            idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
            faces_by_name.setdefault(name, []).extend(
                [idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    parts = []
    all_faces = []
    for part, faces in faces_by_name.items():
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        all_faces.append(f)
        kind = part_kind(part)
        if kind is not None:
            parts.append(LabelledPart(kind, part, v, f))
    rgb = None
    if colours and len(colours) == len(vertices):
        c = np.asarray(colours)
        rgb = np.rint(c * 255.0 if c.max() <= 1.0 else c).astype(np.int64)
    f_all = np.concatenate(all_faces) if all_faces else np.zeros((0, 3), dtype=np.int64)
    return parts, rgb, v, f_all


def _ply_labels(loaded, element: str) -> np.ndarray | None:
    raw = (loaded.metadata or {}).get("_ply_raw", {}).get(element, {}).get("data")
    if raw is None:
        return None
    names = raw.keys() if isinstance(raw, Mapping) else (getattr(getattr(raw, "dtype", None), "names", None) or ())
    for prop in LABEL_PROPERTIES:
        if prop in names:
            return np.asarray(raw[prop]).reshape(-1)
    return None


def _mesh_colours(mesh) -> np.ndarray | None:
    """Per-face colours (m, 3) of a trimesh mesh with face or vertex colours, else None."""
    visual = getattr(mesh, "visual", None)
    kind = getattr(visual, "kind", None)
    if kind == "face":
        return np.asarray(visual.face_colors)[:, :3]
    if kind == "vertex":
        return _face_values(np.asarray(mesh.faces), np.asarray(visual.vertex_colors)[:, :3])
    return None


def _single_mesh_parts(mesh, *, legend, stem_label, ignore_labels) -> tuple[list[LabelledPart], str]:
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    labels = _ply_labels(mesh, "face")
    if labels is not None and len(labels) == len(f):
        return parts_from_face_labels(v, f, labels, stem_label=stem_label, ignore_labels=ignore_labels), \
            "face labels"
    labels = _ply_labels(mesh, "vertex")
    if labels is not None and len(labels) == len(v):
        return parts_from_face_labels(v, f, _face_values(f, labels), stem_label=stem_label,
                                      ignore_labels=ignore_labels), "vertex labels"
    rgb = _mesh_colours(mesh)
    if rgb is not None:
        kind = "face colours" if mesh.visual.kind == "face" else "vertex colours"
        return parts_from_colours(v, f, rgb, legend=legend), kind
    return [], "no labels"


def read_labelled_parts(source: str | Path | bytes | io.IOBase, *, file_type: str | None = None,
                        legend: Mapping[tuple[int, int, int], str] | None = None,
                        stem_label: int = 0, ignore_labels: Iterable[int] = ()) -> list[LabelledPart]:
    """Stem and leaf parts of a mesh file (or its bytes), by whichever labels it carries.

    Tried in order: named parts (OBJ objects/groups, scene nodes); integer face labels;
    integer vertex labels; face colours; vertex colours (see the module docstring).
    In a scene whose nodes are not named as organs, each geometry's own labels or
    colours are read.

    Args:
        source: a path, or the file's bytes / a binary file object (then ``file_type``).
        file_type: "obj", "ply", "glb", "gltf", "off", ... (None: the path's suffix).
        legend: colour legend, see :func:`parts_from_colours`.
        stem_label: see :func:`parts_from_face_labels`.
        ignore_labels: see :func:`parts_from_face_labels`.

    Returns:
        The parts (empty when the mesh labels nothing).

    Raises:
        ValueError: no ``file_type`` for bytes, or a legend that is not valid.
        FileNotFoundError: a path that does not exist.
    """
    import trimesh

    legend = _check_legend(legend)
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"mesh file not found: {path}")
        file_type = (file_type or path.suffix.lstrip(".")).lower()
        data = path.read_bytes()
    else:
        if file_type is None:
            raise ValueError("file_type is needed when the mesh is given as bytes, e.g. 'ply' or 'obj'")
        data = source if isinstance(source, (bytes, bytearray)) else source.read()
        file_type = file_type.lower().lstrip(".")
    if file_type == "obj":
        parts, rgb, v, f = _obj_parts(bytes(data).decode("utf-8", errors="replace"))
        if parts:
            return parts
        if rgb is not None and len(f):
            return parts_from_colours(v, f, _face_values(f, rgb), legend=legend)
        # Colours given through an MTL file or another OBJ dialect: trimesh's reader.
    loaded = trimesh.load(io.BytesIO(bytes(data)), file_type=file_type, process=False)
    if isinstance(loaded, trimesh.Scene):
        named, unnamed = [], []
        for node in loaded.graph.nodes_geometry:
            T, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if not isinstance(geom, trimesh.Trimesh):
                continue
            kind = part_kind(str(node)) or part_kind(str(geom_name))
            v = trimesh.transform_points(np.asarray(geom.vertices, dtype=np.float64), T)
            if kind is not None:
                named.append(LabelledPart(kind, str(node), v, np.asarray(geom.faces, dtype=np.int64)))
            else:
                placed = geom.copy()
                placed.apply_transform(T)
                unnamed.append(placed)
        if named:
            return named
        parts = []
        for mesh in unnamed:
            parts += _single_mesh_parts(mesh, legend=legend, stem_label=stem_label,
                                        ignore_labels=ignore_labels)[0]
        return parts
    parts, how = _single_mesh_parts(loaded, legend=legend, stem_label=stem_label, ignore_labels=ignore_labels)
    _LOG.debug("labelled parts by %s: %d", how, len(parts))
    return parts


def describe(parts: list[LabelledPart]) -> str:
    """A one-line summary: how many stems and leaves, and how the first was named."""
    n_stem = sum(p.kind == "stem" for p in parts)
    n_leaf = sum(p.kind == "leaf" for p in parts)
    first = parts[0].name if parts else "-"
    return f"{n_stem} stem part(s), {n_leaf} leaf part(s) (e.g. {first!r})"
