"""Leaf widths checked against the sensor's range noise, from a scan's own record.

The geometry (each point's beam direction from the rig and its turntable angle) against
hand-computed transforms and the reconstruction itself; which noise a scan had, from
what its parts simulated; and end to end, ``plantsim traits`` on a scan's cloud with
and without its sidecar, and ``evaluate_scan``'s sidecar object.
"""

from __future__ import annotations

import functools
import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from plantsim.cloud.reconstruct import base_to_turntable, beam_dirs_turntable
from plantsim.evaluation import evaluate
from plantsim.evaluation.evaluate import range_noise_sigma_m, range_noise_vectors, scan_range_noise
from plantsim.evaluation.traits import extract_traits
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_maize, make_rosette, to_labelled_obj_bytes, traits_to_json
from plantsim.scan.config import RangeFilter, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.sensor.model import SensorModel, range_sigma_at_least
from plantsim.sensor.spec import URG_04LX_UG01


def test_beam_directions_by_hand_and_back_to_the_lidar_along_the_range():
    T_base_lidar = np.eye(4)
    T_base_lidar[:3, 3] = (0.35, 0.0, 0.15)
    pts = np.array([[0.0, 0.0, 0.15], [0.0, 0.0, 0.15], [0.05, 0.0, 0.55]])
    dirs = beam_dirs_turntable(pts, np.radians([90.0, 0.0, 0.0]), T_base_lidar)
    # Turned 90 deg counter-clockwise, the LiDAR stands at (0, -0.35) in the turntable
    # frame; unturned at (0.35, 0): the third point is 0.3 m in and 0.4 m up from it.
    np.testing.assert_allclose(dirs, [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [-0.6, 0.0, 0.8]], atol=1e-15)
    with pytest.raises(ValueError, match="2 angles for 3 points"):
        beam_dirs_turntable(pts, np.zeros(2), T_base_lidar)


@functools.lru_cache(maxsize=None)
def _plant():
    return make_maize(seed=2, n_leaves=4)


@functools.lru_cache(maxsize=None)
def _scan(ideal: bool = False, range_filter: bool = False):
    plant = _plant()
    config = RunConfig(ideal=ideal, scan=StepScan(step_deg=2.0))
    if range_filter:
        config = config.replace(range_filter=RangeFilter(enabled=True))
    return run_scan(config, plant=plant_from_arrays(plant.vertices_m, plant.faces))


def test_a_scans_points_go_back_along_their_beams_to_the_lidar_by_their_range():
    result = _scan()
    cloud = result.cloud.plant_only()
    dirs = beam_dirs_turntable(cloud.points_turntable, cloud.turntable_angle_rad, result.raw.T_base_lidar)
    origin = base_to_turntable(np.broadcast_to(result.raw.T_base_lidar[:3, 3], dirs.shape),
                               cloud.turntable_angle_rad)
    np.testing.assert_allclose(cloud.points_turntable - cloud.range_m[:, None] * dirs, origin, atol=1e-12)


def test_which_noise_a_scan_had_follows_what_its_parts_simulated():
    lidar, model = URG_04LX_UG01, SensorModel()
    r = np.array([0.2, 0.35, 0.5])
    intensity = np.array([0.02, 0.01, 1.0])
    cloud = SimpleNamespace(range_m=r, intensity=intensity)
    realistic = {"lidar": {"kind": "simulated", "model": lidar.name, "sensor": "realistic",
                           "effects": {"range_noise": True}}}
    sigma, why = range_noise_sigma_m(cloud, realistic, lidar, model)
    np.testing.assert_array_equal(sigma, range_sigma_at_least(r, lidar, intensity=intensity, model=model))
    assert "read back from each point's intensity" in why
    # No intensity recorded, or a real sensor (none given): a white target head-on.
    for parts, c in ((realistic, SimpleNamespace(range_m=r, intensity=None)),
                     ({"lidar": {"kind": "urg", "real": True, "preset": lidar.name}}, cloud)):
        sigma, why = range_noise_sigma_m(c, parts, lidar, model)
        np.testing.assert_array_equal(sigma, range_sigma_at_least(r, lidar))
        assert "white target head-on" in why and "a lower bound" in why
    sigma, why = range_noise_sigma_m(cloud, {"lidar": {"sensor": "ideal"}}, lidar, SensorModel.off())
    assert np.all(sigma == 0) and why == "ideal sensor: no range noise"
    quiet = {"lidar": {"sensor": "realistic", "effects": {"range_noise": False}}}
    sigma, why = range_noise_sigma_m(cloud, quiet, lidar, SensorModel(range_noise=False))
    # What is left is the rounding to the 1 mm resolution: uniform over a step, 1 mm / sqrt(12).
    np.testing.assert_allclose(sigma, 0.001 / np.sqrt(12.0), rtol=1e-12)
    assert "range noise off" in why and "rounding to 1 mm only (0.29 mm)" in why
    sigma, why = range_noise_sigma_m(cloud, quiet, lidar, SensorModel(range_noise=False, quantise=False))
    assert np.all(sigma == 0) and why == "realistic sensor with its range noise off: no range noise"
    assert range_noise_sigma_m(cloud, {**realistic, "range_filter": {}}, lidar, model)[0] is None
    assert range_noise_sigma_m(cloud, {}, lidar, model)[0] is None
    assert range_noise_sigma_m(cloud, realistic, lidar, None) == (
        None, "not checked: the scan does not give its sensor model")
    with pytest.raises(ValueError, match="sigma_m must be finite numbers >= 0"):
        range_noise_vectors(SimpleNamespace(points_turntable=np.zeros((1, 3)), turntable_angle_rad=np.zeros(1)),
                            np.eye(4), np.array([-1.0]))


def test_a_realistic_scans_leaf_widths_are_checked_and_an_ideal_scans_all_resolved():
    noise, why = scan_range_noise(_scan())
    assert noise is not None and "read back from each point's intensity" in why
    # At least the URG-04LX's 10 mm floor along every beam.
    assert np.all(np.linalg.norm(noise, axis=1) >= URG_04LX_UG01.range_sigma_m * (1 - 1e-12))
    pts = _scan().cloud.plant_only().points_turntable
    leaves = extract_traits(pts, range_noise_m=noise).leaves
    assert leaves and all(isinstance(lf.width_resolved, bool) for lf in leaves)
    assert all(lf.noise_width_m > 0 for lf in leaves)
    noise, why = scan_range_noise(_scan(ideal=True))
    assert why == "ideal sensor: no range noise" and not noise.any()
    leaves = extract_traits(_scan(ideal=True).cloud.plant_only().points_turntable, range_noise_m=noise).leaves
    assert leaves and all(lf.width_resolved is True and lf.noise_width_m == 0 for lf in leaves)
    noise, why = scan_range_noise(_scan(range_filter=True))
    assert noise is None and why.startswith("not checked: the range filter")


def test_cli_scan_and_traits_check_the_widths_with_the_sidecar_and_say_so_without_it(tmp_path, capsys):
    from plantsim.cli.app import main

    plant = _plant()
    mesh = tmp_path / "maize.obj"
    mesh.write_bytes(to_labelled_obj_bytes(plant))
    (tmp_path / "maize.traits.json").write_text(traits_to_json(plant))
    cloud = tmp_path / "maize.las"
    assert main(["scan", str(mesh), "-o", str(cloud), "--step-deg", "2", "--no-pictures", "--evaluate"]) == 0
    # The scan's own evaluation prints what its trait errors do not say.
    notes = json.loads((tmp_path / "maize.las.json").read_text())["evaluation"]["traits"]["notes"]
    printed = capsys.readouterr().out
    assert notes and all(f"traits note: {n}" in printed for n in notes)
    out = tmp_path / "t.json"
    assert main(["traits", str(cloud), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert "read back from each point's intensity" in data["leaf_widths_checked_against"]
    assert data["leaves"] and all(isinstance(lf["width_resolved"], bool) for lf in data["leaves"])
    assert "leaf widths checked against: the urg-04lx-ug01's range noise" in printed
    # The rig's beams, from the sidecar, say how far apart they pass at the top: half that
    # gap is in the height, and a note says so.
    assert data["height_top_between_beams"].startswith("half the gap between the urg-04lx-ug01's beams "
                                                       "(0.3516 deg apart) at the top, on the scan's rig")
    gap = data["height_beam_gap_m"]
    assert 0.001 < gap < 0.01 and "between the beams at the top voxel" in printed
    assert f"height: {data['height_top_between_beams']}" in printed
    # What the scan said its rig could not do for the plant comes with the traits.
    said = json.loads((tmp_path / "maize.las.json").read_text())["simulated"]["plan"]["rig_fit_warnings"]
    assert data["scan_rig_fit_warnings"] == said
    assert all(f"note: the scan's rig (its sidecar): {w}" in printed for w in said)
    # The same cloud without its sidecar: nothing is claimed, and the output says why.
    alone = tmp_path / "alone.las"
    shutil.copyfile(cloud, alone)
    assert main(["traits", str(alone), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["leaf_widths_checked_against"].startswith("not checked: no plantsim sidecar (alone.las.json)")
    assert data["height_top_between_beams"].startswith("the top as sampled: no plantsim sidecar (alone.las.json)")
    assert data["height_beam_gap_m"] is None
    assert data["scan_rig_fit_warnings"] is None
    assert all(lf["width_resolved"] is None for lf in data["leaves"])
    # A sidecar of another scan (other point count) is not used.
    other = tmp_path / "other.las"
    shutil.copyfile(cloud, other)
    meta = json.loads((tmp_path / "maize.las.json").read_text())
    meta["counts"]["points_written"] += 1
    (tmp_path / "other.las.json").write_text(json.dumps(meta))
    assert main(["traits", str(other), "-o", str(out)]) == 0
    assert "the scan other.las.json describes wrote" in json.loads(out.read_text())["leaf_widths_checked_against"]
    # A format that drops each point's range and angle cannot be checked, sidecar or not.
    pts = tmp_path / "maize.pts"
    assert main(["scan", str(mesh), "-o", str(pts), "--step-deg", "2", "--no-pictures"]) == 0
    assert main(["traits", str(pts), "-o", str(out)]) == 0
    assert json.loads(out.read_text())["leaf_widths_checked_against"].startswith(
        "not checked: a .pts cloud does not carry each point's range and turntable angle")
    assert json.loads(out.read_text())["height_top_between_beams"].startswith(
        "the top as sampled: a .pts cloud does not carry each point's turntable angle")


def test_traits_of_a_rosette_scanned_edge_on_repeat_the_rigs_warning(tmp_path, capsys):
    """A flat plant on the default rig is seen edge-on (leaf area and count read low by
    occlusion): the traits say so, from the scan's sidecar, and so does a .pts cloud
    (no beams to check widths with, but the same scan)."""
    from plantsim.cli.app import main

    mesh = tmp_path / "rosette.obj"
    mesh.write_bytes(to_labelled_obj_bytes(make_rosette(seed=1, n_leaves=6)))
    for name in ("rosette.las", "rosette.pts"):
        cloud = tmp_path / name
        assert main(["scan", str(mesh), "-o", str(cloud), "--step-deg", "4", "--no-pictures", "--ideal"]) == 0
        capsys.readouterr()
        out = tmp_path / "t.json"
        assert main(["traits", str(cloud), "-o", str(out)]) == 0
        printed = capsys.readouterr().out
        data = json.loads(out.read_text())
        (warning,) = [w for w in data["scan_rig_fit_warnings"] if "edge-on" in w]
        assert warning.startswith("the plant is flat") and f"note: the scan's rig (its sidecar): {warning}" in printed
        # Which points were measured is said: a .pts file carries no classes, so its
        # turntable's points are in the cloud too.
        counts = json.loads((tmp_path / f"{name}.json").read_text())["counts"]
        n_file, n_plant = counts["points_written"], counts["points_written_by_class"]["plant"]
        if name.endswith(".las"):
            assert data["points_measured"].startswith(f"the {n_plant} of {n_file} points classed as plant")
        else:
            assert data["points_measured"].startswith(f"all {n_file} points: the file carries no point classes")
        assert f"points: {data['points_measured']}" in printed
        # The segmentation's own spread: what each shifted voxel grid read.
        counts = data["leaf_counts_over_grids"]
        assert len(counts) == 9 and data["leaf_count"] == sorted(counts)[4]
        assert len(data["leaf_areas_over_grids_m2"]) == 9
        # The plant height's spread over the grids' voxels leads the line; the height is the origin's.
        heights = data["heights_over_grids_m"]
        assert len(heights) == 9 and heights[0] == data["height_m"]
        assert (f"over 9 shifted voxel grids: height {1e3 * min(heights):.4g}-{1e3 * max(heights):.4g} mm, "
                f"leaves {min(counts)}-{max(counts)}") in printed
        # The stem height's spread over the grids, printed where a stem is found: in the
        # .las cloud's plant points (the crown); the .pts cloud, disk points and all,
        # reads no stem, and no stem height is printed.
        stem_heights = data["stem_heights_over_grids_m"]
        spread_line = printed.split("over 9 shifted voxel grids:")[1].splitlines()[0]
        assert len(stem_heights) == 9 and data["stem_count"] == (1 if name.endswith(".las") else 0)
        if data["stem_count"]:
            assert None not in stem_heights and data["stem_height_m"] in stem_heights
            assert spread_line.endswith(f", stem height {1e3 * min(stem_heights):.4g}-"
                                        f"{1e3 * max(stem_heights):.4g} mm (above: the origin grid's height, "
                                        "the median grid's organs)")
        else:
            assert stem_heights == [None] * 9 and "stem height" not in spread_line
    # One grid: the origin's, no spread printed; an even number is refused before any work.
    assert main(["traits", str(cloud), "--grids", "1", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert json.loads(out.read_text())["leaf_counts_over_grids"] == [counts[0]] and "shifted" not in printed
    assert main(["traits", str(cloud), "--grids", "2"]) == 2
    assert "--grids must be an odd number >= 1" in capsys.readouterr().err


def test_evaluate_scan_writes_the_check_and_the_notes_into_the_sidecar_object(tmp_path):
    truth = tmp_path / "truth.json"
    truth.write_text(traits_to_json(_plant()))
    ev = evaluate.evaluate_scan(_scan(), options=evaluate.EvaluationOptions(n_surface_samples=1000),
                                truth_path=truth, threads=1)
    out = ev.to_dict()["traits"]
    assert "read back from each point's intensity" in out["leaf_widths_checked_against"]
    assert out["leaf_widths_resolved"] == [lf.width_resolved for lf in ev.estimate.leaves]
    shares = out["leaf_widths_across_beams_share"]
    assert shares == [lf.width_across_beams_share for lf in ev.estimate.leaves]
    assert all(0.0 <= x <= 1.0 for x in shares)
    assert out["notes"] == list(ev.estimate.notes)
    assert any(n.startswith("stem at") for n in out["notes"])  # the noisy stem's bound is said
    # The height is read between the beams at the top, as `plantsim traits` reads it.
    assert 0.001 < ev.estimate.height_beam_gap_m < 0.01

