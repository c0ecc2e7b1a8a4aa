"""The bad-input corpus: every case stops with one line that says what is wrong, exits non-zero and
writes nothing.

Each CLI case runs ``plantsim`` in this process in a fresh folder holding a good mesh, a good
config and nothing else; afterwards the folder must hold exactly what it held before.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import trimesh

from plantsim.cli.app import main

GOOD_STL = "plant.stl"


def _box_stl() -> bytes:
    box = trimesh.creation.box(extents=[0.04, 0.04, 0.2])
    box.apply_translation([0, 0, 0.1])
    return box.export(file_type="stl")


BOX_STL = _box_stl()


def _binary_stl_with_count(count: int) -> bytes:
    return BOX_STL[:80] + struct.pack("<I", count) + BOX_STL[84:]


# Files a case may add to its folder before running: name -> bytes.
FILES = {
    "empty.stl": b"",
    "garbage.stl": bytes(range(256)) * 3,
    "short.stl": _binary_stl_with_count(1000),
    "nan.obj": b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n",
    "badface.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    "ascii_empty.stl": b"solid x\nendsolid x\n",
    "flat.obj": b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n",
}
HIGH = trimesh.creation.box(extents=[0.02, 0.02, 0.02])
HIGH.apply_translation([0, 0, 8.0])  # 8 m above the disk: beyond the URG-04LX's 5.6 m
FILES["high.stl"] = HIGH.export(file_type="stl")
FILES["plant.ply"] = trimesh.creation.box(extents=[0.04, 0.04, 0.2]).export(file_type="ply")


def toml(text: str) -> dict:
    return {"cfg.toml": text.encode()}


# (id, extra files, argv (with {mesh} and {dir}), fragment of the one error line)
CLI_CASES = [
    # --- meshes
    ("missing mesh", {}, ["scan", "missing.stl"], "mesh file not found: missing.stl"),
    ("empty mesh", {}, ["scan", "empty.stl"], "is empty"),
    ("garbage mesh", {}, ["scan", "garbage.stl"], "header says"),
    ("truncated binary stl", {}, ["scan", "short.stl"],
     "as a binary STL its header says 1,000 triangles while the file holds 12.0 (684 bytes)"),
    ("nan vertices", {}, ["scan", "nan.obj"], "1 of 4 vertices are NaN or infinite"),
    ("face index out of range", {}, ["scan", "badface.obj"], "badface.obj"),
    ("ascii stl without facets", {}, ["scan", "ascii_empty.stl"], "ascii_empty.stl"),
    ("only degenerate faces", {}, ["scan", "flat.obj"], "flat.obj"),
    ("unknown mesh format", {"plant.xyz": b"0 0 0\n"}, ["scan", "plant.xyz"], "plant.xyz"),
    # --- schedule
    ("zero step", {}, ["scan", "{mesh}", "--step-deg", "0"], "step_deg must be > 0"),
    ("negative step", {}, ["scan", "{mesh}", "--step-deg", "-1"], "step_deg must be > 0"),
    ("step not dividing the sweep", {}, ["scan", "{mesh}", "--step-deg", "7"],
     "step_deg must divide sweep_deg evenly"),
    ("absurdly small step", {}, ["scan", "{mesh}", "--step-deg", "1e-300"], "more than 360,000"),
    ("two turns", {}, ["scan", "{mesh}", "--sweep-deg", "720"], "sweep_deg must be at most 360"),
    ("zero sweep", {}, ["scan", "{mesh}", "--sweep-deg", "0"], "sweep_deg must be > 0"),
    ("nan step", {}, ["scan", "{mesh}", "--step-deg", "nan"], "step_deg must be a finite number"),
    ("step in continuous mode", {}, ["scan", "{mesh}", "--mode", "continuous", "--step-deg", "2"],
     "--step-deg applies to step scans"),
    ("rpm in step mode", {}, ["scan", "{mesh}", "--rpm", "5"], "--rpm applies to continuous scans"),
    ("rpm beyond the servo", {}, ["scan", "{mesh}", "--mode", "continuous", "--rpm", "600"],
     "exceeds the servo's no-load speed"),
    ("negative rpm", {}, ["scan", "{mesh}", "--mode", "continuous", "--rpm", "-1"],
     "turntable rpm must be a positive number"),
    # --- sensor
    ("negative rings", {}, ["scan", "{mesh}", "--footprint-rings", "-1"], "footprint_rings"),
    ("rings with the ideal sensor", {}, ["scan", "{mesh}", "--sensor", "ideal", "--footprint-rings", "1"],
     "[sensor_model] footprint_rings is set but the sensor is ideal"),
    ("ideal but realistic", {}, ["scan", "{mesh}", "--ideal", "--sensor", "realistic"],
     "ideal = true makes everything perfect"),
    ("zero threads", {}, ["scan", "{mesh}", "--threads", "0"], "threads must be a positive integer"),
    ("negative seed", {}, ["scan", "{mesh}", "--seed", "-1"], "seed must be a non-negative integer"),
    # --- outputs
    ("output folder missing", {}, ["scan", "{mesh}", "-o", "nowhere/scan.las"], "nowhere"),
    ("unknown output format", {}, ["scan", "{mesh}", "-o", "scan.foo"], ".foo"),
    ("output is the mesh", {}, ["scan", "plant.ply", "-o", "plant.ply"], "is the plant mesh this run reads"),
    ("raw folder is a file", {}, ["scan", "{mesh}", "--raw", "{mesh}", "-o", "x.las"],
     "exists and is not a ROS 2 bag folder"),
    ("sidecar would overwrite the config", {"x.las.json": b"seed = 1\n"},
     ["scan", "{mesh}", "--config", "x.las.json", "-o", "x.las"], "the sidecar output"),
    # --- configuration files
    ("missing config", {}, ["scan", "{mesh}", "--config", "nope.toml"], "config file not found: nope.toml"),
    ("invalid toml", toml("seed = = 1\n"), ["scan", "{mesh}", "--config", "cfg.toml"], "is not valid TOML"),
    ("section as a value", toml("scan = 5\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "scan must be a [scan] section"),
    ("unknown section", toml("[scanner]\nx = 1\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "unknown key(s) or section(s) scanner"),
    ("unknown key", toml("[scan]\nstep = 1\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "unknown key(s) step in [scan]"),
    ("string for a bool", toml('ideal = "false"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "ideal must be true or false"),
    ("string for plant_only", toml('[output]\nplant_only = "false"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "plant_only must be true or false"),
    ("lidar beyond range", toml("[rig]\nlidar_distance_m = 1e6\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "beyond its range_max_m"),
    ("lidar inside the disk", toml("[rig]\nlidar_distance_m = 0.05\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "must exceed disk_radius_m"),
    ("string for a distance", toml('[rig]\nlidar_distance_m = "far"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "lidar_distance_m must be a finite number"),
    ("unknown preset", toml('[lidar]\npreset = "nope"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "unknown LiDAR preset 'nope'"),
    ("range min above max", toml("[lidar]\nrange_min_m = 10.0\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "range_min_m must be less than range_max_m"),
    ("no beams", toml("[lidar]\nn_beams = 0\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "n_beams must be a positive integer"),
    ("unknown mode", toml('[turntable]\nmode = "spin"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "turntable mode must be one of"),
    ("unknown physics", toml('[turntable]\nphysics = "quantum"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "turntable physics must be one of"),
    ("unknown jitter key", toml("[turntable.jitter]\nbogus = 1\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "unknown key(s) bogus in [turntable.jitter]"),
    ("register not an integer", toml('[turntable.registers]\n"Position P Gain" = 1.5\n'),
     ["scan", "{mesh}", "--config", "cfg.toml"], "register 'Position P Gain' must be an integer"),
    ("one-tick encoder", toml("[turntable.encoder]\nticks_per_rev = 1\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "ticks_per_rev must be an integer >= 2"),
    ("timestep too long", toml("[turntable]\ntimestep_s = 1.0\n"), ["scan", "{mesh}", "--config", "cfg.toml"],
     "timestep_s must be at most 0.05 s"),
    ("jitter on a kinematic table", toml('[turntable]\nphysics = "kinematic"\n[turntable.jitter]\nbacklash_deg = 1\n'),
     ["scan", "{mesh}", "--config", "cfg.toml"], "needs the servo's physics, but physics = \"kinematic\""),
    ("rings not a number", toml('[sensor_model]\nfootprint_rings = "two"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "footprint_rings"),
    ("unknown units", toml('[plant]\nunits = "inch"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "units must be one of m, cm, mm"),
    ("unknown up axis", toml('[plant]\nup = "w"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "up must be one of x, y, z"),
    ("unknown placement", toml('[plant]\nplacement = "floating"\n'), ["scan", "{mesh}", "--config", "cfg.toml"],
     "placement must be one of"),
    ("ideal table with encoder noise", toml("[turntable]\nideal = true\n[turntable.encoder]\nnoise_rad = 1e-3\n"),
     ["scan", "{mesh}", "--config", "cfg.toml"], "[turntable.encoder] noise_rad is set but [turntable] ideal = true"),
    ("plant the lidar cannot see", {}, ["scan", "high.stl", "--placement", "none", "--step-deg", "90",
                                        "--sensor", "ideal"], "no beam hit the plant"),
    # --- reconstruct
    ("reconstruct a missing bag", {}, ["reconstruct", "nobag", "-o", "x.las"], "no ROS 2 bag at nobag"),
    ("reconstruct to an unknown format", {}, ["reconstruct", "nobag", "-o", "x.foo"], ".foo"),
    # --- rig scans: refused before a port is opened
    ("rig scan ideal", {}, ["rig", "scan", "{mesh}", "--port", "/dev/null-port", "--ideal"],
     "--ideal cannot make a real servo perfect"),
    ("rig scan with jitter", toml("[turntable.jitter]\nbacklash_deg = 1\n"),
     ["rig", "scan", "{mesh}", "--port", "/dev/null-port", "--config", "cfg.toml"],
     "[turntable.jitter] backlash_deg describes the simulated turntable"),
    ("rig scan continuous", toml('[turntable]\nmode = "continuous"\n'),
     ["rig", "scan", "{mesh}", "--port", "/dev/null-port", "--config", "cfg.toml"],
     "continuous rig scans need a LiDAR that streams"),
    ("rig scan real lidar", {}, ["rig", "scan", "{mesh}", "--port", "/dev/null-port", "--lidar", "urg"],
     "--lidar urg needs --lidar-port PORT"),
    ("rig scan output is the mesh", {}, ["rig", "scan", "plant.ply", "--port", "/dev/null-port", "-o", "plant.ply"],
     "is the plant mesh this run reads"),
]


def _listing(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("files, argv, fragment", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_cli_bad_input_one_line_non_zero_nothing_written(tmp_path, monkeypatch, capsys, files, argv, fragment):
    monkeypatch.chdir(tmp_path)
    (tmp_path / GOOD_STL).write_bytes(BOX_STL)
    for name in set(FILES) & {a for a in argv}:
        (tmp_path / name).write_bytes(FILES[name])
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    before = _listing(tmp_path)
    code = main([a.format(mesh=GOOD_STL, dir=tmp_path) for a in argv])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code != 0
    assert len(err) == 1, err
    assert err[0].startswith("plantsim: error: ") and fragment in err[0], err[0]
    assert _listing(tmp_path) == before


def test_the_corpus_is_at_least_sixty_cases():
    assert len(CLI_CASES) + len(API_CASES) >= 60


# --- the Python API ---------------------------------------------------------------------------

def _api_cases():
    import plantsim

    return [
        ("run_scan of a dict", lambda: plantsim.run_scan({"scan": {}}), TypeError, "config must be a plantsim.RunConfig"),
        ("RunConfig with a float schedule", lambda: plantsim.RunConfig(scan=1.0), TypeError,
         "RunConfig.scan must be a plantsim.StepScan"),
        ("StepScan with a string", lambda: plantsim.StepScan(step_deg="1"), ValueError,
         "step_deg must be a finite number"),
        ("load_plant of a missing file", lambda: plantsim.load_plant("missing.stl"), FileNotFoundError,
         "mesh file not found"),
        ("plant_from_arrays with NaN", lambda: plantsim.plant_from_arrays(
            np.array([[0, 0, 0], [1, 0, math.nan], [0, 1, 0]]), np.array([[0, 1, 2]])), Exception, "NaN or infinite"),
        ("LidarSpec without beams", lambda: plantsim.LidarSpec(n_beams=0, angle_min_deg=0, angle_increment_deg=1,
                                                               range_min_m=0.1, range_max_m=1, scan_period_s=0.1),
         ValueError, "n_beams must be a positive integer"),
        ("RigGeometry with NaN", lambda: plantsim.RigGeometry(lidar_distance_m=math.nan), ValueError,
         "lidar_distance_m must be a finite number"),
        ("turntable that is not one", lambda: plantsim.run_scan(plantsim.RunConfig(), turntable=3), TypeError,
         "turntable must implement plantsim.Turntable"),
        ("encoder with one tick", lambda: plantsim.EncoderConfig(ticks_per_rev=1), ValueError,
         "ticks_per_rev must be an integer >= 2"),
        ("unknown sensor", lambda: plantsim.RunConfig(sensor="perfect"), ValueError, "sensor must be one of"),
        ("unknown caster", lambda: plantsim.RunConfig(caster="gpu"), ValueError, "caster must be one of"),
    ]


API_CASES = [c[0] for c in _api_cases()]


@pytest.mark.parametrize("index", range(len(API_CASES)), ids=API_CASES)
def test_api_bad_input_is_named_at_the_entry_point(tmp_path, monkeypatch, index):
    monkeypatch.chdir(tmp_path)
    _, call, error, fragment = _api_cases()[index]
    with pytest.raises(error, match=None) as caught:
        call()
    assert fragment in str(caught.value)
    assert list(tmp_path.iterdir()) == []
