"""Shared, seeded test objects."""

from dataclasses import replace

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes


def wavy_sheet(nu=8, nv=7, depth=4, seed=0):
    rng = np.random.default_rng(seed)
    cvs, pu, pv = shapes.sheet(nu, nv, width=nu - 3.0, depth=nv - 3.0, height=0.3 * rng.normal(size=(nu, nv)))
    return H.from_grid(cvs, pu, pv, depth=depth)


def with_random_offsets(hs, scale=0.05, seed=1):
    rng = np.random.default_rng(seed)
    for k in range(1, hs.depth):
        idx, off = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, idx, scale * rng.normal(size=off.shape))
    return hs


def nudged(hs, level, rng, cv=None, scale=0.05):
    """``hs`` with one CV moved by a normal step of ``scale``: on level 0 the CV ``cv`` (a random
    one if omitted), on a finer level a random offset of ``level``."""
    if level == 0:
        cvs = hs.cvs.copy()
        i, j = cv if cv is not None else (int(rng.integers(0, cvs.shape[0])), int(rng.integers(0, cvs.shape[1])))
        cvs[i, j] += rng.normal(scale=scale, size=3)
        return replace(hs, cvs=cvs)
    idx, off = H.offsets_of(hs, level)
    off = off.copy()
    off[int(rng.integers(0, len(off)))] += rng.normal(scale=scale, size=3)
    return H.set_offsets(hs, level, idx, off)


@pytest.fixture
def sheet4():
    return wavy_sheet()


# --- scenes: each scene file runs once per test session, through the same code as `acra run` ----

SCENES = __import__("pathlib").Path(__file__).resolve().parents[1] / "scenes"
_scene_runs: dict = {}


def scene_names() -> list[str]:
    """Every scene file in ``scenes/`` (each is run as a test)."""
    return sorted(p.stem for p in SCENES.glob("*.py") if not p.stem.startswith("_"))


@pytest.fixture(scope="session")
def run_scene(tmp_path_factory):
    """``run_scene(name)`` → RunReport (``.output``, ``.stats``, ``.scene``), run once per session.

    The scene file is copied to a temporary directory first, so a test run never writes into the
    repository; the Rerun recording goes beside it as ``NAME.rrd``.
    """
    import shutil

    from pipeline.cli import run_file

    def run(name: str):
        if name not in _scene_runs:
            d = tmp_path_factory.mktemp(name)
            shutil.copy(SCENES / f"{name}.py", d / f"{name}.py")
            _scene_runs[name] = run_file(d / f"{name}.py", rrd=d / f"{name}.rrd")
        return _scene_runs[name]

    return run
