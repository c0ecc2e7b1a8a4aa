"""Pictures: the default scan drawn offscreen shows the plant; PNG encoding is valid."""

import zlib

import numpy as np
import pytest

from plantsim.cloud import render


def _decode_png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, {}
    while pos < len(data):
        n = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        assert zlib.crc32(kind + body) == int.from_bytes(data[pos + 8 + n:pos + 12 + n], "big")
        chunks[kind] = chunks.get(kind, b"") + body
        pos += 12 + n
    w, h = int.from_bytes(chunks[b"IHDR"][:4], "big"), int.from_bytes(chunks[b"IHDR"][4:8], "big")
    raw = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(h, 1 + 3 * w)
    assert (raw[:, 0] == 0).all()
    return raw[:, 1:].reshape(h, w, 3)


def test_png_round_trip():
    image = np.random.default_rng(0).integers(0, 256, (7, 5, 3), dtype=np.uint8)
    np.testing.assert_array_equal(_decode_png(render.png_bytes(image)), image)


def test_error_colours_run_blue_to_red():
    rgba = render.error_colours(np.array([0.0, 0.5, 1.0, 3.0]), 1.0)
    assert rgba[0, 2] > rgba[0, 0] and rgba[2, 0] > rgba[2, 2]
    np.testing.assert_array_equal(rgba[2], rgba[3])  # clipped beyond the maximum


@pytest.fixture(scope="module")
def scan():
    from plantsim.cloud.reconstruct import reconstruct
    from plantsim.plant.mesh import load_plant
    from plantsim.resources import bundled_plant_path
    from plantsim.rig.geometry import RigGeometry
    from plantsim.rig.scene import build_scene
    from plantsim.scan.pipeline import step_and_shoot
    from plantsim.scan.schedule import StepScan
    from plantsim.sensor.spec import URG_04LX_UG01

    plant, rig = load_plant(bundled_plant_path("maize")), RigGeometry()
    cloud = reconstruct(step_and_shoot(build_scene(rig, plant), URG_04LX_UG01,
                                       StepScan(step_deg=30)))
    return cloud, plant, rig, URG_04LX_UG01


def _render_or_skip(fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except render.RenderError as exc:
        pytest.skip(f"no offscreen OpenGL here: {exc}")


def _green(image):
    r, g, b = (image[..., i].astype(int) for i in range(3))
    return (g > 120) & (g > r + 40) & (g > b + 40)


def test_default_scan_picture_shows_the_plant(scan, tmp_path):
    cloud, plant, rig, lidar = scan
    view = render.View(width=320, height=240)
    with_plant = _render_or_skip(render.render_cloud, cloud, rig, plant, lidar=lidar, view=view)
    assert with_plant.shape == (240, 320, 3) and with_plant.dtype == np.uint8
    assert with_plant.std() > 10  # not a uniform picture
    assert _green(with_plant).mean() > 0.01  # the plant (mesh and points) is in view
    # Without the plant and its points, the green is gone: it was the plant.
    empty = _render_or_skip(render.render_scene, rig, None, view=view)
    assert _green(empty).mean() < 0.1 * _green(with_plant).mean()
    # The fan is drawn in its own colour.
    red = (with_plant[..., 0] > 150) & (with_plant[..., 1] < 80) & (with_plant[..., 2] < 80)
    assert red.sum() > 50
    png = tmp_path / "rig.png"
    png.write_bytes(render.png_bytes(with_plant))
    np.testing.assert_array_equal(_decode_png(png.read_bytes()), with_plant)


def test_error_picture_and_cli(scan, tmp_path):
    from plantsim.cli.app import main
    from plantsim.cloud.export import write_cloud

    cloud, plant, rig, _ = scan
    data = _render_or_skip(render.error_picture, cloud, plant, rig,
                           view=render.View(width=160, height=120))
    assert _decode_png(data).shape == (120, 160, 3)
    write_cloud(tmp_path / "scan.ply", cloud)
    out = tmp_path / "pic.png"
    assert main(["render", str(tmp_path / "scan.ply"), "-o", str(out), "--width", "160",
                 "--height", "120"]) == 0
    assert _decode_png(out.read_bytes()).std() > 10
    with pytest.raises(ValueError, match="colour must be 'class' or 'error', got 'rgb'"):
        render.render_cloud(cloud, rig, plant, colour="rgb")
    assert main(["render", "-o", str(tmp_path / "x.jpg")]) == 2


def test_error_picture_states_its_scale_and_draws_a_colour_bar(scan):
    cloud, plant, rig, _ = scan
    picture = _render_or_skip(render.error_picture_of, cloud, plant, rig, error_max_m=0.004,
                              view=render.View(width=320, height=240))
    assert picture.error_max_m == 0.004
    assert picture.scale_text() == "blue 0 mm -> red >= 4 mm"
    image = _decode_png(picture.png)
    assert image.std() > 10  # not uniform
    # The colour bar at the right edge: red at its top, blue at its bottom.
    bar_w = 320 // 48
    column = image[:, 320 - 2 * bar_w + 1].astype(int)
    top, bottom = column[(240 - 120) // 2], column[(240 - 120) // 2 + 119]  # half the height
    assert top[0] > 200 and top[2] < 60 and bottom[2] > 200 and bottom[0] < 60
    # The default scale is the measured 95th percentile of the drawn points.
    auto = _render_or_skip(render.error_picture_of, cloud, plant, rig,
                           view=render.View(width=160, height=120))
    assert 0 < auto.error_max_m < 0.05


@pytest.mark.parametrize("facing", ["towards", "away"])
def test_a_leaf_seen_from_behind_is_drawn(facing):
    """One flat leaf (a single sheet of triangles) shows whichever side faces the camera."""
    from plantsim.plant.mesh import plant_from_arrays
    from plantsim.rig.geometry import RigGeometry

    # A 10 cm square in the x = 0 plane, 5-15 cm up; winding gives a normal of -x or +x.
    square = np.array([[0, -0.05, 0.05], [0, 0.05, 0.05], [0, 0.05, 0.15], [0, -0.05, 0.15]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if facing == "towards":
        faces = faces[:, ::-1]
    leaf = plant_from_arrays(square, faces, placement="none")
    normal = np.cross(*(square[faces[0, 1:]] - square[faces[0, 0]]))
    # The camera looks along +x from -x (azimuth 0), away from the LiDAR's post on +x.
    assert (normal[0] < 0) == (facing == "towards")
    view = render.View(width=160, height=120, azimuth_deg=0.0, elevation_deg=0.0,
                       distance_m=0.5, lookat=(0.0, 0.0, 0.1))
    image = _render_or_skip(render.render_scene, RigGeometry(), leaf, view=view).astype(int)
    green = (image[..., 1] > 2 * image[..., 0] + 10) & (image[..., 1] > 2 * image[..., 2] + 10)
    # At 0.5 m with a 45 deg field of view the square spans 0.24 of the picture's height and
    # 0.18 of its width (4:3): about 4 % of the pixels.
    assert 0.03 * green.size < green.sum() < 0.06 * green.size


def test_a_clouds_picture_draws_its_own_scan_from_its_sidecar(tmp_path, capsys):
    # A cloud from plantsim scan is drawn with the rig, LiDAR and plant its sidecar
    # records (a wheat's cloud was drawn round the bundled maize, on the default rig);
    # without a sidecar no plant is guessed, and the error colours, which need one, ask for it.
    import shutil

    import trimesh

    from plantsim.cli.app import main

    _render_or_skip(render.render_scene, _scene_rig(), None, view=render.View(width=16, height=16))
    post = trimesh.creation.cylinder(radius=0.01, height=0.3, sections=16)
    post.apply_translation([0.0, 0.0, 0.15])
    mesh = tmp_path / "post.stl"
    mesh.write_bytes(post.export(file_type="stl"))
    cloud = tmp_path / "post.las"
    assert main(["scan", str(mesh), "-o", str(cloud), "--step-deg", "45", "--ideal", "--no-pictures"]) == 0
    capsys.readouterr()
    kw = ["--width", "64", "--height", "48"]
    assert main(["render", str(cloud), "-o", str(tmp_path / "a.png"), *kw]) == 0
    assert "rig, LiDAR and plant from post.las.json" in capsys.readouterr().out
    assert main(["render", str(cloud), "-o", str(tmp_path / "e.png"), "--colour", "error", *kw]) == 0
    capsys.readouterr()
    bare = tmp_path / "bare.las"
    shutil.copy(cloud, bare)
    assert main(["render", str(bare), "-o", str(tmp_path / "b.png"), *kw]) == 0
    assert "no sidecar beside the cloud: the default rig, and no plant" in capsys.readouterr().out
    assert main(["render", str(bare), "-o", str(tmp_path / "c.png"), "--colour", "error", *kw]) == 2
    assert "no sidecar (bare.las.json) says which mesh" in capsys.readouterr().err
    assert main(["render", str(bare), "-o", str(tmp_path / "d.png"), "--plant", str(mesh), "--colour", "error",
                 *kw]) == 0


def _scene_rig():
    from plantsim.rig.geometry import RigGeometry

    return RigGeometry()
