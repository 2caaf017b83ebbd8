"""`pipeline.grids`: the set-up clock of `Shape` builders, and a shape's grid cache freed with it."""

import gc
import weakref

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from pipeline import grids
from pipeline import shape as S


def _clock(monkeypatch, ticks):
    """Replace the builders' clock by one that reads ``ticks`` (seconds) in turn; returns the
    list of reads so far."""
    reads = []

    def read():
        reads.append(ticks[len(reads)])
        return reads[-1]

    monkeypatch.setattr(grids.time, "perf_counter", read)
    return reads


def test_a_builder_inside_another_counts_once(monkeypatch):
    """A builder that runs inside another (a shape's patch boxes building its details) adds no
    time of its own: the outer one's 10 ms hold it, and the clock is read twice, not four times."""
    monkeypatch.setattr(grids.SetupClock, "ms", 0.0)
    reads = _clock(monkeypatch, [1.0, 1.010])

    @grids.timed
    def inner():
        return 2

    @grids.timed
    def outer():
        return inner() + inner()

    assert outer() == 4
    assert reads == [1.0, 1.010]
    assert grids.SetupClock.ms == pytest.approx(10.0, abs=1e-9)
    assert grids.SetupClock.open == 0


def test_a_builder_that_raises_inside_another_leaves_the_clock_counting(monkeypatch):
    """A nested builder that raises closes as it unwinds: the outer one's time is counted, and a
    builder after it counts its own."""
    monkeypatch.setattr(grids.SetupClock, "ms", 0.0)
    reads = _clock(monkeypatch, [0.0, 0.004, 0.5, 0.503])

    @grids.timed
    def inner():
        raise ValueError("no grid")

    @grids.timed
    def outer():
        try:
            inner()
        except ValueError:
            return "caught"

    @grids.timed
    def later():
        return "built"

    assert outer() == "caught" and later() == "built"
    assert len(reads) == 4
    assert grids.SetupClock.ms == pytest.approx(7.0, abs=1e-9)
    assert grids.SetupClock.open == 0


def test_a_dropped_shape_its_grids_and_sets_are_freed_without_the_cyclic_collector():
    """A `Shape` and its `GridCache` make no reference cycle: with the cyclic collector off, a
    shape that built grids, point sets and grid sets, and a child shape responded from it that
    reused them (`GridSet`'s ``like``, the parent's grids), are freed by reference counting as
    soon as they are dropped, their grids' arrays with them."""
    hs = H.from_grid(*shapes.sphere(10, 15), depth=2)
    moved = H.from_grid(*shapes.sphere(10, 15, radii=(1.0, 1.0, 1.1)), depth=2)
    patches = np.array([[0, 0], [1, 2], [2, 3]], np.int64)
    enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        parent = S.Shape(hs)
        parent.grids_for(patches)
        parent.cache.set_points(patches)
        found = tuple(range(6))
        parent.cache.gridset(found).nearest(np.zeros((1, 3)))
        child = S.Shape(moved, parent=parent)
        child.cache.gridset(found).nearest(np.zeros((1, 3)))
        assert child.cache.shape is child and parent.cache.shape is parent
        gone = [weakref.ref(x) for x in (parent, child, parent.cache, child.cache)]
        points = weakref.ref(parent.grids[(1, 2)].points.base if parent.grids[(1, 2)].points.base is not None
                             else parent.grids[(1, 2)].points)
        del parent, child
        assert [r() for r in gone] == [None] * 4
        assert points() is None
    finally:
        if enabled:
            gc.enable()
