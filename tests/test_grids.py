"""`pipeline.grids`: the set-up clock of `Shape` builders."""

import pytest

from pipeline import grids


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
