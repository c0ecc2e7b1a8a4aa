"""Export: every format round-trips; LAS checked with laspy itself; atomic writes."""

import io
import json

import laspy
import numpy as np
import pytest

from plantsim.cloud import export as pio
from plantsim.plant.mesh import plant_from_arrays
from plantsim.cloud.reconstruct import reconstruct
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import HitClass, build_scene
from plantsim.sensor.spec import URG_04LX_UG01


@pytest.fixture(scope="module")
def cloud():
    import trimesh

    box = trimesh.creation.box(extents=[0.04, 0.06, 0.12])
    plant = plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces))
    raw = step_and_shoot(build_scene(RigGeometry(), plant), URG_04LX_UG01, StepScan(step_deg=15))
    c = reconstruct(raw, intensity=np.linspace(0, 1, raw.range_m.size).reshape(raw.range_m.shape))
    assert set(np.unique(c.hit_class)) == {HitClass.PLANT, HitClass.TURNTABLE, HitClass.RIG}
    return c


TOLERANCE_M = {".las": 5e-6, ".laz": 5e-6, ".ply": 1e-7, ".pcd": 1e-7, ".txt": 1e-9, ".xyz": 1e-9,
               ".pts": 1e-9, ".e57": 1e-7}


@pytest.mark.parametrize("suffix", list(pio.EXPORTERS))
def test_round_trip_through_memory(cloud, suffix):
    try:
        data = pio.EXPORTERS[suffix](cloud)
    except RuntimeError as exc:
        if suffix not in pio.EXTRA_OF_FORMAT:
            raise
        print(f"skipped: {exc}")
        pytest.skip(f"the {pio.EXTRA_OF_FORMAT[suffix]} extra is not installed: {exc}")
    back = pio.READERS[suffix](data)
    assert len(back) == len(cloud)
    np.testing.assert_allclose(back.points_turntable, cloud.points_turntable, rtol=0,
                               atol=TOLERANCE_M[suffix])
    np.testing.assert_allclose(back.intensity, cloud.intensity, atol=1 / 65535)
    if suffix in pio.LOSSY_FORMATS:
        return
    if suffix in pio.INDEXED_FORMATS:
        np.testing.assert_array_equal(back.beam_index, cloud.beam_index)
        np.testing.assert_array_equal(back.scan_index, cloud.scan_index)
        return
    np.testing.assert_array_equal(back.hit_class, cloud.hit_class)
    np.testing.assert_array_equal(back.beam_index, cloud.beam_index)
    np.testing.assert_array_equal(back.scan_index, cloud.scan_index)
    np.testing.assert_allclose(back.turntable_angle_rad, cloud.turntable_angle_rad, atol=1e-12)
    np.testing.assert_allclose(back.range_m, cloud.range_m, atol=1e-12)
    np.testing.assert_allclose(back.time_s, cloud.time_s, atol=1e-12)
    np.testing.assert_allclose(back.intensity, cloud.intensity, atol=1 / 65535)


def test_las_is_1_4_with_fine_scale_classes_and_gps_time(cloud):
    las = laspy.read(io.BytesIO(pio.to_las(cloud)))
    assert str(las.header.version) == "1.4"
    assert (las.header.scales <= 1e-4).all()
    codes = np.asarray(las.classification)
    assert set(np.unique(codes)) == {4, 64, 65}
    assert (codes[cloud.hit_class == HitClass.PLANT] == 4).all()
    np.testing.assert_allclose(np.asarray(las.gps_time), cloud.time_s)
    for name in ("beam_index", "scan_index", "turntable_angle_rad", "range_m"):
        assert name in las.point_format.extra_dimension_names


def test_plant_only(cloud):
    plant = cloud.plant_only()
    assert 0 < len(plant) < len(cloud) and (plant.hit_class == HitClass.PLANT).all()


def test_write_is_atomic_and_leaves_nothing_on_failure(tmp_path, cloud, monkeypatch):
    out = tmp_path / "scan.ply"
    pio.write_cloud(out, cloud, sidecar={"a": 1})
    assert json.loads((tmp_path / "scan.ply.json").read_text()) == {"a": 1}
    before = out.read_bytes()

    def boom(_cloud):
        raise OverflowError("coordinate does not fit")

    monkeypatch.setitem(pio.EXPORTERS, ".ply", boom)
    with pytest.raises(OverflowError):
        pio.write_cloud(out, cloud)
    assert out.read_bytes() == before  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan.ply", "scan.ply.json"]


def test_output_path_checks(tmp_path):
    with pytest.raises(ValueError, match="use one of .las, .laz, .ply, .pcd, .txt, .xyz, .pts, .e57"):
        pio.check_output_path(tmp_path / "scan.fls")
    with pytest.raises(FileNotFoundError, match="output folder does not exist"):
        pio.check_output_path(tmp_path / "nope" / "scan.las")
