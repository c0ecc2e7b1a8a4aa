"""``plantsim traits CLOUD [--json] [-o traits.json]``: the traits of any cloud.

The cloud (LAS/LAZ/PLY/PCD/TXT, read by :func:`plantsim.cloud.export.read_cloud`) must
be in the turntable frame, metres, z up, the plant base at ``--base-z``. When plantsim's
sidecar is beside it (``CLOUD.json``, from ``plantsim scan``), the sensor's range noise
along each point's beam (the rig's LiDAR pose and each point's turntable angle and
intensity) checks the leaf widths and moves the points that can reach the plant's top
along their beams before the height is read (a note gives the height as measured too),
and the rig's beams say how far apart they pass at the top, which lies between the
highest that hits it and the next: half that gap is added to the height
(``height_top_between_beams`` says so, or why not; ``height_beam_gap_m``);
the output says what that noise is, or why it is not known, and repeats what the scan
said its rig could not do for the plant (``scan_rig_fit_warnings``: a flat plant's
leaves seen edge-on, a top seen at grazing beams), which bounds what the traits can read.

``--labels FIELD`` also measures the leaves a per-point label field of the file gives (a hand
segmentation, a labelled dataset such as Pheno4D's ``x y z label`` text files with
``--stem-label 1 --ignore-labels 0``), each alone by the same per-leaf measures, with no
segmentation (``labelled_leaves`` in the JSON): set against the traits, it says how much of
a leaf trait's error is the segmentation's.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def add_traits_command(sub) -> None:
    """Registers ``traits`` on the ``plantsim`` sub-parsers."""
    p = sub.add_parser("traits", help="extract plant traits from a point cloud",
                       description=__doc__.splitlines()[0])
    p.add_argument("cloud", type=Path, help="point cloud file (.las .laz .ply .pcd .txt)")
    p.add_argument("--json", action="store_true", help="print the traits as JSON")
    p.add_argument("-o", "--output", type=Path, default=None, help="write the traits JSON here")
    p.add_argument("--base-z", type=float, default=0.0, help="z of the plant base, metres (default 0)")
    p.add_argument("--all-points", action="store_true",
                   help="use every point (default: plant-class points when the file has classes)")
    p.add_argument("--grids", type=int, default=9, metavar="N",
                   help="segment the organs on N shifted voxel grids and keep the median's (odd; default 9; "
                        "1: one grid, about a third of the time, no spread)")
    p.add_argument("--labels", metavar="FIELD",
                   help="also measure the leaves a per-point label field gives (a LAS dimension, PLY property, "
                        "PCD field or TXT column; a header-less TXT's 4th column is _col3), each alone with "
                        "the same measures, no segmentation: every label is a leaf but --stem-label's, "
                        "--ignore-labels' and negative ones")
    p.add_argument("--stem-label", type=int, default=0, metavar="N",
                   help="with --labels: the stem's label (default 0); leaves are measured from where they "
                        "meet it")
    p.add_argument("--ignore-labels", type=int, nargs="+", default=[], metavar="N",
                   help="with --labels: labels that are neither leaf nor stem (soil, pot), e.g. 0 for "
                        "Pheno4D's with --stem-label 1")
    p.set_defaults(func=cmd_traits)


def traits_dict(points_turntable, *, base_z: float = 0.0, range_noise_m=None, beam_gaps_m=None,
                grids: int = 9) -> dict:
    """The traits JSON object of a cloud (NaN becomes None)."""
    from plantsim.evaluation.traits import TraitSettings, extract_traits

    return extract_traits(points_turntable, settings=TraitSettings(base_z=base_z, shifted_grids=grids),
                          range_noise_m=range_noise_m, beam_gaps_m=beam_gaps_m).to_dict()


def labelled_leaves_dict(points_turntable, labels, *, stem_label: int = 0, ignore_labels=(),
                         base_z: float = 0.0, range_noise_m=None) -> dict:
    """The leaves per-point ``labels`` give, each measured alone
    (:func:`plantsim.evaluation.traits.measure_labelled_leaves`, on the points of every label
    but ``ignore_labels``': the soil or a pot does not set the voxel), as JSON: every label is
    a leaf but ``stem_label``'s, ``ignore_labels``' and negative ones; a leaf is measured
    from its point nearest a stem point (its nearest the turntable's axis with no stem point).

    Raises:
        ValueError: labels that are not whole numbers, or not one per point.
    """
    import numpy as np

    from plantsim.evaluation.traits import TraitSettings, leaf_bases_at_stem, measure_labelled_leaves

    pts = np.asarray(points_turntable, dtype=np.float64)
    values = np.asarray(labels)
    if values.shape != (len(pts),):
        raise ValueError(f"the labels are {values.shape}, not one per point ({len(pts)})")
    if values.dtype.kind == "f" and not np.all(np.isfinite(values) & (values == np.round(values))):
        raise ValueError("the labels must be whole numbers (a leaf's or organ's id), not measurements")
    values = np.round(values.astype(np.float64)).astype(np.int64)
    stem = values == stem_label
    leaf = (values >= 0) & ~stem & ~np.isin(values, list(ignore_labels))
    leaf_values, leaf_id = np.unique(values[leaf], return_inverse=True)
    ids = np.full(len(pts), -1, dtype=np.int64)
    ids[leaf] = leaf_id
    bases = leaf_bases_at_stem(pts, ids, pts[stem])
    plant = ~np.isin(values, list(ignore_labels))
    measured = measure_labelled_leaves(pts[plant], ids[plant], leaf_bases_m=bases,
                                       range_noise_m=None if range_noise_m is None else
                                       np.asarray(range_noise_m)[plant],
                                       settings=TraitSettings(base_z=base_z))
    out = measured.to_dict()
    out["labels"] = [int(leaf_values[k]) for k in measured.labels]
    out["stem_label"] = int(stem_label)
    out["ignored_labels"] = sorted(int(v) for v in ignore_labels)
    out["n_stem_points"] = int(stem.sum())
    out["measured_from"] = ("each leaf's point nearest a stem point" if bases is not None
                            else "each leaf's point nearest the turntable's axis (no stem point labelled)")
    return out


def points_to_measure(cloud, *, all_points: bool = False):
    """The points whose traits are read, and a sentence saying which: the plant-class
    points when the file classes its points (``--all-points``: every point), else every
    point, said aloud: a file with no classes (.pts, .e57, most clouds from elsewhere)
    holds whatever was scanned, and a turntable's or the soil's points in it would be
    measured as plant."""
    from plantsim.rig.scene import HitClass

    n = len(cloud.points_turntable)
    if all_points:
        return cloud, f"all {n} points (--all-points)"
    mask = _measured_mask(cloud, all_points)
    if not mask.all():
        return cloud.select(mask), f"the {int(mask.sum())} of {n} points classed as plant (--all-points: every point)"
    if bool((cloud.hit_class == HitClass.NONE).all()):
        return cloud, (f"all {n} points: the file carries no point classes, so any turntable, rig or soil "
                       "points in it are measured as plant (plantsim scan's .las, .ply and .pcd keep them "
                       "apart; else crop the cloud to the plant)")
    if (cloud.hit_class == HitClass.PLANT).all():
        return cloud, f"the {n} of {n} points classed as plant (--all-points: every point)"
    return cloud, f"all {n} points: none is classed as plant"


def _measured_mask(cloud, all_points: bool):
    """Which of the file's points :func:`points_to_measure` keeps: the plant-class ones,
    or every one (``all_points``, or none classed as plant)."""
    import numpy as np

    from plantsim.rig.scene import HitClass

    if all_points:
        return np.ones(len(cloud.points_turntable), dtype=bool)
    plant = cloud.hit_class == HitClass.PLANT
    return plant if plant.any() else np.ones(len(cloud.points_turntable), dtype=bool)


def read_sidecar(cloud_path: Path, n_points_in_file: int) -> tuple[dict | None, str]:
    """The plantsim sidecar beside the cloud file, read once; (None, why not) when it is
    missing, unreadable, or describes another cloud (another point count)."""
    from plantsim.cloud.export import sidecar_path

    side = sidecar_path(cloud_path)
    if not side.is_file():
        return None, f"no plantsim sidecar ({side.name}) beside the cloud says which sensor made it"
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
        written = meta["counts"]["points_written"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"{side.name} is not a plantsim scan's sidecar ({type(exc).__name__}: {exc})"
    if written != n_points_in_file:
        return None, f"the cloud holds {n_points_in_file} points, the scan {side.name} describes wrote {written}"
    return meta, ""


def _sidecar_rig(cloud_path: Path, meta: dict | None, why_no_meta: str, *, carried: str, gives: str):
    """((T_base_lidar, LidarSpec), "") of the scan, from its sidecar ``meta``
    (:func:`read_sidecar`); (None, why not) when the format drops each point's
    ``carried``, there is no sidecar for this cloud, or it does not give them (``gives``:
    what the caller looks for in it)."""
    from plantsim.cloud.export import INDEXED_FORMATS, LOSSY_FORMATS, sidecar_path
    from plantsim.sensor.spec import LidarSpec

    suffix = cloud_path.suffix.lower()
    if suffix in LOSSY_FORMATS | INDEXED_FORMATS:
        return None, (f"a {suffix} cloud does not carry each point's {carried} (a .las, .ply or .pcd from "
                      "plantsim scan does)")
    if meta is None:
        return None, why_no_meta
    try:
        return (meta["frames"]["T_base_lidar"], LidarSpec(**meta["config"]["lidar"])), ""
    except (ValueError, KeyError, TypeError) as exc:
        return None, (f"{sidecar_path(cloud_path).name} does not give the scan's {gives} "
                      f"({type(exc).__name__}: {exc})")


def range_noise_from_sidecar(cloud_path: Path, meta: dict | None, why_no_meta: str, cloud):
    """The range noise vectors of ``cloud``'s points (a selection of the file's) from the
    scan's sidecar ``meta`` (:func:`read_sidecar`), and what they are; (None, why not)
    when the format drops each point's beam, there is no sidecar for this cloud, or it
    says the noise is not known."""
    from plantsim.cloud.export import sidecar_path
    from plantsim.evaluation.evaluate import range_noise_sigma_m, range_noise_vectors
    from plantsim.sensor.model import SensorModel

    rig, why = _sidecar_rig(cloud_path, meta, why_no_meta, carried="range and turntable angle",
                            gives="sensor and rig")
    if rig is None:
        return None, f"not checked: {why}"
    T_base_lidar, lidar = rig
    try:
        simulated = meta["simulated"]
        model = SensorModel(**meta["config"]["sensor_model"])
    except (ValueError, KeyError, TypeError) as exc:
        return None, (f"not checked: {sidecar_path(cloud_path).name} does not give the scan's sensor and rig "
                      f"({type(exc).__name__}: {exc})")
    sigma, why = range_noise_sigma_m(cloud, simulated, lidar, model)
    return (None if sigma is None else range_noise_vectors(cloud, T_base_lidar, sigma)), why


def beam_gaps_from_sidecar(cloud_path: Path, meta: dict | None, why_no_meta: str, cloud):
    """How far up the vertical through each of ``cloud``'s points the fan's next beam
    passes (:func:`plantsim.evaluation.evaluate.beam_gaps_m`), from the scan's rig and
    LiDAR in its sidecar ``meta``, and what they are; (None, why not) when the format
    drops each point's turntable angle or there is no sidecar for this cloud."""
    from plantsim.cloud.export import sidecar_path
    from plantsim.evaluation.evaluate import beam_gaps_m

    rig, why = _sidecar_rig(cloud_path, meta, why_no_meta, carried="turntable angle", gives="LiDAR and rig")
    if rig is None:
        return None, f"the top as sampled: {why}"
    T_base_lidar, lidar = rig
    return (beam_gaps_m(cloud, T_base_lidar, lidar.angle_increment_deg),
            f"half the gap between the {lidar.name}'s beams ({lidar.angle_increment_deg:.4g} deg apart) at the "
            f"top, on the scan's rig ({sidecar_path(cloud_path).name})")


def rig_fit_warnings_from_sidecar(meta: dict | None) -> list[str] | None:
    """What the scan's sidecar says its rig could not do for this plant
    (:func:`plantsim.rig.fit.rig_fit_warnings`, recorded at scan time); None without a
    sidecar for this cloud or when it does not say."""
    try:
        warnings = meta["simulated"]["plan"]["rig_fit_warnings"]
    except (KeyError, TypeError):
        return None
    return [str(w) for w in warnings] if isinstance(warnings, list) else None


def cmd_traits(args: argparse.Namespace) -> int:
    from plantsim.cloud.export import read_cloud, read_point_field

    if not args.cloud.is_file():
        print(f"plantsim traits: cloud file not found: {args.cloud}", file=sys.stderr)
        return 2
    if args.labels is None and (args.stem_label != 0 or args.ignore_labels):
        # Nothing is silently ignored: these say how to read --labels.
        print("plantsim traits: --stem-label and --ignore-labels say how to read --labels FIELD; "
              "give --labels too, or drop them", file=sys.stderr)
        return 2
    if args.grids < 1 or args.grids % 2 == 0:
        print(f"plantsim traits: --grids must be an odd number >= 1 (a grid then holds the median leaf "
              f"count), got {args.grids}", file=sys.stderr)
        return 2
    full = read_cloud(args.cloud)
    n_in_file = len(full.points_turntable)
    labels = None
    if args.labels is not None:
        try:
            labels = read_point_field(args.cloud, args.labels)
        except ValueError as exc:
            print(f"plantsim traits: --labels: {exc}", file=sys.stderr)
            return 2
    cloud, measured = points_to_measure(full, all_points=args.all_points)
    pts = cloud.points_turntable
    meta, why_no_meta = read_sidecar(args.cloud, n_in_file)
    noise, checked = range_noise_from_sidecar(args.cloud, meta, why_no_meta, cloud)
    gaps, top_between = beam_gaps_from_sidecar(args.cloud, meta, why_no_meta, cloud)
    rig_warnings = rig_fit_warnings_from_sidecar(meta)
    try:
        out = traits_dict(pts, base_z=args.base_z, range_noise_m=noise, beam_gaps_m=gaps, grids=args.grids)
    except ValueError as exc:
        print(f"plantsim traits: {exc}", file=sys.stderr)
        return 2
    out["points_measured"] = measured
    out["leaf_widths_checked_against"] = checked
    out["height_top_between_beams"] = top_between
    if labels is not None:
        # The same points as the traits': the file's selection of them.
        try:
            out["labelled_leaves"] = {"field": args.labels, **labelled_leaves_dict(
                pts, labels[_measured_mask(full, args.all_points)], stem_label=args.stem_label,
                ignore_labels=args.ignore_labels, base_z=args.base_z, range_noise_m=noise)}
        except ValueError as exc:
            print(f"plantsim traits: --labels {args.labels}: {exc}", file=sys.stderr)
            return 2
    # The rig's limits for this plant, said at scan time, bound what the traits can read
    # (leaves seen edge-on read small and merged; a top seen at grazing beams reads low).
    out["scan_rig_fit_warnings"] = rig_warnings
    text = json.dumps(out, indent=2)
    if args.output is not None:
        args.output.write_text(text + "\n", encoding="utf-8")
    if args.json:
        print(text)
    else:
        def f(v, scale=1.0, unit=""):
            return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v * scale:.4g}{unit}"
        # A diameter the noise hides is the noisy column's width: shown as a bound where no
        # stem's diameter was read (the plant's is then the columns' mean).
        stems_out = out.get("stems") or ()
        bound = "<= " if stems_out and not any(st.get("diameter_resolved", True) for st in stems_out) else ""
        tallest = " (the tallest's)" if len(out.get("stems") or ()) > 1 else ""
        print(f"height {f(out['height_m'], 1e3, ' mm')}; stems {out['stem_count']}, diameter "
              f"{bound}{f(out['stem_diameter_m'], 1e3, ' mm')}, height {f(out['stem_height_m'], 1e3, ' mm')}"
              f"{tallest}; "
              f"leaves {out['leaf_count']}"
              + (f" ({out['lamina_count']} laminae)" if out.get("lamina_count", out["leaf_count"]) != out["leaf_count"]
                 else "")
              + f", area {f(out['leaf_area_m2'], 1e4, ' cm^2')}")
        print(f"points: {measured}")
        if len(out.get("stems") or ()) > 1:
            # A tiller's height is its own; the line above gives the tallest stem's.
            def mm(v, digits=0):
                return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{round(1e3 * v, digits) + 0.0:.{digits}f}"
            print("stems: " + "; ".join(
                f"at ({mm(st['center_xy_m'][0])}, {mm(st['center_xy_m'][1])}) mm, "
                f"{'<= ' if not st.get('diameter_resolved', True) else ''}{mm(st['diameter_m'], 1)} mm wide, "
                f"{mm(st.get('height_m'))} mm tall"
                # Found in its points' turn angles, the noise hiding it from the base slices.
                + (" (in the turn angles)" if st.get("found_in_beams") else "") for st in out["stems"]))
        counts = out.get("leaf_counts_over_grids") or []
        areas = [a for a in out.get("leaf_areas_over_grids_m2") or [] if a is not None]
        if len(counts) > 1:
            # The segmentation's own uncertainty: what the other voxel grids read.
            spread = f"leaves {min(counts)}-{max(counts)}"
            heights = [h for h in out.get("heights_over_grids_m") or [] if h is not None]
            if heights:
                spread = f"height {f(min(heights), 1e3)}-{f(max(heights), 1e3, ' mm')}, " + spread
            if areas:
                spread += f", area {f(min(areas), 1e4)}-{f(max(areas), 1e4, ' cm^2')}"
            stem_heights = [h for h in out.get("stem_heights_over_grids_m") or [] if h is not None]
            if stem_heights:
                spread += f", stem height {f(min(stem_heights), 1e3)}-{f(max(stem_heights), 1e3, ' mm')}"
            print(f"over {len(counts)} shifted voxel grids: {spread} (above: the origin grid's height, "
                  "the median grid's organs)")
        for note in out["notes"]:
            print(f"note: {note}")
        for warning in rig_warnings or ():
            print(f"note: the scan's rig (its sidecar): {warning}")
        print(f"leaf widths checked against: {checked}")
        print(f"height: {top_between}")
        if labels is not None:
            lab = out["labelled_leaves"]
            print(f"labelled leaves ({lab['field']!r}): {lab['leaf_count']} of {len(lab['labels'])} measured, "
                  f"area {f(lab['leaf_area_m2'], 1e4, ' cm^2')}, each alone from {lab['measured_from']} "
                  "(traits.measure_labelled_leaves: the measures above, no segmentation)")
    return 0
