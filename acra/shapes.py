"""Constructors of level-0 control grids for common objects (kept apart from the spline type).

Every function returns ``cvs : (nu, nv, 3) float64`` plus the wraps, ready for
`acra.hspline.from_grid`. Closed objects follow the conventions of acra-notes §1:

* a **sphere** wraps in u and is open in v; at each pole the second row of CVs collapses to the
  pole point and the first row is the third row turned half a revolution, so every meridian
  runs straight over the pole: the surface closes at the pole with a tangent plane there
  (``du`` vanishes at the pole, so its normal is a limit, `acra.hspline.surface_normals`);
* a **torus** wraps in both directions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sheet", "sphere", "torus", "tube"]


def sheet(nu: int, nv: int, width: float = 1.0, depth: float = 1.0, height: np.ndarray | None = None):
    """An open rectangular sheet in the xy-plane, centred at the origin, facing +z.

    The *surface* (not the control net) spans ``width × depth``: an open uniform B-spline with
    ``n`` CVs covers the middle ``n - 3`` CV spacings, so the net extends one spacing beyond.

    Parameters
    ----------
    height : (nu, nv) float64, optional
        z of each CV.

    Returns
    -------
    cvs : (nu, nv, 3) float64, u_periodic False, v_periodic False
    """
    x = (np.arange(nu) - 1.0) / (nu - 3) * width - width / 2.0
    y = (np.arange(nv) - 1.0) / (nv - 3) * depth - depth / 2.0
    xx, yy = np.meshgrid(x, y, indexing="ij")
    zz = np.zeros_like(xx) if height is None else np.asarray(height, dtype=np.float64)
    return np.stack([xx, yy, zz], axis=-1), False, False


def _ring_scale(n: int) -> float:
    """Radius of a periodic cubic B-spline control polygon whose curve has radius ~1.

    A regular n-gon of CVs with radius ``r`` gives a curve whose radius at the CVs' centres is
    ``r (4 + 2 cos(2π/n)) / 6``; scaling by the inverse makes the curve pass through radius 1 there.
    """
    return 6.0 / (4.0 + 2.0 * np.cos(2.0 * np.pi / n))


def sphere(nu: int = 8, nv: int = 8, radii=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)):
    """A closed ellipsoid: periodic in u (around z), open in v (south to north pole).

    Parameters
    ----------
    nu : int
        CVs around (even, at least 4), so the half-turn reflection at the poles is a CV.
    nv : int
        CVs from pole to pole (at least 5): rows ``1`` and ``nv - 2`` are the poles.

    Returns
    -------
    cvs : (nu, nv, 3) float64, u_periodic True, v_periodic False
    """
    if nu % 2 or nu < 4:
        raise ValueError(f"a sphere needs an even number of CVs around, at least 4; got {nu}")
    if nv < 5:
        raise ValueError(f"a sphere needs at least 5 CVs from pole to pole, got {nv}")
    theta = 2.0 * np.pi * np.arange(nu) / nu
    # latitudes of rows 1..nv-2 from -pi/2 to pi/2; rows 0 and nv-1 mirror rows 2 and nv-3
    phi = np.linspace(-np.pi / 2.0, np.pi / 2.0, nv - 2)
    ring = _ring_scale(nu)
    # meridian control polygon: scale so the meridian curve roughly passes through the sphere
    mer = 6.0 / (4.0 + 2.0 * np.cos(np.pi / (nv - 3)))
    cvs = np.zeros((nu, nv, 3))
    for jj, p in enumerate(phi, start=1):
        r = np.cos(p) * ring * mer
        z = np.sin(p) * mer
        if jj in (1, nv - 2):
            r = 0.0
        cvs[:, jj, 0] = r * np.cos(theta)
        cvs[:, jj, 1] = r * np.sin(theta)
        cvs[:, jj, 2] = z
    half = np.roll(np.arange(nu), nu // 2)
    cvs[:, 0] = cvs[half, 2]
    cvs[:, nv - 1] = cvs[half, nv - 3]
    # the surface pole is (R0 + 4 R1 + R2) / 6: place the pole CV so it lands at z = -1 / +1
    cvs[:, 1, 2] = (-6.0 - 2.0 * cvs[0, 2, 2]) / 4.0
    cvs[:, nv - 2, 2] = (6.0 - 2.0 * cvs[0, nv - 3, 2]) / 4.0
    cvs *= np.asarray(radii, dtype=np.float64)
    cvs += np.asarray(center, dtype=np.float64)
    return cvs, True, False


def torus(nu: int = 12, nv: int = 8, major: float = 1.0, minor: float = 0.35, center=(0.0, 0.0, 0.0)):
    """A torus around z: u runs around the major circle, v around the tube; both periodic.

    Returns
    -------
    cvs : (nu, nv, 3) float64, u_periodic True, v_periodic True
    """
    a = 2.0 * np.pi * np.arange(nu) / nu
    b = 2.0 * np.pi * np.arange(nv) / nv
    rs = _ring_scale(nv) * minor
    aa, bb = np.meshgrid(a, b, indexing="ij")
    rad = (major + rs * np.cos(bb)) * _ring_scale(nu)
    cvs = np.stack([rad * np.cos(aa), rad * np.sin(aa), rs * np.sin(bb)], axis=-1)
    return cvs + np.asarray(center, dtype=np.float64), True, True


def tube(nu: int = 8, nv: int = 8, radius: float = 0.5, length: float = 2.0, center=(0.0, 0.0, 0.0)):
    """An open-ended cylinder along z: periodic in u (around), open in v (along).

    Returns
    -------
    cvs : (nu, nv, 3) float64, u_periodic True, v_periodic False
    """
    a = 2.0 * np.pi * np.arange(nu) / nu
    z = (np.arange(nv) - 1.0) / (nv - 3) * length - length / 2.0
    aa, zz = np.meshgrid(a, z, indexing="ij")
    r = radius * _ring_scale(nu)
    cvs = np.stack([r * np.cos(aa), r * np.sin(aa), zz], axis=-1)
    return cvs + np.asarray(center, dtype=np.float64), True, False
