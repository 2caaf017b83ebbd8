"""What the first run after a fresh install compiles (docs/performance.md, *The first run after a
fresh install*): numba compiles its own implementations, such as the stable ``np.argsort``, once
per argument type, inside the first kernel that calls them, about 1 s CPU each."""

import numba
from numba.core import types
from numba.core.compiler import CompilerBase, DefaultPassBuilder, Flags
from numba.core.registry import cpu_target
from numba.core.typed_passes import NopythonTypeInference

from acra import bvh, floattext, kdtree, lattice, meshrows, pseudonormals


class _TypingOnly(CompilerBase):
    """numba's pipeline up to type inference: the argument types of every call, no lowering."""

    def define_pipelines(self):
        pm = DefaultPassBuilder.define_untyped_pipeline(self.state)
        pm.add_pass(NopythonTypeInference, "nopython frontend")
        pm.finalize()
        return [pm]


def _typed(kernel, *argtypes):
    """numba's pipeline state after typing ``kernel`` for arguments ``argtypes`` (the kernels its
    calls reach are compiled, as on a first run)."""
    typing, target = cpu_target.typing_context, cpu_target.target_context
    typing.refresh()
    target.refresh()
    flags = Flags()
    flags.nrt = True
    pipeline = _TypingOnly(typing, target, None, argtypes, None, flags, {})
    pipeline.state.cr = None
    try:
        pipeline.compile_extra(kernel.py_func)
    except numba.core.errors.CompilerError:  # no lowering pass: the pipeline ends after typing
        pass
    return pipeline.state


def _argsort_keys(kernel, *argtypes) -> set:
    """The types of the keys ``kernel``'s ``np.argsort`` calls take for arguments ``argtypes``."""
    st = _typed(kernel, *argtypes)
    return {sig.args[0] for expr, sig in st.calltypes.items()
            if getattr(expr, "op", None) == "call" and "argsort" in str(st.typemap[expr.func.name])}


def test_every_kernels_merge_sort_takes_one_key_type():
    """The kernels' stable sorts all take C-contiguous int64 keys (uint64 and float64 keys mapped
    to int64 of the same order), so numba compiles its merge sort once, not once per key type."""
    arr = lambda dtype, ndim: types.Array(dtype, ndim, "C")  # noqa: E731
    keys = set()
    keys |= _argsort_keys(bvh._stable_order, arr(types.int64, 1))
    keys |= _argsort_keys(meshrows._distinct_rows, arr(types.uint64, 2), arr(types.int64, 1), arr(types.int64, 1))
    keys |= _argsort_keys(pseudonormals.weld, arr(types.float64, 2), arr(types.int64, 2), types.float64)
    keys |= _argsort_keys(pseudonormals.part_mesh, arr(types.float64, 2), arr(types.int64, 2), types.float64,
                          types.boolean)
    keys |= _argsort_keys(lattice.adaptive_mesh, *[arr(types.int64, 1)] * 3, types.int64, types.int64, types.int64,
                          types.boolean, types.boolean)
    keys |= _argsort_keys(lattice.quadtree_leaves, types.int64, types.int64, arr(types.int64, 1), arr(types.int64, 1))
    assert keys == {arr(types.int64, 1)}


def test_the_kd_tree_split_is_compiled_once():
    """`kdtree._build` passes its split axis to `kdtree._select` as an int64 from the start: typing
    it once as the literal 0 of its first assignment would compile `_select` a second time."""
    arr = lambda dtype, ndim: types.Array(dtype, ndim, "C")  # noqa: E731
    i64 = arr(types.int64, 1)
    _typed(kdtree._build, arr(types.float64, 2), i64, i64, i64, i64, arr(types.float64, 1), i64)
    assert kdtree._select.signatures
    assert not any(isinstance(a, types.Literal) for sig in kdtree._select.signatures for a in sig)


def test_the_text_kernels_rare_value_helpers_compile_once():
    """`floattext._float32_text` and `floattext._tuples_text` pass the count of values left to
    USD's writer to their rare values' helpers as an int64 from the start: typed as the literal
    0 of its first assignment, `_put_rare` and `_put_found` would each compile a second time."""
    arr = lambda dtype, readonly=False: types.Array(dtype, 1, "C", readonly=readonly)  # noqa: E731
    _typed(floattext._float32_text, arr(types.uint32), types.int64, arr(types.bool_), arr(types.uint8, True), arr(types.int64),
           arr(types.uint8, True), arr(types.int64), arr(types.uint8))
    _typed(floattext._tuples_text, types.int64, types.int64, arr(types.bool_), arr(types.int64), arr(types.int64), arr(types.int8),
           arr(types.uint8, True), arr(types.int64), arr(types.bool_), arr(types.uint8, True), arr(types.int64), arr(types.uint8))
    for helper in (floattext._put_rare, floattext._put_found):
        assert helper.signatures
        assert not any(isinstance(a, types.Literal) for sig in helper.signatures for a in sig)
