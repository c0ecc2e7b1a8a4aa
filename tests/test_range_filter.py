"""The range-image filter (plantsim.cloud.denoise) against surfaces whose ranges are known."""

import json

import numpy as np
import pytest
import trimesh

from plantsim.cli.app import main
from plantsim.cloud.denoise import filter_range_image, filter_ranges
from plantsim.errors import ConfigError
from plantsim.plant.mesh import plant_from_arrays
from plantsim.scan.config import RangeFilter, RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

ON = RangeFilter(enabled=True)


def _plane(rows=60, beams=80, a=0.35, b=0.0012, c=-0.0007):
    """A surface seen obliquely: its range grows linearly across the image."""
    i, j = np.meshgrid(np.arange(rows), np.arange(beams), indexing="ij")
    return a + b * i + c * j


def test_a_noise_free_oblique_plane_keeps_its_ranges_even_at_its_edges():
    # A window mean would pull a border beam towards the centre by the slope times
    # half the window; the local plane fit is exact on a plane, borders included.
    truth = _plane()
    image = truth.copy()
    image[:, :5] = np.nan  # the plane's edge: misses beside it
    out, sigma, refitted = filter_range_image(image, settings=RangeFilter(sigma_m=0.01))
    assert sigma == 0.01 and refitted[:, 5:].all()
    np.testing.assert_allclose(out[:, 5:], truth[:, 5:], atol=1e-9)
    assert np.isnan(out[:, :5]).all()


def test_noise_on_a_plane_falls_several_fold_and_is_measured_on_the_image():
    rng = np.random.default_rng(3)
    truth = _plane()
    noisy = truth + rng.normal(0.0, 0.010, truth.shape)
    out, sigma, refitted = filter_range_image(noisy)
    assert 0.0085 <= sigma <= 0.0115  # measured (MAD about the window medians), not given
    assert refitted.all()
    inner = (slice(3, -3), slice(3, -3))
    assert np.sqrt(np.mean((out - truth)[inner] ** 2)) < 0.010 / 4  # 49 beams a fit: ~sqrt(3/49)
    # The corners use a quarter of the window and stay unbiased.
    assert np.sqrt(np.mean((out - truth) ** 2)) < 0.010 / 2.5
    assert abs(np.mean(out - truth)) < 0.0005


def test_a_range_step_stays_a_step_and_a_lone_mixed_pixel_joins_a_surface():
    rng = np.random.default_rng(4)
    image = np.full((40, 40), 0.30)
    image[:, 20:] = 0.40  # a leaf edge 10 cm in front of the background
    image += rng.normal(0.0, 0.005, image.shape)
    image[10, 10] = 0.35  # a mixed pixel, halfway between the surfaces, amid the near one
    out, _, _ = filter_range_image(image)
    near, far = out[:, :20], out[:, 20:]
    assert np.abs(near - 0.30).max() < 0.006 and np.abs(far - 0.40).max() < 0.006
    assert abs(out[10, 10] - 0.30) < 0.006


def test_a_lone_return_without_neighbours_keeps_its_range():
    image = np.full((30, 30), np.nan)
    image[15, 15] = 0.42  # a speck: no surface round it to fit
    image[:, 3] = 0.30 + 0.001 * np.arange(30)  # a column one beam wide, seen over all lines
    out, _, refitted = filter_range_image(image, settings=RangeFilter(sigma_m=0.01))
    assert out[15, 15] == 0.42 and not refitted[15, 15]
    assert refitted[3:-3, 3].all()
    np.testing.assert_allclose(out[:, 3], image[:, 3], atol=1e-9)


def test_a_full_turn_wraps_so_the_first_and_last_lines_are_neighbours():
    rng = np.random.default_rng(5)
    image = 0.3 + 0.01 * np.sin(np.linspace(0, 2 * np.pi, 36, endpoint=False))[:, None] + \
        rng.normal(0.0, 0.01, (36, 25))
    out, _, _ = filter_range_image(image, wrap_rows=True)
    rolled, _, _ = filter_range_image(np.roll(image, 7, axis=0), wrap_rows=True)
    np.testing.assert_allclose(rolled, np.roll(out, 7, axis=0), atol=1e-12)
    # Without the wrap the first line has no lines before it: a different fit.
    unwrapped, _, _ = filter_range_image(image)
    assert np.abs(unwrapped[0] - out[0]).max() > 1e-6


@pytest.mark.parametrize("changes, message", [
    (dict(half_lines=-1), "range_filter.half_lines must be >= 0"),
    (dict(half_lines=0, half_beams=0), "both 0"),
    (dict(gate_sigma=0), "range_filter.gate_sigma must be > 0"),
    (dict(min_support=2), "range_filter.min_support must be >= 3"),
    (dict(half_lines=1, half_beams=1, min_support=10), "range_filter.min_support must be <= 9"),
    (dict(sigma_m=-0.01), "range_filter.sigma_m must be >= 0"),
    (dict(enabled="yes"), "range_filter.enabled must be true or false"),
])
def test_impossible_filter_settings_are_refused_with_what_to_change(changes, message):
    with pytest.raises(ValueError, match=message):
        RangeFilter(**changes)


# --- through the pipeline: a box whose distance is exact ------------------------------------------
BOX_CENTRE = np.array([0.05, 0.02, 0.08])
BOX_HALF = np.array([0.03, 0.04, 0.06])


def _box_distance(points):
    d = np.abs(points - BOX_CENTRE) - BOX_HALF
    return np.linalg.norm(np.maximum(d, 0), axis=1) + np.abs(np.minimum(d.max(axis=1), 0))


@pytest.fixture(scope="module")
def box():
    mesh = trimesh.creation.box(extents=2 * BOX_HALF)
    mesh.apply_translation(BOX_CENTRE)
    return plant_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), placement="none")


@pytest.fixture(scope="module")
def box_scans(box):
    config = RunConfig(scan=StepScan(step_deg=2.0))
    plain = run_scan(config, plant=box)
    filtered = run_scan(config.replace(range_filter=ON), plant=box)
    return plain, filtered


def test_a_realistic_scan_with_the_filter_lies_several_times_closer_to_the_surface(box_scans):
    plain, filtered = box_scans
    rms = [np.sqrt(np.mean(_box_distance(r.cloud.plant_only().points_turntable) ** 2)) for r in box_scans]
    assert rms[1] < rms[0] / 3, rms
    # The raw record keeps what the sensor measured; only the points differ.
    np.testing.assert_array_equal(filtered.raw.range_m, plain.raw.range_m)
    assert len(filtered.cloud) == len(plain.cloud)


def test_the_sidecar_says_what_the_filter_did(box_scans):
    plain, filtered = box_scans
    assert "range_filter" not in plain.parts
    report = filtered.parts["range_filter"]
    assert report["window_lines"] == 7 and report["window_beams"] == 7 and report["wrapped"] is True
    assert report["sigma_measured"] is True and 0.005 < report["sigma_m"] < 0.03
    assert report["filtered"] + report["unsupported"] == report["returns"] == int(np.isfinite(plain.raw.range_m).sum())


def test_half_a_turn_does_not_wrap(box_scans):
    plain, _ = box_scans
    half = plain.raw
    keep = np.arange(half.n_lines // 2)
    half = half.replace(range_m=half.range_m[keep], status=half.status[keep], line_stamp_ns=half.line_stamp_ns[keep],
                        commanded_rad=half.commanded_rad[keep],
                        intensity=None if half.intensity is None else half.intensity[keep],
                        hit_class=half.hit_class[keep], geom_id=half.geom_id[keep],
                        true_turntable_angle_rad=half.true_turntable_angle_rad[keep])
    _, report = filter_ranges(half, ON)
    assert report.wrapped is False and report.filtered > 0


def test_filter_settings_with_the_filter_off_or_an_ideal_sensor_are_refused(box):
    with pytest.raises(ConfigError, match=r"half_lines is set but the range filter is off.*enabled = true"):
        run_scan(RunConfig(scan=StepScan(step_deg=30.0), range_filter=RangeFilter(half_lines=2)), plant=box)
    with pytest.raises(ConfigError, match="the sensor is ideal.*remove --range-filter"):
        run_scan(RunConfig(ideal=True, scan=StepScan(step_deg=30.0), range_filter=ON), plant=box)


def test_cli_reconstruct_filters_a_recorded_bag_and_says_so(tmp_path, capsys):
    bag = tmp_path / "raw"
    assert main(["scan", "--step-deg", "10", "--plant-only", "-o", str(tmp_path / "scan.las"), "--raw", str(bag)]) == 0
    out_path = tmp_path / "again.las"
    assert main(["reconstruct", str(bag), "-o", str(out_path), "--range-filter"]) == 0
    assert "range filter: noise" in capsys.readouterr().out
    sidecar = json.loads((tmp_path / "again.las.json").read_text())
    assert sidecar["range_filter"]["filtered"] > 0 and sidecar["range_filter"]["sigma_measured"] is True


def test_cli_scan_with_the_filter_says_so_on_its_summary_line_and_toml_sets_the_window(tmp_path, capsys):
    out_path = tmp_path / "scan.las"
    assert main(["scan", "--step-deg", "10", "--range-filter", "-o", str(out_path)]) == 0
    assert "ranges filtered (noise" in capsys.readouterr().out
    config = tmp_path / "rig.toml"
    config.write_text("[range_filter]\nenabled = true\nhalf_lines = 1\nhalf_beams = 5\n")
    assert main(["scan", "--step-deg", "10", "--config", str(config), "-o", str(out_path)]) == 0
    report = json.loads((tmp_path / "scan.las.json").read_text())["simulated"]["range_filter"]
    assert (report["window_lines"], report["window_beams"]) == (3, 11)
