"""Frames on a Dask cluster: chunks of frames as tasks, results assembled by the client.

`run_frames` is `pipeline.frames.run_frames` spread over Dask workers: a
`distributed.LocalCluster` of ``workers`` processes (one thread each) started for the run, or an
existing cluster at ``scheduler`` (``dask scheduler`` / ``dask worker``, SSH, Kubernetes,
SLURM). The frames are cut into chunks (`plan_chunks`); each chunk is one task, `run_chunk`,
which opens the stage itself from its path (workers get paths, never USD objects), checks the
input's identity (`parts.input_identity`) against the one the client read, runs its frames with
the same `frames.run_frames`, and returns plain arrays (`parts.records_from_result`) and the
frames' statistics. The client gathers the chunks as they complete (updating the one progress
bar), rebuilds the results (`parts.assemble`) and writes the output layer as a single process
does: the bytes are the same whatever the number of workers and the chunking, because every
frame's result depends only on the input at that frame (each frame starts from the animator's
shape).

Faults. A task whose worker dies is run again on another worker (Dask reschedules the tasks of
a lost worker, up to its ``allowed-failures``; ``retries=RETRIES`` covers exceptions raised
inside a task). Bad input is not retried: `run_chunk` returns the `InputError` as a value and
the client raises it, cancels the other chunks and writes nothing, so the user sees the same one
line as from a single process.

State carried between frames. A chunk of a stage with state across frames (relaxation,
plasticity) that starts after the stage's first frame recomputes what it carries in, as
`frames.run_frames` does for any frame range (`pipeline.state.for_run`), so chunks split anywhere
and the output stays identical to a single process. `plan_chunks` takes a ``can_start`` test for
a planner that wants chunks to start only where nothing is carried in.

Dask is an optional dependency (``pip install 'acra[farm]'``), imported only when a run asks
for workers; importing this module does not need it.
"""

from __future__ import annotations

import logging
import math
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from acra import memo
from pipeline.model import InputError

__all__ = ["RETRIES", "CONNECT_TIMEOUT", "CHUNKS_PER_WORKER", "FarmError", "FarmTimings", "require", "plan_chunks", "run_chunk", "run_frames", "connect"]

RETRIES = 2  # reruns of a task that raised; a lost worker's tasks are rescheduled by Dask itself
CONNECT_TIMEOUT = "20s"  # waiting for a --scheduler that does not answer
CHUNKS_PER_WORKER = 3  # default chunks per worker: collision frames cost ~100x a free frame, so
# several chunks per worker let a worker that drew free frames take the next chunk


class FarmError(RuntimeError):
    """The cluster could not finish the run (a chunk lost more workers than Dask allows)."""


@dataclass
class FarmTimings:
    """Wall-clock seconds of a distributed run's phases (for the benchmark).

    Attributes
    ----------
    startup : float
        Starting the LocalCluster (or connecting) and importing the pipeline on every worker.
    frames : float
        From submitting the chunks to the last chunk gathered.
    assemble : float
        Rebuilding the results from the chunks' arrays (`parts.assemble`).
    chunks : list of list of int
        The frames of each chunk, as planned.
    cpu : dict
        Worker address -> CPU seconds its chunks took (`time.process_time` of the worker
        process around `run_chunk`): the work done, whatever else the machine runs.
    """

    startup: float = 0.0
    frames: float = 0.0
    assemble: float = 0.0
    chunks: list = field(default_factory=list)
    cpu: dict = field(default_factory=dict)


def plan_chunks(frames: list[int], size: int, can_start: Callable[[int], bool] | None = None) -> list[list[int]]:
    """Cut ``frames`` (in order) into chunks of about ``size`` frames.

    A chunk ends once it holds ``size`` frames and the next frame may start a chunk
    (``can_start(frame)``, default always: frames carry nothing). A run of frames none of which
    may start a chunk stays in the chunk before it, however long.
    """
    if size < 1:
        raise ValueError(f"chunk size must be at least 1, got {size}")
    chunks: list[list[int]] = []
    for f in frames:
        if chunks and (len(chunks[-1]) < size or not (can_start is None or can_start(f))):
            chunks[-1].append(f)
        else:
            chunks.append([f])
    return chunks


def run_chunk(stage_path: str, identity: str, frames: list[int], options) -> dict:
    """One task: open the stage, respond ``frames`` with `frames.respond_frames`, return plain data
    (the display is the whole run's: the client chooses it, `display.finish`).

    Runs on a worker. Returns ``{"frames", "records", "stats", "error", "worker", "cpu"}``: the
    records of `parts.records_from_result`, the `frames.FrameStats` list, ``error``, an
    `InputError` (bad or changed input) or ``None``, the worker's address and the CPU seconds
    the chunk took. Bad input is returned, not raised, so Dask does not retry it.
    """
    from pipeline import frames as frame_loop
    from pipeline import parts, usdio

    cpu0 = time.process_time()
    try:
        stage = usdio.open_input(stage_path)
        scene = usdio.read_scene(stage)  # first: input made bad meanwhile gets a single process's line
        found = parts.input_identity(stage)
        if found != identity:
            raise InputError(stage_path, None, f"changed during the run (identity {found[:12]} on this worker, {identity[:12]} when the run started)")
        with memo.scope():  # the chunk's answers kept across its frames, dropped with it
            result, stats = frame_loop.respond_frames(stage, scene, list(frames), options)
    except InputError as err:
        return {"frames": list(frames), "records": {}, "stats": [], "error": err, "worker": _worker_address(), "cpu": 0.0}
    records = parts.records_from_result(result)
    return {"frames": list(frames), "records": records, "stats": stats, "error": None,
            "worker": _worker_address(), "cpu": time.process_time() - cpu0}


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):  # called outside a Dask worker
        return "local"


def _warm() -> None:
    """Import the frame loop on a worker before the first task (counted as start-up)."""
    from pipeline import frames, output_layer, parts, usdio  # noqa: F401


def require(option: str):
    """The ``distributed`` module, or an `InputError` on ``option`` saying how to install it."""
    try:
        import distributed
    except ImportError as exc:
        raise InputError(option, None, f"needs Dask distributed, which is not installed ({exc}): pip install 'acra[farm]'") from None
    return distributed


def worker_env(workers: int, cores: int | None = None) -> dict[str, str]:
    """The environment of a LocalCluster's ``workers`` processes on ``cores`` (the machine's):
    each may use ``cores // workers`` threads, at least 1 (``NUMBA_NUM_THREADS``, which a
    collision frame's pair measure reads, `pipeline.workers`), so the workers together keep to
    the machine's cores."""
    cores = cores or os.cpu_count() or 1
    return {"NUMBA_NUM_THREADS": str(max(1, cores // workers))}


def connect(workers: int | None = None, scheduler: str | None = None):
    """A Dask ``(client, cluster)``: a new LocalCluster of ``workers`` processes with one thread
    each (``cluster`` to close after the client), or a client of the running ``scheduler``
    (``cluster`` is ``None``). Every worker has imported the frame loop when this returns.
    """
    option = "--scheduler" if scheduler else "--workers"
    distributed = require(option)
    cluster = None
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError("--scheduler", None, f"cannot reach a Dask scheduler at {scheduler}: {' '.join(str(exc).split())}") from None
        try:  # a scheduler without workers would hold the chunks forever
            client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
        except TimeoutError:
            client.close()
            raise InputError("--scheduler", None, f"the Dask scheduler at {scheduler} has no workers (waited {CONNECT_TIMEOUT})") from None
    else:
        if workers is None or workers < 1:
            raise InputError("--workers", None, f"must be at least 1, got {workers}")
        cluster = distributed.LocalCluster(
            n_workers=workers, processes=True, threads_per_worker=1,
            dashboard_address=":0", silence_logs=logging.CRITICAL,  # a chunk's failure reaches the client; worker logs would only repeat it
            env=worker_env(workers),
        )
        client = distributed.Client(cluster, set_as_default=False)
    try:
        client.run(_warm)
    except BaseException:
        _close(client, cluster)
        raise
    return client, cluster


def _close(client, cluster) -> None:
    client.close()
    if cluster is not None:
        cluster.close()


def run_frames(
    stage_path: Path,
    identity: str,
    scene,
    frames: list[int],
    options,
    workers: int | None = None,
    scheduler: str | None = None,
    chunk: int | None = None,
    on_chunk: Callable[[int], None] | None = None,
    timings: FarmTimings | None = None,
):
    """`frames.run_frames` on Dask: chunks of frames responded on the workers, the run's display
    chosen and evaluated on the client (`display.finish`); returns ``(output_layer.FramesResult,
    list of FrameStats)``.

    ``stage_path`` is the USD stage (a scene file is exported by the caller first) and
    ``identity`` its `parts.input_identity` as the client read it; ``scene`` its `SceneModel`.
    ``chunk`` is frames per task (default: `CHUNKS_PER_WORKER` chunks per worker).
    ``on_chunk(n)`` is called on the client as each chunk of ``n`` frames completes.
    ``timings``, if given, receives the phases' seconds. Raises the first chunk's `InputError`
    (the other chunks are cancelled) or `FarmError`.
    """
    from pipeline import parts

    timings = timings if timings is not None else FarmTimings()
    if chunk is not None and chunk < 1:
        raise InputError("--chunk", None, f"must be at least 1, got {chunk}")
    t0 = time.perf_counter()
    client, cluster = connect(workers, scheduler)
    try:
        timings.startup = time.perf_counter() - t0
        n_workers = max(1, len(client.scheduler_info()["workers"]))
        size = chunk or max(1, math.ceil(len(frames) / (CHUNKS_PER_WORKER * n_workers)))
        chunks = timings.chunks = plan_chunks(frames, size)
        t1 = time.perf_counter()
        run = uuid.uuid4().hex[:8]
        chunk_of = {
            client.submit(run_chunk, str(stage_path), identity, c, options, key=f"acra-chunk-{run}-{k}", retries=RETRIES, pure=False): c
            for k, c in enumerate(chunks)
        }
        futures = list(chunk_of)
        distributed = require("--workers")
        records: dict = {}
        stats: list = []
        try:
            for future in distributed.as_completed(futures, loop=client.loop):
                try:
                    out = future.result()
                except Exception as exc:  # a lost worker more often than Dask allows, or a bug
                    raise FarmError(f"frames {parts.frame_spans(chunk_of[future])} failed on the cluster: {type(exc).__name__}: {' '.join(str(exc).split())}") from exc
                if out["error"] is not None:
                    raise out["error"]
                records.update(out["records"])
                timings.cpu[out["worker"]] = timings.cpu.get(out["worker"], 0.0) + out["cpu"]
                stats.extend(out["stats"])
                if on_chunk is not None:
                    on_chunk(len(out["frames"]))
        except BaseException:
            client.cancel(futures)
            raise
        timings.frames = time.perf_counter() - t1
    finally:
        _close(client, cluster)
    missing = sorted(set(frames) - set(records))
    if missing:  # every chunk was gathered, so this is a defect, never a partial output
        raise FarmError(f"frames {parts.frame_spans(missing)} came back from no chunk")
    t2 = time.perf_counter()
    from pipeline import display, usdio

    result, stats = parts.assemble(scene, records), sorted(stats, key=lambda s: s.frame)
    display.finish(usdio.open_input(stage_path), scene, result, stats, options)
    timings.assemble = time.perf_counter() - t2
    return result, stats
