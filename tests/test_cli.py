"""`pipeline.cli.main` as a library call and as the process's command (the GC freeze of a program run)."""

import gc
import shutil
import subprocess
import sys
from pathlib import Path

from pxr import Usd

from conftest import interrupted_run
from pipeline.cli import main

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


def test_library_calls_leave_the_callers_gc_alone(tmp_path):
    """Only a process that is the command freezes its objects; a test or script calling main() keeps
    collecting its garbage."""
    scene = tmp_path / SCENE.name
    shutil.copy(SCENE, scene)
    before = gc.get_freeze_count()
    assert main(["run", str(scene), "--quiet", "--frames", "1:2"]) == 0
    assert main(["run", str(tmp_path / "missing.usda"), "--quiet"]) == 2
    assert gc.get_freeze_count() == before


def test_program_run_freezes_and_still_runs_exit_handlers(tmp_path):
    """As the command (argv from sys.argv) the run freezes import-time objects and, at the end,
    everything; atexit handlers still run, and the output layer and the recording are complete."""
    from rerun.chunk import RrdReader

    scene = tmp_path / SCENE.name
    shutil.copy(SCENE, scene)
    out, rrd = tmp_path / "box.acra.usda", tmp_path / "box.rrd"
    code = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print('atexit frozen', gc.get_freeze_count() > 0, flush=True))\n"
        "from pipeline.cli import main\n"
        f"sys.argv = ['acra', 'run', {str(scene)!r}, '-o', {str(out)!r}, '--rrd', {str(rrd)!r}, '--quiet', '--frames', '1:2']\n"
        "sys.exit(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "atexit frozen True" in done.stdout
    assert "acra: 2 frames" in done.stdout
    stage = Usd.Stage.Open(str(out))
    assert stage.GetPrimAtPath("/World/Sheet").GetAttribute("points").GetTimeSamples() == [1.0, 2.0]
    assert "/world/World/Sheet" in {c.entity_path for c in RrdReader(str(rrd)).stream()}


def test_program_exits_without_teardown_after_exit_handlers_and_output(tmp_path):
    """`program` (the ``acra`` script, ``python -m pipeline.cli``) runs the atexit handlers, flushes
    what the run printed and exits with main's status, but skips the interpreter's teardown: an
    object left at module level is never finalised."""
    scene = tmp_path / SCENE.name
    shutil.copy(SCENE, scene)
    out = tmp_path / "box.acra.usda"
    code = (
        "import atexit, sys\n"
        "class Probe:\n"
        "    def __del__(self):\n"
        "        print('torn down', flush=True)\n"
        "probe = Probe()\n"
        "atexit.register(lambda: print('atexit ran', flush=True))\n"
        "from pipeline.cli import program\n"
        "sys.argv = ['acra'] + sys.argv[1:]\n"
        "program()\n"
    )
    run = [sys.executable, "-c", code, "run"]
    done = subprocess.run(run + [str(scene), "-o", str(out), "--quiet", "--frames", "1:2"],
                          capture_output=True, text=True, cwd=tmp_path, env=_env())
    assert done.returncode == 0, done.stderr
    assert "acra: 2 frames" in done.stdout and "atexit ran" in done.stdout
    assert "torn down" not in done.stdout
    assert Usd.Stage.Open(str(out)).GetPrimAtPath("/World/Sheet").GetAttribute("points").GetTimeSamples() == [1.0, 2.0]
    missing = subprocess.run(run + [str(tmp_path / "missing.usda"), "--quiet"], capture_output=True, text=True,
                             cwd=tmp_path, env=_env())
    assert missing.returncode == 2 and "acra: error:" in missing.stderr and "atexit ran" in missing.stdout


# --- a command line a TD can script --------------------------------------------------------------

REPO = Path(__file__).resolve().parents[1]


def _env():
    import os

    return {**os.environ, "PYTHONPATH": str(REPO)}


def test_version_comes_from_the_package_metadata(capsys):
    """Issue 18, row 6: `acra --version` was no such option."""
    from importlib import metadata

    import pytest

    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"acra {metadata.version('acra')}"


def test_the_version_is_read_only_for_version(tiny_stage, tmp_path, monkeypatch):
    """Building the command line does not read the package metadata: only `acra --version` does."""
    from pipeline import cli

    def read():
        raise AssertionError("the package metadata was read")

    monkeypatch.setattr(cli, "_version", read)
    assert main(["run", str(tiny_stage(frames=2)), "-o", str(tmp_path / "o.usdc"), "--quiet"]) == 0


def test_progress_in_a_log_is_plain_lines(tiny_stage, tmp_path):
    """Issue 18, row 7: with stderr not a terminal the bar wrote carriage-return frames into the log."""
    src = tiny_stage(frames=4)
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(tmp_path / "o.usdc")],
                          capture_output=True, text=True, env=_env(), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "\r" not in done.stderr and "\x1b" not in done.stderr
    assert done.stderr.splitlines()[0] == "acra: frame 1 done (1/4)"
    assert done.stderr.splitlines()[-1] == "acra: frame 4 done (4/4)"


def test_chunks_failing_on_the_cluster_exit_1_naming_the_frames(tiny_stage, tmp_path, monkeypatch, capsys):
    """A `FarmError` from the frames (retries spent) is exit status 1 with one line; the command
    line matches it without importing the farm's module for a run that has none."""
    from pipeline import farm, run

    def failing(*args, **kwargs):
        raise farm.FarmError("frames 3-4 failed on the cluster: OSError: gone")

    monkeypatch.setattr(run, "run_file", failing)
    assert main(["run", str(tiny_stage(frames=4)), "-o", str(tmp_path / "o.usdc"), "--quiet"]) == 1
    assert capsys.readouterr().err == "acra: error: frames 3-4 failed on the cluster: OSError: gone; nothing written\n"

def _interrupt(tiny_stage, tmp_path, sig):
    """Start a 400-frame run (every frame in contact) as a real process, send ``sig`` once it has
    reported its first frame, and return (exit status, stderr, files left in ``tmp_path``)."""
    src = tiny_stage(frames=400, top=0.4, depth=0.2)
    extra = ["--rrd", str(tmp_path / "o.rrd"), "--report", str(tmp_path / "o.json")]
    return interrupted_run(src, tmp_path / "o.usda", sig, extra=extra, env=_env())


def test_sigint_half_way_writes_nothing_and_leaves_no_temporary_file(tiny_stage, tmp_path):
    import signal

    code, err, files = _interrupt(tiny_stage, tmp_path, signal.SIGINT)
    assert code == 130, (code, err, files)  # the run's stderr names what ended it otherwise
    assert err.strip().splitlines()[-1] == "acra: interrupted; nothing written" and "Traceback" not in err
    assert files == ["tiny.usda"]


def test_sigterm_half_way_writes_nothing_and_leaves_no_temporary_file(tiny_stage, tmp_path):
    import signal

    code, err, files = _interrupt(tiny_stage, tmp_path, signal.SIGTERM)
    assert code == 143, (code, err, files)  # the run's stderr names what ended it otherwise
    assert err.strip().splitlines()[-1] == "acra: interrupted; nothing written" and "Traceback" not in err
    assert files == ["tiny.usda"]


# --- start-up: a command imports what it needs ---------------------------------------------------

def _program(tmp_path, argv: list[str]) -> tuple[subprocess.CompletedProcess, set]:
    """Run ``acra ARGV`` as the process's command; its exit and the modules it imported."""
    code = (
        "import json, sys\n"
        "from pipeline.cli import main\n"
        f"sys.argv = ['acra'] + {argv!r}\n"
        "try:\n    status = main()\nexcept SystemExit as done:\n    status = done.code\n"
        "print(json.dumps(sorted(sys.modules)))\n"
        "sys.exit(status)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), cwd=tmp_path)
    import json

    return done, set(json.loads(done.stdout.splitlines()[-1]))


def test_version_imports_neither_numpy_nor_usd(tmp_path):
    done, modules = _program(tmp_path, ["--version"])
    assert done.returncode == 0 and done.stdout.startswith("acra ")
    assert not modules & {"numpy", "pxr", "scipy", "trimesh", "fcl", "rerun", "dask"}


def test_a_run_imports_no_preview_farm_or_plotting_and_reports_its_phases(tiny_stage, tmp_path):
    """Without --rrd, --workers or a plot, `acra run` imports neither rerun, dask nor matplotlib;
    its --report splits the wall clock into the run's phases, in order."""
    import json

    src, rep = tiny_stage(frames=2), tmp_path / "r.json"
    done, modules = _program(tmp_path, ["run", str(src), "-o", str(tmp_path / "o.usdc"), "--quiet", "--report", str(rep)])
    assert done.returncode == 0, done.stderr
    tops = {m.split(".")[0] for m in modules}
    assert not tops & {"rerun", "dask", "distributed", "matplotlib"}
    data = json.loads(rep.read_text())
    assert list(data["phases"]) == ["imports", "scene", "read", "frames", "write"]
    assert data["phases"]["imports"] > 0 and data["phases"]["scene"] == 0  # a stage, not a scene file
    assert all(s >= 0 for s in data["phases"].values())
    assert sum(data["phases"].values()) - data["phases"]["imports"] <= data["seconds"]


def test_a_run_on_deformables_alone_imports_no_trimesh(tmp_path):
    """The demo (two deformables) imports neither trimesh, networkx nor rtree: rays are cast
    through embreex directly (`queries.RayMesh`), barycentric coordinates and the merged mesh are
    `acra.meshops`'s, and trimesh is imported only for rigid colliders' meshes
    (`geometry.prepare_collider`) and the rare float64 retry of a ray embree lets through."""
    scene = tmp_path / "dog_head_spike.py"
    shutil.copy(Path(__file__).resolve().parents[1] / "scenes" / "dog_head_spike.py", scene)
    done, modules = _program(tmp_path, ["run", str(scene), "-o", str(tmp_path / "o.usdc"), "--quiet", "--frames", "13:15",
                                        "--over-tolerance", "warn"])
    assert done.returncode == 0, done.stderr
    assert "in collision" in done.stdout and " 0 in collision" not in done.stdout
    tops = {m.split(".")[0] for m in modules}
    assert not tops & {"trimesh", "networkx", "rtree"}
    # fcl is for pairs `acra.narrow.crossings` does not settle alone and for colliders; the farm's
    # module for --workers; the path curves for a scene that moves a prim along a path; UsdPhysics
    # for a stage with meshes (a collider is a Mesh with its CollisionAPI)
    assert not tops & {"fcl"}
    assert not modules & {"pipeline.farm", "pipeline.animation.paths", "pipeline.animation.quaternions", "pxr.UsdPhysics"}
    # scipy's kd-tree and hull come from their compiled modules (`pipeline.spatial`): the
    # scipy.spatial package's __init__, and scipy.special it pulls in, are never run
    assert {"scipy.spatial._ckdtree", "scipy.spatial._qhull"} <= modules
    assert not modules & {"scipy.spatial", "scipy.special"}
    # nor scipy.linalg's __init__ (its Cython LAPACK and BLAS tables are loaded alone), nor what
    # scipy's array-API layer would import of numpy while copying its namespace (numpy.f2py, with
    # charset_normalizer, and numpy.testing): lazy modules whose code never ran
    assert not modules & {"scipy.linalg._basic", "scipy.linalg._decomp", "numpy.f2py.crackfortran", "numpy.testing._private",
                          "charset_normalizer"}
    # nor scipy.sparse's (the kd-tree's module imports it for sparse outputs no run asks for)
    assert "scipy.sparse" in modules and not modules & {"scipy.sparse._base", "scipy.sparse._csr", "scipy.sparse._coo"}
    # numba's configuration reads no .numba_config.yaml here, so PyYAML is never imported (`acra`)
    assert "yaml" not in tops


def test_scipy_spatial_imported_later_holds_the_same_classes():
    """A later `import scipy.spatial` (trimesh for a rigid collider) finds the compiled modules
    `pipeline.spatial` loaded and binds them: one cKDTree and one ConvexHull class in the process."""
    code = (
        "import sys\n"
        "from pipeline import spatial\n"
        "assert 'scipy.spatial' not in sys.modules\n"
        "import numpy as np, scipy.spatial\n"
        "assert scipy.spatial.cKDTree is spatial.cKDTree and scipy.spatial.ConvexHull is spatial.ConvexHull\n"
        "assert scipy.spatial.QhullError is spatial.QhullError\n"
        "hull = spatial.ConvexHull(np.random.default_rng(1).random((30, 3)))\n"
        "assert len(scipy.spatial.Delaunay(hull.points).simplices) > 0\n"
        "import scipy.linalg, scipy.linalg.cython_lapack\n"
        "assert scipy.linalg.cython_lapack is sys.modules['scipy.linalg.cython_lapack']\n"
        "assert np.allclose(scipy.linalg.inv(np.eye(3) * 2), np.eye(3) / 2)\n"
        "np.testing.assert_equal(np.ma.masked_array([1, 2], [0, 1]).sum(), 1)\n"
        "assert callable(np.f2py.run_main) and type(np.f2py) is type(sys)\n"
        "tree = spatial.cKDTree(hull.points)\n"
        "import scipy.sparse\n"
        "assert type(tree.sparse_distance_matrix(tree, 0.3, output_type='coo_matrix')) is scipy.sparse.coo_matrix\n"
        "from scipy.sparse.csgraph import connected_components\n"
        "assert scipy.sparse is sys.modules['scipy.sparse'] and type(scipy.sparse) is type(sys)\n"
        "assert connected_components(scipy.sparse.eye(3, format='csr'))[0] == 3\n"
        "print('same', len(hull.vertices) > 3)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env())
    assert done.returncode == 0 and done.stdout.strip() == "same True", done.stderr
