"""pipeline.farm: frames on Dask give the same output layer, byte for byte, as one process.

Four shots (a sheet under a box, a rolling bump, two closed deformables, a ball that carries its
dent across frames), each over a short
range with free and collision frames, run four ways: one process; a 2-worker LocalCluster; a
loopback cluster (`dask scheduler` and two `dask worker` processes on 127.0.0.1); frame-range
parts merged by `acra merge`. Then the faults: a worker killed while it runs a chunk, and bad
input met by a worker.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline import cli, farm, parts, usdio
from pipeline.run import run_file
from pipeline.frames import RunOptions
from pipeline.model import InputError

distributed = pytest.importorskip("distributed")  # in the test extra: `pip install -e '.[test]'`

ROOT = Path(__file__).parents[1]
# scene, frames (free and collision frames), chunk size, the two part ranges
SHOTS = {
    "box_into_sheet": ("9:13", 2, ("9:10", "11:13")),
    "rolling_bump": ("3:8", 1, ("3:5", "6:8")),
    "closed_objects": ("3:5", 1, ("3:3", "4:5")),  # two deformables
    # state across frames: a chunk or part that starts after the stage's start recomputes what the
    # ball carries into it (`pipeline.state.for_run`), so it starts mid-recovery here
    "soft_ball": ("3:7", 2, ("3:4", "5:7")),
}


def _export(name: str, directory: Path) -> Path:
    """The scene's stage as a .usda in ``directory`` (the repository's scenes/ stays untouched)."""
    import runpy

    stage = runpy.run_path(str(ROOT / "scenes" / f"{name}.py"), run_name="acra_scene")["build"]()
    return usdio.export_layer(stage.GetRootLayer(), directory / f"{name}.usda")


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    """name -> (stage path, frames, chunk, part ranges, bytes of the single-process output)."""
    out = {}
    for name, (frames, chunk, ranges) in SHOTS.items():
        d = tmp_path_factory.mktemp(name)
        stage = _export(name, d)
        report = run_file(stage, d / "single.usda", frames)
        assert any(s.in_collision for s in report.stats) and not all(s.in_collision for s in report.stats)
        out[name] = (stage, frames, chunk, ranges, report.output.read_bytes())
    return out


@pytest.fixture(scope="module")
def local_cluster():
    cluster = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=":0")
    yield cluster
    cluster.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args: list[str]) -> subprocess.Popen:
    """A ``dask`` command in its own session (killed with its process group), this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "dask", *args], env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _worker(address: str, name: str) -> subprocess.Popen:
    # no nanny: the process is the worker, so killing it loses the worker (a nanny would restart it)
    return _start(["worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host", "127.0.0.1", "--name", name])


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


@pytest.fixture(scope="module")
def loopback():
    """A scheduler and two workers on 127.0.0.1; yields ``(address, processes)``."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    procs = [_start(["scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1], "--no-dashboard"])]
    try:
        procs += [_worker(address, f"loop-{k}") for k in range(2)]
        with distributed.Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address, procs
    finally:
        for p in reversed(procs):
            _kill(p)


# --------------------------------------------------------------------------------------------
# byte-identical output


@pytest.mark.parametrize("name", SHOTS)
def test_local_cluster_output_is_byte_identical(shots, local_cluster, name):
    stage, frames, chunk, _, single = shots[name]
    out = run_file(stage, stage.parent / "local.usda", frames, scheduler=local_cluster.scheduler_address, chunk=chunk).output
    assert out.read_bytes() == single


@pytest.mark.parametrize("name", SHOTS)
def test_loopback_cluster_output_is_byte_identical(shots, loopback, name):
    stage, frames, _, _, single = shots[name]
    out = run_file(stage, stage.parent / "loopback.usda", frames, scheduler=loopback[0]).output  # default chunking
    assert out.read_bytes() == single


@pytest.mark.parametrize("name", SHOTS)
def test_parts_merged_are_byte_identical(shots, tmp_path, capsys, name):
    """Parts in a directory of their own; the merged layer beside the input, like the single run's."""
    stage, _, _, ranges, single = shots[name]
    for r in reversed(ranges):  # the order parts arrive in does not matter
        assert cli.main(["run", str(stage), "--frames", r, "--part", str(tmp_path / "parts"), "--quiet"]) == 0
    first, last = ranges[0].split(":")[0], ranges[-1].split(":")[1]
    merged = stage.parent / "merged.usda"
    assert cli.main(["merge", str(tmp_path / "parts"), "-o", str(merged), "--frames", f"{first}:{last}"]) == 0
    assert merged.read_bytes() == single
    assert f"-> {merged}" in capsys.readouterr().out


def test_workers_option_starts_a_local_cluster_and_reports_the_same_figures(shots):
    stage, frames, _, _, single = shots["rolling_bump"]
    farmed = run_file(stage, stage.parent / "workers.usda", frames, workers=2)
    assert farmed.output.read_bytes() == single
    one = run_file(stage, stage.parent / "again.usda", frames)
    key = lambda r: [(s.frame, s.in_collision, s.iterations, s.residual, s.residual_rel) for s in r.stats]  # noqa: E731
    assert key(farmed) == key(one)


def test_local_cluster_workers_share_the_cores_between_their_threads():
    assert farm.worker_env(2, cores=2) == {"NUMBA_NUM_THREADS": "1"}
    assert farm.worker_env(1, cores=2) == {"NUMBA_NUM_THREADS": "2"}
    assert farm.worker_env(3, cores=8) == {"NUMBA_NUM_THREADS": "2"}
    assert farm.worker_env(16, cores=8) == {"NUMBA_NUM_THREADS": "1"}
    client, cluster = farm.connect(workers=2)
    try:
        seen = client.run(lambda: __import__("os").environ.get("NUMBA_NUM_THREADS"))
    finally:
        farm._close(client, cluster)
    assert sorted(seen.values()) == [farm.worker_env(2)["NUMBA_NUM_THREADS"]] * 2


def test_usdc_output_is_byte_identical(shots, local_cluster):
    stage, frames, chunk, _, _ = shots["closed_objects"]
    single = run_file(stage, stage.parent / "single.usdc", frames).output.read_bytes()
    farmed = run_file(stage, stage.parent / "farmed.usdc", frames, scheduler=local_cluster.scheduler_address, chunk=chunk)
    assert farmed.output.read_bytes() == single


# --------------------------------------------------------------------------------------------
# faults


def test_worker_killed_mid_chunk_is_retried_and_output_is_complete(shots, loopback):
    """A third worker joins the loopback cluster; once it runs a chunk it is killed (SIGKILL)."""
    address, _ = loopback
    stage, frames, _, _, single = shots["closed_objects"]
    victim = _worker(address, "victim")
    killed: dict = {}
    try:
        with distributed.Client(address, timeout="60s") as watch:
            watch.wait_for_workers(3, timeout=120)
            addr = next(a for a, w in watch.scheduler_info()["workers"].items() if w["name"] == "victim")

            def kill_when_busy():
                deadline = time.monotonic() + 120
                while time.monotonic() < deadline and "at" not in killed:
                    busy = [k for k in watch.processing().get(addr, ()) if "acra-chunk" in str(k)]
                    if busy:
                        _kill(victim)
                        killed["at"], killed["task"] = time.monotonic(), busy[0]
                    time.sleep(0.02)

            killer = threading.Thread(target=kill_when_busy)
            killer.start()
            report = run_file(stage, stage.parent / "killed.usda", frames, scheduler=address, chunk=1)
            killer.join()
    finally:
        _kill(victim)
    assert "at" in killed, "the victim never ran a chunk: nothing was tested"
    assert victim.returncode == -signal.SIGKILL
    assert sorted(s.frame for s in report.stats) == list(range(3, 6))
    assert report.output.read_bytes() == single


def test_bad_input_met_by_a_worker_stops_the_run_with_the_single_process_line(shots, local_cluster, tmp_path):
    """The input turns bad after the client read it: the worker's InputError reaches the client whole."""
    stage, frames, _, _, _ = shots["box_into_sheet"]
    bad = tmp_path / "shot.usda"
    bad.write_bytes(stage.read_bytes())
    opened = usdio.open_input(bad)
    scene, identity = usdio.read_scene(opened), parts.input_identity(opened)
    text, n = re.subn(r"float acra:rigidity = [0-9.e+-]+", "float acra:rigidity = 500", bad.read_text())
    assert n == 1
    bad.write_text(text)
    single = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(bad), "-o", str(tmp_path / "x.usda")],
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True)
    assert single.returncode == 2 and len(single.stderr.strip().splitlines()) == 1
    with pytest.raises(InputError) as err:
        farm.run_frames(bad, identity, scene, [9, 10, 11, 12], RunOptions(), scheduler=local_cluster.scheduler_address, chunk=1)
    assert f"acra: error: {err.value}" == single.stderr.strip()  # pickled across whole (InputError.__reduce__)
    assert "acra:rigidity" in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shot.usda"]  # nothing written


def test_changed_input_is_refused_by_the_workers(shots, local_cluster):
    stage, _, _, _, _ = shots["rolling_bump"]
    scene = usdio.read_scene(usdio.open_input(stage))
    with pytest.raises(InputError, match="changed during the run"):
        farm.run_frames(stage, "0" * 64, scene, [1, 2], RunOptions(), scheduler=local_cluster.scheduler_address)


def test_workers_without_dask_is_one_line_and_exit_2(shots, tmp_path, monkeypatch, capsys):
    stage, _, _, _, _ = shots["rolling_bump"]
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    assert cli.main(["run", str(stage), "-o", str(tmp_path / "out.usda"), "--workers", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("acra: error: --workers: needs Dask distributed")
    assert "acra[farm]" in err and not (tmp_path / "out.usda").exists()


def test_pipeline_imports_without_dask():
    code = "import sys; sys.modules['distributed'] = None; sys.modules['dask'] = None; import pipeline.farm, pipeline.parts, pipeline.cli"
    subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)


def test_unreachable_scheduler_is_one_line(shots, tmp_path, capsys, monkeypatch):
    stage, _, _, _, _ = shots["rolling_bump"]
    address = f"tcp://127.0.0.1:{_free_port()}"
    monkeypatch.setattr(farm, "CONNECT_TIMEOUT", "2s")
    assert cli.main(["run", str(stage), "-o", str(tmp_path / "out.usda"), "--scheduler", address, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"acra: error: --scheduler: cannot reach a Dask scheduler at {address}") and "\n" not in err


# --------------------------------------------------------------------------------------------
# chunks


def test_plan_chunks_exact():
    assert farm.plan_chunks([1, 2, 3, 4, 5], 2) == [[1, 2], [3, 4], [5]]
    assert farm.plan_chunks([1, 2, 3, 4, 5, 6], 2, can_start=lambda f: f in (1, 5)) == [[1, 2, 3, 4], [5, 6]]
    with pytest.raises(ValueError):
        farm.plan_chunks([1], 0)


@settings(max_examples=200, deadline=None)
@given(st.integers(-5, 5), st.integers(0, 40), st.integers(1, 8), st.sets(st.integers(-5, 45)))
def test_plan_chunks_cuts_only_where_allowed_and_as_soon_as_allowed(start, n, size, starts):
    frames = list(range(start, start + n))
    chunks = farm.plan_chunks(frames, size, can_start=lambda f: f in starts)
    assert [f for c in chunks for f in c] == frames
    for c in chunks[1:]:
        assert c[0] in starts
    for c in chunks[:-1]:
        assert len(c) >= size and not any(f in starts for f in c[size:])


@pytest.mark.parametrize("option", [["--workers", "0"], ["--workers", "2", "--chunk", "0"], ["--chunk", "3"]])
def test_bad_farm_options_are_one_line_before_anything_is_read(tmp_path, capsys, option):
    missing = tmp_path / "no_such_shot.usda"  # never opened: the options are refused first
    assert cli.main(["run", str(missing), *option]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"acra: error: {option[-2]}: ") and "no_such_shot" not in err


def test_scheduler_without_workers_is_one_line(shots, tmp_path, capsys, monkeypatch):
    stage, _, _, _, _ = shots["rolling_bump"]
    monkeypatch.setattr(farm, "CONNECT_TIMEOUT", "1s")
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as empty:
        assert cli.main(["run", str(stage), "-o", str(tmp_path / "out.usda"), "--scheduler", empty.scheduler_address, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"acra: error: --scheduler: the Dask scheduler at {empty.scheduler_address} has no workers (waited 1s)"
    assert not (tmp_path / "out.usda").exists()
