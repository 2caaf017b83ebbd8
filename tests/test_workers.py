"""pipeline.workers: two independent calls side by side, as if one after the other."""

import contextvars
import threading

import pytest
from numba.core import config

from pipeline import workers

_NAME = contextvars.ContextVar("name")


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_both_gives_the_two_answers_in_order_and_leaves_one_thread(monkeypatch, threads):
    """With one thread both calls run in the caller's thread; with more the second runs in a
    thread of its own, in the caller's context, joined before `both` returns."""
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", threads)
    assert workers.threads() == threads
    _NAME.set("caller")
    before = threading.active_count()
    caller = threading.get_ident()
    a, b = workers.both(lambda: (threading.get_ident(), _NAME.get()), lambda: (threading.get_ident(), _NAME.get()))
    assert a == (caller, "caller") and b[1] == "caller"
    assert (b[0] == caller) == (threads == 1)
    assert threading.active_count() == before


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("which", ["first", "second", "both"])
def test_an_exception_of_either_call_is_raised_in_the_caller(monkeypatch, threads, which):
    """The first call's exception where both raise; no thread is left behind either way."""
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", threads)
    before = threading.active_count()
    ran = []

    def call(name):
        def f():
            ran.append(name)
            if which in (name, "both"):
                raise ValueError(name)
            return name
        return f

    with pytest.raises(ValueError, match="first" if which == "both" else which):
        workers.both(call("first"), call("second"))
    assert threading.active_count() == before
    assert "first" in ran and ("second" in ran or threads == 1)


def test_no_thread_count_below_one(monkeypatch):
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 0)
    assert workers.threads() == 1


def test_a_kept_block_hands_every_second_call_to_one_parked_thread(monkeypatch):
    """Inside `workers.kept` the second calls all run in one thread, not the caller's, in the
    caller's context, with the answers and exceptions `both` gives without the block; the
    thread is ended with the block."""
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 2)
    _NAME.set("caller")
    before = threading.active_count()
    caller = threading.get_ident()
    seconds = set()
    with workers.kept():
        for n in range(5):
            a, b = workers.both(lambda n=n: (n, threading.get_ident()), lambda n=n: (-n, threading.get_ident(), _NAME.get()))
            assert a == (n, caller) and b[0] == -n and b[2] == "caller"
            seconds.add(b[1])
        assert threading.active_count() == before + 1
        with pytest.raises(ValueError, match="second"):
            workers.both(lambda: 1, lambda: (_ for _ in ()).throw(ValueError("second")))
        with pytest.raises(ValueError, match="first"):
            workers.both(lambda: (_ for _ in ()).throw(ValueError("first")), lambda: (_ for _ in ()).throw(ValueError("second")))
        assert workers.both(lambda: "a", lambda: "b") == ("a", "b")  # usable after an exception
    assert len(seconds) == 1 and caller not in seconds
    assert threading.active_count() == before


def test_a_both_inside_a_kept_blocks_call_starts_a_thread_of_its_own(monkeypatch):
    """A `both` inside ``first`` (the parked thread busy), inside ``second`` (another thread)
    or in a forked child (another process) does not use the block's thread; the answers are
    the same."""
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 2)
    before = threading.active_count()

    def inner():
        return workers.both(lambda: "x", lambda: "y")

    with workers.kept():
        assert workers.both(inner, inner) == (("x", "y"), ("x", "y"))
        assert workers.both(lambda: 0, lambda: 1) == (0, 1)
        parked = workers._parked()
        parked.pid = -1  # as a forked child sees it
        assert workers._parked() is None and workers.both(lambda: 2, lambda: 3) == (2, 3)
        parked.pid = workers.os.getpid()
    assert threading.active_count() == before


def test_one_thread_makes_no_parked_thread(monkeypatch):
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 1)
    before = threading.active_count()
    with workers.kept():
        assert workers.both(lambda: threading.active_count(), lambda: threading.active_count()) == (before, before)
    assert threading.active_count() == before
