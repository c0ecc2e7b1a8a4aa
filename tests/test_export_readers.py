"""plantsim's readers on the files other tools and older plantsim versions leave.

Complements tests/test_interop.py (which opens plantsim's files in the other
tools): the way back, empty clouds, and lossless text.
"""

import shutil
import subprocess

import numpy as np
import pytest

from plantsim.cloud import export as pio
from plantsim.cloud.reconstruct import PointCloud
from plantsim.rig.scene import HitClass


def _cloud(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return PointCloud(
        points_turntable=rng.uniform(-0.2, 0.4, (n, 3)),
        hit_class=rng.choice([HitClass.PLANT, HitClass.TURNTABLE, HitClass.RIG], n).astype(np.uint8),
        beam_index=rng.integers(0, 726, n).astype(np.uint16),
        scan_index=rng.integers(0, 100_000, n).astype(np.uint32),
        turntable_angle_rad=rng.uniform(0, 2 * np.pi, n),
        range_m=rng.uniform(0.02, 4.0, n),
        time_s=rng.uniform(0, 600, n),
        intensity=rng.uniform(0, 1, n).astype(np.float32),
    )


def _assert_fields_equal(back, cloud):
    np.testing.assert_array_equal(back.hit_class, cloud.hit_class)
    np.testing.assert_array_equal(back.beam_index, cloud.beam_index)
    np.testing.assert_array_equal(back.scan_index, cloud.scan_index)
    np.testing.assert_array_equal(back.turntable_angle_rad, cloud.turntable_angle_rad)
    np.testing.assert_array_equal(back.range_m, cloud.range_m)
    np.testing.assert_array_equal(back.time_s, cloud.time_s)
    np.testing.assert_array_equal(back.intensity, cloud.intensity)


@pytest.mark.parametrize("suffix", [".txt", ".xyz"])
def test_text_round_trips_every_field_bit_for_bit(suffix):
    cloud = _cloud()
    back = pio.READERS[suffix](pio.EXPORTERS[suffix](cloud))
    np.testing.assert_allclose(back.points_turntable, cloud.points_turntable, rtol=0, atol=5e-10)
    _assert_fields_equal(back, cloud)


@pytest.mark.parametrize("suffix", list(pio.EXPORTERS))
def test_an_empty_cloud_round_trips(suffix):
    back = pio.READERS[suffix](pio.EXPORTERS[suffix](_cloud(0)))
    assert len(back) == 0 and back.points_turntable.shape == (0, 3)


def test_plantsim_0_2_files_keep_their_intensity_scale():
    # plantsim 0.2 wrote intensity as uint16 0..65535 (PLY, PCD) and integers in text.
    rows = np.array([(0.1, 0.2, 0.3, 4, 65535)],
                    dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("c", "u1"), ("i", "<u2")])
    ply = (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
           b"property double y\nproperty double z\nproperty uchar classification\n"
           b"property ushort intensity\nend_header\n" + rows.tobytes())
    pcd = (b"VERSION 0.7\nFIELDS x y z classification intensity\nSIZE 8 8 8 1 2\n"
           b"TYPE F F F U U\nCOUNT 1 1 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n"
           + rows.tobytes())
    txt = b"//x y z classification intensity beam_index\n0.1 0.2 0.3 64 32768 7\n"
    for back in (pio.from_ply(ply), pio.from_pcd(pcd)):
        assert back.hit_class[0] == HitClass.PLANT and back.intensity[0] == 1.0
    back = pio.from_txt(txt)
    assert back.hit_class[0] == HitClass.TURNTABLE and back.beam_index[0] == 7
    np.testing.assert_allclose(back.intensity, [32768 / 65535], rtol=1e-6)


def test_a_pcd_pcl_converted_from_our_ply_reads_back_whole(tmp_path):
    if shutil.which("pcl_ply2pcd") is None:
        print("skipping: pcl_ply2pcd is not on PATH (Debian package pcl-tools)")
        pytest.skip("pcl_ply2pcd is not installed (Debian package pcl-tools)")
    cloud = _cloud()
    pio.write_cloud(tmp_path / "c.ply", cloud)
    result = subprocess.run(["pcl_ply2pcd", str(tmp_path / "c.ply"), str(tmp_path / "c.pcd")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    back = pio.read_cloud(tmp_path / "c.pcd")  # fields named scalar_* by the PLY
    np.testing.assert_array_equal(back.points_turntable, cloud.points_turntable.astype(np.float32))
    _assert_fields_equal(back, cloud)
