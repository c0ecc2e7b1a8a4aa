"""plantsim.evaluate and ``plantsim scan --evaluate``: every scan reports its own error."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import evaluate
from plantsim.cli.app import main
from plantsim.plant.mesh import plant_from_arrays
from plantsim.transforms import make_T, rot_x, rot_z

STALK_TRUTH = {"height_m": 0.2, "stems": [{"index": 0, "base_xy_m": [0.0, 0.0], "diameter_m": 0.03}]}


@pytest.fixture
def stalk(tmp_path):
    """A 30 x 30 x 200 mm box, with an exact-traits file beside it when asked."""
    box = trimesh.creation.box(extents=[0.03, 0.03, 0.2])
    path = tmp_path / "stalk.stl"
    path.write_bytes(box.export(file_type="stl"))
    return path


def test_scan_without_evaluate_has_no_evaluation_and_imports_no_metrics(tmp_path, stalk):
    # The plain scan must stay as fast as before: scipy's metrics and traits are not imported.
    code = ("import sys; from plantsim.cli import main; "
            f"main(['scan', {str(stalk)!r}, '-o', {str(tmp_path / 'a.las')!r}, '--step-deg', '45']); "
            "print(sorted(m for m in ('plantsim.evaluation.evaluate', 'plantsim.evaluation.metrics', 'plantsim.evaluation.traits') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"
    meta = json.loads((tmp_path / "a.las.json").read_text())
    assert "evaluation" not in meta and "evaluate" not in meta["timings_s"]
    # 8 lines at the default 0.5 s a step; the last line takes one 0.1 s scan period.
    assert meta["simulated_rig_time_s"] == pytest.approx(7 * 0.5 + 0.1)


def test_scan_evaluate_adds_metrics_and_time_to_the_sidecar(tmp_path, stalk, capsys):
    out = tmp_path / "ev.las"
    assert main(["scan", str(stalk), "-o", str(out), "--step-deg", "30", "--ideal", "--evaluate"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("wrote ") and lines[1].startswith("evaluation: cloud->mesh median ")
    meta = json.loads((tmp_path / "ev.las.json").read_text())
    ev = meta["evaluation"]
    assert ev["n_points"] == meta["counts"]["points_written_by_class"]["plant"] > 0
    # An ideal scan's points lie on the mesh: the exact distance is rounding only.
    assert ev["max"] < 1e-6
    assert 0 < ev["coverage"] < 1 and ev["chamfer"] > 0
    assert {"median", "p95", "p99", "mesh_to_cloud_mean", "bands"} <= set(ev)
    assert ev["time_s"] == meta["timings_s"]["evaluate"] > 0
    assert "traits" not in ev  # no stalk.traits.json beside the mesh


def test_scan_evaluate_compares_traits_when_a_traits_file_sits_beside_the_mesh(tmp_path, stalk):
    (tmp_path / "stalk.traits.json").write_text(json.dumps(STALK_TRUTH))
    assert main(["scan", str(stalk), "-o", str(tmp_path / "ev.ply"), "--step-deg", "10", "--ideal",
                 "--evaluate"]) == 0
    traits = json.loads((tmp_path / "ev.ply.json").read_text())["evaluation"]["traits"]
    assert traits["truth"] == str(tmp_path / "stalk.traits.json")
    assert traits["n_stems"] == [1, 1]
    height = traits["errors"]["height_m"]
    assert height["reference"] == 0.2 and height["relative_error"] < 0.02
    # A 30 mm square read as a circle: the fit lies between the inscribed and circumscribed.
    assert 0.03 <= traits["errors"]["stem_diameter_m"]["estimate"] <= 0.03 * math.sqrt(2)


def test_truth_traits_path_finds_both_spellings(tmp_path):
    mesh = tmp_path / "p.obj"
    assert evaluate.truth_traits_path(mesh) is None
    (tmp_path / "p.obj.traits.json").write_text("{}")
    assert evaluate.truth_traits_path(mesh) == tmp_path / "p.obj.traits.json"
    (tmp_path / "p.traits.json").write_text("{}")
    assert evaluate.truth_traits_path(mesh) == tmp_path / "p.traits.json"


def test_bundled_plants_have_their_traits_found():
    from plantsim.resources import bundled_plant_path

    for name in ("maize", "wheat"):
        assert evaluate.truth_traits_path(bundled_plant_path(name)).name == f"{name}.traits.json"


def test_truth_is_moved_with_the_placement():
    truth = {"height_m": 0.5, "stems": [{"index": 0, "base_xy_m": [0.01, 0.0], "diameter_m": 0.004}],
             "leaves": [{"index": 0, "length_m": 0.2, "width_m": 0.01}]}
    T = make_T(rot_z(math.pi / 2), [0.1, 0.2, 0.003])
    moved = evaluate.truth_in_turntable(truth, T)
    assert moved["stems"][0]["base_xy_m"] == pytest.approx([0.1, 0.21])
    assert moved["height_m"] == 0.5  # a length: the placement does not change it
    assert moved["leaves"] == truth["leaves"]
    assert truth["stems"][0]["base_xy_m"] == [0.01, 0.0]  # the input is left alone
    with pytest.raises(ValueError, match=r"T_turntable_mesh must keep the mesh's z axis up"):
        evaluate.truth_in_turntable(truth, make_T(rot_x(math.pi / 2)))
    with pytest.raises(ValueError, match=r"T_turntable_mesh must have shape \(4, 4\), got \(3, 3\)"):
        evaluate.truth_in_turntable(truth, np.eye(3))


def test_evaluate_cloud_on_an_analytic_box_and_with_no_points(box_mesh, tmp_path):
    v, f = box_mesh
    plant = plant_from_arrays(v, f, placement="none")
    corners = v[:4]  # vertices lie on the mesh: distance 0
    ev = evaluate.evaluate_cloud(corners + [0.0, 0.0, 0.001] * (corners[:, 2:] > 0), plant,
                                 options=evaluate.EvaluationOptions(n_surface_samples=1000))
    assert ev.n_points == 4 and ev.metrics.n_points == 4
    assert ev.metrics.max == pytest.approx(0.001, abs=1e-12)
    assert ev.traits is None and ev.truth_path is None
    empty = evaluate.evaluate_cloud(np.zeros((0, 3)), plant)
    assert empty.n_points == 0 and empty.metrics is None
    assert json.loads(json.dumps(empty.to_dict()))["n_points"] == 0
    with pytest.raises(FileNotFoundError, match=r"truth_path: traits file not found: .*nope.json"):
        evaluate.evaluate_cloud(corners, plant, truth_path=tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"truth_path: .*bad.json is not valid JSON"):
        evaluate.evaluate_cloud(corners, plant, truth_path=tmp_path / "bad.json")


def test_evaluation_options_are_validated():
    with pytest.raises(ValueError, match=r"coverage_distance must be a finite number > 0 metres, got 0"):
        evaluate.EvaluationOptions(coverage_distance=0)
    with pytest.raises(ValueError, match=r"n_surface_samples must be an integer >= 1, got 0"):
        evaluate.EvaluationOptions(n_surface_samples=0)
    with pytest.raises(ValueError, match=r"seed must be a non-negative integer, got -1"):
        evaluate.EvaluationOptions(seed=-1)
    with pytest.raises(TypeError):
        evaluate.EvaluationOptions(0.002)  # keyword-only


def _noisy_box_cloud(v, f, n=3000):
    from plantsim.evaluation.metrics import sample_surface

    pts, _ = sample_surface(v, f, n, rng=3)
    return pts + np.random.default_rng(4).normal(scale=0.001, size=pts.shape)


def test_progress_reaches_the_end_and_threads_do_not_change_the_answer(box_mesh):
    v, f = box_mesh
    plant = plant_from_arrays(v, f, placement="none")
    pts = _noisy_box_cloud(v, f)
    options = evaluate.EvaluationOptions(n_surface_samples=20_000)
    seen = []
    many = evaluate.evaluate_cloud(pts, plant, options=options, threads=None,
                                   progress=lambda done, total: seen.append((done, total)))
    one = evaluate.evaluate_cloud(pts, plant, options=options, threads=1)
    a, b = many.to_dict(), one.to_dict()
    a.pop("time_s"), b.pop("time_s")
    assert a == b
    # Distances, then coverage samples; one total throughout, never going back.
    totals = {t for _, t in seen}
    assert totals == {len(pts) + 20_000}
    done = [d for d, _ in seen]
    assert done == sorted(done) and done[-1] == len(pts) + 20_000
    assert any(d == len(pts) for d in done)  # the distance part ends before coverage starts


def test_the_distances_are_the_exact_reference_kernels(box_mesh):
    from plantsim.evaluation import metrics

    v, f = box_mesh
    plant = plant_from_arrays(v, f, placement="none")
    pts = _noisy_box_cloud(v, f, 2000)
    options = evaluate.EvaluationOptions(n_surface_samples=5000)
    grid = metrics.MeshProximity(plant.vertices_turntable, plant.faces, backend="grid")
    igl = metrics.MeshProximity(plant.vertices_turntable, plant.faces, backend="igl")
    by_grid = evaluate.evaluate_cloud(pts, plant, options=options, proximity=grid).metrics
    by_igl = evaluate.evaluate_cloud(pts, plant, options=options, proximity=igl).metrics
    for name in ("median", "p95", "max", "mean", "rms", "coverage", "chamfer"):
        assert getattr(by_igl, name) == pytest.approx(getattr(by_grid, name), rel=0, abs=1e-15)


def test_threads_are_checked_capped_at_the_cores_and_taken_from_the_scan(box_mesh, monkeypatch):
    from types import SimpleNamespace

    from plantsim.cloud.reconstruct import PointCloud
    from plantsim.evaluation import metrics

    cores = evaluate.evaluation_threads(None)
    assert cores >= 1 and evaluate.evaluation_threads(10_000) == cores
    assert evaluate.evaluation_threads(1) == 1
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match=r"threads must be a positive integer or None \(all cores\)"):
            evaluate.evaluation_threads(bad)
    v, f = box_mesh
    plant = plant_from_arrays(v, f, placement="none")
    pts = _noisy_box_cloud(v, f, 500)
    n = len(pts)
    cloud = PointCloud(points_turntable=pts, hit_class=np.ones(n, np.uint8),
                       beam_index=np.zeros(n, np.uint16), scan_index=np.zeros(n, np.uint32),
                       turntable_angle_rad=np.zeros(n), range_m=np.ones(n), time_s=np.zeros(n))
    used = []
    real = metrics.cloud_mesh_metrics
    monkeypatch.setattr(metrics, "cloud_mesh_metrics",
                        lambda *a, **k: used.append(k["workers"]) or real(*a, **k))
    result = SimpleNamespace(cloud=cloud, plant=plant, parts={},
                             config=SimpleNamespace(threads=1, lidar=None, sensor_model=None))
    evaluate.evaluate_scan(result, options=evaluate.EvaluationOptions(n_surface_samples=100))
    assert evaluate.scan_beam_gaps(result) is None  # no LiDAR given: the top as sampled
    result.config.threads = None
    evaluate.evaluate_scan(result, options=evaluate.EvaluationOptions(n_surface_samples=100))
    assert used == [1, cores]


def test_scan_evaluate_draws_the_error_picture_or_says_why_not(tmp_path, stalk, capsys, monkeypatch):
    from plantsim.cloud import render

    out = tmp_path / "ev.las"
    assert main(["scan", str(stalk), "-o", str(out), "--step-deg", "30", "--evaluate"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    picture = tmp_path / "ev.las.error.png"
    if line.startswith("error picture: skipped"):
        print(f"no offscreen OpenGL here, the picture's pixels are not checked: {line}")
        assert not picture.exists()
    else:
        assert line.startswith(f"error picture: {picture} (plant points by distance to the mesh, "
                               "blue 0 mm -> red >= ")
        from test_render import _decode_png

        image = _decode_png(picture.read_bytes())
        assert image.shape == (720, 960, 3) and image.std() > 10  # not uniform

    # No GL backend: one line, the scan and its sidecar written all the same.
    def no_gl(*args, **kwargs):
        raise render.RenderError("no offscreen OpenGL: egl: missing; osmesa: missing. Install EGL")

    monkeypatch.setattr(render, "error_picture_of", no_gl)
    out2 = tmp_path / "nogl.las"
    assert main(["scan", str(stalk), "-o", str(out2), "--step-deg", "30", "--evaluate"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == ("error picture: skipped (no offscreen OpenGL: egl: missing; osmesa: missing. "
                         "Install EGL); --no-pictures silences this")
    assert out2.exists() and (tmp_path / "nogl.las.json").exists()
    assert not (tmp_path / "nogl.las.error.png").exists()

    # --no-pictures: neither picture nor line.
    out3 = tmp_path / "quiet.las"
    assert main(["scan", str(stalk), "-o", str(out3), "--step-deg", "30", "--evaluate",
                 "--no-pictures"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and lines[1].startswith("evaluation: ")
    assert not (tmp_path / "quiet.las.error.png").exists()


def test_traits_beside_the_metrics_give_the_serial_answer(tmp_path, stalk):
    from plantsim.evaluation.metrics import sample_surface
    from plantsim.plant.mesh import load_plant

    (tmp_path / "stalk.traits.json").write_text(json.dumps(STALK_TRUTH))
    plant = load_plant(stalk)
    pts, _ = sample_surface(plant.vertices_turntable, plant.faces, 4000, rng=1)
    pts = pts + np.random.default_rng(2).normal(scale=0.0005, size=pts.shape)
    options = evaluate.EvaluationOptions(n_surface_samples=5000)
    serial = evaluate.evaluate_cloud(pts, plant, options=options, threads=1).to_dict()
    beside = evaluate.evaluate_cloud(pts, plant, options=options, threads=2).to_dict()
    serial.pop("time_s"), beside.pop("time_s")
    assert serial["traits"]["truth"] == str(tmp_path / "stalk.traits.json")
    assert json.dumps(serial, sort_keys=True) == json.dumps(beside, sort_keys=True)
