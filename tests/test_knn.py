"""The evaluation's neighbour index: pykdtree and SciPy give the same neighbours."""

import numpy as np
import pytest

from plantsim.evaluation import knn
from plantsim.evaluation.knn import NeighbourIndex

pytest.importorskip("pykdtree", reason="pykdtree not installed (pip install pykdtree)")


def _cloud(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    # Scan-like: points on lines, plus a few far ones.
    t = rng.uniform(0, 1, n)
    return np.column_stack([np.cos(7 * t) * 0.1, np.sin(7 * t) * 0.1, t * 0.5]) + rng.normal(0, 0.002, (n, 3))


@pytest.mark.parametrize("k", [1, 9, 17])
def test_pykdtree_and_scipy_give_the_same_distances(k):
    pts = _cloud()
    queries = _cloud(1000, seed=1)
    d_pk, i_pk = NeighbourIndex(pts, backend="pykdtree").query(queries, k=k)
    d_sp, i_sp = NeighbourIndex(pts, backend="scipy").query(queries, k=k)
    assert d_pk.shape == d_sp.shape == ((1000,) if k == 1 else (1000, k))
    assert i_pk.dtype == np.int64
    np.testing.assert_array_equal(d_pk, d_sp)
    # Indices agree up to ties; each index points at a point at that distance.
    q = queries if k == 1 else queries[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(pts[i_pk] - q, axis=-1), d_pk, rtol=0, atol=1e-15)


def test_a_missing_neighbour_reads_as_scipy_has_it():
    pts = _cloud(5)
    d, i = NeighbourIndex(pts, backend="pykdtree").query(pts[:2], k=8)
    d_sp, i_sp = NeighbourIndex(pts, backend="scipy").query(pts[:2], k=8)
    assert np.isinf(d[:, 5:]).all() and (i[:, 5:] == 5).all()
    np.testing.assert_array_equal(d, d_sp)
    np.testing.assert_array_equal(i[:, 5:], i_sp[:, 5:])


def test_fewer_threads_than_cores_go_to_scipy(monkeypatch):
    index = NeighbourIndex(_cloud())
    monkeypatch.setattr(knn, "_cores", lambda: 4)
    assert not index._use_pykdtree(1) and not index._use_pykdtree(3)
    assert index._use_pykdtree(-1) and index._use_pykdtree(4)
    monkeypatch.setattr(knn, "pykdtree_available", lambda: False)
    assert not index._use_pykdtree(-1)  # not installed: SciPy, the same answers


def test_an_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="backend must be 'auto', 'scipy' or 'pykdtree', got 'flann'"):
        NeighbourIndex(_cloud(), backend="flann")
