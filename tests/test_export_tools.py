"""The writers checked against the readers users open them with.

Open3D (PyPI) and PCL's command-line tools (Debian ``pcl-tools``) read every
file and every field is compared; both skip with a printed reason when they are
not installed. PDAL has no Debian package here: the LAS header bits PDAL checks
(WKT bit, return numbers) are checked with laspy, field by field. The
CloudCompare conventions (PLY ``scalar_`` names, TXT header) are checked on the
header text, since CloudCompare has no headless package to run here.
"""

import io
import re
import shutil
import subprocess

import laspy
import numpy as np
import pytest

from plantsim.cloud import export as pio
from plantsim.cloud.reconstruct import PointCloud
from plantsim.rig.scene import HitClass


def _cloud(n=200, seed=0, intensity=True):
    rng = np.random.default_rng(seed)
    return PointCloud(
        points_turntable=rng.uniform(-0.2, 0.4, (n, 3)),
        hit_class=rng.choice([HitClass.PLANT, HitClass.TURNTABLE, HitClass.RIG], n).astype(np.uint8),
        beam_index=rng.integers(0, 726, n).astype(np.uint16),
        scan_index=rng.integers(0, 100_000, n).astype(np.uint32),
        turntable_angle_rad=rng.uniform(0, 2 * np.pi, n),
        range_m=rng.uniform(0.02, 4.0, n),
        time_s=rng.uniform(0, 600, n),
        intensity=rng.uniform(0, 1, n).astype(np.float32) if intensity else None,
    )


@pytest.fixture(scope="module")
def cloud():
    return _cloud()


def _expected(cloud):
    codes = np.array([0, 4, 64, 65])[cloud.hit_class]
    return {"intensity": cloud.intensity, "classification": codes,
            "beam_index": cloud.beam_index, "scan_index": cloud.scan_index,
            "turntable_angle_rad": cloud.turntable_angle_rad, "range_m": cloud.range_m,
            "time": cloud.time_s}


def _assert_same_cloud(back, cloud, xyz_atol):
    assert len(back) == len(cloud)
    np.testing.assert_allclose(back.points_turntable, cloud.points_turntable, rtol=0, atol=xyz_atol)
    np.testing.assert_array_equal(back.hit_class, cloud.hit_class)
    np.testing.assert_array_equal(back.beam_index, cloud.beam_index)
    np.testing.assert_array_equal(back.scan_index, cloud.scan_index)
    np.testing.assert_array_equal(back.turntable_angle_rad, cloud.turntable_angle_rad)
    np.testing.assert_array_equal(back.range_m, cloud.range_m)
    np.testing.assert_array_equal(back.time_s, cloud.time_s)


# --- plantsim's own readers: every format, every field, through memory ------

@pytest.mark.parametrize("suffix", list(pio.EXPORTERS))
def test_every_field_round_trips_exactly(cloud, suffix):
    back = pio.READERS[suffix](pio.encode_cloud("c" + suffix, cloud))
    xyz_atol = {".las": 5e-6, ".laz": 5e-6, ".ply": 3e-8, ".pcd": 3e-8}.get(suffix, 5e-10)
    _assert_same_cloud(back, cloud, xyz_atol)
    # LAS stores intensity as uint16; the others as float32 (exact).
    np.testing.assert_allclose(back.intensity, cloud.intensity, rtol=0,
                               atol=0.5 / 65535 if suffix in (".las", ".laz") else 0)


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_double_precision_keeps_float64_coordinates(cloud, suffix):
    data = pio.encode_cloud("c" + suffix, cloud, precision="double")
    back = pio.READERS[suffix](data)
    np.testing.assert_array_equal(back.points_turntable, cloud.points_turntable)
    single = pio.encode_cloud("c" + suffix, cloud)
    assert len(data) - len(single) == 3 * 4 * len(cloud)


def test_unknown_precision_is_refused(cloud):
    with pytest.raises(ValueError, match="precision must be one of single, double, got 'half'"):
        pio.encode_cloud("c.ply", cloud, precision="half")


def test_no_intensity_reads_back_as_none():
    c = _cloud(20, intensity=False)
    for suffix in pio.EXPORTERS:
        assert pio.READERS[suffix](pio.encode_cloud("c" + suffix, c)).intensity is None, suffix


def test_empty_cloud_round_trips():
    c = _cloud(0)
    for suffix in pio.EXPORTERS:
        assert len(pio.READERS[suffix](pio.encode_cloud("c" + suffix, c))) == 0, suffix


def test_write_cloud_and_read_cloud_laz(tmp_path, cloud):
    pio.write_cloud(tmp_path / "scan.laz", cloud)
    _assert_same_cloud(pio.read_cloud(tmp_path / "scan.laz"), cloud, 5e-6)


# --- the declared types (what the tools' typed loaders need) ---------------

def _ply_properties(data):
    header = data[:data.index(b"end_header")].decode("ascii")
    return re.findall(r"^property (\S+) (\S+)$", header, flags=re.M)


def test_ply_types_and_names(cloud):
    props = _ply_properties(pio.to_ply(cloud))
    assert props[:4] == [("float32", "x"), ("float32", "y"), ("float32", "z"),
                         ("float32", "intensity")]
    # CloudCompare loads a vertex property as a scalar field by itself only when
    # its name contains "scal" (or "intensity"); the rest it drops in headless use.
    assert all("scal" in name for _, name in props[4:]) and len(props) == 10
    assert _ply_properties(pio.to_ply(cloud, precision="double"))[0] == ("float64", "x")


def test_pcd_types_for_pcl_point_types(cloud):
    header = pio.to_pcd(cloud).split(b"DATA")[0].decode("ascii")
    fields = dict(line.split(" ", 1) for line in header.splitlines() if not line.startswith("#"))
    names, sizes, types = (fields[k].split() for k in ("FIELDS", "SIZE", "TYPE"))
    spec = dict(zip(names, zip(types, sizes)))
    assert [spec[a] for a in ("x", "y", "z", "intensity")] == [("F", "4")] * 4  # PointXYZI
    assert spec["label"] == ("U", "4")  # PointXYZL


def test_txt_header_is_one_cloudcompare_reads(cloud):
    first = pio.to_txt(cloud).split(b"\n", 1)[0].decode("ascii")
    assert first.startswith("//")
    names = first[2:].split()
    assert names[:4] == ["x", "y", "z", "intensity"]
    # CloudCompare's ASCII reader: a name containing "SCALAR" is a scalar field;
    # unnamed small-integer columns would be guessed as RGB.
    assert all("scalar" in n for n in names[4:]) and len(names) == 10
    assert not pio.to_xyz(cloud).startswith((b"//", b"#"))


# --- LAS / LAZ: what PDAL and the spec check --------------------------------

def test_las_header_bits_returns_and_scan_angle(cloud):
    beam_angle_rad = np.deg2rad(-120 + 240 * np.linspace(0, 1, len(cloud)))
    las = laspy.read(io.BytesIO(pio.to_las(cloud, beam_angle_rad=beam_angle_rad)))
    assert las.header.point_format.id == 6 and str(las.header.version) == "1.4"
    assert las.header.global_encoding.wkt  # PDAL <= 2.7.1 refuses formats 6-10 without it
    assert (np.asarray(las.return_number) == 1).all()
    assert (np.asarray(las.number_of_returns) == 1).all()
    np.testing.assert_allclose(np.asarray(las.scan_angle) * 0.006, np.rad2deg(beam_angle_rad),
                               atol=0.003)
    assert (np.asarray(las.point_source_id) == 0).all()
    np.testing.assert_allclose(np.asarray(las.intensity) / 65535, cloud.intensity, atol=0.5 / 65535)
    np.testing.assert_array_equal(np.asarray(las.classification), _expected(cloud)["classification"])


def test_las_scan_angle_checks(cloud):
    with pytest.raises(ValueError, match=r"beam_angle_rad must have shape \(200,\)"):
        pio.to_las(cloud, beam_angle_rad=np.zeros(3))
    with pytest.raises(ValueError, match="beam_angle_rad must lie within"):
        pio.to_las(cloud, beam_angle_rad=np.full(len(cloud), np.deg2rad(200.0)))


def test_laz_is_lossless_and_smaller(cloud):
    big = _cloud(5000, seed=1)
    las, laz = pio.to_las(big), pio.to_laz(big)
    assert laz[:4] == b"LASF" and len(laz) < 0.75 * len(las)
    a, b = laspy.read(io.BytesIO(las)), laspy.read(io.BytesIO(laz))
    assert list(a.point_format.dimension_names) == list(b.point_format.dimension_names)
    for name in a.point_format.dimension_names:
        np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), err_msg=name)


# --- Open3D ------------------------------------------------------------------

@pytest.fixture(scope="module")
def o3d():
    try:
        import open3d
    except ImportError as exc:  # not in the test extra: large, and no wheel for every Python
        print(f"skipping Open3D checks: {exc}")
        pytest.skip(f"open3d is not installed ({exc}); pip install open3d to run these")
    return open3d


def test_open3d_reads_every_ply_field(o3d, tmp_path, cloud):
    path = tmp_path / "c.ply"
    pio.write_cloud(path, cloud)
    pc = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(pc.point.positions.numpy(),
                                  cloud.points_turntable.astype(np.float32))
    expected = _expected(cloud)
    for name, values in expected.items():
        key = name if name == "intensity" else f"scalar_{name}"
        assert key in pc.point, f"Open3D dropped {key}"
        np.testing.assert_array_equal(pc.point[key].numpy().ravel(), values, err_msg=key)
    legacy = o3d.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(np.asarray(legacy.points),
                                  cloud.points_turntable.astype(np.float32))


def test_open3d_reads_every_pcd_field(o3d, tmp_path, cloud):
    path = tmp_path / "c.pcd"
    pio.write_cloud(path, cloud)
    pc = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(pc.point.positions.numpy(),
                                  cloud.points_turntable.astype(np.float32))
    for name, values in _expected(cloud).items():
        key = "label" if name == "classification" else name
        assert key in pc.point, f"Open3D dropped {key}"
        np.testing.assert_array_equal(pc.point[key].numpy().ravel(), values, err_msg=key)


def test_open3d_reads_the_xyz(o3d, tmp_path, cloud):
    path = tmp_path / "c.xyz"
    pio.write_cloud(path, cloud)
    for pc in (o3d.io.read_point_cloud(str(path)), o3d.t.io.read_point_cloud(str(path))):
        points = np.asarray(pc.points) if hasattr(pc, "points") else pc.point.positions.numpy()
        np.testing.assert_allclose(points, cloud.points_turntable, rtol=0, atol=1e-6)


# --- PCL's command-line tools --------------------------------------------------

def _pcl(tool, *args):
    if shutil.which(tool) is None:
        print(f"skipping PCL checks: {tool} is not on PATH (apt-get install pcl-tools)")
        pytest.skip(f"{tool} is not installed (Debian package pcl-tools)")
    result = subprocess.run([tool, *map(str, args)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout + result.stderr


def test_pcl_converts_our_ply_keeping_every_field(tmp_path, cloud):
    pio.write_cloud(tmp_path / "c.ply", cloud)
    _pcl("pcl_ply2pcd", tmp_path / "c.ply", tmp_path / "from_ply.pcd")
    back = pio.read_cloud(tmp_path / "from_ply.pcd")
    _assert_same_cloud(back, pio.from_ply(pio.to_ply(cloud)), 0)
    np.testing.assert_array_equal(back.intensity, cloud.intensity)


def test_pcl_converts_our_pcd_keeping_every_field(tmp_path, cloud):
    pio.write_cloud(tmp_path / "c.pcd", cloud)
    _pcl("pcl_pcd2ply", tmp_path / "c.pcd", tmp_path / "from_pcd.ply")
    back = pio.read_cloud(tmp_path / "from_pcd.ply")
    _assert_same_cloud(back, pio.from_pcd(pio.to_pcd(cloud)), 0)
    np.testing.assert_array_equal(back.intensity, cloud.intensity)


@pytest.mark.parametrize("suffix", [".pcd", ".ply"])
def test_pcl_typed_pointxyz_loader_reads_the_coordinates(tmp_path, cloud, suffix):
    # pcl_compute_hausdorff loads pcl::PointXYZ clouds: were x y z of a type
    # PointXYZ cannot take, both would load as all zeros and the distance be 0.
    shift_m = 0.125
    moved = PointCloud(**{**cloud.__dict__,
                          "points_turntable": cloud.points_turntable + [shift_m, 0, 0]})
    paths = []
    for name, c in (("a", cloud), ("b", moved)):
        pio.write_cloud(tmp_path / f"{name}{suffix}", c)
        if suffix == ".ply":  # the tool reads PCD only: convert, keeping the PLY's types
            _pcl("pcl_ply2pcd", tmp_path / f"{name}.ply", tmp_path / f"{name}.pcd")
        paths.append(tmp_path / f"{name}.pcd")
    out = _pcl("pcl_compute_hausdorff", *paths)
    distance = float(re.search(r"Hausdorff Distance: ([0-9.eE+-]+)", out).group(1))
    # The farthest point of a from b's cloud: at most the shift, and well above 0.
    assert 0.02 < distance <= shift_m + 1e-6


def test_older_plantsim_files_still_read():
    # plantsim 0.2 wrote uint16 intensity (0..65535) and unprefixed names.
    ply = (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
           b"property double y\nproperty double z\nproperty uchar classification\n"
           b"property ushort intensity\nend_header\n"
           + np.array([(0.1, 0.2, 0.3, 4, 65535)], dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                                          ("c", "u1"), ("i", "<u2")]).tobytes())
    txt = b"//x y z classification intensity beam_index\n0.1 0.2 0.3 64 32768 7\n"
    a, b = pio.from_ply(ply), pio.from_txt(txt)
    assert a.hit_class[0] == HitClass.PLANT and a.intensity[0] == 1.0
    assert b.hit_class[0] == HitClass.TURNTABLE and b.beam_index[0] == 7
    np.testing.assert_allclose(b.intensity, [32768 / 65535], rtol=1e-6)
