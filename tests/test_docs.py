"""The documentation site (`mkdocs.yml`, `docs/`) and every command the docs and README quote.

The site must build with ``mkdocs build --strict`` (any warning fails: a broken link, a page
missing from the nav). Every command quoted in `docs/` and `README.md` must exist: each
``python3 benchmarks/NAME.py`` file, each ``python -m pipeline.NAME`` module, and each
``acra SUB --option`` an option of that sub-command in `pipeline.cli.build_parser`.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import cli

ROOT = Path(__file__).parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]

# a benchmark script, a pipeline module, an `acra` command with its arguments up to the end of
# the code span, line or shell comment
BENCHMARK = re.compile(r"python3? (benchmarks/[A-Za-z0-9_]+\.py)")
MODULE = re.compile(r"python3? -m (pipeline(?:\.[A-Za-z0-9_]+)+)")
ACRA = re.compile(r"(?<![\w./-])acra ([a-z]+)((?: [^`\n#]*)?)")


def _quoted(pattern: re.Pattern) -> list[tuple[str, re.Match]]:
    return [(page.name, match) for page in PAGES for match in pattern.finditer(page.read_text(encoding="utf-8"))]


def test_the_site_builds_without_warnings(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        if os.environ.get("ACRA_REQUIRE_DOCS"):
            pytest.fail("ACRA_REQUIRE_DOCS is set but mkdocs is not installed (pip install -e '.[test]')")
        pytest.skip("mkdocs is not installed (pip install -e '.[test]'); set ACRA_REQUIRE_DOCS to make this a failure")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "WARNING" not in done.stderr, done.stderr[-4000:]
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for page in sorted((ROOT / "docs").glob("*.md")):
        assert page.name in nav, f"{page.name} is not in mkdocs.yml's nav"
        assert (tmp_path / "site" / ("" if page.stem == "index" else page.stem) / "index.html").exists(), page.name


def test_every_quoted_benchmark_exists():
    quoted = _quoted(BENCHMARK)
    assert len(quoted) > 10  # the docs name their commands
    missing = sorted({(page, m.group(1)) for page, m in quoted if not (ROOT / m.group(1)).is_file()})
    assert not missing, missing


def test_every_quoted_pipeline_module_exists():
    quoted = _quoted(MODULE)
    assert quoted
    missing = sorted({(page, m.group(1)) for page, m in quoted if importlib.util.find_spec(m.group(1)) is None})
    assert not missing, missing


def _subcommands() -> dict[str, set[str]]:
    """Each `acra` sub-command's option strings, from the parser the command line uses."""
    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
    return {name: {s for a in sub._actions for s in a.option_strings} for name, sub in action.choices.items()}


def test_every_quoted_acra_command_and_option_exists():
    commands = _subcommands()
    quoted = _quoted(ACRA)
    assert any(m.group(1) == "run" for _, m in quoted) and any(m.group(1) == "bench" for _, m in quoted)
    wrong = []
    for page, m in quoted:
        sub, rest = m.group(1), m.group(2)
        if sub not in commands:
            wrong.append((page, m.group(0).strip(), f"no sub-command {sub!r}"))
            continue
        for option in re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", rest):
            if option not in commands[sub]:
                wrong.append((page, m.group(0).strip(), f"no option {option}"))
    assert not wrong, wrong


def test_the_getting_started_scene_builds_a_valid_stage(tmp_path):
    """The scene of docs/index.md, "Your first scene", as a reader would save it."""
    from pipeline import usdio

    (code,) = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "index.md").read_text(encoding="utf-8"), re.S)
    scene = tmp_path / "my_scene.py"
    scene.write_text(code, encoding="utf-8")
    namespace: dict = {}
    exec(compile(code, str(scene), "exec"), namespace)
    read = usdio.read_scene(namespace["build"]())
    assert [m.path for m in read.deformables] == ["/World/Cloth"] and len(read.colliders) == 1
