"""Every output opened by the field's own readers, and every field checked.

Open3D (PyPI) and PCL's command-line tools (Debian ``pcl-tools``, installed by
``.ci/run``) read the files plantsim writes; laspy re-reads the LAS/LAZ header
fields other tools check (PDAL refuses LAS 1.4 without the WKT bit). Each
reader that is missing skips with the reason printed.
"""

import io
import shutil
import subprocess

import laspy
import numpy as np
import pytest

from plantsim.cloud import export as pio
from plantsim.cloud.reconstruct import reconstruct
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import HitClass, build_scene
from plantsim.scan.pipeline import step_and_shoot
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import URG_04LX_UG01


@pytest.fixture(scope="module")
def cloud():
    import trimesh

    box = trimesh.creation.box(extents=[0.04, 0.06, 0.12])
    plant = plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces))
    raw = step_and_shoot(build_scene(RigGeometry(), plant), URG_04LX_UG01, StepScan(step_deg=30))
    rng = np.random.default_rng(3)
    return reconstruct(raw, intensity=rng.uniform(0.05, 1.0, raw.range_m.shape))


def _codes(cloud):
    return np.array([pio.CLASSIFICATION[HitClass(c)] for c in cloud.hit_class])


def _open3d():
    try:
        import open3d
    except ImportError as error:  # pragma: no cover - depends on the platform's wheels
        pytest.skip(f"open3d cannot be imported here ({error}); pip install open3d")
    return open3d


def _check_fields(cloud, get, names):
    """``get(name)`` -> (n,) array for every plantsim field, under the format's names."""
    expected = {
        "classification": _codes(cloud), "intensity": cloud.intensity,
        "beam_index": cloud.beam_index, "scan_index": cloud.scan_index,
        "turntable_angle_rad": cloud.turntable_angle_rad, "range_m": cloud.range_m,
        "time": cloud.time_s}
    for field, values in expected.items():
        got = get(names.get(field, field))
        assert got is not None, f"{field} was dropped"
        np.testing.assert_allclose(np.asarray(got, np.float64).ravel(), values,
                                   rtol=1e-6, atol=1e-7, err_msg=field)


def test_las_header_fields_other_tools_check(cloud):
    for data in (pio.to_las(cloud), pio.to_laz(cloud)):
        las = laspy.read(io.BytesIO(data))
        assert las.header.global_encoding.wkt  # LAS 1.4 R15: required for formats 6-10
        assert (np.asarray(las.return_number) == 1).all()
        assert (np.asarray(las.number_of_returns) == 1).all()
        np.testing.assert_array_equal(np.asarray(las.point_source_id), cloud.scan_index)
        np.testing.assert_array_equal(np.asarray(las.classification), _codes(cloud))
    assert len(pio.to_laz(cloud)) < len(pio.to_las(cloud)) / 2


def test_open3d_reads_every_field_of_ply_and_pcd(tmp_path, cloud):
    o3d = _open3d()
    for suffix, names in ((".ply", {n: "scalar_" + n for n in (
            "classification", "beam_index", "scan_index", "turntable_angle_rad",
            "range_m", "time")}),
            (".pcd", {"classification": "label"})):
        path = tmp_path / f"c{suffix}"
        pio.write_cloud(path, cloud)
        t = o3d.t.io.read_point_cloud(str(path))
        np.testing.assert_allclose(t.point.positions.numpy(), cloud.points_turntable,
                                   atol=1e-7, err_msg=suffix)
        _check_fields(cloud, lambda n: t.point[n].numpy() if n in t.point else None, names)
        assert len(o3d.io.read_point_cloud(str(path)).points) == len(cloud)


@pytest.mark.parametrize("suffix", [".xyz", ".pts"])
def test_open3d_reads_the_ascii_formats(tmp_path, cloud, suffix):
    o3d = _open3d()
    path = tmp_path / f"c{suffix}"
    pio.write_cloud(path, cloud)
    t = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_allclose(t.point.positions.numpy(), cloud.points_turntable, atol=1e-6)
    if suffix == ".pts":
        np.testing.assert_allclose(t.point.intensities.numpy().ravel(), cloud.intensity,
                                   rtol=1e-6)


def _pcl(tool):
    path = shutil.which(tool)
    if path is None:
        pytest.skip(f"{tool} not found: PCL's tools come from Debian's pcl-tools "
                    "(apt-get install pcl-tools; .ci/run does)")
    return path


def test_pcl_reads_every_field_of_ply_and_pcd(tmp_path, cloud):
    ply2pcd, convert = _pcl("pcl_ply2pcd"), _pcl("pcl_convert_pcd_ascii_binary")
    pio.write_cloud(tmp_path / "c.ply", cloud)
    pio.write_cloud(tmp_path / "c.pcd", cloud)
    # PCL's PLY reader -> PCD writer; PCL's PCD reader -> ASCII PCD writer.
    subprocess.run([ply2pcd, str(tmp_path / "c.ply"), str(tmp_path / "from_ply.pcd")],
                   check=True, capture_output=True)
    subprocess.run([convert, str(tmp_path / "c.pcd"), str(tmp_path / "ascii.pcd"), "0"],
                   check=True, capture_output=True)
    for name, aliases in (("from_ply.pcd", {n: "scalar_" + n for n in (
            "classification", "beam_index", "scan_index", "turntable_angle_rad", "range_m",
            "time")}), ("ascii.pcd", {"classification": "label"})):
        text = (tmp_path / name).read_bytes()
        header = dict(line.split(" ", 1) for line in text.decode("ascii", "replace")
                      .split("\nDATA")[0].splitlines() if not line.startswith("#"))
        fields = header["FIELDS"].split()
        types = dict(zip(fields, zip(header["TYPE"].split(), header["SIZE"].split())))
        # PointXYZ/PointXYZI read only float32 x y z intensity.
        for f in ("x", "y", "z", "intensity"):
            assert types[f] == ("F", "4"), (name, f, types[f])
        rows = _pcd_rows(text)
        np.testing.assert_allclose(np.stack([rows["x"], rows["y"], rows["z"]], 1),
                                   cloud.points_turntable, atol=1e-6, err_msg=name)
        assert np.abs(rows["x"]).max() > 0.01  # not the all-zero cloud of a type mismatch
        _check_fields(cloud, lambda n: rows[n] if n in rows.dtype.names else None, aliases)
    if "label" in fields:
        assert types["label"] == ("U", "4")


def _pcd_rows(data: bytes) -> np.ndarray:
    """The raw rows of a PCD (binary or ASCII), under the file's own field names."""
    head, _, body = data.partition(b"\nDATA ")
    kind, _, body = body.partition(b"\n")
    header = dict(line.split(" ", 1) for line in head.decode().splitlines()
                  if not line.startswith("#"))
    names, sizes, types = (header[k].split() for k in ("FIELDS", "SIZE", "TYPE"))
    dtype = np.dtype([(n, f"<{ {'F': 'f', 'U': 'u', 'I': 'i'}[t] }{s}")
                      for n, s, t in zip(names, sizes, types)])
    if kind.strip() == b"binary":
        return np.frombuffer(body, dtype=dtype, count=int(header["POINTS"]))
    table = np.loadtxt(io.BytesIO(body), ndmin=2)
    rows = np.empty(len(table), dtype=dtype)
    for i, n in enumerate(names):
        rows[n] = table[:, i]
    return rows


def test_cloudcompare_header_names_scalar_fields_not_colours(cloud):
    """CloudCompare maps ``//`` header names to columns; a name with ``Scalar`` is a scalar field."""
    header = pio.to_txt(cloud).split(b"\n", 1)[0].decode()
    names = header[2:].split()
    assert names[:3] == ["X", "Y", "Z"]
    assert all(n == "Intensity" or n.startswith("Scalar_") for n in names[3:])
    assert not {"R", "G", "B", "Red", "Green", "Blue"} & set(names)
