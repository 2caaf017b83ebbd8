"""The machine's second core within a frame: two independent calls side by side.

A collision frame's work is a chain of Python and numpy glue between compiled kernels, and the
kernels (`acra.depthbound`, `acra.bvh`, `acra.pseudonormals`, `acra.meshrows`, ...) are compiled
``nogil=True``: while one thread is inside a kernel, another can run Python or a kernel of its
own. `both` runs two calls that share no state they write, the second in a thread of its own,
and returns their answers as if they had run one after the other: each answer is a function of
its call's inputs alone, so the bits do not depend on how the two interleave.

The number of threads a frame may use is numba's own setting, ``NUMBA_NUM_THREADS`` (numba's
default: the machine's cores). A farm running one process per core sets ``NUMBA_NUM_THREADS=1``
and every call runs in the caller's thread, one after the other, as without this module
(`docs/farm.md`). Within a `kept` block (a run, `pipeline.run.run_file`; a frame loop,
`pipeline.frames.respond_frames`) the second calls go to one thread parked between them, made
at the block's first call and joined when the block ends; outside one, `both` starts a thread
for its call and joins it before it returns. So no thread outlives a run or a frame loop:
`pipeline.cli`'s fast exit (taken only where the main thread is alone) and a fork after a run
(a Dask worker's process, a test) see one thread, and a process forked within a block (whose
child has no parked thread) starts a thread per call there.

The second call runs in a copy of the caller's `contextvars` context: the run's memo
(`acra.memo.scope`) and numpy's error state (a context variable) are the caller's. A memo
table is a plain ``dict``: an entry added or an eviction (`acra.memo._evict`, which tolerates
the other thread's changes) is safe from either thread, but an entry both calls would make is
made first, in the caller's thread (`pipeline.residual.measure_frame`), so it is made once and
the tables hold their entries in the order one thread gives. Where the two calls would each add
entries (a round's two displays, `pipeline.display.Displays.build`), each call writes no shared
table: the caller plans both first, in order, and adds each call's entries after both have
ended, in the order one thread would have added them.

What runs side by side: a closed pair's two sides (`pipeline.residual.measure_frame`), a
round's two deformables' displays (`pipeline.display.Displays.build`, from
`pipeline.frames._Run.visible`) and, at the end of a run, a ``.usda`` layer's array texts
(`pipeline.output_layer._SharedText`, through `acra.floattext.tuples_texts`: two sides of whole
attributes' chains of samples, each text made from its own array and the text of the sample
before it alone, into its own slot of a list).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import threading
from typing import Any, Callable, Iterator

__all__ = ["both", "kept", "threads"]


def threads() -> int:
    """The threads a frame may use: numba's ``NUMBA_NUM_THREADS`` (read at numba's import; the
    machine's cores unless set), at least 1."""
    from numba.core import config

    return max(1, int(config.NUMBA_NUM_THREADS))


class _Second:
    """One parked thread that runs the second calls of `both` for the thread that made it.

    Starting a thread for each call costs about 0.15 ms CPU (its stack, its interpreter state,
    the wait for it to run); a parked thread is handed a call through two locks for about a
    third of that. ``go`` is released to hand it a call (``job``: a context and a callable;
    None ends the thread), ``done`` by the thread once the call's answer or exception is in
    ``out``. ``owner`` is the thread that may hand it calls, ``pid`` the process it runs in
    (after a fork the child has no such thread), ``busy`` whether a call is under way (a
    `both` inside a ``first`` starts a thread of its own)."""

    __slots__ = ("busy", "done", "go", "job", "out", "owner", "pid", "thread")

    def __init__(self) -> None:
        self.go, self.done = threading.Lock(), threading.Lock()
        self.go.acquire()
        self.done.acquire()
        self.job: tuple | None = None
        self.out: list = [None, None]  # the call's answer, or its exception
        self.owner, self.pid, self.busy = threading.get_ident(), os.getpid(), False
        self.thread = threading.Thread(target=self._loop, name="acra-second-core", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while True:
            self.go.acquire()
            job = self.job
            if job is None:
                return
            self.job = None
            try:
                self.out[0] = job[0].run(job[1])
            except BaseException as exc:  # raised in the owner's thread by `both`
                self.out[1] = exc
            self.done.release()

    def usable(self) -> bool:
        """Whether the calling thread may hand this thread a call now."""
        return not self.busy and self.owner == threading.get_ident() and self.pid == os.getpid()

    def close(self) -> None:
        """End the thread and wait for it (nothing to do in a forked child, which has none)."""
        if self.pid == os.getpid():
            self.job = None
            self.go.release()
            self.thread.join()


# the current `kept` block: the thread that opened it and its parked thread once made (``[]``
# until then); None outside a block
_KEPT: contextvars.ContextVar[tuple[int, list] | None] = contextvars.ContextVar("acra_second_core", default=None)


@contextlib.contextmanager
def kept() -> Iterator[None]:
    """Inside the block (a run, `pipeline.run.run_file`; a frame loop, `pipeline.frames.respond_frames`,
    which a farm chunk runs)
    `both` hands its second calls to one parked thread, made at the first such call and ended
    with the block, instead of a thread started for each call: a run's collision frames make two
    such calls each. The thread is joined before the block ends, so no thread outlives the run."""
    block = _KEPT.get()
    if block is not None and block[0] == threading.get_ident():  # a block inside a block keeps the outer one's
        yield
        return
    holder: list = []
    token = _KEPT.set((threading.get_ident(), holder))
    try:
        yield
    finally:
        _KEPT.reset(token)
        for parked in holder:
            parked.close()


def _parked() -> _Second | None:
    """The current `kept` block's parked thread, made on first use, where the caller may hand it
    a call now (`_Second.usable`); else None."""
    block = _KEPT.get()
    if block is None or block[0] != threading.get_ident():
        return None
    holder = block[1]
    if not holder:
        holder.append(_Second())
    return holder[0] if holder[0].usable() else None


def both(first: Callable[[], Any], second: Callable[[], Any]) -> tuple[Any, Any]:
    """``(first(), second())``: with two threads or more (`threads`), ``second`` in a thread of its
    own while ``first`` runs in the caller's, else one after the other. An exception of either
    is raised in the caller once both have ended (``first``'s if both raise). Inside a `kept`
    block the thread is the block's parked one, else one started for the call."""
    if threads() < 2:
        return first(), second()
    context = contextvars.copy_context()
    parked = _parked()
    if parked is not None:
        parked.busy, parked.out = True, [None, None]
        parked.job = (context, second)
        parked.go.release()
        try:
            a = first()
        finally:
            parked.done.acquire()
            parked.busy = False
        out = parked.out
    else:
        out = [None, None]  # second's answer, or its exception

        def run() -> None:
            try:
                out[0] = context.run(second)
            except BaseException as exc:  # raised in the caller's thread below
                out[1] = exc

        worker = threading.Thread(target=run, name="acra-second-core", daemon=True)
        worker.start()
        try:
            a = first()
        finally:
            worker.join()
    if out[1] is not None:
        raise out[1]
    return a, out[0]
