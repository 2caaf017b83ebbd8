"""Answers kept within one run: named, bounded tables that belong to the run, not to a module.

A frame asks many questions the frame before asked on the same content (a static object's
shape, a contact held still, the same solve), so modules keep recent answers by content or by
the identity of the objects they were taken of. Those tables live in a `Memo`, one per run:

* `pipeline.run.run_file` (and a farm part) computes inside ``with memo.scope():``, a memo of
  its own that is dropped, with everything it holds, when the run ends. Two runs in one process,
  or two in two threads of one process (a Dask worker with several threads), never see each
  other's answers.
* Outside a scope (a test or a benchmark calling the frame loop directly) the context has one
  memo, made on first use; `forget` empties it, so the next frames compute everything as the
  first frames of a fresh process do.

A module declares its table once, ``_ANSWERS = memo.Table("detect.answers")``: a handle whose
entries are the current memo's (a `contextvars.ContextVar` names the memo, so each thread and
each asyncio task sees its own, except a thread run in a copy of another's context, as a frame's
second thread is, `pipeline.workers`: the two share the run's tables, and an eviction tolerates
the other thread's changes, `_evict`). A table is an insertion-ordered ``dict`` behind the handle
(`Table.entries`); the handle answers the mapping operations the modules use, and `Table.kept`
is the common rule: the answer under a key, made if missing, the most recent ``size`` kept.

Every answer a table holds is what the computation would give again: keys hold the content's
bytes, or the identity of objects the entry keeps (or weakly references) so an ``id`` is never
mistaken for a later object's. So whether an answer is found or computed never changes a bit of
a run's output, only its time.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import Any, Callable, Iterator

__all__ = ["Memo", "Table", "current", "forget", "scope"]


class Memo:
    """The tables of one run: ``tables`` maps a table's name to its entries (a ``dict``, most
    recent last where its module keeps an order)."""

    __slots__ = ("tables",)

    def __init__(self) -> None:
        self.tables: dict[str, dict] = {}

    def clear(self) -> None:
        """Drop every entry of every table."""
        for entries in self.tables.values():
            entries.clear()


_CURRENT: contextvars.ContextVar[Memo] = contextvars.ContextVar("acra_memo")


def current() -> Memo:
    """The memo of the running scope, or the context's own (made on first use)."""
    try:
        return _CURRENT.get()
    except LookupError:
        memo = Memo()
        _CURRENT.set(memo)
        return memo


@contextlib.contextmanager
def scope() -> Iterator[Memo]:
    """A fresh `Memo` for the code inside the ``with`` block (a run); the memo before it is the
    current one again after the block, and the block's is dropped."""
    memo = Memo()
    token = _CURRENT.set(memo)
    try:
        yield memo
    finally:
        _CURRENT.reset(token)


def forget() -> None:
    """Empty every table of the current memo: what follows computes everything again, as a fresh
    run does."""
    current().clear()


class Table:
    """A module's handle on one named table of the current memo.

    Parameters
    ----------
    name : str
        Unique over the package (``"module.what"``); the key of the entries in `Memo.tables`.
    size : int or None
        What `kept` keeps by default: the most recent ``size`` entries (``None``: no bound; the
        module bounds the table itself, e.g. by dropping entries whose object died).
    """

    __slots__ = ("name", "size")

    _NAMES: set = set()

    def __init__(self, name: str, size: int | None = None) -> None:
        if name in Table._NAMES:
            raise ValueError(f"memo table {name!r} is declared twice")
        Table._NAMES.add(name)
        self.name = name
        self.size = size

    def __repr__(self) -> str:
        return f"memo.Table({self.name!r}, size={self.size})"

    def entries(self) -> dict:
        """The current memo's entries of this table (made empty on first use)."""
        try:
            memo = _CURRENT.get()
        except LookupError:
            memo = current()
        entries = memo.tables.get(self.name)
        if entries is None:  # one dict however many threads ask first (`setdefault` is atomic)
            entries = memo.tables.setdefault(self.name, {})
        return entries

    def kept(self, key: Any, make: Callable[[], Any], size: int | None = None) -> Any:
        """The entry under ``key``, made by ``make()`` if missing, moved to the most recent; the
        ``size`` (default: the table's) most recent entries are kept."""
        entries = self.entries()
        hit = entries.pop(key, None)
        if hit is None:
            hit = make()
        entries[key] = hit
        bound = self.size if size is None else size
        if bound is not None:
            _evict(entries, bound)
        return hit

    def trim(self, size: int | None = None) -> None:
        """Drop the oldest entries past ``size`` (default: the table's)."""
        _evict(self.entries(), self.size if size is None else size)

    # the mapping operations the modules use, on the current memo's entries
    def get(self, key: Any, default: Any = None) -> Any:
        return self.entries().get(key, default)

    def pop(self, key: Any, *default: Any) -> Any:
        return self.entries().pop(key, *default)

    def setdefault(self, key: Any, default: Any = None) -> Any:
        return self.entries().setdefault(key, default)

    def __getitem__(self, key: Any) -> Any:
        return self.entries()[key]

    def __setitem__(self, key: Any, value: Any) -> None:
        self.entries()[key] = value

    def __delitem__(self, key: Any) -> None:
        del self.entries()[key]

    def __contains__(self, key: Any) -> bool:
        return key in self.entries()

    def __len__(self) -> int:
        return len(self.entries())

    def __iter__(self) -> Iterator:
        return iter(self.entries())

    def keys(self):
        return self.entries().keys()

    def values(self):
        return self.entries().values()

    def items(self):
        return self.entries().items()

    def clear(self) -> None:
        self.entries().clear()


def _evict(entries: dict, bound: int) -> None:
    """Drop the oldest of ``entries`` until at most ``bound`` remain. A frame's second thread
    (`pipeline.workers`) shares the run's memo, so another thread may add or drop an entry
    between this one taking the table's iterator and its first key (``RuntimeError``), or drop
    that key first: the oldest key is taken again, and a key already gone is passed over."""
    while len(entries) > bound:
        try:
            oldest = next(iter(entries))
        except (RuntimeError, StopIteration):
            continue
        entries.pop(oldest, None)
