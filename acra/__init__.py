"""ACRA's algorithm: H-splines, the response and their compiled kernels (no USD, fcl or rerun).

Importing the package makes numba's cache loads of its kernels skip parsing their linkable
bitcode (`acra.kernelcache`).
"""

from acra import kernelcache as _kernelcache

_kernelcache.install()
