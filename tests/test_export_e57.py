"""E57 output (the ``e57`` extra, pye57 over libE57Format): fields survive a round
trip through the library's own reader; a missing extra is named before any work."""

import builtins

import numpy as np
import pytest

from plantsim.cloud import export as pio
from plantsim.cloud.reconstruct import PointCloud


def _pye57_or_skip():
    try:
        import pye57
    except ImportError as exc:
        print(f"skipped: pye57 is not installed ({exc}); pip install 'plantsim[e57]'")
        pytest.skip(f"pye57 is not installed ({exc}); pip install 'plantsim[e57]'")
    return pye57


def _cloud(n_lines=3, n_beams=5, *, first_line=0):
    rng = np.random.default_rng(7)
    n = n_lines * n_beams
    return PointCloud(
        points_turntable=rng.normal(size=(n, 3)) * 0.1,
        hit_class=np.full(n, 1, np.uint8),
        beam_index=np.tile(np.arange(n_beams), n_lines).astype(np.uint16),
        scan_index=np.repeat(np.arange(first_line, first_line + n_lines), n_beams).astype(np.uint32),
        turntable_angle_rad=np.zeros(n), range_m=np.ones(n), time_s=np.zeros(n),
        intensity=rng.random(n).astype(np.float32))


def test_e57_round_trip_through_libe57format_keeps_xyz_intensity_and_indices(tmp_path):
    pye57 = _pye57_or_skip()
    cloud = _cloud()
    path = tmp_path / "scan.e57"
    pio.write_cloud(path, cloud)
    e57 = pye57.E57(str(path))
    try:
        assert e57.scan_count == 1
        raw = e57.read_scan_raw(0)
    finally:
        e57.close()
    # Read by pye57 itself, not only by plantsim's reader. pye57 stores coordinates
    # as single-precision floats: 0.1 um at these 0.1 m.
    np.testing.assert_allclose(np.column_stack([raw["cartesianX"], raw["cartesianY"],
                                                raw["cartesianZ"]]), cloud.points_turntable,
                               rtol=0, atol=1e-7)
    np.testing.assert_allclose(raw["intensity"], cloud.intensity, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(raw["rowIndex"], cloud.beam_index)
    np.testing.assert_array_equal(raw["columnIndex"], cloud.scan_index)
    back = pio.read_cloud(path)
    np.testing.assert_allclose(back.points_turntable, cloud.points_turntable, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(back.scan_index, cloud.scan_index)


def test_e57_refuses_a_line_index_it_cannot_hold():
    _pye57_or_skip()
    with pytest.raises(OverflowError, match="scan_index reaches 65537, above the 65535"):
        pio.to_e57(_cloud(first_line=65535))


def test_e57_without_pye57_names_the_extra_before_any_work(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_pye57(name, *args, **kwargs):
        if name == "pye57":
            raise ImportError("No module named 'pye57'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pye57)
    with pytest.raises(RuntimeError, match=r"pip install 'plantsim\[e57\]'"):
        pio.check_output_path(tmp_path / "scan.e57")
