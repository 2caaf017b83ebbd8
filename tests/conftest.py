"""Shared, seeded test objects."""

import signal
import subprocess
import sys
import threading
from dataclasses import replace

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from pipeline import geometry
from pipeline.model import ColliderModel


def wavy_sheet(nu=8, nv=7, depth=4, seed=0):
    rng = np.random.default_rng(seed)
    cvs, pu, pv = shapes.sheet(nu, nv, width=nu - 3.0, depth=nv - 3.0, height=0.3 * rng.normal(size=(nu, nv)))
    return H.from_grid(cvs, pu, pv, depth=depth)


def with_random_offsets(hs, scale=0.05, seed=1):
    rng = np.random.default_rng(seed)
    for k in range(1, hs.depth):
        idx, off = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, idx, scale * rng.normal(size=off.shape))
    return hs


def nudged(hs, level, rng, cv=None, scale=0.05):
    """``hs`` with one CV moved by a normal step of ``scale``: on level 0 the CV ``cv`` (a random
    one if omitted), on a finer level a random offset of ``level``."""
    if level == 0:
        cvs = hs.cvs.copy()
        i, j = cv if cv is not None else (int(rng.integers(0, cvs.shape[0])), int(rng.integers(0, cvs.shape[1])))
        cvs[i, j] += rng.normal(scale=scale, size=3)
        return replace(hs, cvs=cvs)
    idx, off = H.offsets_of(hs, level)
    off = off.copy()
    off[int(rng.integers(0, len(off)))] += rng.normal(scale=scale, size=3)
    return H.set_offsets(hs, level, idx, off)


@pytest.fixture
def sheet4():
    return wavy_sheet()


# --- detection: a box collider, transforms, a sphere and a sheet, finite contacts ---------------

# A box: vertex 4x + 2y + z has coordinate -1/+1 per bit; 12 triangles wound outward.
BOX_VERTICES = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
BOX_TRIANGLES = np.array([
    [0, 1, 3], [0, 3, 2],  # -x
    [4, 6, 7], [4, 7, 5],  # +x
    [0, 4, 5], [0, 5, 1],  # -y
    [2, 3, 7], [2, 7, 6],  # +y
    [0, 2, 6], [0, 6, 4],  # -z
    [1, 5, 7], [1, 7, 3],  # +z
])


def box(half, path="/box"):
    return geometry.prepare_collider(ColliderModel(path, BOX_VERTICES * half, BOX_TRIANGLES))


def move(x=0.0, y=0.0, z=0.0):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def sphere_geom(xform=None, name="/sphere"):
    return geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(16, 14)), move() if xform is None else xform, name)


def sheet_geom(n=10, width=7.0):
    return geometry.SurfaceGeometry(H.from_grid(*shapes.sheet(n, n, width=width, depth=width)), move(), "/sheet")


def assert_finite(contact):
    for name in ("uv_a", "uv_b", "local_b", "point_a", "point_b"):
        x = getattr(contact, name)
        assert x is None or np.all(np.isfinite(x)), name
    for reg in (contact.region_a, contact.region_b):
        assert np.all(np.isfinite(reg.points)) and np.all(np.isfinite(reg.depth))
    assert np.isfinite(contact.depth) and np.isfinite(contact.t_contact)


# --- scenes: each scene file runs once per test session, through the same code as `acra run` ----

SCENES = __import__("pathlib").Path(__file__).resolve().parents[1] / "scenes"
_scene_runs: dict = {}


def scene_names() -> list[str]:
    """Every scene file in ``scenes/`` (each is run as a test)."""
    return sorted(p.stem for p in SCENES.glob("*.py") if not p.stem.startswith("_"))


@pytest.fixture(scope="session")
def run_scene(tmp_path_factory):
    """``run_scene(name)`` → RunReport (``.output``, ``.stats``, ``.scene``), run once per session.

    The scene file is copied to a temporary directory first, so a test run never writes into the
    repository; the Rerun recording goes beside it as ``NAME.rrd``.
    """
    import shutil

    from pipeline.run import run_file

    def run(name: str):
        if name not in _scene_runs:
            d = tmp_path_factory.mktemp(name)
            shutil.copy(SCENES / f"{name}.py", d / f"{name}.py")
            _scene_runs[name] = run_file(d / f"{name}.py", rrd=d / f"{name}.rrd")
        return _scene_runs[name]

    return run


def scene_stages(report):
    """The input stage a scene run read and the output layer it wrote, opened as a USD client
    opens them: ``(input, output)`` ``Usd.Stage``s."""
    from pxr import Usd

    src = report.output.with_name(report.output.name.replace(".acra.usda", ".usda"))
    return Usd.Stage.Open(str(src)), Usd.Stage.Open(str(report.output))


def scene_run(run_scene, name):
    """``(report, input stage, output stage)`` of scene ``name``'s session run (`scene_stages`)."""
    report = run_scene(name)
    return (report, *scene_stages(report))


def display_points(stage, path, frame=None) -> np.ndarray:
    """``points (n, 3) float64`` of the Mesh at ``path`` at ``frame`` (its default value if None)."""
    from pxr import Usd, UsdGeom

    attr = UsdGeom.Mesh(stage.GetPrimAtPath(path)).GetPointsAttr()
    return np.asarray(attr.Get(Usd.TimeCode.Default() if frame is None else frame), dtype=np.float64)


def elastic_state(stage, path, frame):
    """The carried elastic field of the deformable at ``path`` as the output layer holds it at
    ``frame``: level-0 vectors ``(nu*nv, 3) float32``, offsets ``(c, 3) float32`` and each
    offset's level ``(c,) int``."""
    prim = stage.GetPrimAtPath(path)
    cvs = np.asarray(prim.GetAttribute("acra:state:elasticCvs").Get(frame))
    offsets = np.asarray(prim.GetAttribute("acra:state:elasticOffsets").Get(frame)).reshape(-1, 3)
    return cvs, offsets, np.asarray(prim.GetAttribute("acra:state:offsetLevel").Get(frame))


def elastic_levels(stage, path, frame):
    """The carried elastic field of a two-level deformable by level: level-0 vectors ``(nu*nv, 3)``
    and level-1 offsets ``(c, 3)`` (`elastic_state`)."""
    cvs, offsets, level = elastic_state(stage, path, frame)
    return cvs, offsets[level == 1]


# --- a tiny stage for command-line tests: a 4x4 sheet and a box that presses into it -----------


def write_tiny_stage(path, frames=3, n=4, levels=1, samples=2, depth=0.1, top=1.0, end=None, sheet=None, **deformable):
    """Save a stage to ``path``: ``/World/Sheet`` (an ``n`` x ``n`` open sheet, 2 units wide, at
    z = 0) and ``/World/Mover/Box`` (a 1-unit collider box keyed from its centre at z = ``top``
    at frame 1 down to ``depth`` into the sheet at frame ``frames``); the stage ends at ``end``
    (default ``frames``), and ``sheet(prim, cvs)`` adds to the sheet's prim. Returns the path."""
    from acra import shapes
    from pipeline import authoring

    stage = authoring.new_stage(1, frames if end is None else end, fps=24, up_axis="Z")
    cvs, _, _ = shapes.sheet(n, n, width=2.0, depth=2.0)
    deformable.setdefault("absorption", [0.0] * (levels - 1) + [1.0])
    prim = authoring.add_deformable(stage, "/World/Sheet", cvs, levels=levels, samples=samples, **deformable)
    if sheet is not None:
        sheet(prim, cvs)
    verts, faces = authoring.box(1.0)
    mover = authoring.add_xform(stage, "/World/Mover")
    authoring.add_collider(stage, "/World/Mover/Box", verts, faces)
    authoring.key_transform(mover, 1, translate=(0.0, 0.0, top))
    authoring.key_transform(mover, frames, translate=(0.0, 0.0, 0.5 - depth))
    return authoring.save(stage, path)


@pytest.fixture
def tiny_stage(tmp_path):
    """``tiny_stage(name="tiny.usda", **kw)`` → path of a `write_tiny_stage` stage in ``tmp_path``."""

    def make(name="tiny.usda", **kw):
        return write_tiny_stage(tmp_path / name, **kw)

    return make


# --- what a response moved: the animator's surface against the output layer's --------------------


def surface_moves(report, path: str, frame: int, steps: int = 8):
    """The deformable ``path`` at ``frame`` of a finished run: world points ``(m, 3) float64`` of
    the animator's surface on a grid of ``steps`` per level-0 patch edge, their parameters
    ``(m, 2) float64``, and each one's world move ``(m, 3) float64`` to the responded surface (the
    output layer's ``acra:response:*``, double precision) at the same parameters."""
    from pxr import Usd

    from acra import hspline
    from pipeline import output_layer, usdio
    from pipeline.model import apply_xform

    src, out = Usd.Stage.Open(str(report.stage_path)), Usd.Stage.Open(str(report.output))
    k = [m.path for m in report.scene.deformables].index(path)
    state = usdio.state_at(src, report.scene, frame)[0][k]
    after = output_layer.read_output_hierarchy(out, path, frame)
    axes = [np.arange(d.patches0 * steps + (0 if d.periodic else 1)) / steps for d in (after.u, after.v)]
    uv = np.stack([a.ravel() for a in np.meshgrid(*axes, indexing="ij")], axis=1)
    world = [apply_xform(state.xform, hspline.evaluate(hs, uv[:, 0], uv[:, 1], det=hspline.details(hs)).points)
             for hs in (state.surface, after)]
    return world[0], uv, world[1] - world[0]


def deepest_move(report, path: str, frame: int):
    """Where a response moved the deformable ``path`` most at ``frame`` (`surface_moves`): that
    point's world position ``(3,)`` and parameters ``(2,)``, its move's length, and the largest
    move along world x or y of any point (0 for a press straight down)."""
    p, uv, d = surface_moves(report, path, frame)
    move = np.linalg.norm(d, axis=1)
    k = int(np.argmax(move))
    return p[k], uv[k], float(move[k]), float(np.abs(d[:, :2]).max())


# --- random triangle sets ------------------------------------------------------------------------


def soup(seed: int, n: int) -> np.ndarray:
    """``n`` random triangles of random sizes (a few long slivers among them)."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-1, 1, (n, 1, 3))
    return centre + rng.normal(size=(n, 3, 3)) * rng.choice([0.01, 0.1, 0.5], size=(n, 1, 1))


def rotated_scaled(seed):
    """A seeded matrix ``(4, 4)``: rotation, non-uniform scale and a translation."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q @ np.diag(rng.uniform(0.3, 3.0, 3))
    m[:3, 3] = rng.normal(size=3) * 5
    return m


# --- a real `acra run` interrupted half-way ------------------------------------------------------


def interrupted_run(src, out, sig, delay: float = 0.0, extra=(), env=None):
    """Run ``acra run SRC -o OUT [EXTRA]`` as a real process in ``out``'s directory, send ``sig``
    ``delay`` seconds after it reports its first frame, and return (exit status, stderr, the
    names of the files in that directory).

    The run is started as from a terminal: SIGINT and SIGTERM at their default actions, whatever
    the test runner inherited (a shell without job control starts background jobs, and so their
    children, with SIGINT ignored, and an ignored signal stays ignored across exec)."""
    work = out.parent
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(out), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=work,
        preexec_fn=lambda: [signal.signal(s, signal.SIG_DFL) for s in (signal.SIGINT, signal.SIGTERM)])
    lines, started = [], threading.Event()

    def read():
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("acra: frame 1 done"):
                started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert started.wait(timeout=120), "".join(lines)
        threading.Event().wait(delay)
        proc.send_signal(sig)
        proc.wait(timeout=120)
        reader.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, "".join(lines), sorted(p.name for p in work.iterdir())


def usd_array_text(values, type_name: str) -> str:
    """USD's own `.usda` text of the array ``values`` as an attribute of ``type_name``
    (``"float3[]"``, ``"double2[]"``, ``"int[]"``, …): what its text writer puts after ``= ``,
    the text `acra.floattext` is held to."""
    from pxr import Sdf

    kind = Sdf.ValueTypeNames.Find(type_name)
    layer = Sdf.Layer.CreateAnonymous("t.usda")
    prim = Sdf.CreatePrimInLayer(layer, "/A")
    Sdf.AttributeSpec(prim, "v", kind, Sdf.VariabilityVarying, True).default = kind.type.pythonClass.FromNumpy(np.ascontiguousarray(values))
    line = next(x for x in layer.ExportToString().splitlines() if f"{type_name} v = " in x)
    return line.split(" = ", 1)[1]


def responded_sphere(seed, absorption=(0, 0.5, 0.5)):
    """A closed sphere with random offsets, level 2 movable about a random patch, and a response
    there seeded with it as parent: ``hs``, ``out``, the response's report, the generator and the
    response's world point ``p (1, 3)``."""
    from acra import respond as R
    from acra.controls import check_controls
    from acra.targets import DataPoints
    from pipeline import shape as S

    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(24, 16), depth=3)
    u0 = int(rng.integers(0, 24))
    hs = with_random_offsets(H.make_movable(hs, 2, [[4 * u0, 24]]), 0.02, seed)
    uv = np.array([[u0 + rng.uniform(0, 1), 6 + rng.uniform(0, 1)]])
    p = H.evaluate(hs, uv[:, 0], uv[:, 1]).points
    out, rep = R.respond(hs, DataPoints(uv, 0.9 * p, np.array([True])), check_controls(3, absorption=list(absorption)))
    S.seed_details(out, rep.details, parent=hs)
    return hs, out, rep, rng, p
