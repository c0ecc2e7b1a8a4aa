"""The sensor model through the run pipeline, the exporters and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from plantsim.cli.app import main
from plantsim.scan.config import PlantOptions, RunConfig
from plantsim.cloud.export import encode_cloud, from_las, from_ply
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.sensor.spec import BeamStatus


@pytest.fixture(scope="module")
def stem_path(tmp_path_factory):
    """A 0.3 m 'plant': a 10 mm stem with a 40 mm-wide leaf plate, as binary STL."""
    stem = trimesh.creation.cylinder(radius=0.005, height=0.3, sections=24)
    stem.apply_translation([0, 0, 0.15])
    leaf = trimesh.creation.box(extents=[0.04, 0.002, 0.06])
    leaf.apply_translation([0.0, 0.0, 0.2])
    path = tmp_path_factory.mktemp("plant") / "stem.stl"
    trimesh.util.concatenate([stem, leaf]).export(path)
    return str(path)


def config(path, **kw):
    return RunConfig(plant=PlantOptions(mesh=path), scan=StepScan(step_deg=10.0), **kw)


def test_ideal_run_is_the_plain_ray_caster(stem_path):
    result = run_scan(config(stem_path, ideal=True))
    reference = step_and_shoot(result.scene, result.config.lidar, result.config.scan)
    np.testing.assert_array_equal(result.raw.range_m, reference.range_m)
    np.testing.assert_array_equal(result.raw.status, reference.status)
    assert result.raw.intensity is None and result.cloud.intensity is None


def test_realistic_run_is_deterministic_per_seed_and_writes_intensity(stem_path):
    a = run_scan(config(stem_path, seed=3))
    b = run_scan(config(stem_path, seed=3))
    c = run_scan(config(stem_path, seed=4))
    assert encode_cloud("x.las", a.cloud) == encode_cloud("x.las", b.cloud)
    assert encode_cloud("x.ply", a.cloud) == encode_cloud("x.ply", b.cloud)
    assert not np.array_equal(a.cloud.points_turntable[:100], c.cloud.points_turntable[:100])
    cloud = a.cloud
    assert cloud.intensity is not None and np.all((cloud.intensity > 0) & (cloud.intensity <= 1))
    las = from_las(encode_cloud("x.las", cloud))
    np.testing.assert_allclose(las.intensity, cloud.intensity, atol=1 / 65535)
    ply = from_ply(encode_cloud("x.ply", cloud))
    np.testing.assert_allclose(ply.intensity, cloud.intensity, atol=1 / 65535)
    # Misses stay misses: one point per OK beam and none for the rest.
    assert len(cloud) == int((a.raw.status == BeamStatus.OK).sum())


def test_cli_lidar_and_footprint_options_reach_the_sidecar(stem_path, tmp_path):
    out = tmp_path / "scan.las"
    assert main(["scan", stem_path, "-o", str(out), "--step-deg", "30", "--lidar", "utm-30lx",
                 "--footprint-rings", "1", "--seed", "5"]) == 0
    sidecar = json.loads((tmp_path / "scan.las.json").read_text())
    assert sidecar["config"]["lidar"]["name"] == "utm-30lx"
    assert sidecar["config"]["sensor_model"]["footprint_rings"] == 1
    assert set(sidecar["counts"]["by_status"]) == {"ok", "no_echo", "too_near", "low_intensity",
                                                   "edge"}
    assert main(["scan", stem_path, "-o", str(out), "--step-deg", "30", "--ideal"]) == 0
    assert json.loads((tmp_path / "scan.las.json").read_text())["config"]["ideal"] is True


def test_cli_rejects_a_bad_ring_count(stem_path, tmp_path, capsys):
    assert main(["scan", stem_path, "-o", str(tmp_path / "s.las"), "--footprint-rings", "-2"]) == 2
    assert "footprint_rings must be an integer from 0 to 10, got -2" in capsys.readouterr().err
