"""The `.usda` text of a run's collision frames' displays (`acra.floattext.tuples_texts`), timed.

    PYTHONPATH=$PWD python3 benchmarks/usda_text.py [SCENE.py] [--repeat 40]

Runs the scene once (`frames.run_frames`), then formats the display ``points`` and ``normals``
of its collision frames as `output_layer._SharedText` does in a layer of the collision frames
alone (`acra bench`'s collision-frame write): each attribute's first frame whole, each later
frame from the previous frame's text (`tuples_texts`' ``refs``), one call for all of them, with
USD's writer for the values the kernels leave to it (`output_layer._float_texts`). Prints the
CPU milliseconds (`time.process_time`) per collision frame, median and range over ``--repeat``
calls, and the same for the largest deformable's first collision frame's ``points`` formatted
whole; then the collision frames' response arrays of ``double3[]`` (each deformable's
``acra:response:cvs`` and ``acra:response:offsets`` of 64 tuples or more, those a layer writes
from `floattext`), formatted by `floattext.tuples_texts` and, for comparison, by USD's writer
(`Sdf.Layer.ExportToString` of a layer holding each as a default value); and the digits of the
largest deformable's display surface parameters (``acra:display:uv``, dyadic values of few bits)
by `doubledigits.shortest_digits64` (their exact decimal first), by Ryu's steps alone
(`doubledigits._d2s`, a loop compiled here) and by the exact decimal alone (`doubledigits._exact`, a loop compiled here). The last line is a
digest of every text made (SHA-1 of their bytes, first 12 hex digits), the same for two
checkouts that write the same text. The script imports `acra` and `pipeline` from
``PYTHONPATH``: run it with two checkouts' paths, alternated, to compare them on the same arrays.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import shutil
import statistics
import tempfile
import time

import numpy as np
from pxr import Sdf, Vt

from numba import njit

from acra import floattext

try:  # a checkout that writes float64 digits itself
    from acra import doubledigits
except ImportError:
    doubledigits = None
from acra.hspline import to_arrays
from pipeline import frames, output_layer, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def cpu_ms(fn, repeat: int) -> list[float]:
    """CPU milliseconds of each of ``repeat`` calls of ``fn()``."""
    spent = []
    for _ in range(repeat):
        t = time.process_time()
        fn()
        spent.append(1e3 * (time.process_time() - t))
    return spent


@njit(cache=False)
def exact_alone(bits):
    """`doubledigits._exact`'s digits of each nonzero finite float64 of ``bits (n,) uint64``."""
    cs = np.zeros(bits.shape[0], np.int64)
    ks = np.zeros(bits.shape[0], np.int64)
    for i in range(bits.shape[0]):
        b = np.int64(bits[i]) & 0x7FFFFFFFFFFFFFFF
        if b != 0 and (b >> 52) != 0x7FF:
            cs[i], ks[i], _ = doubledigits._exact(b)
    return cs, ks


@njit(cache=False)
def ryu_alone(bits):
    """`doubledigits._d2s`'s digits of each nonzero finite float64 of ``bits (n,) uint64``."""
    cs = np.zeros(bits.shape[0], np.int64)
    ks = np.zeros(bits.shape[0], np.int64)
    for i in range(bits.shape[0]):
        b = np.int64(bits[i]) & 0x7FFFFFFFFFFFFFFF
        if b != 0 and (b >> 52) != 0x7FF:
            cs[i], ks[i] = doubledigits._d2s(b)
    return cs, ks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--repeat", type=int, default=40)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / args.scene.name
        shutil.copy(args.scene, src)
        stage = usdio.open_input(usdio.load_scene_file(src))
        scene = usdio.read_scene(stage)
        result, stats = frames.run_frames(stage, scene, list(range(scene.start, scene.end + 1)), frames.RunOptions())
    colliding = [s.frame for s in stats if s.in_collision]
    if not colliding:
        raise SystemExit(f"{args.scene.name}: no collision frame")
    arrays, refs = [], []
    for path in sorted(result.frames[colliding[0]]):
        for kind in ("points", "normals"):
            for f in colliding:
                refs.append(len(arrays) - 1 if f != colliding[0] else None)
                arrays.append(np.ascontiguousarray(getattr(result.frames[f][path], kind), dtype=np.float32))
    largest = max(sorted(result.frames[colliding[0]]), key=lambda p: len(result.frames[colliding[0]][p].points))
    whole = np.ascontiguousarray(result.frames[colliding[0]][largest].points, dtype=np.float32)
    floattext.tuples_texts(arrays, output_layer._float_texts, refs)  # kernels loaded or compiled
    rows = {
        f"the {len(colliding)} collision frames' display texts, per collision frame":
            [t / len(colliding) for t in cpu_ms(lambda: floattext.tuples_texts(arrays, output_layer._float_texts, refs), args.repeat)],
        f"{largest}'s frame-{colliding[0]} points ({len(whole)} tuples) whole":
            cpu_ms(lambda: floattext.tuples_texts([whole], output_layer._float_texts), args.repeat),
    }
    doubles = [a for f in colliding for path in sorted(result.frames[f]) for a in (
        usdio.cvs_to_flat(np.asarray(result.frames[f][path].surface.cvs, dtype=np.float64)),
        np.ascontiguousarray(to_arrays(result.frames[f][path].surface).offsets, dtype=np.float64)) if len(a) >= output_layer._SHARED_MIN]
    floattext.tuples_texts(doubles, output_layer._float_texts)
    layer = Sdf.Layer.CreateAnonymous("doubles.usda")
    prim = Sdf.CreatePrimInLayer(layer, "/A")
    for i, a in enumerate(doubles):
        Sdf.AttributeSpec(prim, f"v{i}", Sdf.ValueTypeNames.Double3Array, Sdf.VariabilityVarying, True).default = Vt.Vec3dArray.FromNumpy(a)
    name = f"the {len(colliding)} collision frames' response `double3[]` arrays ({len(doubles)}, {sum(map(len, doubles))} tuples), per collision frame"
    rows[name + ", `floattext`"] = [t / len(colliding) for t in cpu_ms(lambda: floattext.tuples_texts(doubles, output_layer._float_texts), args.repeat)]
    rows[name + ", USD's writer"] = [t / len(colliding) for t in cpu_ms(layer.ExportToString, args.repeat)]
    topology = result.topologies.get(largest) or next(m.topology for m in scene.deformables if m.path == largest)
    sites = np.ascontiguousarray(np.stack([topology.u, topology.v], axis=1), dtype=np.float64).reshape(-1).view(np.uint64)
    if doubledigits is not None:
        ryu_alone(sites)
        rows[f"{largest}'s display surface parameters ({sites.size} values), `shortest_digits64`"] = cpu_ms(lambda: doubledigits.shortest_digits64(sites), args.repeat)
        rows["the same, Ryu's steps alone"] = cpu_ms(lambda: ryu_alone(sites), args.repeat)
        exact_alone(sites)
        rows["the same, the exact decimal alone"] = cpu_ms(lambda: exact_alone(sites), args.repeat)
    digest = hashlib.sha1()
    for text in floattext.tuples_texts(arrays, output_layer._float_texts, refs) + floattext.tuples_texts(doubles, output_layer._float_texts):
        digest.update(text.tobytes())
    print(f"{args.scene.name}, CPU ms, median (range) of {args.repeat} calls\n")
    print("| text | CPU ms |\n|---|---:|")
    for name, v in rows.items():
        print(f"| {name} | {statistics.median(v):.3f} ({min(v):.3f}–{max(v):.3f}) |")
    print(f"\ndigest of the texts: {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
