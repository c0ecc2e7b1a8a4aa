"""Outputs as a unit: all replaced or none, never over an input, stale temporaries cleaned up."""

from __future__ import annotations

import errno
import json
import logging
import os
import signal

import numpy as np
import pytest
import trimesh

from plantsim.cli.app import main
from plantsim.cloud import outputs as outputs_mod
from plantsim.cloud.outputs import OutputSet, clean_stale
from plantsim.plant.mesh import plant_from_arrays
from plantsim.scan.config import OutputOptions, RunConfig
from plantsim.scan.pipeline import run_scan, write_result
from plantsim.scan.schedule import StepScan


@pytest.fixture(scope="module")
def plant():
    box = trimesh.creation.box(extents=[0.04, 0.06, 0.1])
    box.apply_translation([0.03, 0.0, 0.05])
    return plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces), placement="none")


@pytest.fixture
def mesh_file(tmp_path):
    path = tmp_path / "in.ply"
    trimesh.creation.box(extents=[0.04, 0.06, 0.1]).export(path)
    return path


def result_for(plant, tmp_path, seed=0, raw=True):
    config = RunConfig(seed=seed, scan=StepScan(step_deg=90),
                       output=OutputOptions(path=str(tmp_path / "c.las"), raw=str(tmp_path / "bag") if raw else None))
    return run_scan(config, plant=plant)


def snapshot(tmp_path):
    return {p.relative_to(tmp_path): p.read_bytes() for p in sorted(tmp_path.rglob("*")) if p.is_file()}


def one_line_error(capsys):
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    return err[0]


def test_an_output_that_is_the_input_mesh_is_refused(mesh_file, capsys):
    before = mesh_file.read_bytes()
    assert main(["scan", str(mesh_file), "-o", str(mesh_file)]) == 2
    assert one_line_error(capsys) == (f"plantsim: error: the cloud output {mesh_file} is the plant mesh this run "
                                      f"reads; choose another output path (nothing was written)")
    assert mesh_file.read_bytes() == before


def test_a_sidecar_that_would_overwrite_the_config_file_is_refused(mesh_file, tmp_path, capsys):
    config = tmp_path / "x.las.json"  # an unlucky name: the sidecar of x.las
    config.write_text("seed = 1\n")
    assert main(["scan", str(mesh_file), "--config", str(config), "-o", str(tmp_path / "x.las")]) == 2
    assert "the sidecar output" in one_line_error(capsys)
    assert config.read_text() == "seed = 1\n" and not (tmp_path / "x.las").exists()


def test_a_raw_folder_that_is_a_file_is_refused(mesh_file, tmp_path, capsys):
    assert main(["scan", str(mesh_file), "--raw", str(mesh_file), "-o", str(tmp_path / "x.las")]) == 2
    assert "exists and is not a ROS 2 bag folder" in one_line_error(capsys)
    assert not (tmp_path / "x.las").exists()


def test_a_failed_swap_puts_the_old_outputs_back(plant, tmp_path, monkeypatch):
    write_result(result_for(plant, tmp_path, seed=0))
    before = snapshot(tmp_path)
    real_replace = os.replace

    def failing_replace(src, dst):
        if str(dst).endswith(".las.json") and ".plantsim-new-" in str(src):  # moving the new sidecar in
            raise OSError(errno.EIO, "Input/output error", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(outputs_mod.os, "replace", failing_replace)
    with pytest.raises(OSError, match=r"could not replace .*c.las.json: Input/output error; the earlier outputs "
                                      r"are unchanged"):
        write_result(result_for(plant, tmp_path, seed=1))
    monkeypatch.setattr(outputs_mod.os, "replace", real_replace)
    assert snapshot(tmp_path) == before  # the bag, the cloud and the sidecar of the first run, nothing else


def test_a_full_disk_names_the_path_and_changes_nothing(plant, tmp_path, monkeypatch):
    write_result(result_for(plant, tmp_path, seed=0, raw=False))
    before = snapshot(tmp_path)
    real_fsync = os.fsync

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(outputs_mod.os, "fsync", full)
    with pytest.raises(OSError, match=r"could not write .*c.las: No space left on device"):
        write_result(result_for(plant, tmp_path, seed=1, raw=False))
    monkeypatch.setattr(outputs_mod.os, "fsync", real_fsync)
    assert snapshot(tmp_path) == before


def test_a_sidecar_that_fails_while_the_cloud_is_written_changes_nothing(plant, tmp_path, monkeypatch):
    """The cloud is staged on a worker thread beside the sidecar's making; a failure there waits for it."""
    from plantsim.scan import pipeline

    write_result(result_for(plant, tmp_path, seed=0, raw=False))
    before = snapshot(tmp_path)

    def broken(result):
        raise RuntimeError("sidecar failed")

    monkeypatch.setattr(pipeline, "sidecar", broken)
    with pytest.raises(RuntimeError, match="sidecar failed"):
        write_result(result_for(plant, tmp_path, seed=1, raw=False))
    assert snapshot(tmp_path) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_ctrl_c_during_the_swap_is_held_until_all_outputs_are_in(plant, tmp_path, monkeypatch):
    write_result(result_for(plant, tmp_path, seed=0))
    new = result_for(plant, tmp_path, seed=1)
    real_replace = os.replace
    calls = []

    def interrupted_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
        return real_replace(src, dst)

    monkeypatch.setattr(outputs_mod.os, "replace", interrupted_replace)
    with pytest.raises(KeyboardInterrupt):
        write_result(new)
    monkeypatch.setattr(outputs_mod.os, "replace", real_replace)
    side = json.loads((tmp_path / "c.las.json").read_text())
    assert side["seed"] == 1  # the new sidecar beside the new cloud
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_temporaries_of_a_killed_run_are_cleaned_up_and_said(tmp_path, caplog):
    target = tmp_path / "scan.las"
    dead = 2 ** 22 + 12345  # beyond Linux's default pid_max: no such process
    stale = tmp_path / f".scan.las.plantsim-new-{dead}"
    stale.write_bytes(b"half a cloud")
    old = tmp_path / f".scan.las.plantsim-old-{dead}"
    old.write_bytes(b"the previous cloud")
    with caplog.at_level(logging.WARNING):
        removed = clean_stale([target])
    assert set(removed) == {stale, old}
    assert target.read_bytes() == b"the previous cloud"  # killed between the two moves: restored
    assert not stale.exists() and "left by an earlier run that was killed" in caplog.text


def test_output_set_discards_what_was_not_committed(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")
    with OutputSet() as out:
        out.stage_bytes(target, b"new")
        out.stage_folder(tmp_path / "bag")
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]
