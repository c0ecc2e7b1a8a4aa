"""k nearest neighbours for the evaluation: pykdtree when it may use every core, SciPy otherwise.

The evaluation's heaviest neighbour queries (each cloud point's 8 nearest for the outlier
filter, the 17 nearest of a subsample for the point spacing, every surface sample's
nearest cloud point for coverage) cost about a third less CPU with ``pykdtree``
(OpenMP, the pytroll project's k-d tree) than with SciPy's ``cKDTree`` on a scan's cloud,
with the same distances to the last bit (a test compares them). pykdtree takes its thread
count from OpenMP (``OMP_NUM_THREADS``, default every core), not per call, so it is used
only when a query may use every core (``workers=-1`` or at least the cores); a query told
to use fewer threads, or a machine without pykdtree, goes to ``cKDTree`` with ``workers``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from plantsim._cores import usable_cores as _cores

__all__ = ["NeighbourIndex", "pykdtree_available"]

# pykdtree marks a missing neighbour (k larger than the points) by these.
_PK_MISSING_DIST = 1e150


def pykdtree_available() -> bool:
    """Whether ``pykdtree`` can be imported."""
    try:
        import pykdtree.kdtree  # noqa: F401
    except ImportError:
        return False
    return True


class NeighbourIndex:
    """A k-d tree of (n, 3) points whose ``query`` answers as ``cKDTree.query`` does.

    Args:
        points: (n, 3) float64, any frame and units; n >= 1.
        backend: "auto" (pykdtree where a query may use every core), "scipy" or "pykdtree".

    Raises:
        ValueError: an unknown backend, or "pykdtree" without it installed.
    """

    def __init__(self, points: np.ndarray, *, backend: str = "auto") -> None:
        if backend not in ("auto", "scipy", "pykdtree"):
            raise ValueError(f"backend must be 'auto', 'scipy' or 'pykdtree', got {backend!r}")
        if backend == "pykdtree" and not pykdtree_available():
            raise ValueError("backend='pykdtree' needs pykdtree: pip install pykdtree")
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.n = len(self.points)
        self.backend = backend
        self._scipy: cKDTree | None = None
        self._pk = None

    @property
    def scipy_tree(self) -> cKDTree:
        """SciPy's tree of the same points (built on first use), for the queries pykdtree lacks."""
        if self._scipy is None:
            self._scipy = cKDTree(self.points)
        return self._scipy

    def _use_pykdtree(self, workers: int) -> bool:
        if self.backend == "scipy":
            return False
        if self.backend == "pykdtree":
            return True
        return (workers == -1 or workers >= _cores()) and pykdtree_available()

    def query(self, queries: np.ndarray, k: int = 1, *, workers: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the ``k`` nearest points, nearest first.

        Args:
            queries: (m, 3) float64.
            k: neighbours (>= 1).
            workers: threads (-1: every core).

        Returns:
            (m,) float64 and (m,) int64 for ``k == 1``, else (m, k) each; a missing
            neighbour (``k > n``) has distance inf and index n, as SciPy gives.
        """
        q = np.ascontiguousarray(queries, dtype=np.float64)
        if not self._use_pykdtree(workers):
            return self.scipy_tree.query(q, k=k, workers=workers)
        if self._pk is None:
            from pykdtree.kdtree import KDTree

            self._pk = KDTree(self.points)
        dist, idx = self._pk.query(q, k=k)
        idx = idx.astype(np.int64)
        missing = dist >= _PK_MISSING_DIST
        if missing.any():
            dist = np.where(missing, np.inf, dist)
            idx[missing] = self.n
        return dist, idx
