"""A study on a Dask LocalCluster gives the rows of the local run."""

import concurrent.futures

import numpy as np
import pytest
import trimesh

from plantsim.evaluation import study

TIMING = {"wall_time_s", "cpu_time_s", "evaluate_time_s"}


@pytest.fixture
def stalk(tmp_path):
    box = trimesh.creation.box(extents=[0.03, 0.03, 0.2])
    path = tmp_path / "stalk.stl"
    path.write_bytes(box.export(file_type="stl"))
    return path


def _same(rows_a, rows_b):
    assert len(rows_a) == len(rows_b)
    for a, b in zip(rows_a, rows_b):
        assert a.keys() == b.keys()
        for key in a.keys() - TIMING:
            if isinstance(a[key], float):
                np.testing.assert_equal(a[key], b[key], err_msg=key)
            else:
                assert a[key] == b[key], key


def test_dask_local_cluster_study_equals_the_local_one(stalk):
    distributed = pytest.importorskip("distributed", reason="pip install 'plantsim[cluster]'")
    sweep = study.Sweep(plants=(str(stalk),), grid=(("step_deg", (90.0, 45.0)), ("ideal", (True, False))),
                        evaluation=study.EvaluationOptions(n_surface_samples=2000))
    local = study.run_study(sweep, max_workers=1, threads_per_run=1)
    assert all(r["error"] == "" for r in local)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        executor, _ = study.dask_executor(client)
        seen = []
        remote = study.run_study(sweep, executor=executor, send_meshes=True, threads_per_run=1,
                                 progress=lambda done, total, row: seen.append(done))
    assert seen == [1, 2, 3, 4]
    _same(local, remote)


def test_sent_meshes_are_read_on_the_worker_not_from_the_path(stalk, tmp_path):
    sweep = study.Sweep(plants=(str(stalk),), grid=(("step_deg", (90.0,)),), base={"ideal": True},
                        evaluation=study.EvaluationOptions(n_surface_samples=500))
    seen_paths = []

    class Recording(concurrent.futures.ThreadPoolExecutor):
        def submit(self, fn, *args, **kwargs):
            seen_paths.append(args[3][0] if args[3] else None)
            stalk.rename(tmp_path / "moved.stl")  # the worker cannot read the original path
            return super().submit(fn, *args, **kwargs)

    with Recording(max_workers=1) as pool:
        rows = study.run_study(sweep, executor=pool, send_meshes=True)
    assert seen_paths == ["stalk.stl"] and rows[0]["error"] == "" and rows[0]["plant_points"] > 0


def test_executor_options_are_checked():
    sweep = study.Sweep(plants=("maize",))
    with pytest.raises(ValueError, match=r"run_study\.send_meshes must be true or false, got 'yes'"):
        study.run_study(sweep, executor=None, send_meshes="yes")
    with pytest.raises(ValueError, match=r"run_study\.threads_per_run must be >= 1, got 0"):
        study.run_study(sweep, threads_per_run=0)
