"""Where a scan's time went: the sidecar's per-phase ray counts add up."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from plantsim.plant.mesh import plant_from_arrays
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan, sidecar
from plantsim.scan.schedule import StepScan
from plantsim.turntable.options import TurntableOptions


@pytest.fixture(scope="module")
def plant():
    box = trimesh.creation.box(extents=[0.04, 0.06, 0.2])
    box.apply_translation([0.03, -0.02, 0.1])
    return plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces), placement="none")


def test_adaptive_footprint_counts_add_up_to_the_rays_cast(plant):
    result = run_scan(RunConfig(sensor="realistic", scan=StepScan(step_deg=20)), plant=plant)
    n_lines, n_beams = result.raw.range_m.shape
    perf = sidecar(result)["performance"]
    fp, effects = perf["footprint_and_bookkeeping"], result.parts["lidar"]["effects"]
    assert effects["adaptive_footprint"]
    n_sub = effects["footprint_subrays"]
    assert fp["subrays_per_beam"] == n_sub
    # every beam casts its probes; each refined beam casts its other sub-rays
    n_probe = fp["probe_rays"] // (n_lines * n_beams)
    assert fp["probe_rays"] == n_lines * n_beams * n_probe and 1 < n_probe < n_sub
    assert 0 < fp["beams_refined"] < n_lines * n_beams  # the box's edges are refined, its faces not
    assert fp["refine_rays"] == fp["beams_refined"] * (n_sub - n_probe)
    assert fp["subrays"] == fp["probe_rays"] + fp["refine_rays"] == perf["turning_cast"]["rays"]
    assert fp["rays_per_s"] == pytest.approx(fp["subrays"] / fp["s"], rel=1e-3)
    assert perf["sensor_model"]["beams"] == n_lines * n_beams
    assert perf["sensor_model"]["beams_per_s"] == pytest.approx(n_lines * n_beams / perf["sensor_model"]["s"],
                                                                 rel=1e-3)
    assert "physics" not in perf  # a kinematic step scan runs no physics


def test_a_scan_with_servo_physics_reports_its_steps_per_second(plant):
    config = RunConfig(sensor="ideal", turntable=TurntableOptions(mode="continuous", rpm=10, physics="dynamic"))
    result = run_scan(config, plant=plant)
    physics = sidecar(result)["performance"]["physics"]
    assert physics["steps"] == result.diagnostics["physics_steps"] > 1000
    assert physics["s"] == result.timings_s["turntable"]
    assert physics["steps_per_s"] == round(physics["steps"] / physics["s"])
