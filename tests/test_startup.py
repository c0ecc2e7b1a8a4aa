"""Start-up and loading: the fast de-duplication, and what a scan's process loads."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from plantsim.plant.mesh import unique_rows


def _lexsort_reference(vertices):
    """unique rows as a stable lexsort gives them: sorted, each the first of its equals."""
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    ordered = vertices[order]
    new = np.r_[True, (ordered[1:] != ordered[:-1]).any(axis=1)]
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return ordered[new], inverse


@pytest.mark.parametrize("float32_exact", [True, False])
def test_unique_rows_is_numpys_unique_with_signed_zeros_and_extremes(float32_exact):
    rng = np.random.default_rng(3)
    values = np.array([0.0, -0.0, 1.5, -1.5, 3e-8, -2.0, 0.1, 3e38, -1e-30, np.float32(1e-45)])
    values = values.astype(np.float32).astype(np.float64)
    for _ in range(50):
        vertices = rng.choice(values, size=(int(rng.integers(1, 80)), 3))
        if not float32_exact:
            vertices = vertices + rng.normal(size=vertices.shape) * 1e-3  # not float32: the lexsort path
        unique, inverse = unique_rows(vertices)
        expected, expected_inverse = np.unique(vertices, axis=0, return_inverse=True)
        np.testing.assert_array_equal(unique, expected)
        np.testing.assert_array_equal(inverse, expected_inverse.reshape(-1))
        np.testing.assert_array_equal(unique[inverse], vertices)
        reference, _ = _lexsort_reference(vertices)
        # -0.0 and +0.0 are one row; the first of them in the input represents it, as before.
        np.testing.assert_array_equal(np.signbit(unique), np.signbit(reference))


def tetra_stl(tmp_path):
    """A 20 cm tetrahedron, the smallest plant a scan accepts, as an STL file."""
    import trimesh

    mesh = tmp_path / "tetra.stl"
    trimesh.Trimesh([[0, 0, 0], [0.05, 0, 0.02], [0, 0.05, 0.04], [0.01, 0.01, 0.2]],
                    [[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]]).export(mesh)
    return mesh


def test_unique_rows_of_an_empty_array():
    unique, inverse = unique_rows(np.zeros((0, 3)))
    assert unique.shape == (0, 3) and inverse.shape == (0,)


def test_a_scan_process_loads_no_hardware_no_evaluation_no_http_client_no_toml_and_no_openssl():
    code = ("import sys\n"
            "from plantsim.cli.app import build_parser, _lean_scan_process\n"
            "build_parser(only_scan=True)\n"
            "_lean_scan_process()\n"
            "import mujoco, laspy\n"
            "from plantsim.scan import pipeline\n"
            "bad = sorted(m for m in sys.modules if m.startswith(('plantsim.hardware', 'plantsim.evaluation.metrics',"
            " 'plantsim.plant.procedural', 'matplotlib', 'rosbags', 'glfw', 'tomllib', 'hashlib'))"
            " or m == 'requests' and sys.modules[m])\n"
            "print(','.join(bad), hasattr(mujoco, 'MjModel'), laspy.LasData is not None)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["True", "True"], result.stdout


def test_the_full_parser_still_has_every_command():
    from plantsim.cli.app import build_parser

    full = build_parser()
    scan_only = build_parser(only_scan=True)
    choices = full._subparsers._group_actions[0].choices
    assert {"scan", "reconstruct", "calibrate", "rig", "study"} <= set(choices)
    assert set(scan_only._subparsers._group_actions[0].choices) == {"scan"}


def test_a_kinematic_scan_cast_with_embree_never_loads_mujoco(tmp_path):
    """The whole `plantsim scan` of a small plant, in its own process: MuJoCo's code never runs."""
    pytest.importorskip("embreex", reason="without embreex the scan casts with MuJoCo")
    mesh = tetra_stl(tmp_path)
    out = tmp_path / "x.las"
    code = ("import sys\n"
            "from plantsim.cli.app import main\n"
            f"sys.argv = ['plantsim', 'scan', {str(mesh)!r}, '--step-deg', '30', '-o', {str(out)!r}]\n"
            "main()\n"
            "from plantsim._lazy import is_loaded\n"
            "print('mujoco loaded' if is_loaded('mujoco') or 'mujoco._structs' in sys.modules else 'no mujoco')\n")
    for sensor in ("ideal", "realistic"):
        result = subprocess.run([sys.executable, "-c", code.replace("'30',", f"'30', '--sensor', '{sensor}',")],
                                capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        assert result.stdout.split("\n")[-2] == "no mujoco", result.stdout
        sidecar = json.loads((tmp_path / "x.las.json").read_text())
        assert "mujoco" in sidecar["versions"]["not_loaded"]
        assert "no MuJoCo model used to cast" in sidecar["simulated"]["lidar"]["ray_caster_detail"]


@pytest.mark.parametrize("argv, user, expected", [
    (["plantsim", "scan", "plant.stl"], None, "1"),
    (["plantsim", "-v", "scan"], None, "1"),
    (["plantsim", "study", "sweep.toml"], None, None),
    (["plantsim", "scan"], "4", "4"),  # the user's own choice stands
])
def test_a_scan_process_runs_blas_on_one_thread(argv, user, expected):
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if user is not None:
        env["OPENBLAS_NUM_THREADS"] = user
    code = (f"import sys; sys.argv = {argv!r}\n"
            "import plantsim.cli, os\n"
            "print(os.environ.get('OPENBLAS_NUM_THREADS'))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(expected)


def test_a_finished_scan_process_ends_with_its_exit_handlers_run_and_its_output_flushed(tmp_path):
    """`plantsim scan` skips Python's teardown (plantsim.cli.run), not the exit handlers nor the output."""
    mesh = tetra_stl(tmp_path)
    out = tmp_path / "x.las"
    code = ("import atexit, sys\n"
            "atexit.register(lambda: print('exit handlers ran'))\n"
            "sys.argv = ['plantsim', 'scan', sys.argv[1], '--step-deg', '30', '--sensor', 'ideal', '-o', sys.argv[2]]\n"
            "from plantsim.cli import run\n"
            "run()\n"
            "print('not reached')\n")
    result = subprocess.run([sys.executable, "-c", code, str(mesh), str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("wrote ") and lines[-1] == "exit handlers ran", result.stdout
    from plantsim.cloud.export import from_las

    assert len(from_las(out.read_bytes())) > 0
    # A failed scan ends the same way, with its exit status and message.
    result = subprocess.run([sys.executable, "-c", code, str(tmp_path / "missing.stl"), str(out)],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert "mesh file not found" in result.stderr and result.stdout == "exit handlers ran\n"


def test_only_a_scan_written_as_las_or_laz_loads_laspy(tmp_path):
    """laspy is imported ahead, on a thread, for a LAS output; a PLY scan never loads it."""
    mesh = tetra_stl(tmp_path)
    code = ("import sys\n"
            "from plantsim.cli.app import main\n"
            "sys.argv = ['plantsim', 'scan', sys.argv[1], '--step-deg', '30', '--sensor', 'ideal', '-o', sys.argv[2]]\n"
            "assert main() == 0\n"
            "print('laspy' in sys.modules)\n")
    for name, loaded in (("x.ply", "False"), ("x.las", "True")):
        result = subprocess.run([sys.executable, "-c", code, str(mesh), str(tmp_path / name)],
                                capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        assert result.stdout.splitlines()[-1] == loaded, (name, result.stdout)
