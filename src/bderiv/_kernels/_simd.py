"""Explicit 8-wide float64 vectors in numba: a type whose LLVM value is ``<8 x double>``.

Numba leaves the loops of the chain kernels scalar (it turns LLVM's SLP vectoriser off,
and its arrays carry no ``noalias``, so the loop vectoriser cannot prove the table rows
apart from the scratch rows). These intrinsics write the vector code directly: a row of
a table is one load, the arg-min one reduction, a compare and a count of trailing zeros.
LLVM legalises ``<8 x double>`` on every target (one AVX-512 register, two AVX2 or four
NEON registers), so the same code compiles everywhere; ``BDERIV_KERNELS=plain`` selects
the scalar kernels instead (see ``_core.PLAIN``).

Loads and stores address 8 consecutive float64 of a C-contiguous 2-D array at
``a[row, col]`` (no bounds check: callers pad rows to a multiple of 8).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, register_model

#: lanes of one vector
WIDTH = 8
_VEC = ir.VectorType(ir.DoubleType(), WIDTH)
_I32 = ir.IntType(32)


class F64x8(types.Type):
    """Numba type of an ``<8 x double>`` value (lives in registers, never in arrays)."""

    def __init__(self):
        super().__init__(name="f64x8")


f64x8 = F64x8()


@register_model(F64x8)
class _F64x8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _VEC)


def _address(context, builder, aryty, ary, row, col):
    arr = context.make_array(aryty)(context, builder, ary)
    ptr = cgutils.get_item_pointer(context, builder, aryty, arr, [row, col], wraparound=False)
    return builder.bitcast(ptr, _VEC.as_pointer())


def _splat(builder, x):
    v = builder.insert_element(ir.Constant(_VEC, ir.Undefined), x, ir.Constant(_I32, 0))
    zeros = ir.Constant(ir.VectorType(_I32, WIDTH), [0] * WIDTH)
    return builder.shuffle_vector(v, ir.Constant(_VEC, ir.Undefined), zeros)


def _llvm_function(builder, name, ret, args):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, args), name)


@intrinsic
def load(typingctx, a, row, col):
    """a[row, col:col + 8] as a vector."""
    def codegen(context, builder, sig, args):
        return builder.load(_address(context, builder, sig.args[0], *args), align=8)
    return f64x8(a, row, col), codegen


@intrinsic
def store(typingctx, a, row, col, v):
    """a[row, col:col + 8] = v."""
    def codegen(context, builder, sig, args):
        builder.store(args[3], _address(context, builder, sig.args[0], *args[:3]), align=8)
        return context.get_dummy_value()
    return types.void(a, row, col, v), codegen


@intrinsic
def splat(typingctx, x):
    """(x, x, ..., x)."""
    def codegen(context, builder, sig, args):
        return _splat(builder, args[0])
    return f64x8(types.float64), codegen


@intrinsic
def mul(typingctx, a, b):
    """a * b, lane by lane."""
    def codegen(context, builder, sig, args):
        return builder.fmul(*args)
    return f64x8(a, b), codegen


@intrinsic
def sub(typingctx, a, b):
    """a - b, lane by lane."""
    def codegen(context, builder, sig, args):
        return builder.fsub(*args)
    return f64x8(a, b), codegen


@intrinsic
def total(typingctx, a):
    """The sum of the lanes (a tree of lane-wise sums)."""
    def codegen(context, builder, sig, args):
        return _tree(builder, args[0], builder.fadd)
    return types.float64(a), codegen


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c, lane by lane, fused (one rounding)."""
    def codegen(context, builder, sig, args):
        return builder.call(_llvm_function(builder, "llvm.fma.v8f64", _VEC, [_VEC] * 3), args)
    return f64x8(a, b, c), codegen


def _tree(builder, v, combine):
    """Lane 0 of three rounds of ``v = combine(v, v with its lanes rotated by 4, 2, 1)``."""
    undef = ir.Constant(_VEC, ir.Undefined)
    for half in (4, 2, 1):
        swap = ir.Constant(ir.VectorType(_I32, WIDTH), [(i + half) % WIDTH
                                                        for i in range(WIDTH)])
        v = combine(v, builder.shuffle_vector(v, undef, swap))
    return builder.extract_element(v, ir.Constant(_I32, 0))


@intrinsic
def smallest(typingctx, a):
    """The smallest lane (a NaN lane may or may not win: callers check what they select)
    as a tree of lane-wise minimums (``llvm.vector.reduce.fmin`` without fast-math flags
    lowers to a chain of scalar minimums with NaN checks)."""
    def codegen(context, builder, sig, args):
        return _tree(builder, args[0],
                     lambda v, w: builder.select(builder.fcmp_ordered("<", v, w), v, w))
    return types.float64(a), codegen


@intrinsic
def equal_mask(typingctx, a, x):
    """Bit k set iff lane k of a equals x."""
    def codegen(context, builder, sig, args):
        bits = builder.bitcast(builder.fcmp_ordered("==", args[0], _splat(builder, args[1])),
                               ir.IntType(WIDTH))
        return builder.zext(bits, ir.IntType(64))
    return types.int64(a, types.float64), codegen


@intrinsic
def where_bits(typingctx, a, bits, x):
    """a with every lane k whose bit k is set in ``bits`` (its low 8 bits) replaced by x."""
    def codegen(context, builder, sig, args):
        lanes = builder.bitcast(builder.trunc(args[1], ir.IntType(WIDTH)),
                                ir.VectorType(ir.IntType(1), WIDTH))
        return builder.select(lanes, _splat(builder, args[2]), args[0])
    return f64x8(a, types.int64, types.float64), codegen


@intrinsic
def trailing_zeros(typingctx, x):
    """Index of the lowest set bit of an int64 (64 for 0)."""
    def codegen(context, builder, sig, args):
        i64 = ir.IntType(64)
        fn = _llvm_function(builder, "llvm.cttz.i64", i64, [i64, ir.IntType(1)])
        return builder.call(fn, [args[0], ir.Constant(ir.IntType(1), 0)])
    return types.int64(types.int64), codegen


@intrinsic
def prefetch(typingctx, a, row, col):
    """Ask the cache for the line holding a[row, col] (a hint: no effect on results)."""
    def codegen(context, builder, sig, args):
        byte_ptr = ir.IntType(8).as_pointer()
        ptr = builder.bitcast(_address(context, builder, sig.args[0], *args), byte_ptr)
        i32 = ir.IntType(32)
        fn = _llvm_function(builder, "llvm.prefetch.p0", ir.VoidType(),
                            [byte_ptr, i32, i32, i32])
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()
    return types.void(a, row, col), codegen
