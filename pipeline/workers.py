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
(`docs/farm.md`). The second thread is started for the two calls and joined before `both`
returns, so no thread outlives a frame: `pipeline.cli`'s fast exit (taken only where the main
thread is alone) and a fork after a frame (a Dask worker's process, a test) see one thread.

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

import contextvars
import threading
from typing import Any, Callable

__all__ = ["threads", "both"]


def threads() -> int:
    """The threads a frame may use: numba's ``NUMBA_NUM_THREADS`` (read at numba's import; the
    machine's cores unless set), at least 1."""
    from numba.core import config

    return max(1, int(config.NUMBA_NUM_THREADS))


def both(first: Callable[[], Any], second: Callable[[], Any]) -> tuple[Any, Any]:
    """``(first(), second())``: with two threads or more (`threads`), ``second`` in a thread of its
    own while ``first`` runs in the caller's, else one after the other. An exception of either
    is raised in the caller once both have ended (``first``'s if both raise)."""
    if threads() < 2:
        return first(), second()
    context = contextvars.copy_context()
    out: list = [None, None]  # second's answer, or its exception

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
