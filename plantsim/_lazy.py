"""Modules loaded on first use, so that a run pays only for what it uses.

``mujoco = lazy_module("mujoco")`` at the top of a module binds a module object
whose code runs on its first attribute access (:class:`importlib.util.LazyLoader`,
the standard library's lazy import). A kinematic scan cast with Embree never
touches MuJoCo, and so never loads it (about 0.1 s); everything else that
imports ``mujoco`` gets the same module, loaded when first used.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_module(name: str) -> ModuleType:
    """The module ``name``, imported now if it is already loaded, else on its first attribute access.

    Raises:
      ModuleNotFoundError: ``name`` is not installed (found out now, not on first use).
    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)
    spec.loader = importlib.util.LazyLoader(spec.loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def is_loaded(name: str) -> bool:
    """Whether ``name``'s code has run (a lazy module that nothing has used yet has not)."""
    module = sys.modules.get(name)
    if module is None:
        return False
    lazy_type = getattr(importlib.util, "_LazyModule", ())  # the class a lazy module has until it runs
    return not isinstance(module, lazy_type)


class LazyGenerator:
    """``numpy.random.default_rng(seed)``, made on first use.

    ``numpy.random`` costs about 10 ms to import; a scan with a perfect sensor and
    turntable draws no random number and so never loads it. Every attribute is the
    generator's own (``rng.normal``, ``rng.bit_generator``...), and the stream is the
    one ``default_rng(seed)`` gives, whenever the first draw happens.
    """

    __slots__ = ("_seed", "_generator")

    def __init__(self, seed: int | None) -> None:
        self._seed = seed
        self._generator = None

    @property
    def generator(self):
        """The ``numpy.random.Generator`` itself (made now if it was not yet)."""
        if self._generator is None:
            import numpy as np

            self._generator = np.random.default_rng(self._seed)
        return self._generator

    def __getattr__(self, name: str):
        return getattr(self.generator, name)
