"""Explicit float64 vectors in numba: types whose LLVM value is ``<W x double>``.

Numba leaves the loops of the chain kernels scalar (it turns LLVM's SLP vectoriser off,
and its arrays carry no ``noalias``, so the loop vectoriser cannot prove the table rows
apart from the scratch rows). These intrinsics write the vector code directly: a row of
a table is one load, the arg-min one reduction, a compare and a count of trailing zeros.
A vector lives in registers (a local variable), never in an array.

The width W is a multiple of 8 up to 64, fixed at compile time by a :func:`static` value
passed to the kernel (numba compiles one specialisation per value, as it does per dtype):
``load``, ``load_first`` and ``splat`` take it, the other operations read W from their
operands.
LLVM legalises ``<W x double>`` on every target (W / 8 AVX-512 registers, W / 4 AVX2 or
W / 2 NEON registers), so the same code compiles everywhere; ``BDERIV_KERNELS=plain``
selects the scalar kernels instead (see ``_core.PLAIN``).

Loads and stores address W consecutive float64 of a C-contiguous 2-D array at
``a[row, col]`` (no bounds check: callers pad rows to a multiple of W), or the first
``count`` of them (``load_first``/``store_first``, for unpadded rows).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic, models, register_model

_I32 = ir.IntType(32)
_I64 = ir.IntType(64)


def static(value: int) -> tuple:
    """A non-negative int that kernels are compiled for (a vector width, a flag), as the
    tuple of ``value`` zeros: numba types it ``UniTuple(int64, value)``, so the value is in
    the type and numba compiles one specialisation per value, as it does per dtype. Pass it
    inside a kernel's tables; :func:`value` reads it as a constant (loops over it unroll).
    (A tuple and not a type of our own: numba's dispatcher recognises tuples in C, and a
    new type would send every call through Python's typeof: docs/benchmarks.md, "Kernel
    design choices, measured".)"""
    if isinstance(value, bool) or int(value) != value or value < 0:
        raise ValueError(f"a static value must be a non-negative int, got {value!r}")
    return (0,) * int(value)


class F64xW(types.Type):
    """Numba type of a ``<width x double>`` value."""

    def __init__(self, width: int):
        self.width = width
        super().__init__(name=f"f64x{width}")


def _static(w) -> int:
    """The int a :func:`static` tuple's type stands for."""
    if not isinstance(w, types.BaseTuple) or any(t != types.int64 for t in w):
        raise errors.TypingError(f"expected a static value (a tuple of int64 zeros), got {w}")
    return len(w)


def _width(w) -> int:
    """The vector width a static value stands for (a multiple of 8, at most 64)."""
    width = _static(w)
    if width % 8 or not 8 <= width <= 64:
        raise errors.TypingError(f"a vector width must be a static multiple of 8 in [8, 64], "
                                 f"got {width}")
    return width


@register_model(F64xW)
class _F64xWModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _vec(fe_type.width))


def _vec(width):
    return ir.VectorType(ir.DoubleType(), width)


def _address(context, builder, aryty, ary, row, col, width):
    arr = context.make_array(aryty)(context, builder, ary)
    ptr = cgutils.get_item_pointer(context, builder, aryty, arr, [row, col], wraparound=False)
    return builder.bitcast(ptr, _vec(width).as_pointer())


def _splat(builder, x, width, kind=None):
    vty = ir.VectorType(kind or ir.DoubleType(), width)
    v = builder.insert_element(ir.Constant(vty, ir.Undefined), x, ir.Constant(_I32, 0))
    zeros = ir.Constant(ir.VectorType(_I32, width), [0] * width)
    return builder.shuffle_vector(v, ir.Constant(vty, ir.Undefined), zeros)


def _first(builder, count, width):
    """The mask of lanes ``0 .. count - 1``."""
    lanes = ir.Constant(ir.VectorType(_I64, width), list(range(width)))
    return builder.icmp_signed("<", lanes, _splat(builder, count, width, _I64))


def _llvm_function(builder, name, ret, args):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, args), name)


def _suffix(width):
    return f"v{width}f64"


@intrinsic
def value(typingctx, w):
    """The int of a :func:`static` value, as a compile-time constant."""
    number = _static(w)

    def codegen(context, builder, sig, args):
        return context.get_constant(types.int64, number)
    return types.int64(w), codegen


@intrinsic
def load(typingctx, a, row, col, w):
    """a[row, col:col + W] as a vector (W: the static value ``w``)."""
    width = _width(w)

    def codegen(context, builder, sig, args):
        return builder.load(_address(context, builder, sig.args[0], *args[:3], width), align=8)
    return F64xW(width)(a, row, col, w), codegen


@intrinsic
def load_first(typingctx, a, row, col, count, w):
    """a[row, col:col + count] in the first ``count`` lanes (0 <= count <= W), zeros in
    the others; nothing beyond is read."""
    width = _width(w)

    def codegen(context, builder, sig, args):
        vty = _vec(width)
        fn = _llvm_function(builder, f"llvm.masked.load.{_suffix(width)}.p0", vty,
                            [vty.as_pointer(), _I32, ir.VectorType(ir.IntType(1), width), vty])
        ptr = _address(context, builder, sig.args[0], *args[:3], width)
        return builder.call(fn, [ptr, ir.Constant(_I32, 8), _first(builder, args[3], width),
                                 ir.Constant(vty, [0.0] * width)])
    return F64xW(width)(a, row, col, types.int64, w), codegen


@intrinsic
def store(typingctx, a, row, col, v):
    """a[row, col:col + W] = v."""
    def codegen(context, builder, sig, args):
        ptr = _address(context, builder, sig.args[0], *args[:3], v.width)
        builder.store(args[3], ptr, align=8)
        return context.get_dummy_value()
    return types.void(a, row, col, v), codegen


@intrinsic
def store_first(typingctx, a, row, col, count, v):
    """a[row, col:col + count] = the first ``count`` lanes of v (0 <= count <= W)."""
    def codegen(context, builder, sig, args):
        vty = _vec(v.width)
        fn = _llvm_function(builder, f"llvm.masked.store.{_suffix(v.width)}.p0",
                            ir.VoidType(),
                            [vty, vty.as_pointer(), _I32, ir.VectorType(ir.IntType(1), v.width)])
        ptr = _address(context, builder, sig.args[0], *args[:3], v.width)
        builder.call(fn, [args[4], ptr, ir.Constant(_I32, 8),
                          _first(builder, args[3], v.width)])
        return context.get_dummy_value()
    return types.void(a, row, col, types.int64, v), codegen


@intrinsic
def splat(typingctx, x, w):
    """(x, x, ..., x), W lanes."""
    width = _width(w)

    def codegen(context, builder, sig, args):
        return _splat(builder, args[0], width)
    return F64xW(width)(types.float64, w), codegen


def _lanewise(op):
    @intrinsic
    def lanewise(typingctx, a, b):
        def codegen(context, builder, sig, args):
            return getattr(builder, op)(*args)
        return a(a, b), codegen
    return lanewise


#: a + b, a - b, a * b, lane by lane
add, sub, mul = _lanewise("fadd"), _lanewise("fsub"), _lanewise("fmul")


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c, lane by lane, fused (one rounding)."""
    def codegen(context, builder, sig, args):
        vty = _vec(a.width)
        fn = _llvm_function(builder, f"llvm.fma.{_suffix(a.width)}", vty, [vty] * 3)
        return builder.call(fn, args)
    return a(a, b, c), codegen


def _tree(builder, v, width, combine):
    """Lane 0 of: the 8-lane chunks of v combined lane by lane (in order), then three
    rounds of ``v = combine(v, v with its lanes rotated by 4, 2, 1)``."""
    undef = ir.Constant(_vec(width), ir.Undefined)

    def lanes(idx):
        return builder.shuffle_vector(v, undef, ir.Constant(ir.VectorType(_I32, 8), idx))

    acc = lanes(list(range(8)))
    for c in range(1, width // 8):
        acc = combine(acc, lanes(list(range(8 * c, 8 * c + 8))))
    undef8 = ir.Constant(_vec(8), ir.Undefined)
    for half in (4, 2, 1):
        swap = ir.Constant(ir.VectorType(_I32, 8), [(i + half) % 8 for i in range(8)])
        acc = combine(acc, builder.shuffle_vector(acc, undef8, swap))
    return builder.extract_element(acc, ir.Constant(_I32, 0))


@intrinsic
def total(typingctx, a):
    """The sum of the lanes (a tree of lane-wise sums)."""
    def codegen(context, builder, sig, args):
        return _tree(builder, args[0], a.width, builder.fadd)
    return types.float64(a), codegen


@intrinsic
def smallest(typingctx, a):
    """The smallest lane (a NaN lane may or may not win: callers check what they select)
    as a tree of lane-wise minimums (``llvm.vector.reduce.fmin`` without fast-math flags
    lowers to a chain of scalar minimums with NaN checks)."""
    def codegen(context, builder, sig, args):
        return _tree(builder, args[0], a.width,
                     lambda v, w: builder.select(builder.fcmp_ordered("<", v, w), v, w))
    return types.float64(a), codegen


@intrinsic
def equal_mask(typingctx, a, x):
    """Bit k set iff lane k of a equals x."""
    def codegen(context, builder, sig, args):
        eq = builder.fcmp_ordered("==", args[0], _splat(builder, args[1], a.width))
        return builder.zext(builder.bitcast(eq, ir.IntType(a.width)), _I64)
    return types.int64(a, types.float64), codegen


@intrinsic
def where_bits(typingctx, a, bits, x):
    """a with every lane k whose bit k is set in ``bits`` (its low W bits) replaced by x."""
    def codegen(context, builder, sig, args):
        lanes = builder.bitcast(builder.trunc(args[1], ir.IntType(a.width)),
                                ir.VectorType(ir.IntType(1), a.width))
        return builder.select(lanes, _splat(builder, args[2], a.width), args[0])
    return a(a, types.int64, types.float64), codegen


@intrinsic
def where_greater(typingctx, a, b, x, y):
    """x where a > b (a NaN lane compares false), else y; lane by lane."""
    def codegen(context, builder, sig, args):
        return builder.select(builder.fcmp_ordered(">", args[0], args[1]), args[2], args[3])
    return x(a, b, x, y), codegen


@intrinsic
def trailing_zeros(typingctx, x):
    """Index of the lowest set bit of an int64 (64 for 0)."""
    def codegen(context, builder, sig, args):
        fn = _llvm_function(builder, "llvm.cttz.i64", _I64, [_I64, ir.IntType(1)])
        return builder.call(fn, [args[0], ir.Constant(ir.IntType(1), 0)])
    return types.int64(types.int64), codegen


@intrinsic
def prefetch(typingctx, a, row, col):
    """Ask the cache for the line holding a[row, col] (a hint: no effect on results)."""
    def codegen(context, builder, sig, args):
        byte_ptr = ir.IntType(8).as_pointer()
        arr = context.make_array(sig.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, sig.args[0], arr, list(args[1:]),
                                       wraparound=False)
        fn = _llvm_function(builder, "llvm.prefetch.p0", ir.VoidType(),
                            [byte_ptr, _I32, _I32, _I32])
        builder.call(fn, [builder.bitcast(ptr, byte_ptr), ir.Constant(_I32, 0),
                          ir.Constant(_I32, 3), ir.Constant(_I32, 1)])
        return context.get_dummy_value()
    return types.void(a, row, col), codegen



@intrinsic
def float_bits(typingctx, x):
    """The IEEE bits of a float64, as an int64 (a bit cast: no conversion)."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], _I64)
    return types.int64(types.float64), codegen


@intrinsic
def bits_float(typingctx, i):
    """The float64 whose IEEE bits are the int64 i (a bit cast)."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


@intrinsic
def outside_mask(typingctx, a, lo, hi):
    """Bit k set iff lane k of a is neither 0 nor of a magnitude in [lo, hi] (NaN too)."""
    def codegen(context, builder, sig, args):
        vty = _vec(a.width)
        fabs = _llvm_function(builder, f"llvm.fabs.{_suffix(a.width)}", vty, [vty])
        mag = builder.call(fabs, [args[0]])
        zero = builder.fcmp_ordered("==", args[0], ir.Constant(vty, [0.0] * a.width))
        inside = builder.and_(builder.fcmp_ordered(">=", mag, _splat(builder, args[1], a.width)),
                              builder.fcmp_ordered("<=", mag, _splat(builder, args[2], a.width)))
        bad = builder.not_(builder.or_(zero, inside))
        return builder.zext(builder.bitcast(bad, ir.IntType(a.width)), _I64)
    return types.int64(a, types.float64, types.float64), codegen
