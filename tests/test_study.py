"""plantsim.study and ``plantsim study``: sweeps, the Pareto front, the CSV and the plot."""

import math

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import study
from plantsim.scan.config import config_from_dict
from plantsim.scan.plan import plan_scan
from plantsim.cli.app import main


# --------------------------------------------------------------------------
# the Pareto front (pure)
# --------------------------------------------------------------------------
def brute_force_front(e, t):
    """A run is on the front when no other run is no worse in both and better in one."""
    n = len(e)
    out = np.zeros(n, bool)
    for i in range(n):
        if not (math.isfinite(e[i]) and math.isfinite(t[i])):
            continue
        out[i] = not any(
            math.isfinite(e[j]) and math.isfinite(t[j]) and e[j] <= e[i] and t[j] <= t[i]
            and (e[j] < e[i] or t[j] < t[i]) for j in range(n))
    return out


def test_pareto_front_of_a_small_example():
    # time:  1    2    3    4    5
    # error: 5    3    4    1    1
    front = study.pareto_front([5, 3, 4, 1, 1], [1, 2, 3, 4, 5])
    assert front.tolist() == [True, True, False, True, False]


def test_pareto_front_ties_and_nan():
    # Equal runs are both on the front; a tie in time keeps only the lower error;
    # NaN never is on it.
    front = study.pareto_front([2, 2, 3, 1, math.nan, 0.5], [1, 1, 1, 5, 0.1, math.nan])
    assert front.tolist() == [True, True, False, True, False, False]
    assert study.pareto_front([], []).tolist() == []


@pytest.mark.parametrize("seed", range(5))
def test_pareto_front_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    e = rng.integers(0, 6, 40).astype(float)  # many ties
    t = rng.integers(0, 6, 40).astype(float)
    e[rng.random(40) < 0.1] = np.nan
    assert study.pareto_front(e, t).tolist() == brute_force_front(e, t).tolist()


def test_pareto_front_checks_lengths():
    with pytest.raises(ValueError, match=r"errors and times must have the same length, got 2 and 3"):
        study.pareto_front([1, 2], [1, 2, 3])


# --------------------------------------------------------------------------
# sweeps as data
# --------------------------------------------------------------------------
def test_runs_expand_the_grid_and_do_not_repeat_ideal_runs_for_sensor_settings():
    sweep = study.Sweep(plants=("maize", "wheat"),
                        grid=(("step_deg", (2.0, 1.0)), ("footprint_rings", (0, 2)),
                              ("ideal", (True, False))))
    runs = sweep.runs()
    # Per plant and step: one ideal run, two realistic (one per ring count).
    assert len(runs) == 2 * 2 * 3
    assert runs[0] == {"plant": "maize", "step_deg": 2.0, "footprint_rings": None, "ideal": True}
    assert {"plant": "wheat", "step_deg": 1.0, "footprint_rings": 2, "ideal": False} in runs
    assert sweep.setting_names == ("step_deg", "footprint_rings", "ideal")


def test_ideal_is_always_a_column_and_comes_from_the_base():
    sweep = study.Sweep(plants=("maize",), grid=(("step_deg", (4.0,)),), base={"ideal": True})
    assert sweep.runs() == [{"plant": "maize", "step_deg": 4.0, "ideal": True}]
    assert sweep.setting_names == ("step_deg", "ideal")


def test_config_data_builds_valid_configurations():
    sweep = study.Sweep(plants=("wheat",), grid=(("n_beams", (100,)), ("step_deg", (3.0,))),
                        base={"lidar": {"range_max_m": 4.0}})
    (run,) = sweep.runs()
    config = config_from_dict(sweep.config_data(run))
    assert config.plant.bundled == "wheat" and config.threads == 1
    assert config.scan.step_deg == 3.0 and config.ideal is False
    # The field of view is kept: 100 beams over the URG-04LX's 682 steps of 360/1024 degrees.
    assert config.lidar.n_beams == 100 and config.lidar.range_max_m == 4.0
    assert config.lidar.fov_deg == pytest.approx(682 * 360 / 1024)
    assert config.lidar.steps_per_rev is None


def test_sweep_validation_names_the_problem():
    with pytest.raises(ValueError, match=r"plants must name at least one plant, got none"):
        study.Sweep(plants=())
    with pytest.raises(ValueError, match=r"unknown setting 'step' in grid; valid settings: mode, step_deg, n_beams"):
        study.Sweep(plants=("maize",), grid=(("step", (1.0,)),))
    with pytest.raises(ValueError, match=r"setting 'rpm' has no values to try"):
        study.Sweep(plants=("maize",), grid=(("rpm", ()),))
    with pytest.raises(ValueError, match=r"grid names a setting twice"):
        study.Sweep(plants=("maize",), grid=(("seed", (1,)), ("seed", (2,))))
    with pytest.raises(ValueError, match=r"rpm applies to continuous scans only"):
        study.Sweep(plants=("maize",), grid=(("rpm", (1.0,)),))
    with pytest.raises(ValueError, match=r"timestep_s applies to scans with the servo's physics only"):
        study.Sweep(plants=("maize",), grid=(("timestep_s", (1e-3,)),))
    study.Sweep(plants=("maize",), grid=(("rpm", (1.0,)),), base={"turntable": {"mode": "continuous"}})
    with pytest.raises(FileNotFoundError, match=r"plant must be a bundled plant \(maize, wheat, calibration-target\) or a mesh"):
        study.plant_overrides("nowhere.stl")
    with pytest.raises(ValueError, match=r"run 0 .* is not a valid configuration: .*step_deg must divide"):
        study.run_study(study.Sweep(plants=("maize",), grid=(("step_deg", (7.0,)),)))
    # A setting the run's parts would not use is refused before any run, not as an error row.
    with pytest.raises(ValueError, match=r"run 0 .* is not a valid configuration: \[lidar\] edge_range_spread_m is "
                                         r"set but \[sensor_model\] dropouts is false"):
        study.run_study(study.Sweep(plants=("maize",), grid=(("step_deg", (45.0,)),),
                                    base={"sensor_model": {"dropouts": False}, "lidar": {"edge_range_spread_m": 0.01}}),
                        progress=lambda *a: pytest.fail("a run started"))
    with pytest.raises(ValueError, match=r"max_workers must be a positive integer or None, got 0"):
        study.run_study(study.Sweep(plants=("maize",)), max_workers=0)


def test_range_noise_scale_scales_the_presets_noise_and_refuses_what_would_ignore_it():
    sweep = study.Sweep(plants=("wheat",), grid=(("range_noise_scale", (0.25,)),),
                        base={"lidar": {"range_sigma_m": 0.02}})
    (run,) = sweep.runs()
    lidar = config_from_dict(sweep.config_data(run)).lidar
    # Both parts of sigma = hypot(floor, rel / sqrt(P)) scale, from the base's own values.
    assert lidar.range_sigma_m == pytest.approx(0.005) and lidar.range_sigma_rel == pytest.approx(0.0025)
    with pytest.raises(ValueError, match=r"range_noise_scale must be a finite number > 0, got 0.0; for no range "
                                         r"noise set \[sensor_model\] range_noise = false"):
        study.Sweep(plants=("wheat",), grid=(("range_noise_scale", (1.0, 0.0)),))
    with pytest.raises(ValueError, match=r"range_noise_scale scales the range noise, which the base configuration "
                                         r"turns off"):
        study.Sweep(plants=("wheat",), grid=(("range_noise_scale", (0.5,)),),
                    base={"sensor_model": {"range_noise": False}})
    # Every run ideal: a sensor-only setting would be blank in all of them.
    with pytest.raises(ValueError, match=r"footprint_rings, range_noise_scale change the realistic sensor only, "
                                         r"and every run is ideal"):
        study.Sweep(plants=("wheat",), grid=(("footprint_rings", (0, 1)), ("range_noise_scale", (0.5,))),
                    base={"ideal": True})
    with pytest.raises(ValueError, match=r"footprint_rings changes the realistic sensor only"):
        study.Sweep(plants=("wheat",), grid=(("footprint_rings", (0,)), ("ideal", (True,))))
    study.Sweep(plants=("wheat",), grid=(("footprint_rings", (0,)), ("ideal", (True, False))), base={"ideal": True})
    # A bad value of any setting fails when the sweep is made, before any run.
    with pytest.raises(ValueError, match=r"n_beams must be at least 2"):
        study.Sweep(plants=("wheat",), grid=(("n_beams", (100, 1)),))


def test_a_quarter_of_the_range_noise_scatters_the_points_a_quarter_as_far(stalk):
    sweep = study.Sweep(plants=(str(stalk),), grid=(("step_deg", (45.0,)), ("range_noise_scale", (1.0, 0.25))),
                        evaluation=study.EvaluationOptions(n_surface_samples=2000))
    rows = {r["range_noise_scale"]: r for r in study.run_study(sweep, max_workers=1)}
    assert rows[1.0]["error"] == rows[0.25]["error"] == ""
    # The box's faces are seen head-on or nearly: the points' distance to the mesh is the
    # noise's; its RMS scales with the noise (the 1 mm rounding aside).
    assert rows[0.25]["rms_m"] / rows[1.0]["rms_m"] == pytest.approx(0.25, abs=0.05)


def test_sweep_is_frozen_and_its_base_read_only():
    base = {"scan": {"sweep_deg": 90.0}}
    sweep = study.Sweep(plants=["maize"], base=base)
    base["ideal"] = True  # the caller's dict is copied
    assert "ideal" not in sweep.base
    with pytest.raises(TypeError):
        sweep.base["ideal"] = True
    with pytest.raises(AttributeError):
        sweep.plants = ("wheat",)


# --------------------------------------------------------------------------
# CSV
# --------------------------------------------------------------------------
def test_csv_round_trip_with_blanks_and_failures():
    rows = [{"run": 0, "plant": "maize", "step_deg": 1.0, "ideal": True, "chamfer_m": 0.00123456789,
             "error": ""},
            {"run": 1, "plant": "wheat", "step_deg": 0.5, "ideal": False, "chamfer_m": math.nan,
             "leaf_width_m_rel_error": 0.1, "error": "SimulationError: boom"}]
    text = study.rows_to_csv(rows)
    header = text.splitlines()[0].split(",")
    assert header == ["run", "plant", "step_deg", "ideal", "chamfer_m", "leaf_width_m_rel_error", "error"]
    back = study.read_csv_rows(text)
    assert back[0]["chamfer_m"] == 0.00123456789 and back[0]["leaf_width_m_rel_error"] is None
    assert back[1]["chamfer_m"] is None and back[1]["error"] == "SimulationError: boom"
    assert back[0]["ideal"] is True and back[1]["ideal"] is False


# --------------------------------------------------------------------------
# real runs (small)
# --------------------------------------------------------------------------
@pytest.fixture
def stalk(tmp_path):
    box = trimesh.creation.box(extents=[0.03, 0.03, 0.2])
    path = tmp_path / "stalk.stl"
    path.write_bytes(box.export(file_type="stl"))
    return path


def test_run_study_in_process_gives_a_row_per_run(stalk):
    sweep = study.Sweep(plants=(str(stalk),), grid=(("step_deg", (90.0, 45.0)), ("ideal", (True, False))),
                        evaluation=study.EvaluationOptions(n_surface_samples=2000))
    seen = []
    rows = study.run_study(sweep, max_workers=1, progress=lambda done, total, row: seen.append((done, total)))
    assert seen == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert [r["run"] for r in rows] == [0, 1, 2, 3]
    for r in rows:
        assert r["error"] == "" and r["plant_points"] > 0
        assert r["wall_time_s"] > 0 and r["cpu_time_s"] > 0
        assert {"median_m", "p95_m", "chamfer_m", "coverage"} <= set(r)
    ideal = [r for r in rows if r["ideal"]]
    assert all(r["max_m"] < 1e-6 for r in ideal)
    # Twice the lines, twice the simulated rig time (0.5 s a step, 0.1 s the last line).
    assert [r["simulated_rig_time_s"] for r in ideal] == pytest.approx([3 * 0.5 + 0.1, 7 * 0.5 + 0.1])


def test_a_failing_run_is_a_row_with_its_error(stalk, monkeypatch):
    def broken(config, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr("plantsim.scan.pipeline.run_scan", broken)
    row = study.run_one({"plant": str(stalk), "ideal": True}, {"plant": {"mesh": str(stalk)}})
    assert row == {"plant": str(stalk), "ideal": True, "error": "RuntimeError: boom"}


def test_plot_is_a_png_and_needs_data():
    rows = [{"plant": "maize", "ideal": i % 2 == 0, "step_deg": s, "wall_time_s": 1 / s,
             "chamfer_m": 0.001 * s, "error": ""} for i, s in enumerate((4.0, 2.0, 1.0, 0.5))]
    png = study.plot_error_vs_time(rows, title="t")
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    with pytest.raises(ValueError, match=r"no run has both 'p95_m' and 'wall_time_s' to plot"):
        study.plot_error_vs_time(rows, error="p95_m")


def test_cli_study_runs_in_parallel_and_writes_csv_and_png(tmp_path, stalk, capsys):
    out = tmp_path / "s.csv"
    code = main(["study", "--plant", str(stalk), "--step-deg", "90", "45", "--ideal-and-realistic",
                 "--footprint-rings", "0", "1", "--workers", "2", "-o", str(out)])
    assert code == 0
    assert "wrote 6 runs" in capsys.readouterr().out
    rows = study.read_csv_rows(out.read_text())
    assert len(rows) == 6 and all(r["error"] is None for r in rows)
    assert sorted((r["ideal"], r["footprint_rings"]) for r in rows if r["step_deg"] == 90) == [
        (False, 0), (False, 1), (True, None)]
    assert (tmp_path / "s.png").read_bytes().startswith(b"\x89PNG")


def test_cli_study_bad_input_is_one_line(tmp_path, capsys):
    assert main(["study", "--step-deg", "7", "-o", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert "plantsim: error: run 0" in err and "step_deg must divide sweep_deg evenly" in err
    assert main(["study", "--rpm", "1", "-o", str(tmp_path / "s.csv")]) == 2
    assert "rpm applies to continuous scans only" in capsys.readouterr().err
    assert main(["study", "-o", str(tmp_path / "nope" / "s.csv")]) == 2
    assert "output folder does not exist" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_a_sweep_over_modes_blanks_what_a_mode_does_not_use():
    sweep = study.Sweep(plants=("maize",), grid=(("mode", ("step", "continuous")), ("step_deg", (2.0, 1.0)),
                                                 ("rpm", (1.0,))))
    runs = sweep.runs()
    assert {"plant": "maize", "mode": "continuous", "step_deg": None, "rpm": 1.0, "ideal": False} in runs
    assert {"plant": "maize", "mode": "step", "step_deg": 1.0, "rpm": None, "ideal": False} in runs
    assert len(runs) == 3  # two step runs, one continuous run (not repeated per step)
    for run in runs:  # every run's configuration passes the pipeline's checks
        plan_scan(config_from_dict(sweep.config_data(run)))


def test_study_rows_say_what_was_simulated(monkeypatch):
    row = study.run_one({"plant": "maize", "mode": "continuous", "rpm": 5.0, "ideal": True},
                        {"turntable": {"mode": "continuous", "rpm": 5.0}, "scan": {"sweep_deg": 20.0},
                         "ideal": True, "threads": 1})
    assert row["error"] == "" and row["sensor"] == "ideal" and row["turntable_motion"] == "kinematic"
    assert row["mode"] == "continuous" and row["angle_mode"] == "interpolate"


def test_study_rows_carry_what_the_turntable_did():
    row = study.run_one({"plant": "maize", "mode": "continuous", "rpm": 10.0, "ideal": False},
                        {"turntable": {"mode": "continuous", "rpm": 10.0, "physics": "dynamic"},
                         "scan": {"sweep_deg": 30.0}, "sensor": "ideal", "threads": 1})
    assert row["error"] == "" and row["turntable_motion"] == "physics"
    assert row["turntable_physics_steps"] > 0 and row["turntable_max_tracking_error_rad"] >= 0
    assert row["angle_error_n_points"] > 0 and row["angle_error_displacement_max_m"] >= 0
