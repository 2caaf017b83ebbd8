"""acra.memo: tables of answers owned by a run."""

import threading

import pytest

from acra import memo


def _table(name: str, size: int | None = 3) -> memo.Table:
    """A table of its own name for one test (names are unique over the process)."""
    return memo.Table(f"test_memo.{name}", size)


def test_kept_makes_once_and_keeps_the_most_recent():
    """`Table.kept` calls ``make`` only for a missing key; a hit moves to the most recent; past
    the size the least recently used goes first."""
    t = _table("kept")
    made = []

    def make(k):
        return lambda: made.append(k) or k * 10

    with memo.scope():
        assert [t.kept(k, make(k)) for k in (1, 2, 3)] == [10, 20, 30]
        assert t.kept(1, make(1)) == 10  # a hit: not made again, now the most recent
        assert t.kept(4, make(4)) == 40  # 2 is the least recently used
        assert made == [1, 2, 3, 4]
        assert list(t) == [3, 1, 4] and len(t) == 3 and 2 not in t
        assert t.kept(2, make(2), size=1) == 20 and list(t) == [2]  # an explicit bound


def test_trim_and_mapping_operations():
    """The handle's mapping operations act on the current memo's entries; `trim` drops the oldest."""
    t = _table("mapping", 2)
    with memo.scope() as m:
        t["a"], t["b"], t["c"] = 1, 2, 3
        assert m.tables["test_memo.mapping"] == {"a": 1, "b": 2, "c": 3}
        t.trim()
        assert dict(t.items()) == {"b": 2, "c": 3} and list(t.keys()) == ["b", "c"] and list(t.values()) == [2, 3]
        assert t.get("a") is None and t.get("a", 0) == 0 and t["b"] == 2
        assert t.pop("b") == 2 and t.pop("b", None) is None
        assert t.setdefault("d", 4) == 4 and t.setdefault("d", 5) == 4
        del t["c"]
        assert t.entries() == {"d": 4}
        t.clear()
        assert not len(t)
        with pytest.raises(KeyError):
            t["missing"]


def test_scope_is_fresh_and_restores_the_one_before():
    """A scope starts with no entries and hides the outer memo's; after it (even left by an
    exception) the outer entries are the current ones again; `forget` empties the current only."""
    t = _table("scope")
    with memo.scope():
        t["outer"] = 1
        with memo.scope():
            assert "outer" not in t and not len(t)
            t["inner"] = 2
        assert dict(t.items()) == {"outer": 1}
        with pytest.raises(RuntimeError), memo.scope():
            t["thrown"] = 3
            raise RuntimeError
        assert dict(t.items()) == {"outer": 1}
        with memo.scope():
            t["inner"] = 2
            memo.forget()
            assert not len(t)
        assert dict(t.items()) == {"outer": 1}


def test_threads_see_their_own_memo():
    """Each thread's context has its own memo: an answer kept in one is not served in another."""
    t = _table("threads")
    t.clear()
    t["main"] = 0
    seen = {}

    def work(name):
        seen[name] = dict(t.items())
        t[name] = 1
        seen[name + " after"] = dict(t.items())

    threads = [threading.Thread(target=work, args=(n,)) for n in ("a", "b")]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert seen == {"a": {}, "a after": {"a": 1}, "b": {}, "b after": {"b": 1}}
    assert dict(t.items()) == {"main": 0}
    t.clear()


def test_a_name_is_declared_once():
    """Two tables of one name would share entries: the second declaration is refused."""
    _table("twice")
    with pytest.raises(ValueError, match="test_memo.twice"):
        _table("twice")


def test_two_threads_sharing_a_memo_keep_its_bound_and_raise_nothing():
    """A frame's second thread runs in a copy of the caller's context (`pipeline.workers`), so
    both threads read and write the run's tables: evictions racing each other must neither raise
    nor leave a table past its bound."""
    import contextvars
    import sys

    errors: list = []

    def hammer(seed: int) -> None:
        try:
            for i in range(40_000):
                _SHARED.kept((seed, i % 7), lambda: i)
                if i % 5 == 0:
                    _SHARED.trim(2)
        except Exception as exc:  # reported below, in the test's thread
            errors.append(repr(exc))

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # hand the GIL over as often as the interpreter allows
    try:
        with memo.scope():
            threads = [threading.Thread(target=contextvars.copy_context().run, args=(hammer, s)) for s in range(2)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert errors == []
            assert len(_SHARED) <= 4
    finally:
        sys.setswitchinterval(interval)


_SHARED = memo.Table("test_memo.shared", 4)
