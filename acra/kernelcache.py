"""Loading acra's compiled kernels from numba's on-disk cache without parsing their LLVM bitcode.

Every kernel of `acra` is ``njit(cache=True)``: a process after the first loads each kernel it
calls from numba's cache (``__pycache__/*.nbi``, ``*.nbc``) instead of compiling it. numba stores
a kernel as its machine code (an object file) and its linkable LLVM bitcode, which it needs only
to inline the kernel into a kernel compiled later. On a load, numba (0.60 to 0.68 at least) parses
that bitcode into an LLVM module and walks the module's functions and globals in Python to note
the symbols it defines, which the JIT's lookup of the kernel's entry point checks; together about
7 ms CPU a kernel, 70 % of a load, and a run of the demo loads about 50 kernels.

`install` makes a load read the defined symbols from the object file's symbol table instead
(`defined_symbols`: ELF, the format of Linux objects; a symbol is defined there when its section
index is not ``SHN_UNDEF``) and keep the bitcode as bytes, parsed the first time another kernel
links the loaded one in (`CPUCodeLibrary._get_module_for_linking`). The machine code run is the
same object code either way; only when and how the symbol names are found changes. Every symbol
the bitcode defines is defined in the object file (`tests/test_kernelcache.py` compares the two
sets for loaded kernels); should an entry point still be missing from the names read, its
library's bitcode is parsed and its symbols noted as numba does before the JIT is asked for it
(`JITCodeLibrary.get_pointer_to_function`), so a load never yields a null entry. An object file that is not 64-bit little-endian ELF (macOS's
Mach-O, Windows' COFF) or a numba whose code library lacks the methods used here is loaded by
numba's own code.

Before each load numba refreshes its target and typing contexts (``Cache.load_overload``): the
refresh imports numba's implementation modules, initialises its runtime (NRT) and third-party
extensions, and installs every registered typing and lowering declaration into the two contexts,
which initialises each overload template (each of those refreshes the target context again,
~250 nested refreshes). Only compiling reads those declarations, and numba's compiler refreshes
both contexts before it types a function (``CompilerBase``); a load rebuilds machine code that is
already typed and lowered. `install` makes a load refresh the contexts once with the installation
held back (`_refresh_for_loads`): every import and initialisation the refresh does still happens
then, and the declarations are installed, in the same order, at the first compile (0.15-0.2 s
CPU of a demo run: the first load's refresh and the other loads' 0.1 ms each).

numba keeps a cached kernel while its own source file is unchanged (the file's digest is the
cache's stamp), but a kernel holds the machine code of every compiled function it calls and every
global constant it reads, from other modules too: `acra.sides` compiles `acra.kernels.eval_points`
into its own code. `install` makes the stamp of a kernel defined in `acra` cover the modules its
file imports from `acra`, transitively (`dependency_stamp`), so a changed callee's module (an
upgrade, a checkout) makes every kernel that holds it compile again instead of running its
old code.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re

import numpy as np

__all__ = ["defined_symbols", "dependency_stamp", "install"]

_PACKAGES = (os.path.dirname(os.path.abspath(__file__)),)  # the directories whose kernels `dependency_stamp` stamps
# ``from acra[.m] import ...`` and ``from .[m] import ...``, at any indentation (a function may
# import where it is called), with a parenthesised list over several lines
_IMPORT = re.compile(r"^[ \t]*from[ \t]+(acra\.\w+|acra|\.\w+|\.)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)", re.M)

_SECTION = np.dtype([("name", "<u4"), ("type", "<u4"), ("flags", "<u8"), ("addr", "<u8"), ("offset", "<u8"),
                     ("size", "<u8"), ("link", "<u4"), ("info", "<u4"), ("align", "<u8"), ("entsize", "<u8")])
_SYMBOL = np.dtype([("name", "<u4"), ("info", "u1"), ("other", "u1"), ("shndx", "<u2"), ("value", "<u8"), ("size", "<u8")])
_SHT_SYMTAB = 2
_SHN_UNDEF = 0


def defined_symbols(obj: bytes) -> set[str] | None:
    """The names of the symbols a 64-bit little-endian ELF object file ``obj`` defines (section
    index not ``SHN_UNDEF``, a name given), or None where ``obj`` is not such a file with one
    symbol table."""
    if len(obj) < 64 or obj[:4] != b"\x7fELF" or obj[4] != 2 or obj[5] != 1:
        return None
    shoff = int.from_bytes(obj[0x28:0x30], "little")
    shentsize = int.from_bytes(obj[0x3A:0x3C], "little")
    shnum = int.from_bytes(obj[0x3C:0x3E], "little")
    if shentsize != _SECTION.itemsize or shoff + shnum * shentsize > len(obj):
        return None
    sections = np.frombuffer(obj, _SECTION, count=shnum, offset=shoff)
    which = np.flatnonzero(sections["type"] == _SHT_SYMTAB)
    if which.size != 1:
        return None
    table = sections[which[0]]
    if int(table["link"]) >= shnum or int(table["entsize"]) != _SYMBOL.itemsize:
        return None
    names = sections[int(table["link"])]
    start, size = int(table["offset"]), int(table["size"])
    nstart, nsize = int(names["offset"]), int(names["size"])
    if start + size > len(obj) or nstart + nsize > len(obj):
        return None
    symbols = np.frombuffer(obj, _SYMBOL, count=size // _SYMBOL.itemsize, offset=start)
    strings = obj[nstart:nstart + nsize]
    at = symbols["name"][(symbols["shndx"] != _SHN_UNDEF) & (symbols["name"] != 0)]
    return {strings[a:strings.index(b"\0", a)].decode() for a in at.tolist()}


@functools.lru_cache(maxsize=None)
def _file(path: str, mtime: float, size: int) -> tuple[bytes, tuple[str, ...]]:
    """The sha256 digest of the source file ``path`` and the files of the modules of its package
    it imports (`_IMPORT`), as of its ``mtime`` and ``size``."""
    with open(path, "rb") as f:
        text = f.read()
    here = os.path.dirname(path)
    names = set()
    for source, listed in _IMPORT.findall(text.decode("utf-8", "replace")):
        if source not in ("acra", "."):  # ``from acra.m import ...``, ``from .m import ...``
            names.add(source.rsplit(".", 1)[1])
        else:  # ``from acra import a, b as c``: modules, or names of the package's __init__
            names.update(n.split(" as ")[0].strip() for n in listed.strip("()").replace("\n", " ").split(","))
    files = (os.path.join(here, n + ".py") for n in sorted(names) if n.isidentifier())
    return hashlib.sha256(text).digest(), tuple(f for f in files if f != path and os.path.isfile(f))


def _stat(path: str) -> tuple[str, float, int]:
    st = os.stat(path)
    return path, st.st_mtime, st.st_size


def dependency_stamp(path: str) -> bytes:
    """A digest of the source file ``path`` and of every module of its package it imports,
    transitively: it differs whenever any of those files' contents do."""
    path = os.path.abspath(path)
    seen, todo = {}, [path]
    while todo:
        p = todo.pop()
        if p not in seen:
            seen[p] = _file(*_stat(p))
            todo.extend(seen[p][1])
    h = hashlib.sha256()
    for p in sorted(seen):
        h.update(os.path.basename(p).encode() + b"\0" + seen[p][0])
    return h.digest()


def _stamp_dependencies(caching) -> bool:
    """Make the cache stamp of a kernel defined in a module of this package `dependency_stamp`'s
    beside numba's own (the stamp is compared for equality when the cache index is read), where
    numba's source-file locators have the method this wraps."""
    mixin = getattr(caching, "_SourceFileBackedLocatorMixin", None)
    own = getattr(mixin, "get_source_stamp", None)
    if own is None or getattr(own, "_acra", False):
        return own is not None

    def get_source_stamp(self):
        stamp = own(self)
        path = getattr(self, "_py_file", None)
        if not isinstance(path, str) or os.path.dirname(os.path.abspath(path)) not in _PACKAGES or not os.path.isfile(path):
            return stamp
        return stamp, dependency_stamp(path)

    get_source_stamp._acra = True
    mixin.get_source_stamp = get_source_stamp
    return True


def _caching_methods_known() -> bool:
    """Whether numba's cache has the load this module replaces (``Cache.load_overload`` refreshing
    the target context, then ``_load_overload`` under ``_guard_against_spurious_io_errors``) and its
    contexts the refresh `_refresh_for_loads` holds the installation of."""
    from numba.core import base, caching
    from numba.core.typing import context

    cache = getattr(caching, "Cache", None)
    return (cache is not None and all(hasattr(cache, n) for n in ("load_overload", "_load_overload",
                                                                    "_guard_against_spurious_io_errors"))
            and all(hasattr(c, n) for c in (base.BaseContext, context.BaseContext)
                    for n in ("refresh", "install_registry")))


def _methods():
    """numba's code library class and the original methods `install` wraps, or None where this
    numba lacks any of them."""
    try:
        from numba.core import codegen
    except ImportError:  # pragma: no cover - numba is a dependency
        return None
    lib = getattr(codegen, "CPUCodeLibrary", None)
    jit = getattr(codegen, "JITCodeLibrary", None)
    need = ("_unserialize", "_get_module_for_linking", "enable_object_caching", "_set_compiled_object",
            "_finalize_final_module")
    if (lib is None or jit is None or not all(hasattr(lib, n) for n in need) or not hasattr(jit, "get_pointer_to_function")
            or not hasattr(getattr(codegen, "JitEngine", None), "_load_defined_symbols")):
        return None
    return codegen, lib, jit


def _refresh_for_loads(target_context) -> None:
    """Refresh ``target_context`` and its typing context as numba's cache load does, except that
    neither installs its registries' declarations (each context's ``install_registry`` is shadowed
    on the instance while the refresh runs): the refresh's imports, the runtime's initialisation and
    the extensions' entry points run; a later refresh (every compile's) installs everything
    registered by then. Once per target context."""
    if getattr(target_context, "_acra_refreshed_for_loads", False):
        return
    held = (target_context, target_context.typing_context)
    for ctx in held:
        ctx.install_registry = _held_back
    try:
        target_context.refresh()
    finally:
        for ctx in held:
            del ctx.install_registry
    target_context._acra_refreshed_for_loads = True


def _held_back(registry) -> None:
    """A context's ``install_registry`` while `_refresh_for_loads` runs: the registry's
    declarations stay queued in it for the next refresh."""


def install() -> bool:
    """Make numba's cache loads read the defined symbols from the object code and defer parsing
    the linkable bitcode (module docstring); idempotent. Returns whether the loads are changed
    (False where this numba's code library differs from the one described)."""
    from numba.core import caching

    _stamp_dependencies(caching)
    found = _methods()
    if found is None:
        return False
    codegen, lib, jit = found
    if getattr(lib._unserialize, "_acra", False):
        return True
    unserialize = lib._unserialize.__func__
    for_linking = lib._get_module_for_linking
    pointer = jit.get_pointer_to_function
    from llvmlite import binding as ll

    def _unserialize(cls, cg, state):
        name, kind, data = state
        names = defined_symbols(data[0]) if kind == "object" else None
        engine = getattr(cg, "_engine", None)
        if names is None or not isinstance(getattr(engine, "_defined_symbols", None), set):
            return unserialize(cls, cg, state)
        object_code, bitcode = data
        self = cg.create_library(name)
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        self._acra_bitcode = bitcode
        self._finalize_final_module()
        engine._defined_symbols |= names
        return self

    def _get_module_for_linking(self):
        bitcode = getattr(self, "_acra_bitcode", None)
        if bitcode is not None and self._shared_module is None:
            self._shared_module = ll.parse_bitcode(bitcode)
            self._acra_bitcode = None
        return for_linking(self)

    def get_pointer_to_function(self, name):
        # a name the object file's table did not give is looked up as numba's own load does, in
        # the bitcode's definitions, so a load never hands back a null entry point
        if getattr(self, "_acra_bitcode", None) is not None and not self._codegen._engine.is_symbol_defined(name):
            self._codegen._engine._load_defined_symbols(_get_module_for_linking(self))
        return pointer(self, name)

    def load_overload(self, sig, target_context):
        _refresh_for_loads(target_context)  # numba's refreshes it in full here
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    _unserialize._acra = True
    if _caching_methods_known():
        caching.Cache.load_overload = load_overload
    lib._unserialize = classmethod(_unserialize)
    lib._get_module_for_linking = _get_module_for_linking
    jit.get_pointer_to_function = get_pointer_to_function
    return True
