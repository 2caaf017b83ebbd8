"""What a round's display evaluation would save by starting its vertices from kept partial sums.

    PYTHONPATH=$PWD python3 benchmarks/partial_sums.py [--repeat 30]

`acra.kernels.eval_points` sums a point's levels in ascending order into one running sum. A
response changes only some levels of a surface (its absorbing levels), so through the level ``j
- 1`` below the lowest level ``j`` that differs from the surface a round's display is evaluated
since (`pipeline.display.Displays._nearest`), a vertex's running sum holds the same bits in the
two evaluations: kept for the vertices the earlier display evaluated (points and first
derivatives, 9 floats a vertex), the round's evaluation could start each of them there and add
levels ``j..top`` alone, the same additions in the same order.

Runs `dog_head_spike` frame 5, then frames 13-17 once to warm up, then once more after
`pipeline.run.forget` and frame 5, recording every round's display evaluation
(`acra.tessellate._normals_into` inside `display.Displays._build`, with the display it is
evaluated since). Prints, per evaluation: the vertices evaluated, those the earlier display has
a vertex at (the same parameters), the lowest changed level ``j`` (bits of the level-0 CVs, then
each level's active patches, CV keys and detail vectors), the mean count of active levels below
``j`` and from ``j`` on at those vertices (`HSpline._terms_index`'s lookup), whether the earlier
display evaluated every one of them (so a sparse keep, the evaluated rows' sums alone, serves),
and the CPU milliseconds (``time.process_time``, least of ``--repeat``) of `eval_points` against
a copy of it that starts those vertices from their sums through level ``j - 1`` (`eval_from`,
the sums taken beforehand by `eval_points` with ``top = j - 1``), whose outputs it checks equal
bit for bit. Then the cost of keeping the sums: `acra.tessellate._carry` of a round's display
with 12 columns carried beside the points instead of 3 (the sums kept for every row, copied
with the display), and a fresh ``(m, 9) float64`` array written for the evaluated rows alone.
Sums are per collision frame over frames 13-17.
"""

from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
from numba import njit

from acra import hspline, tessellate
from acra.changes import bits
from acra.kernels import _add_term, _basis, _domain, _half, _same, _segment, eval_points
from pipeline import display, frames, usdio
from pipeline.run import forget

ROOT = pathlib.Path(__file__).resolve().parents[1]
FRAMES = list(range(13, 18))


@njit(nogil=True)
def eval_from(u, v, order, side, top, nu, u_periodic, nv, v_periodic, cvs,
              levels, keys, shifts, ends, patch_rows, table_rows, table, out, warm, first, init):
    """`eval_points` (the same arguments through ``out``), except that a point with ``warm[i]``
    (``(m,) bool``) starts from ``init[:, i] ((nslot, m, 3) float64)``, its sum through the
    visited levels before ``levels[first]``, and adds the levels from ``levels[first]`` on."""
    m = u.shape[0]
    p0u = nu if u_periodic else nu - 3
    p0v = nv if v_periodic else nv - 3
    nslot = 1 if order == 0 else (3 if order == 1 else 6)
    nlev = 0
    while nlev < levels.shape[0] and levels[nlev] <= top:
        nlev += 1
    base = table_rows[0]
    ru = np.zeros((3, 4))
    rv = np.zeros((3, 4))
    sum_ = np.zeros((6, 3))
    half = np.zeros((max(nlev, 1), 4, 3, 3))
    half_v = np.full(max(nlev, 1), np.nan)
    half_block = np.full(max(nlev, 1), -1, np.int64)
    rows0 = np.empty((4, 4), np.int64)
    last_key = np.full(nlev, -1, np.int64)
    last_row = np.full(nlev, -1, np.int64)
    last_pos = np.zeros(nlev, np.int64)
    seg_v = np.empty(nlev, np.int64)
    t_v = np.empty(nlev)
    last_v = np.nan
    for i in range(m):
        u0 = _domain(u[i], p0u, u_periodic)
        v0 = _domain(v[i], p0v, v_periodic)
        if u0 != u0 or v0 != v0:
            for s in range(nslot):
                for c in range(3):
                    out[s, i, c] = np.nan
            continue
        new_v = not _same(v0, last_v)
        last_v = v0
        start = 1
        if warm[i]:
            for s in range(nslot):
                for c in range(3):
                    sum_[s, c] = init[s, i, c]
            start = max(first, 1)
        else:
            su, tu = _segment(u0, 0, p0u, u_periodic, side)
            for s in range(nslot):
                for c in range(3):
                    sum_[s, c] = -0.0
            _basis(tu, 1.0, order, ru)
            if not (half_block[0] == su and _same(v0, half_v[0])):
                sv, tv = _segment(v0, 0, p0v, v_periodic, side)
                for a in range(4):
                    iu = su + a
                    if u_periodic and iu >= nu:
                        iu -= nu
                    for b in range(4):
                        iv = sv + b
                        if v_periodic and iv >= nv:
                            iv -= nv
                        rows0[a, b] = iu * nv + iv
                _basis(tv, 1.0, order, rv)
                _half(rv, order, cvs, rows0, 0, half[0])
                half_v[0], half_block[0] = v0, su
            _add_term(ru, order, half[0], sum_)
        for lv in range(1, nlev):
            k = levels[lv]
            if new_v:
                seg_v[lv], t_v[lv] = _segment(v0, k, p0v, v_periodic, side)
            if lv < start:
                continue
            su, tu = _segment(u0, k, p0u, u_periodic, side)
            sv, tv = seg_v[lv], t_v[lv]
            want = su * (p0v << k) + sv + shifts[lv - 1]
            if want == last_key[lv]:
                lo = last_row[lv]
            else:
                lo = 0 if lv == 1 else ends[lv - 2]
                hi = ends[lv - 1]
                if want > last_key[lv] >= 0:
                    lo = last_pos[lv]
                    step = 1
                    while lo + step < hi and keys[lo + step] < want:
                        lo += step
                        step <<= 1
                    hi = min(lo + step, hi)
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if keys[mid] < want:
                        lo = mid + 1
                    else:
                        hi = mid
                last_pos[lv] = lo
                if lo == ends[lv - 1] or keys[lo] != want:
                    lo = -1
                last_key[lv] = want
                last_row[lv] = lo
            if lo < 0:
                continue
            scale = float(1 << k)
            _basis(tu, scale, order, ru)
            if not (half_block[lv] == lo and _same(v0, half_v[lv])):
                _basis(tv, scale, order, rv)
                _half(rv, order, table, patch_rows[lo], base, half[lv])
                half_v[lv], half_block[lv] = v0, lo
            _add_term(ru, order, half[lv], sum_)
        for s in range(nslot):
            for c in range(3):
                out[s, i, c] = sum_[s, c]


@njit(nogil=True)
def active_levels(u, v, side, top, nu, u_periodic, nv, v_periodic, levels, keys, shifts, ends, below, j):
    """Per point ``(m,) float64`` of ``u, v``, the visited levels whose patch under it is active
    (level 0 always), counted into ``below (2, m) int64``: row 0 the levels under ``j``, row 1
    the others (`eval_points`' segments and key lookup)."""
    p0u = nu if u_periodic else nu - 3
    p0v = nv if v_periodic else nv - 3
    nlev = 0
    while nlev < levels.shape[0] and levels[nlev] <= top:
        nlev += 1
    for i in range(u.shape[0]):
        u0 = _domain(u[i], p0u, u_periodic)
        v0 = _domain(v[i], p0v, v_periodic)
        below[0 if j > 0 else 1, i] += 1
        for lv in range(1, nlev):
            k = levels[lv]
            su, _ = _segment(u0, k, p0u, u_periodic, side)
            sv, _ = _segment(v0, k, p0v, v_periodic, side)
            want = su * (p0v << k) + sv + shifts[lv - 1]
            lo = 0 if lv == 1 else ends[lv - 2]
            at = lo + np.searchsorted(keys[lo:ends[lv - 1]], want)
            if at < ends[lv - 1] and keys[at] == want:
                below[0 if k < j else 1, i] += 1


def lowest_changed(a: hspline.HSpline, da, b: hspline.HSpline, db) -> int:
    """The lowest level whose terms may differ between ``a`` (details ``da``) and ``b`` (``db``):
    the level-0 CVs' bits, then each level's visited active patches, CV keys and detail vectors'
    bits; ``b.depth`` where none does."""
    if a.cvs.shape != b.cvs.shape or np.any(bits(a.cvs) != bits(b.cvs)):
        return 0
    la, lb = (set(hs._terms_index[0].tolist()) for hs in (a, b))
    for k in range(1, b.depth):
        pa = a.level(k).patches if k in la else a.level(k).patches[:0]
        pb = b.level(k).patches if k in lb else b.level(k).patches[:0]
        if not (pa.size or pb.size):
            continue
        ka, kb = a.level(k).cv_keys, b.level(k).cv_keys
        if not (np.array_equal(pa, pb) and np.array_equal(ka, kb)):
            return k
        va, vb = da.vectors[k - 1], db.vectors[k - 1]
        if va.shape != vb.shape or np.any(bits(va) != bits(vb)):
            return k
    return b.depth


def least(f, repeat: int) -> float:
    """The least CPU milliseconds of ``repeat`` calls of ``f``."""
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        f()
        best = min(best, time.process_time() - t)
    return 1e3 * best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=30, help="calls to take the least of (default 30)")
    args = ap.parse_args()
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    frames.run_frames(stage, scene, [5])
    frames.respond_frames(stage, scene, FRAMES)

    calls: list = []  # (surface, details, u, v, rows, topology, the display it is evaluated since)
    carries: list = []  # `_carry`'s arguments of the rounds' displays
    built, normals_into, carry = display.Displays._build, tessellate._normals_into, tessellate._carry
    now: dict = {}
    evaluated: dict = {}  # id(a display's limit normals) -> the rows its evaluation took (frame 5's too)

    def build(self, p):
        now["plan"] = p
        try:
            return built(self, p)
        finally:
            now.pop("plan", None)

    def recording(hs, u, v, det, rows, points, limit):
        p = now.get("plan")
        if p is not None and p.surface is hs:
            old = p.old.display if isinstance(p.old, display._Pending) else p.old
            calls.append((hs, det, u.copy(), v.copy(), rows.copy(), p.built[0], old))
            evaluated[id(limit)] = rows.copy()
        return normals_into(hs, u, v, det, rows, points, limit)

    def carrying(*a):
        if now.get("plan") is not None and a[1].shape[0]:
            carries.append(a)
        return carry(*a)

    display.Displays._build, tessellate._normals_into, tessellate._carry = build, recording, carrying
    try:
        forget()
        frames.run_frames(stage, scene, [5])
        calls.clear(), carries.clear()
        frames.respond_frames(stage, scene, FRAMES)
    finally:
        display.Displays._build, tessellate._normals_into, tessellate._carry = built, normals_into, carry

    shown = sum(old is not None for *_, old in calls)
    print(f"dog_head_spike frames 13-17: {len(calls)} round display evaluations, {shown} of them since an earlier "
          f"display (listed), CPU ms least of {args.repeat}\n")
    print("| vertices | evaluated | on the earlier display | j | active levels < j / >= j | earlier evaluated them "
          "| `eval_points` | from kept sums | same bits |\n|---:|---:|---:|---:|---|---|---:|---:|---|")
    full_sum = part_sum = glue = compare = 0.0
    for hs, det, u, v, rows, topo, old in calls:
        ev = hspline.eval_arrays(hs, det)
        top, levels, keys, shifts, ends = ev[0], ev[6], ev[7], ev[8], ev[9]
        m = u.size
        if old is None or old.topology is None:
            continue
        if old.topology is topo:
            src, found = rows, np.ones(m, bool)
        else:
            src_all, found_all = tessellate._matched(old.topology, topo, None)
            src, found = src_all[rows], found_all[rows]
        j = lowest_changed(old.surface, old.details, hs, det)
        counts = np.zeros((2, m), np.int64)
        active_levels(u, v, 0, top, ev[1], ev[2], ev[3], ev[4], levels, keys, shifts, ends, counts, j)
        kept = evaluated.get(id(old.normals))
        had = bool(kept is not None and np.isin(src[found], kept).all())
        first = int(np.searchsorted(levels, j))
        warm = found if j > 0 else np.zeros(m, bool)
        init = np.empty((3, m, 3))
        if j > 0:
            eval_points(u, v, 1, 0, *hspline.eval_arrays(hs, det, j - 1), init)
        full, part = np.empty((3, m, 3)), np.empty((3, m, 3))
        eval_points(u, v, 1, 0, *ev, full)
        eval_from(u, v, 1, 0, *ev, part, warm, first, init)
        same = np.array_equal(full.view(np.int64), part.view(np.int64))
        tf = least(lambda: eval_points(u, v, 1, 0, *ev, full), args.repeat)
        tp = least(lambda: eval_from(u, v, 1, 0, *ev, part, warm, first, init), args.repeat)
        full_sum, part_sum = full_sum + tf, part_sum + tp
        if kept is not None:
            # what the round would add to find the sums: each warm vertex's place among the earlier
            # display's evaluated rows (none where they are its rows in its order; else the
            # evaluated rows' places by row, one scatter and one gather); and ``j`` by
            # `lowest_changed`, which `acra.changes.changed_cells` walks the same levels for
            def find():
                if found.all() and np.array_equal(kept, src):
                    return
                pos = np.empty(len(old.points), np.int64)
                pos[kept] = np.arange(kept.size)
                pos[src[found]]
            glue += least(find, args.repeat)
            compare += least(lambda: lowest_changed(old.surface, old.details, hs, det), args.repeat)
        lv = f"{counts[0, found].mean():.2f} / {counts[1, found].mean():.2f}" if found.any() else "—"
        print(f"| {topo.u.size:,} | {m:,} | {int(found.sum()):,} | {j} | {lv} | {'yes' if had else 'no'} "
              f"| {tf:.3f} | {tp:.3f} | {'yes' if same else 'NO'} |")
    n = len(FRAMES)
    print(f"\nper collision frame: `eval_points` {full_sum / n:.3f} ms, from kept sums {part_sum / n:.3f}, "
          f"saved {(full_sum - part_sum) / n:.3f}; the sums' places {glue / n:.3f}, j compared again "
          f"{compare / n:.3f}")

    narrow = wide = sparse = 0.0
    for a in carries:
        old_points, old_limit = a[0], a[1]
        rows = a[10].shape[0]
        cols12 = np.zeros((old_limit.shape[0], 12))
        cols12[:, :3] = old_limit

        def carried(limit_cols, old_cols, keep):
            points, limit = np.empty((rows, 3)), np.empty((rows, limit_cols))
            idx = carry(old_points, old_cols, *a[2:9], points, limit, a[11])
            if keep:
                np.empty((idx.size, 9)).fill(0.0)

        narrow += least(lambda: carried(3, old_limit, False), args.repeat)
        wide += least(lambda: carried(12, cols12, False), args.repeat)
        sparse += least(lambda: carried(3, old_limit, True), args.repeat)
    print(f"`_carry` of the rounds' displays ({len(carries)}), per collision frame: {narrow / n:.3f} ms; with 9 "
          f"columns more {wide / n:.3f} (+{(wide - narrow) / n:.3f}); with a fresh (m, 9) array for the rows "
          f"evaluated {sparse / n:.3f} (+{(sparse - narrow) / n:.3f})")


if __name__ == "__main__":
    main()
