"""scipy's kd-tree (``cKDTree``) and convex hull (``ConvexHull``, ``QhullError``), loaded without
the ``scipy.spatial`` package's ``__init__``.

``import scipy.spatial`` (or any of its submodules) first runs the package's ``__init__``, which
imports every part of the package: the rotations, distance metrics and spherical interpolation
bring in ``scipy.special``, the Delaunay and Voronoi wrappers more. The pipeline uses two classes
of two compiled modules, ``scipy.spatial._ckdtree`` and ``scipy.spatial._qhull``; this module
loads those extension modules from their files under their own names in ``sys.modules``, so
they are the same modules (and classes) a later ``import scipy.spatial`` finds and binds: every
answer is scipy's own. Measured after numpy, numba and pxr (dog_head_spike's imports, CPU
seconds, 3 alternated processes): 0.17-0.19 loading the two against 0.27-0.30 importing the
package. A scipy whose layout differs (a module not found, or not loadable alone) gets the
package import instead.

What those two modules import is trimmed the same way. ``_qhull`` needs LAPACK's Cython table,
``scipy.linalg.cython_lapack``, and numba's first kernel load imports it and BLAS's
(``cython_blas``): both are loaded from their files too, and the ``scipy.linalg`` package that
holds them is a lazy module whose ``__init__`` runs at its first use (about 0.13 s). ``_ckdtree`` imports ``scipy._lib._util``, whose array-API
layer copies numpy's namespace attribute by attribute and so would import ``numpy.f2py`` (with
``charset_normalizer``) and ``numpy.testing``, which no run calls (about 0.11 s): those two are
set up as lazy modules first (`importlib.util.LazyLoader`), which run their own code at the first
use of one of their attributes, so a later caller gets numpy's modules. ``_ckdtree`` also imports
``scipy.sparse``, for the sparse-matrix outputs of ``sparse_distance_matrix`` that no run asks
for: it is an `_Unrun` module, whose code runs at its first use (about 0.04 s CPU otherwise).
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
import types

import numpy  # noqa: F401  (the parent of the lazy submodules `_deferred` sets up)

__all__ = ["ConvexHull", "QhullError", "cKDTree"]

# numpy's submodules that scipy's array-API layer touches while it copies numpy's namespace and
# no run calls: each loads at its first attribute access instead of at import
_COPIED_UNUSED = ("numpy.f2py", "numpy.testing")

# LAPACK's and BLAS's Cython tables: _qhull calls the first, and numba's first kernel load imports
# both (`numba.np.linalg.ensure_blas`) to bind the compiled kernels' linear algebra; loaded from
# their files, with the scipy.linalg package a lazy module that runs its __init__ at first use
_LAPACK = ("scipy.linalg.cython_lapack", "scipy.linalg.cython_blas")


class _Unrun(types.ModuleType):
    """A package module whose code has not run: reading its ``__spec__`` leaves it so (a compiled
    module's ``import`` of it checks only that the package is not half-initialised), any other
    attribute runs its code into this same object, which from then on is a plain module.
    `importlib.util.LazyLoader` runs the code at ``__spec__`` too, so a Cython ``import`` of the
    package would run it at once."""

    def __getattribute__(self, attr):
        if attr == "__spec__":
            return types.ModuleType.__getattribute__(self, attr)
        spec = types.ModuleType.__getattribute__(self, "__spec__")
        types.ModuleType.__setattr__(self, "__class__", types.ModuleType)
        try:
            spec.loader.exec_module(self)
        except BaseException:
            sys.modules.pop(spec.name, None)
            raise
        return getattr(self, attr)


def _unrun(name: str) -> None:
    """Put ``name`` (``scipy.sparse``), unless imported already, in ``sys.modules`` and on its
    parent as an `_Unrun` module: a compiled module that imports it without calling into it leaves
    its code unrun; the first use of it, or a later ``import`` of it that binds one of its names,
    runs it as the package's own module."""
    if name in sys.modules:
        return
    spec = importlib.util.find_spec(name)
    if spec is None or not hasattr(spec.loader, "exec_module"):
        return
    module = importlib.util.module_from_spec(spec)
    module.__class__ = _Unrun
    sys.modules[name] = module
    parent, _, leaf = name.rpartition(".")
    setattr(sys.modules[parent], leaf, module)


def _deferred(name: str, children: tuple = ()) -> None:
    """Put a lazy module for ``name`` (``numpy.f2py``) in ``sys.modules`` and on its parent
    package, unless imported already: its code runs at the first access of one of its attributes
    (or at a later ``import`` of it), so it is then the package's own module. ``children``: its
    submodules loaded already (`_compiled`), bound as its attributes as an import would bind them."""
    if name in sys.modules:
        return
    spec = importlib.util.find_spec(name)
    if spec is None or not hasattr(spec.loader, "exec_module"):
        return
    spec.loader = importlib.util.LazyLoader(spec.loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    for child in children:
        setattr(module, child.__name__.rpartition(".")[2], child)  # kept when the module runs
    parent, _, leaf = name.rpartition(".")
    setattr(sys.modules[parent], leaf, module)


def _compiled(name: str):
    """The extension module ``name`` (``scipy.spatial._ckdtree``): the one in ``sys.modules`` if
    imported, else loaded from its file with its parent package left unimported; ``None`` if
    there is no such file."""
    if name in sys.modules:
        return sys.modules[name]
    parent, _, leaf = name.rpartition(".")
    spec = importlib.util.find_spec(parent)  # finds the package's directory without running it
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = os.path.join(folder, leaf + suffix)
            if os.path.isfile(path):
                found = importlib.util.spec_from_file_location(name, path)
                module = importlib.util.module_from_spec(found)
                sys.modules[name] = module
                try:
                    found.loader.exec_module(module)
                except BaseException:
                    del sys.modules[name]
                    raise
                return module
    return None


def _classes() -> tuple:
    """``(cKDTree, ConvexHull, QhullError)``, from the compiled modules or else the package."""
    try:
        for name in _COPIED_UNUSED:
            _deferred(name)
        tables = tuple(_compiled(name) for name in _LAPACK)
        if all(t is not None for t in tables):  # the package, lazy, holds them as its attributes
            _deferred("scipy.linalg", tables)
        _unrun("scipy.sparse")  # _ckdtree imports it for its sparse-matrix outputs, which no run asks for
        kdtree, qhull = _compiled("scipy.spatial._ckdtree"), _compiled("scipy.spatial._qhull")
        if kdtree is not None and qhull is not None:
            return kdtree.cKDTree, qhull.ConvexHull, qhull.QhullError
    except (ImportError, AttributeError):
        pass
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    return cKDTree, ConvexHull, QhullError


cKDTree, ConvexHull, QhullError = _classes()
