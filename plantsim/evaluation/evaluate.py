"""How wrong one scan is: its cloud against the mesh it scanned, and its traits
against the plant's exact traits.

plantsim knows the truth of every scan: the placed mesh (``ScanResult.plant``), and,
for the bundled plants (or any mesh with a ``<name>.traits.json`` beside it, as
written by ``scripts/make_plants.py``), the exact traits the plant was built with.
:func:`evaluate_scan` measures the plant-class points of a result against both:

- cloud-to-mesh metrics (:func:`plantsim.metrics.cloud_mesh_metrics`): exact distance
  quantiles, Chamfer distance, coverage, coverage by height band;
- trait errors (:func:`plantsim.traits.compare_traits`): traits extracted from the
  cloud (S) against the exact traits (R), absolute and ``|S - R| / R`` as the paper
  reports them;
- when the mesh file says which faces are leaves (``plantsim plant make``'s OBJ, named
  parts, face labels or colours), its leaves measured alone: each point labelled by the
  leaf its beam hit, each leaf measured by the same per-leaf measures with no
  segmentation (:func:`plantsim.evaluation.traits.measure_labelled_leaves`). Against
  the traits extracted, it splits the leaf area's error into the segmentation's and
  what the scan itself sees: how well the rig would measure the plant were its leaves
  cut out perfectly.

Only points whose first surface was the plant are measured: the turntable and the rig
are not part of the truth. The traits file is in the mesh's own frame (metres, z up);
it is moved to the turntable frame with the run's ``T_turntable_mesh``.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import logging
import math
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from plantsim._cores import usable_cores
from plantsim.evaluation import metrics, traits
from plantsim.plant import labels
from plantsim.plant.mesh import PlantMesh
from plantsim.validation import SettingTypeError, check_bool

logger = logging.getLogger(__name__)

TRAITS_SUFFIX = ".traits.json"


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvaluationOptions:
    """How a scan is measured.

    Attributes:
        coverage_distance: a mesh point is covered when a cloud point lies this
            close, metres (> 0).
        band_height: height of the coverage bands, metres (> 0).
        n_surface_samples: area-uniform mesh samples for coverage and the
            mesh-to-cloud side of the Chamfer distance (>= 1).
        seed: seed of those samples (the evaluation is deterministic).
        traits: also compare traits when an exact-traits file is found.
        trait_settings: how traits are extracted (None: the defaults).
    """

    coverage_distance: float = 0.002
    band_height: float = 0.05
    n_surface_samples: int = 200_000
    seed: int = 0
    traits: bool = True
    trait_settings: traits.TraitSettings | None = None

    def __post_init__(self) -> None:
        for name in ("coverage_distance", "band_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0 metres, got {value!r}")
        if isinstance(self.n_surface_samples, bool) or not isinstance(self.n_surface_samples, int) \
                or self.n_surface_samples < 1:
            raise ValueError(f"n_surface_samples must be an integer >= 1, got {self.n_surface_samples!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        check_bool("evaluation", "traits", self.traits)
        if self.trait_settings is not None and not isinstance(self.trait_settings,
                                                              traits.TraitSettings):
            raise SettingTypeError("evaluation.trait_settings must be a TraitSettings or None, "
                                   f"got {type(self.trait_settings).__name__}")


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """A scan's errors.

    Attributes:
        n_points: plant-class points measured.
        metrics: cloud-to-mesh metrics, or None when the cloud holds no plant point.
        traits: trait errors against the exact traits, or None without a traits
            file (or without plant points).
        estimate: the traits extracted from the cloud, or None as for ``traits``.
        truth_path: the exact-traits file used, or None.
        time_s: wall time of the evaluation, seconds.
        range_noise_source: what the leaf widths were checked against (the range
            noise, :func:`range_noise_sigma_m`), or why they were not; None when not said.
        labelled_leaves: the mesh's labelled leaves measured alone from the points
            (:func:`labelled_leaf_mesh`, :func:`plantsim.evaluation.traits.measure_labelled_leaves`),
            or None when the mesh labels no leaf or traits were not compared.
        labelled_leaves_source: how the points were labelled, or why they were not.
        leaf_match: the leaves the traits were read from matched to those labelled leaves,
            point by point (:class:`plantsim.evaluation.organ_match.LeafMatch`: a count can
            be right with leaves split and others merged), or None as ``labelled_leaves``.
    """

    n_points: int
    metrics: metrics.CloudMeshMetrics | None
    traits: traits.TraitComparison | None
    estimate: traits.PlantTraits | None
    truth_path: str | None
    time_s: float
    range_noise_source: str | None = None
    labelled_leaves: traits.LabelledLeaves | None = None
    labelled_leaves_source: str | None = None
    leaf_match: Any = None

    def to_dict(self) -> dict[str, Any]:
        """The sidecar's ``evaluation`` object: the metrics' fields at the top level,
        then ``traits`` (``truth``, ``n_stems``/``n_leaves`` as [estimate, truth],
        ``errors`` keyed by trait, the extraction's ``notes``, per found leaf whether
        its width is resolved against the range noise, ``leaf_widths_resolved``, and
        what that noise was, ``leaf_widths_checked_against``) and ``time_s``.
        JSON-ready (NaN becomes None)."""
        out: dict[str, Any] = {"truth": "placed mesh, plant-class points only",
                               "n_points": self.n_points}
        if self.metrics is not None:
            out.update(self.metrics.to_dict())
        if self.traits is not None:
            out["traits"] = {
                "truth": self.truth_path,
                "n_stems": list(self.traits.n_stems),
                "n_leaves": list(self.traits.n_leaves),
                "errors": {e.trait: metrics._to_jsonable({
                    "estimate": e.estimate, "reference": e.reference,
                    "absolute_error": e.absolute_error, "relative_error": e.relative_error,
                    "unit": e.unit}) for e in self.traits.errors},
            }
            if self.estimate is not None:
                out["traits"]["notes"] = list(self.estimate.notes)
                out["traits"]["leaf_widths_resolved"] = [lf.width_resolved for lf in self.estimate.leaves]
                out["traits"]["leaf_widths_across_beams_share"] = metrics._to_jsonable(
                    [lf.width_across_beams_share for lf in self.estimate.leaves])
            if self.range_noise_source is not None:
                out["traits"]["leaf_widths_checked_against"] = self.range_noise_source
            if self.labelled_leaves is not None:
                # The leaf area's error were the leaves cut out perfectly, beside the one read.
                reference = next((e.reference for e in self.traits.errors if e.trait == "leaf_area_m2"), None)
                area = self.labelled_leaves.leaf_area_m2
                labelled = self.labelled_leaves.to_dict()
                labelled["leaf_area_relative_error"] = metrics._to_jsonable(
                    abs(area - reference) / reference if reference and math.isfinite(area) else None)
                labelled["how"] = self.labelled_leaves_source
                out["traits"]["labelled_leaves_measured_alone"] = labelled
            if self.leaf_match is not None:
                fields = {k: v for k, v in dataclasses.asdict(self.leaf_match).items() if k != "pairs"}
                out["traits"]["leaves_matched"] = metrics._to_jsonable({**fields, "summary": self.leaf_match.summary()})
            elif self.labelled_leaves_source is not None:
                out["traits"]["labelled_leaves_measured_alone"] = {"how": self.labelled_leaves_source}
        out["time_s"] = self.time_s
        return out


def range_noise_sigma_m(cloud: Any, simulated: Mapping[str, Any], lidar: Any, model: Any = None
                        ) -> tuple[np.ndarray | None, str]:
    """Per point of a cloud, the least standard deviation its range noise had, from what
    the scan simulated: what the traits check leaf widths against.

    Args:
        cloud: the :class:`plantsim.cloud.reconstruct.PointCloud` (its ``range_m`` and
            ``intensity``).
        simulated: what the scan's parts did (``ScanResult.parts``; the sidecar's
            ``simulated``).
        lidar: the :class:`plantsim.sensor.spec.LidarSpec` of the scan.
        model: its :class:`plantsim.sensor.model.SensorModel` (None for a real sensor).

    Returns:
        ((n,) float64 metres, or None when not known; what it is), e.g. "the
        urg-04lx-ug01's range noise (received-power law, at least 10 mm), read back
        from each point's intensity". A simulated sensor's is read back from each
        point's intensity (:func:`plantsim.sensor.model.range_sigma_at_least`); a real
        sensor's, which gives no intensity, is its preset's at a white target head-on:
        a lower bound, so a width it flags is unresolved for certain. A simulated sensor
        with its range noise off still rounds its ranges to its resolution: that error,
        uniform over one step, is ``resolution / sqrt(12)`` (0.29 mm for 1 mm).
    """
    from plantsim.sensor.model import range_sigma_at_least

    part = simulated.get("lidar") or {}
    if "range_filter" in simulated:
        return None, "not checked: the range filter replaced the sensor's noise by an unknown residual"
    if not part:
        return None, "not checked: the scan does not say which LiDAR it used"
    n = len(cloud.range_m)
    law = f"{lidar.noise_law} law, at least {1e3 * lidar.range_sigma_m:.3g} mm"
    if part.get("real"):
        return (range_sigma_at_least(cloud.range_m, lidar),
                f"the {lidar.name}'s range noise ({law}) at a white target head-on, a lower bound")
    if part.get("sensor") == "ideal":
        return np.zeros(n), "ideal sensor: no range noise"
    if model is None:
        return None, "not checked: the scan does not give its sensor model"
    if not model.range_noise:
        if model.quantise and lidar.range_resolution_m > 0:
            # Rounding to the resolution is an error uniform over one step: sigma = step / sqrt(12).
            sigma = lidar.range_resolution_m / math.sqrt(12.0)
            return (np.full(n, sigma), f"realistic sensor with its range noise off: its ranges' rounding to "
                    f"{1e3 * lidar.range_resolution_m:.3g} mm only ({1e3 * sigma:.2g} mm)")
        return np.zeros(n), "realistic sensor with its range noise off: no range noise"
    if cloud.intensity is None or not model.intensity:
        return (range_sigma_at_least(cloud.range_m, lidar),
                f"the {lidar.name}'s range noise ({law}) at a white target head-on (no intensity "
                "recorded), a lower bound")
    return (range_sigma_at_least(cloud.range_m, lidar, intensity=cloud.intensity, model=model),
            f"the {lidar.name}'s range noise ({law}), read back from each point's intensity")


def range_noise_vectors(cloud: Any, T_base_lidar: Any, sigma_m: Any) -> np.ndarray:
    """Per point, its beam's unit direction in the turntable frame times its range noise's
    standard deviation: the ``range_noise_m`` of
    :func:`plantsim.evaluation.traits.extract_traits`.

    Args:
        cloud: the :class:`plantsim.cloud.reconstruct.PointCloud` (its
            ``points_turntable`` and ``turntable_angle_rad``).
        T_base_lidar: (4, 4) the rig's LiDAR pose.
        sigma_m: (n,) or scalar, metres (>= 0): :func:`range_noise_sigma_m`.

    Returns:
        (n, 3) float64 metres.
    """
    from plantsim.cloud.reconstruct import beam_dirs_turntable

    sigma = np.asarray(sigma_m, dtype=np.float64)
    if not np.all(np.isfinite(sigma) & (sigma >= 0)):
        raise ValueError("sigma_m must be finite numbers >= 0 metres")
    dirs = beam_dirs_turntable(cloud.points_turntable, cloud.turntable_angle_rad, T_base_lidar)
    return (sigma[:, None] if sigma.ndim == 1 else sigma) * dirs


# Below this share of a beam's spacing turned upright, the fan lies too near the
# horizontal for its neighbouring beams to bound a top from above (:func:`beam_gaps_m`).
_GAP_MIN_UPRIGHT = 0.1


def beam_gaps_m(cloud: Any, T_base_lidar: Any, angle_increment_deg: float) -> np.ndarray:
    """Per point, how far up the vertical through it the fan's next beam passes: the
    ``beam_gaps_m`` of :func:`plantsim.evaluation.traits.extract_traits`.

    Neighbouring beams at range ``R`` lie ``R dtheta`` apart across the beam, within
    the fan; along the vertical through the point that is ``R dtheta / |e_z|``, with
    ``e`` the unit vector across the beam within the fan (``n x d``: the fan's normal
    ``n``, the lidar's +Z, crossed with the beam's direction ``d``). For an upright fan
    ``|e_z|`` is the cosine of the beam's elevation: a beam level with the point gives
    ``R dtheta``, one looking up at 45 deg twice ``R dtheta / sqrt 2``. The top of a
    thin organ lies between the highest beam that hits it and the next, which passes
    over it: this is that interval.

    Args:
        cloud: the :class:`plantsim.cloud.reconstruct.PointCloud` (its
            ``points_turntable`` and ``turntable_angle_rad``).
        T_base_lidar: (4, 4) the rig's LiDAR pose.
        angle_increment_deg: the fan's angle between neighbouring beams, degrees (> 0;
            :attr:`plantsim.sensor.spec.LidarSpec.angle_increment_deg`).

    Returns:
        (n,) float64 metres; NaN where the fan there lies within ``asin 0.1`` (5.7 deg)
        of the horizontal, whose beams bound no top from above.
    """
    from plantsim.cloud.reconstruct import base_to_turntable, beam_dirs_turntable

    step = float(angle_increment_deg)
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"angle_increment_deg must be a number > 0, got {angle_increment_deg!r}")
    T = np.asarray(T_base_lidar, dtype=np.float64)
    pts = np.asarray(cloud.points_turntable, dtype=np.float64).reshape(-1, 3)
    theta = np.asarray(cloud.turntable_angle_rad, dtype=np.float64).reshape(-1)
    d = beam_dirs_turntable(pts, theta, T)
    origin = base_to_turntable(np.broadcast_to(T[:3, 3], pts.shape), theta)
    normal = base_to_turntable(np.broadcast_to(T[:3, 2], pts.shape), theta)
    upright = np.abs(np.cross(normal, d)[:, 2])
    range_m = np.linalg.norm(pts - origin, axis=1)
    gaps = np.full(len(pts), np.nan)
    ok = upright >= _GAP_MIN_UPRIGHT
    gaps[ok] = range_m[ok] * math.radians(step) / upright[ok]
    return gaps


def scan_beam_gaps(result) -> np.ndarray | None:
    """:func:`beam_gaps_m` of a scan's plant points, from its rig and LiDAR: pass them to
    ``extract_traits(result.cloud.plant_only().points_turntable, beam_gaps_m=...)``. None
    when the scan does not give its LiDAR (the top is then read as sampled)."""
    lidar = getattr(getattr(result, "config", None), "lidar", None)
    if lidar is None:
        return None
    return beam_gaps_m(result.cloud.plant_only(), result.raw.T_base_lidar, lidar.angle_increment_deg)


def truth_traits_path(source: str | Path) -> Path | None:
    """The exact-traits file beside a mesh, if any.

    ``assets/maize.stl`` has ``assets/maize.traits.json``; ``plant.obj.traits.json``
    is found too.

    Args:
        source: the mesh file's path.

    Returns:
        The path, or None when there is no such file.
    """
    mesh = Path(source)
    for candidate in (mesh.with_suffix(TRAITS_SUFFIX), mesh.with_name(mesh.name + TRAITS_SUFFIX)):
        if candidate.is_file():
            return candidate
    return None


def truth_in_turntable(truth: Mapping[str, Any], T_turntable_mesh: Any) -> dict[str, Any]:
    """An exact-traits dict (mesh frame) moved to the turntable frame.

    Stem bases ``(x, y, 0)`` are mapped by the placement. Heights, lengths, widths
    and distances are lengths and do not change under a rigid placement (the
    height is the top above the base, and the cloud's is measured above the disk
    top, where placement "base" puts the base).

    Args:
        truth: parsed traits JSON, metres, mesh frame, z up.
        T_turntable_mesh: (4, 4) float64, mesh -> turntable; must keep z up
            (a turn about z and a translation).

    Returns:
        A new dict in the turntable frame.

    Raises:
        ValueError: when the placement tilts z (the traits file's up axis then
            disagrees with the placed mesh).
    """
    T = np.asarray(T_turntable_mesh, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T_turntable_mesh must have shape (4, 4), got {T.shape}")
    if abs(T[2, 2] - 1.0) > 1e-9:
        raise ValueError("T_turntable_mesh must keep the mesh's z axis up to compare traits "
                         f"(got T[2, 2] = {T[2, 2]:.6g}); the traits file is in metres, z up")
    out = dict(truth)
    stems = []
    for stem in truth.get("stems") or ():
        stem = dict(stem)
        x, y = stem["base_xy_m"]
        p = T @ np.array([float(x), float(y), 0.0, 1.0])
        stem["base_xy_m"] = [float(p[0]), float(p[1])]
        stems.append(stem)
    out["stems"] = stems
    return out


# Part names and label properties read by plantsim.plant.labels (kept here for callers).
STEM_NAMES = labels.STEM_NAMES
LEAF_NAMES = labels.LEAF_NAMES
PLY_LABEL_PROPERTIES = labels.LABEL_PROPERTIES


def truth_from_labelled_mesh(path: str | Path | bytes, *, units_scale: float = 1.0,
                             n_samples_per_m2: float = 4.0e6, file_type: str | None = None,
                             legend: Mapping[tuple[int, int, int], str] | None = None,
                             stem_label: int = 0) -> dict[str, Any] | None:
    """Exact traits of a mesh that says which faces are stems and leaves.

    The parts are read by :func:`plantsim.plant.labels.read_labelled_parts`: named
    objects/groups/scene nodes, integer face or vertex labels, face or vertex colours.
    Computed from the mesh itself, in the truth-file schema of docs/traits.md
    ("Truth files"; :func:`plantsim.evaluation.traits.traits_from_truth`), mesh frame,
    metres, z up: ``height_m`` (top of all parts above the lowest stem vertex, or the
    lowest vertex without a stem); per stem ``base_xy_m`` and ``diameter_m`` (algebraic
    circle fit, :func:`plantsim.evaluation.traits.fit_circle`, to the stem's vertices in
    its lowest 10 % of height) and ``height_m`` (its z extent); per leaf ``area_m2``
    (the sum of its triangle areas: one side of a sheet; a closed thin solid counts
    both sides, so halve it), ``length_m`` and ``width_m`` (the cloud method's
    midrib geodesic and cross width, :func:`plantsim.evaluation.traits.leaf_length_width`,
    on a dense uniform sampling of that leaf alone, so no segmentation error enters);
    ``leaf_area_m2`` their sum; ``stem_count``, ``leaf_count``.

    Args:
        path: mesh file, or its bytes (then ``file_type``).
        units_scale: metres per mesh unit (0.001 for millimetres).
        n_samples_per_m2: surface samples per m^2 for leaf length/width (4e6: ~0.5 mm
            spacing); 0 skips length and width (count, areas and heights only).
        file_type: "obj", "ply", "glb", ... for bytes (None: the path's suffix).
        legend: colour legend, {(r, g, b): "stem" | "leaf" | "ignore"}.
        stem_label: the integer label of stem faces (0).

    Returns:
        The truth dict, or None when the mesh names no stem or leaf part.
    """
    parts = [(p.kind, p.name, p.vertices, p.faces) for p in labels.read_labelled_parts(
        path if isinstance(path, (bytes, bytearray)) else Path(path), file_type=file_type,
        legend=legend, stem_label=stem_label)]
    if not parts:
        return None
    import trimesh

    stems, leaves, z_all, z_stem = [], [], [], []
    for kind, name, v, f in parts:
        v = v * units_scale
        used = np.unique(f)
        if len(f) == 0:
            continue
        z_all.append(v[used, 2])
        if kind == "stem":
            vz = v[used]
            z_stem.append(vz[:, 2])
            lo, hi = float(vz[:, 2].min()), float(vz[:, 2].max())
            band = vz[vz[:, 2] <= lo + 0.1 * (hi - lo) + 1e-12]
            entry: dict[str, Any] = {"index": len(stems), "name": name, "height_m": hi - lo}
            try:
                fit = traits.fit_circle(band[:, :2])
                entry["base_xy_m"] = [float(fit.center_xy[0]), float(fit.center_xy[1])]
                entry["diameter_m"] = 2.0 * float(fit.radius)
            except ValueError:
                entry["base_xy_m"] = [float(band[:, 0].mean()), float(band[:, 1].mean())]
            stems.append(entry)
        else:
            mesh = trimesh.Trimesh(v, f, process=False)
            area = float(mesh.area)
            if n_samples_per_m2 <= 0:
                leaves.append({"index": len(leaves), "name": name, "area_m2": area})
                continue
            n = int(np.clip(area * n_samples_per_m2, 500, 200_000))
            samples, _ = trimesh.sample.sample_surface_even(mesh, n, seed=0) if hasattr(
                trimesh.sample, "sample_surface_even") else trimesh.sample.sample_surface(mesh, n)
            spacing = math.sqrt(area / max(len(samples), 1))
            length, width = traits.leaf_length_width(samples, link_distance=4.0 * spacing,
                                                     bin_length=max(8.0 * spacing, 1e-4))
            leaves.append({"index": len(leaves), "name": name, "length_m": length, "width_m": width,
                           "area_m2": area})
    if not z_all:
        return None
    z = np.concatenate(z_all)
    base = float(np.concatenate(z_stem).min()) if z_stem else float(z.min())
    where = "<bytes>" if isinstance(path, (bytes, bytearray)) else Path(path).name
    truth: dict[str, Any] = {"height_m": float(z.max()) - base, "source": f"labelled mesh {where}"}
    if stems:
        truth["stems"] = [s for s in stems if "base_xy_m" in s]
        truth["stem_count"] = len(stems)
    if leaves:
        truth["leaves"] = leaves
        truth["leaf_count"] = len(leaves)
        truth["leaf_area_m2"] = float(sum(lf["area_m2"] for lf in leaves))
    return truth


# The truth-file schema's keys (docs/traits.md, "Truth files"); all optional. The core
# keys carry the traits every scan is measured on; the others are extras.
TRUTH_CORE_KEYS = ("height_m", "stems", "leaves", "leaf_area_m2")
TRUTH_EXTRA_KEYS = ("stem_distances_m", "convex_hull_volume_m3", "projected_area_xy_m2")
TRUTH_KEYS = TRUTH_CORE_KEYS + TRUTH_EXTRA_KEYS
_TRUTH_INFO_KEYS = {"name", "generator", "seed", "params", "units", "up", "source", "stem_diameter_m",
                    "mean_stem_distance_m", "mean_nearest_stem_distance_m", "leaf_width_m",
                    "leaf_length_m", "n_vertices", "n_faces", "stem_count", "leaf_count", "petioles",
                    "branches"}


def truth_notes(truth: Mapping[str, Any]) -> list[str]:
    """Notes on a truth dict: the schema keys it lacks (their traits are skipped) and the
    keys it has outside the schema (ignored).

    Returns:
        Sentences: "truth lacks ..." for core keys (height, stems, leaves, leaf area),
        "truth has no ..." for extras (stem distances with two stems or more, hull
        volume, projected area), "truth keys not in the schema ...". Empty when all is there.
    """
    def absent(key: str) -> bool:
        return truth.get(key) in (None, [], ())

    notes = []
    core = [key for key in TRUTH_CORE_KEYS if absent(key)]
    if core:
        notes.append(f"truth lacks {', '.join(core)}: those traits are not compared")
    n_stems = len(truth.get("stems") or ())
    extra = [key for key in TRUTH_EXTRA_KEYS if absent(key) and (key != "stem_distances_m" or n_stems >= 2)]
    if extra:
        notes.append(f"truth has no {', '.join(extra)}: not compared")
    unknown = sorted(set(truth) - set(TRUTH_KEYS) - _TRUTH_INFO_KEYS)
    if unknown:
        notes.append(f"truth keys not in the schema, ignored: {', '.join(unknown)}")
    return notes


def _labelled_truth(plant: PlantMesh) -> dict[str, Any] | None:
    """Truth from the plant's own file when it labels its parts; None (with a note) otherwise."""
    from plantsim.plant.mesh import UNITS_TO_M

    source = Path(str(plant.source))
    if not source.is_file():
        return None
    try:
        truth = truth_from_labelled_mesh(source, units_scale=UNITS_TO_M.get(plant.units, 1.0))
    except (ValueError, OSError, KeyError, IndexError) as exc:
        logger.warning("could not read part labels from %s, traits not compared: %s", source, exc)
        return None
    if truth is None:
        logger.info("%s has no traits file and names no stem/leaf parts: traits not compared", source)
    elif plant.up != "z":
        logger.warning("%s: truth from part labels needs a z-up mesh (up is %r): traits not compared",
                       source, plant.up)
        return None
    return truth


def labelled_leaf_mesh(plant: PlantMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The leaves (and stems) the plant's own file labels, in the turntable frame:
    (vertices (v, 3), faces (f, 3), each face's leaf index or -1 for a stem (f,), each
    leaf's base (k, 3)); None when the file labels no leaf (or is not a file).

    The parts are read by :func:`plantsim.plant.labels.read_labelled_parts` (named
    objects or groups, face or vertex labels, colours), scaled by the plant's units and
    placed with its ``T_turntable_mesh``. A leaf's base is its vertex nearest a stem's (where
    it grows from the stem, or its petiole's end), or with no stem part the one nearest the
    turntable's axis.

    Raises:
        ValueError, OSError: a file whose labels cannot be read.
    """
    from plantsim.plant.mesh import UNITS_TO_M
    from plantsim.transforms import apply_T

    source = Path(str(plant.source))
    if not source.is_file():
        return None
    parts = [p for p in labels.read_labelled_parts(source) if len(p.faces)]
    if not any(p.kind == "leaf" for p in parts):
        return None
    scale = UNITS_TO_M.get(plant.units, 1.0)
    vertices, faces, face_leaf, leaf_vertices, stem_vertices = [], [], [], [], [np.zeros((0, 3))]
    offset = 0
    for p in parts:
        used = np.unique(p.faces)
        v = apply_T(plant.T_turntable_mesh, np.asarray(p.vertices, dtype=np.float64) * scale)
        vertices.append(v)
        faces.append(np.asarray(p.faces, dtype=np.int64) + offset)
        offset += len(v)
        if p.kind == "leaf":
            face_leaf.append(np.full(len(p.faces), len(leaf_vertices), dtype=np.int64))
            leaf_vertices.append(v[used])
        else:
            face_leaf.append(np.full(len(p.faces), -1, dtype=np.int64))
            stem_vertices.append(v[used])
    vertex_leaf = np.concatenate([np.full(len(lv), k) for k, lv in enumerate(leaf_vertices)])
    bases = traits.leaf_bases_at_stem(np.vstack(leaf_vertices), vertex_leaf, np.vstack(stem_vertices))
    if bases is None:
        bases = np.array([lv[int(np.argmin(np.hypot(lv[:, 0], lv[:, 1])))] for lv in leaf_vertices])
    return np.vstack(vertices), np.vstack(faces), np.concatenate(face_leaf), bases


def _labelled_leaves(pts: np.ndarray, plant: PlantMesh, range_noise_m: Any,
                     settings: traits.TraitSettings | None, organs: Any = None) -> tuple[Any, str, Any]:
    """The plant file's labelled leaves measured alone from ``pts``, how the points were
    labelled, and the segmentation ``organs`` (the traits', or None) matched to them
    (:class:`plantsim.evaluation.organ_match.LeafMatch`); (None, why not, None) when the file
    labels no leaf or cannot be read."""
    from plantsim.evaluation.organ_match import match_leaves

    try:
        mesh = labelled_leaf_mesh(plant)
    except (ValueError, OSError, KeyError, IndexError) as exc:
        return None, f"not measured: the mesh's part labels could not be read ({type(exc).__name__}: {exc})", None
    if mesh is None:
        return None, "not measured: the mesh labels no leaf (named parts, face labels or colours)", None
    vertices, faces, face_leaf, bases = mesh
    noise = None if range_noise_m is None else np.asarray(range_noise_m, dtype=np.float64)
    noisy = noise is not None and bool(np.any(noise))
    proximity = _Proximities(plant, vertices, faces)
    point_leaf, nearest = _true_leaf_of(pts, noise if noisy else None, plant, proximity, face_leaf)
    how = (f"{len(bases)} leaves labelled in the mesh; each point labelled by the leaf its beam hit "
           f"(organ_match.surface_points_along_beams; {nearest} of {len(pts)} by their nearest face, their "
           "beam meeting no face within 4 sigma)" if noisy else
           f"{len(bases)} leaves labelled in the mesh; each point labelled by its nearest face")
    measured = traits.measure_labelled_leaves(pts, point_leaf, leaf_bases_m=bases, range_noise_m=noise,
                                              settings=settings)
    matched = None
    if organs is not None:
        # The segmented points are the cloud's kept ones, on a file's grid: labelled as above.
        truth = _true_leaf_of(organs.points, organs.range_noise_m, plant, proximity, face_leaf)[0]
        matched = match_leaves(organs.leaf_label, truth, n_true_leaves=len(bases))
    return measured, how + "; each leaf measured alone (traits.measure_labelled_leaves)", matched


# A point on the placed mesh lies on a labelled part's face when it is this close to it: the
# parts are the same triangles, read from the same file (float32 rounding in the cast, and a
# LAS file's 0.01 mm grid, stay far below the millimetres between two organs).
_ON_PART_M = 2e-5


class _Proximities:
    """The exact-distance queries :func:`_true_leaf_of` needs, each built once: the
    labelled parts' (``parts``) and, when first asked for, the whole placed plant's."""

    def __init__(self, plant: PlantMesh, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._plant_mesh = plant
        self.parts = metrics.MeshProximity(vertices, faces)
        self._plant: metrics.MeshProximity | None = None

    @property
    def plant(self) -> metrics.MeshProximity:
        if self._plant is None:
            self._plant = metrics.MeshProximity(self._plant_mesh.vertices_turntable, self._plant_mesh.faces)
        return self._plant


def _true_leaf_of(points: np.ndarray, noise: np.ndarray | None, plant: PlantMesh, proximity: _Proximities,
                  face_leaf: np.ndarray) -> tuple[np.ndarray, int]:
    """Each point's leaf in the labelled parts (-1 for a stem, or a part the file labels
    neither, such as a petiole, an ear or a pot), and how many were read at their nearest
    face rather than where their beam hit. A point's surface is where its beam met the whole
    placed plant (:func:`plantsim.evaluation.organ_match.surface_points_along_beams`), not
    only its labelled parts: a beam that hit a petiole is no leaf's; without noise, or where
    the beam meets no face within 4 sigma (a footprint's edge), the plant's nearest point to
    it (as :func:`plantsim.evaluation.organ_match.leaf_labels_along_beams` falls back)."""
    from plantsim.evaluation.organ_match import surface_points_along_beams

    surface = np.full(points.shape, np.nan)
    if noise is not None and np.any(noise):
        surface = surface_points_along_beams(points, noise, plant.vertices_turntable, plant.faces)
    gone = ~np.isfinite(surface[:, 0])
    if gone.any():
        surface[gone] = proximity.plant.query(points[gone]).closest_points
    missed = int(gone.sum()) if noise is not None and np.any(noise) else 0
    closest = proximity.parts.query(surface)
    on_part = closest.distance <= _ON_PART_M
    return np.where(on_part, face_leaf[closest.triangle_index], -1), missed


# Progress of the trait extraction, in the units of the distance part (one a
# cloud point): it reports only when done, and costs about five times the exact
# distances a point (libigl, bundled maize, 70k-280k points), so the bar moves
# about evenly in time.
_TRAITS_WORK_PER_POINT = 5


def evaluation_threads(threads: int | None) -> int:
    """The threads an evaluation uses: ``threads`` capped at the cores (None: all cores).

    Raises:
        ValueError: ``threads`` not a positive integer or None.
    """
    cores = usable_cores()
    if threads is None:
        return cores
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be a positive integer or None (all cores), got {threads!r}")
    return min(threads, cores)


def evaluate_cloud(points_turntable: Any, plant: PlantMesh, *,
                   options: EvaluationOptions = EvaluationOptions(),
                   truth_path: str | Path | None = None, threads: int | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   proximity: metrics.MeshProximity | None = None,
                   range_noise_m: Any = None, range_noise_source: str | None = None,
                   beam_gaps_m: Any = None) -> Evaluation:
    """Measures plant points against the placed mesh and, if known, the exact traits.

    Args:
        points_turntable: (n, 3) float64, metres, turntable frame: points on the
            plant only (n may be 0).
        plant: the placed mesh that was scanned.
        options: how to measure.
        truth_path: exact-traits JSON; None looks beside the mesh file
            (:func:`truth_traits_path`).
        threads: threads for the KD-tree queries (None: all cores; capped at
            the cores). The answers do not depend on it.
        progress: called as ``progress(done, total)`` in work units that grow
            about evenly with time (distances, then coverage, then traits);
            ``done == total`` at the end. Never called for an empty cloud.
        proximity: a prebuilt :class:`plantsim.evaluation.metrics.MeshProximity`
            of ``plant.vertices_turntable`` / ``plant.faces``, to measure many
            clouds of one plant without rebuilding its tree.
        range_noise_m: (n, 3) per point, its range noise along its beam
            (:func:`range_noise_vectors`): the extracted leaf widths are checked
            against it (``extract_traits``' ``range_noise_m``); None: not checked.
        range_noise_source: what ``range_noise_m`` is, or why it is None, for the
            sidecar (:func:`range_noise_sigma_m`'s second value).
        beam_gaps_m: (n,) per point, how far up the vertical through it the fan's next
            beam passes (:func:`beam_gaps_m`): the height adds half the top's
            (``extract_traits``' ``beam_gaps_m``); None: the top as sampled.

    Returns:
        Evaluation.

    Raises:
        ValueError: non-finite points, a traits file that is not valid, or
            ``threads`` not a positive integer.
        FileNotFoundError: an explicit ``truth_path`` that does not exist.
    """
    t0 = time.perf_counter()
    workers = evaluation_threads(threads)
    pts = np.asarray(points_turntable, dtype=np.float64).reshape(-1, 3)
    if truth_path is None:
        found = truth_traits_path(plant.source) if options.traits else None
    else:
        found = Path(truth_path)
        if not found.is_file():
            raise FileNotFoundError(f"truth_path: traits file not found: {found}")
    if len(pts) == 0:
        logger.warning("no point hit the plant: nothing to evaluate")
        return Evaluation(n_points=0, metrics=None, traits=None, estimate=None,
                          truth_path=str(found) if found else None, time_s=time.perf_counter() - t0)
    labelled = _labelled_truth(plant) if found is None and truth_path is None and options.traits else None
    with_traits = (found is not None or labelled is not None) and options.traits
    n_metric = len(pts) + options.n_surface_samples
    total = n_metric + (_TRAITS_WORK_PER_POINT * len(pts) if with_traits else 0)
    # With two threads or more, the traits are extracted beside the metrics: both
    # spend much of their time in numpy and scipy code that releases the GIL.
    pool = (concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="traits")
            if with_traits and workers >= 2 else None)
    try:
        estimate_future = (None if pool is None else
                           pool.submit(traits.traits_and_segmentation, pts, settings=options.trait_settings,
                                       range_noise_m=range_noise_m, beam_gaps_m=beam_gaps_m))
        measured = metrics.cloud_mesh_metrics(
            pts, plant.vertices_turntable, plant.faces, coverage_distance=options.coverage_distance,
            band_height=options.band_height, n_surface_samples=options.n_surface_samples,
            rng=np.random.default_rng(options.seed), proximity=proximity, workers=workers,
            progress=None if progress is None else (lambda done, _n: progress(done, total)))
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    comparison = estimate = organs = None
    if with_traits:
        try:
            truth = labelled if found is None else json.loads(found.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"truth_path: {found} is not valid JSON: {exc}") from exc
        for note in truth_notes(truth) if isinstance(truth, Mapping) else ():
            logger.log(logging.INFO if note.startswith("truth has no") else logging.WARNING,
                       "%s: %s", found or plant.source, note)
        try:
            reference = traits.traits_from_truth(truth_in_turntable(truth, plant.T_turntable_mesh))
            estimate, organs = (traits.traits_and_segmentation(pts, settings=options.trait_settings,
                                                               range_noise_m=range_noise_m,
                                                               beam_gaps_m=beam_gaps_m)
                                if estimate_future is None else estimate_future.result())
            comparison = traits.compare_traits(estimate, reference)
        except (ValueError, KeyError, TypeError) as exc:
            # A truth file in another schema costs the trait comparison, never the scan.
            logger.warning("truth %s not usable for traits, comparison skipped: %s", found, exc)
            comparison = estimate = None
    leaves_alone, leaves_how, matched = None, None, None
    if comparison is not None:
        leaves_alone, leaves_how, matched = _labelled_leaves(pts, plant, range_noise_m, options.trait_settings,
                                                             organs)
    if progress is not None:
        progress(total, total)
    if found is None and labelled is not None:
        found = f"{plant.source} (face labels)"
    return Evaluation(n_points=int(len(pts)), metrics=measured, traits=comparison, estimate=estimate,
                      truth_path=str(found) if found else None, time_s=time.perf_counter() - t0,
                      range_noise_source=range_noise_source if with_traits else None,
                      labelled_leaves=leaves_alone, labelled_leaves_source=leaves_how, leaf_match=matched)


def evaluate_scan(result, *, options: EvaluationOptions = EvaluationOptions(),
                  truth_path: str | Path | None = None, threads: int | None = None,
                  progress: Callable[[int, int], None] | None = None,
                  proximity: metrics.MeshProximity | None = None) -> Evaluation:
    """Measures a :class:`plantsim.scan.pipeline.ScanResult` (its plant-class points).

    Args:
        result: the scan.
        options: how to measure.
        truth_path: exact-traits JSON; None looks beside the mesh file.
        threads: as :func:`evaluate_cloud`; None takes the scan's own
            ``config.threads`` (``--threads``, the TOML's ``threads``).
        progress: as :func:`evaluate_cloud`.
        proximity: as :func:`evaluate_cloud`.

    Returns:
        Evaluation.
    """
    if threads is None:
        threads = getattr(getattr(result, "config", None), "threads", None)
    noise, source = scan_range_noise(result)
    return evaluate_cloud(result.cloud.plant_only().points_turntable, result.plant,
                          options=options, truth_path=truth_path, threads=threads,
                          progress=progress, proximity=proximity, range_noise_m=noise,
                          range_noise_source=source, beam_gaps_m=scan_beam_gaps(result))


def scan_range_noise(result) -> tuple[np.ndarray | None, str]:
    """The range noise vectors of a scan's plant points (:func:`range_noise_vectors` of
    :func:`range_noise_sigma_m`) and what they are, or (None, why not): what
    :func:`evaluate_scan` checks the leaf widths against; pass them to
    ``extract_traits(result.cloud.plant_only().points_turntable, range_noise_m=...)``."""
    cloud = result.cloud.plant_only()
    sigma, source = range_noise_sigma_m(cloud, result.parts, result.config.lidar, result.config.sensor_model)
    return (None if sigma is None else range_noise_vectors(cloud, result.raw.T_base_lidar, sigma)), source
