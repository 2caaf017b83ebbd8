"""What the benchmarks that write their tables into a page share: the commit a run measured and
the replacement of the generated block between a page's two marker lines.

    from doc_tables import commit_of, replace_block
"""

from __future__ import annotations

import subprocess
from pathlib import Path


def commit_of(root: Path) -> str:
    """Short commit of the checkout ``root`` (``+`` when it has uncommitted changes), or '?'."""
    try:
        sha = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()
        return sha + ("+" if dirty else "")
    except (subprocess.CalledProcessError, FileNotFoundError):
        return "?"


def replace_block(text: str, block: str, begin: str, end: str) -> str:
    """``text`` with what lies between the lines ``begin`` and ``end`` replaced by ``block``;
    ``block`` alone if ``text`` has no such markers."""
    if begin not in text or end not in text:
        return block + "\n"
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{block}\n{end}{tail}"
