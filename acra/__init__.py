"""ACRA's algorithm: H-splines, the response and their compiled kernels (no USD, fcl or rerun).

Importing the package makes numba's cache loads of its kernels skip parsing their linkable
bitcode (`acra.kernelcache`).

numba's configuration imports PyYAML only to read a ``.numba_config.yaml`` in the working
directory; where there is none when numba is first imported here, the import is skipped (PyYAML
is 20 ms CPU of a process's start) and PyYAML stays importable for everything else.
"""

import os as _os
import sys as _sys


def _import_numba() -> None:
    """Import numba's configuration, without PyYAML where no ``.numba_config.yaml`` is here."""
    if "numba" in _sys.modules or "yaml" in _sys.modules or _os.path.isfile(".numba_config.yaml"):
        return
    _sys.modules["yaml"] = None  # numba's optional `import yaml` then fails at once
    try:
        import numba.core.config  # noqa: F401
    finally:
        del _sys.modules["yaml"]


_import_numba()

from acra import kernelcache as _kernelcache  # noqa: E402

_kernelcache.install()
