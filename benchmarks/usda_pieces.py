"""The demo run's `.usda` layer written as `output_layer._Text` writes it (its pieces gathered by
`os.writev`) against one `write` per piece through a buffered file, CPU (user and system) ms.

    PYTHONPATH=$PWD python3 benchmarks/usda_pieces.py [--repeat 8]

Runs `scenes/dog_head_spike.py` once (`acra run`'s `run_file`), keeps the layer's `_Text` (its
text and its arrays' texts), then writes it to new files in a temporary directory, the two ways
alternated, and prints the medians. Both write the same bytes.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import resource
import statistics
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _cpu() -> tuple[float, float]:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime, r.ru_stime


def _piece_by_piece(text, path: str) -> None:
    """One `write` per piece through Python's buffered file."""
    view, at = memoryview(text.text), 0
    with open(path, "wb") as fh:
        for m in text.pattern.finditer(text.text):
            fh.write(view[at:m.start()])
            fh.write(text.values[text.which[m.group()]])
            at = m.end()
        fh.write(view[at:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=8)
    args = ap.parse_args()
    from pipeline import output_layer
    from pipeline.run import run_file

    kept = []
    export = output_layer._Text.Export

    def grab(self, path):
        kept.append(self)
        return export(self, path)

    output_layer._Text.Export = grab
    work = pathlib.Path(tempfile.mkdtemp())
    src = work / "dog_head_spike.py"
    src.write_text((ROOT / "scenes" / "dog_head_spike.py").read_text())
    run_file(src, work / "out.usda")
    text = kept[-1]
    ways = {"os.writev of the pieces (`_Text.Export`)": lambda p: export(text, p), "one write a piece, buffered": lambda p: _piece_by_piece(text, p)}
    spent: dict = {name: [] for name in ways}
    for i in range(args.repeat):
        for name in (list(ways) if i % 2 else list(ways)[::-1]):
            path = str(work / f"{i}.usda")
            u0, s0 = _cpu()
            ways[name](path)
            u1, s1 = _cpu()
            spent[name].append((u1 - u0, s1 - s0))
            os.unlink(path)
    size = os.path.getsize(work / "out.usda") / 1e6
    print(f"dog_head_spike's layer, {size:.1f} MB, medians of {args.repeat} writes to new files, CPU ms\n")
    print("| way | user | system | both |\n|---|---:|---:|---:|")
    for name, v in spent.items():
        print(f"| {name} | {1e3 * statistics.median(u for u, _ in v):.1f} | {1e3 * statistics.median(s for _, s in v):.1f} "
              f"| {1e3 * statistics.median(u + s for u, s in v):.1f} |")


if __name__ == "__main__":
    main()
