"""What the call-replay benchmarks share (`closest_calls.py`, `signed_calls.py`): the command line,
recording one function's calls over a run's frames, timing their replay and printing the line;
and the CPU time spent inside `acra`'s compiled kernels (`kernels_clocked`, for the bounds of
`second_core.py` and `regions_bound.py`).

A replay times one function apart from the frame: the scene's ``--frames`` run after a free frame
(frame 5) with the function wrapped to keep each call's arguments, then the calls are made again
``--passes`` times on one BLAS thread (as the frame loop runs), and the CPU milliseconds a
collision frame of the median and fastest pass are printed with a digest of every answer: two
checkouts answer alike when their digests agree.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = pathlib.Path(__file__).resolve().parents[1]


def arguments(description: str) -> argparse.Namespace:
    """``[SCENE.py] [--frames 13:17] [--passes 40]``, with ``frames`` as a list of ints."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17", help="first:last, inclusive")
    ap.add_argument("--passes", type=int, default=40)
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))
    args.frames = list(range(first, last + 1))
    return args


def recorded(scene: str, frames: list[int], owner, name: str, keep) -> list:
    """The arguments ``keep(*args)`` of every call of ``owner.name`` (a module's function or a
    class's method, read from its owner at each call) over ``frames`` of ``scene``, after frame 5."""
    from pipeline import frames as F
    from pipeline import usdio

    calls = []
    real = getattr(owner, name)

    def wrapper(*args, **kwargs):
        calls.append(keep(*args, **kwargs))
        return real(*args, **kwargs)

    with threadpool_limits(1):
        stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(scene)))
        scene_model = usdio.read_scene(stage)
        F.run_frames(stage, scene_model, [5])
        setattr(owner, name, wrapper)
        try:
            F.run_frames(stage, scene_model, frames)
        finally:
            setattr(owner, name, real)
    return calls


def timed(replay, passes: int) -> tuple[list, list[float]]:
    """The answers of ``replay()`` and the CPU seconds of ``passes`` more calls of it, on one BLAS thread."""
    with threadpool_limits(1):
        answers = replay()
        times = []
        for _ in range(passes):
            t = time.process_time()
            replay()
            times.append(time.process_time() - t)
    return answers, times


def report(args: argparse.Namespace, what: str, times: list[float], arrays) -> None:
    """Print the scene, its frames, ``what`` was replayed, the CPU ms a frame and the digest of ``arrays``."""
    digest = hashlib.sha1()
    for a in arrays:
        digest.update(np.ascontiguousarray(a).tobytes())
    ms = [1e3 * t / len(args.frames) for t in times]
    print(f"{pathlib.Path(args.scene).stem} frames {args.frames[0]}-{args.frames[-1]}: {what}; "
          f"CPU ms a frame, median {statistics.median(ms):.3f}, fastest {min(ms):.3f} (of {args.passes} passes); "
          f"answers {digest.hexdigest()[:12]}")


def kernels_clocked(inside: list) -> list:
    """Wraps every compiled kernel `acra`'s modules define (numba ``CPUDispatcher``) so that its
    calls add their CPU seconds to ``inside[0]``; returns ``[(module, name, kernel)]`` to put
    them back. A kernel called from another compiled kernel is not wrapped there (it is inlined
    in the caller's machine code), so each second counts once."""
    import importlib
    import pkgutil

    import acra
    from numba.core.registry import CPUDispatcher

    wrapped = []
    for info in pkgutil.iter_modules(acra.__path__):
        module = importlib.import_module(f"acra.{info.name}")
        for name, f in list(vars(module).items()):
            if isinstance(f, CPUDispatcher) and getattr(f, "__module__", None) == module.__name__:
                def timed(*a, _f=f, **k):
                    t = time.process_time()
                    try:
                        return _f(*a, **k)
                    finally:
                        inside[0] += time.process_time() - t
                setattr(module, name, timed)
                wrapped.append((module, name, f))
    return wrapped
