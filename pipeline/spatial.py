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
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys

__all__ = ["ConvexHull", "QhullError", "cKDTree"]


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
        kdtree, qhull = _compiled("scipy.spatial._ckdtree"), _compiled("scipy.spatial._qhull")
        if kdtree is not None and qhull is not None:
            return kdtree.cKDTree, qhull.ConvexHull, qhull.QhullError
    except (ImportError, AttributeError):
        pass
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    return cKDTree, ConvexHull, QhullError


cKDTree, ConvexHull, QhullError = _classes()
