"""acra.kernelcache: numba's cache loads read the defined symbols from the object code and parse
the linkable bitcode only when another kernel links the loaded one in."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import acra  # noqa: F401  (installs the cache loads)
from acra import bvh, floattext, kernelcache

ROOT = Path(__file__).resolve().parents[1]


def _child(code: str, cwd: Path, extra_path: Path | None = None) -> dict:
    """Run ``code`` in a fresh interpreter (this checkout and ``extra_path`` importable); its
    last stdout line, JSON."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(str(p) for p in (extra_path, ROOT) if p is not None)
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_not_elf_is_none():
    assert kernelcache.defined_symbols(b"") is None
    assert kernelcache.defined_symbols(b"\xcf\xfa\xed\xfe" + bytes(200)) is None  # Mach-O 64
    assert kernelcache.defined_symbols(b"\x7fELF\x01\x01" + bytes(200)) is None  # 32-bit
    assert kernelcache.defined_symbols(b"\x7fELF\x02\x01" + bytes(58)) is None  # no section table


def test_numba_skips_pyyaml_unless_a_numba_config_file_is_here(tmp_path):
    """Importing acra imports numba without PyYAML where the working directory holds no
    ``.numba_config.yaml`` (numba reads nothing else with it); PyYAML stays importable, and a
    directory with the file gets numba's own reading of it."""
    code = """
        import json, sys
        import acra
        from numba.core import config
        without = "yaml" in sys.modules
        import yaml
        print(json.dumps([without, yaml.safe_load("a: 1"), config.DEVELOPER_MODE]))
    """
    assert _child(code, tmp_path) == [False, {"a": 1}, 0]
    (tmp_path / ".numba_config.yaml").write_text("developer_mode: 1\n")
    assert _child(code, tmp_path) == [True, {"a": 1}, 1]


def test_install_is_idempotent_and_installed():
    from numba.core import codegen

    first = codegen.CPUCodeLibrary._unserialize
    assert kernelcache.install() is True
    assert codegen.CPUCodeLibrary._unserialize.__func__ is first.__func__
    assert getattr(first, "_acra", False)


PROBE = """
import json, sys
{before}
from llvmlite import binding as ll
parsed = []
parse = ll.parse_bitcode
def counted(data):
    parsed.append(len(data))
    return parse(data)
ll.parse_bitcode = counted
import numba.core.caching as caching
loads = []
load = caching.Cache.load_overload
def kept(self, sig, ctx):
    got = load(self, sig, ctx)
    loads.append(got is not None)
    return got
caching.Cache.load_overload = kept
import kernels
out = {{"value": float(kernels.scaled_sum(kernels.np.arange(5.0), 2.0)), "loads": loads, "parsed_on_load": len(parsed)}}
from numba import njit
@njit
def linked(x):  # compiled here: links the cached kernel in
    return kernels.scaled_sum(x, 3.0) + 1.0
out["linked"] = float(linked(kernels.np.arange(5.0)))
out["parsed_after_link"] = len(parsed)
print(json.dumps(out))
"""

KERNELS = """
import numpy as np
from numba import njit

@njit(cache=True)
def scaled_sum(x, s):
    t = 0.0
    for v in x:
        t += s * v
    return t
"""


@pytest.mark.parametrize("installed", [True, False])
def test_cached_kernel_loads_without_parsing_and_links_later(tmp_path, installed):
    """A cached kernel loads without its bitcode parsed (numba's own load parses it once), gives
    the same answer, and a kernel compiled later that calls it links it in (parsed then)."""
    (tmp_path / "kernels.py").write_text(KERNELS)
    before = "import acra" if installed else ""
    first = _child(PROBE.format(before=before), tmp_path, tmp_path)  # compiles and writes the cache
    assert first["loads"] == [False] and first["value"] == 20.0 and first["linked"] == 31.0
    again = _child(PROBE.format(before=before), tmp_path, tmp_path)
    assert again["loads"] == [True]
    assert again["value"] == 20.0 and again["linked"] == 31.0
    if installed:
        assert again["parsed_on_load"] == 0
        assert again["parsed_after_link"] == 1
    else:
        assert again["parsed_on_load"] == 1


ACRA_LOADS = """
import json
import acra
from llvmlite import binding as ll
import numba.core.caching as caching
from acra import kernelcache
objects, libs = [], []
symbols = kernelcache.defined_symbols
def seen(obj):
    objects.append(obj)
    return symbols(obj)
kernelcache.defined_symbols = seen
load = caching.Cache.load_overload
def kept(self, sig, ctx):
    got = load(self, sig, ctx)
    if got is not None:
        libs.append((objects[-1], got.library._acra_bitcode))
    return got
caching.Cache.load_overload = kept
import numpy as np
from acra import bvh, floattext
floattext.tuples_text(np.linspace(-2.0, 3.0, 30, dtype=np.float32).reshape(10, 3), lambda v: [repr(float(x)) for x in v])
tri = np.random.default_rng(1).random((40, 3, 3))
bvh.closest(bvh.build(tri), np.random.default_rng(2).random((7, 3)))
report = []
for obj, bitcode in libs:
    mod = ll.parse_bitcode(bitcode)
    want = {g.name for gs in (mod.functions, mod.global_variables) for g in gs if not g.is_declaration}
    have = symbols(obj)
    report.append([len(want), len(want - have)])
print(json.dumps(report))
"""


def test_object_code_defines_every_symbol_the_bitcode_does(tmp_path):
    """For acra's kernels loaded from the cache, the object file's defined symbols include every
    symbol the kernel's linkable bitcode defines (what numba's own load notes)."""
    floattext.tuples_text(np.ones((2, 3), np.float32), lambda v: [repr(float(x)) for x in v])  # compiled and cached
    bvh.closest(bvh.build(np.random.default_rng(1).random((40, 3, 3))), np.zeros((1, 3)))
    report = _child(ACRA_LOADS, tmp_path)
    assert len(report) >= 4  # the kernels loaded from the cache in the child
    for want, missing in report:
        assert want > 0 and missing == 0


HELD_BACK = """
import json, math
import acra
import numpy as np
from numba import njit, typed, types
from numba.core.registry import cpu_target
from numba.core.typing import npydecl
import kernels
value = float(kernels.scaled_sum(np.arange(5.0), 2.0))  # loaded from the cache
typing = cpu_target.typing_context
held = npydecl.registry not in typing._registries
@njit
def later(x):  # compiled after the load: numpy's, math's and a typed dict's declarations, the cached kernel linked
    d = typed.Dict.empty(key_type=types.int64, value_type=types.float64)
    for i in range(x.size):
        d[i] = math.sqrt(x[i])
    return np.sum(np.sort(x)) + d[4] + kernels.scaled_sum(x, 1.0)
print(json.dumps({"value": value, "held": held, "later": float(later(np.arange(5.0))),
                  "installed": npydecl.registry in typing._registries}))
"""


def test_a_cache_load_holds_back_the_declarations_until_a_compile(tmp_path):
    """A cache load refreshes numba's contexts without installing the typing and lowering
    declarations (`kernelcache._refresh_for_loads`); a function compiled after it gets them all
    (numpy, math, typed containers) and links the loaded kernel in."""
    (tmp_path / "kernels.py").write_text(KERNELS)
    _child(PROBE.format(before="import acra"), tmp_path, tmp_path)  # compiles and writes the cache
    got = _child(HELD_BACK, tmp_path, tmp_path)
    assert got == {"value": 20.0, "held": True, "later": 10.0 + 2.0 + 10.0, "installed": True}


def test_dependency_stamp_covers_the_modules_a_file_imports_transitively(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from . import b\n")
    (pkg / "b.py").write_text("def f():\n    from .c import x\n")
    (pkg / "c.py").write_text("x = 1\n")
    (pkg / "d.py").write_text("y = 1\n")
    a = str(pkg / "a.py")
    first = kernelcache.dependency_stamp(a)
    (pkg / "d.py").write_text("y = 2\n")  # imported by nothing a imports
    assert kernelcache.dependency_stamp(a) == first
    (pkg / "c.py").write_text("x = 22\n")  # a -> b -> c, imported inside a function
    second = kernelcache.dependency_stamp(a)
    assert second != first
    (pkg / "c.py").write_text("x = 1\n")  # content, not time: the same text gives the same stamp
    assert kernelcache.dependency_stamp(a) == first


def test_a_kernel_compiles_again_when_a_kernel_it_calls_changes(tmp_path):
    """numba checks a cached kernel against its own file alone; a kernel holds the code of the
    kernels it calls, so a changed callee must not leave the caller's old code running."""
    pkg = tmp_path / "kpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "callee.py").write_text("from numba import njit\n\n\n@njit(cache=True)\ndef f():\n    return 1\n")
    (pkg / "caller.py").write_text("from numba import njit\n\nfrom . import callee\n\n\n"
                                   "@njit(cache=True)\ndef g():\n    return callee.f() + 10\n")
    code = f"""
        import json, os
        os.environ["NUMBA_CACHE_DIR"] = {str(tmp_path / "cache")!r}
        import acra
        from acra import kernelcache
        kernelcache._PACKAGES += ({str(pkg)!r},)
        from kpkg import caller
        print(json.dumps({{"g": int(caller.g()), "stats": [len(caller.g.stats.cache_hits), len(caller.g.stats.cache_misses)]}}))
    """
    assert _child(code, tmp_path, tmp_path)["g"] == 11
    assert _child(code, tmp_path, tmp_path) == {"g": 11, "stats": [1, 0]}  # loaded from the cache
    (pkg / "callee.py").write_text("from numba import njit\n\n\n@njit(cache=True)\ndef f():\n    return 2\n")
    assert _child(code, tmp_path, tmp_path)["g"] == 12
