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
