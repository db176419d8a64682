"""Eight-lane float32 vectors (LLVM ``<8 x float>``, one AVX2 register) for numba kernels.

Numba's auto-vectoriser handles simple loops, but a sparse row times a block
of columns needs several accumulators kept in registers across the row's
neighbours, with one scalar weight broadcast to all lanes; written as loops
over columns it pays runtime alias checks and loop set-up for every row and
group of neighbours. These intrinsics let a kernel say it directly::

    acc = vsplat(d) * vload(u, row + c)           # 8 columns of row i
    acc = vfma(vsplat(w), vload(u, j * b + c), acc)
    vstore(lap, c, acc)

``vload``/``vstore`` address a C-contiguous array by flat element offset and
check nothing: the caller keeps ``offset + 8`` within the array. ``vfma`` is
the fused multiply-add ``llvm.fma`` (one rounding), the same operation that
``fastmath={"contract"}`` gives a scalar ``acc + w * x``, so a scalar tail
written that way rounds exactly like the vector lanes.

Vectors also take ``+ - * /``, unary ``-`` and ``< >=`` (lane masks, combined
with ``&`` and reduced by :func:`vany`), emitted with the same ``contract``
flag as numba's scalar code under ``fastmath={"contract"}``: one function
written over these operators, e.g. the reaction term, compiles for float32
scalars and for vectors and rounds the same way in both.
"""

from __future__ import annotations

import operator

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, overload, register_model

__all__ = ["LANES", "float32x8", "mask8", "vload", "vstore", "vsplat", "vfma", "vany"]

#: float32 lanes of one vector
LANES = 8
_VECTOR = ir.VectorType(ir.FloatType(), LANES)


class Float32x8(types.Type):
    """Numba type of an eight-lane float32 vector held in a register."""

    def __init__(self) -> None:
        super().__init__(name="float32x8")


class Mask8(types.Type):
    """Numba type of eight lane flags (a vector comparison's result)."""

    def __init__(self) -> None:
        super().__init__(name="mask8")


float32x8 = Float32x8()
mask8 = Mask8()
_MASK = ir.VectorType(ir.IntType(1), LANES)
_CONTRACT = ("contract",)


@register_model(Float32x8)
class _Float32x8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _VECTOR)


@register_model(Mask8)
class _Mask8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _MASK)


def _address(context, builder, array_type, array, offset):
    """Pointer to element ``offset`` of a C-contiguous array, as a vector pointer."""
    data = cgutils.create_struct_proxy(array_type)(context, builder, value=array).data
    return builder.bitcast(builder.gep(data, [offset]), _VECTOR.as_pointer())


def _check_array(array) -> None:
    if not (isinstance(array, types.Array) and array.dtype == types.float32 and array.layout == "C"):
        raise TypeError(f"expected a C-contiguous float32 array, got {array}")


@intrinsic
def vload(typingctx, array, offset):
    """Elements ``offset .. offset + 7`` of the C-contiguous float32 ``array`` (flat index)."""
    _check_array(array)

    def codegen(context, builder, sig, args):
        return builder.load(_address(context, builder, sig.args[0], *args), align=4)

    return float32x8(array, types.intp), codegen


@intrinsic
def vstore(typingctx, array, offset, vector):
    """Write ``vector`` to elements ``offset .. offset + 7`` of ``array`` (flat index)."""
    _check_array(array)

    def codegen(context, builder, sig, args):
        builder.store(args[2], _address(context, builder, sig.args[0], args[0], args[1]), align=4)
        return context.get_dummy_value()

    return types.none(array, types.intp, float32x8), codegen


@intrinsic
def vsplat(typingctx, x):
    """``x`` (float32) in every lane."""

    def codegen(context, builder, sig, args):
        lane0 = builder.insert_element(ir.Constant(_VECTOR, ir.Undefined), args[0], ir.Constant(ir.IntType(32), 0))
        zeros = ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES)
        return builder.shuffle_vector(lane0, ir.Constant(_VECTOR, ir.Undefined), zeros)

    return float32x8(types.float32), codegen


@intrinsic
def vfma(typingctx, a, b, c):
    """Lane-wise ``a * b + c`` with a single rounding."""

    def codegen(context, builder, sig, args):
        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_VECTOR, [_VECTOR] * 3), "llvm.fma.v8f32")
        return builder.call(fma, args)

    return float32x8(float32x8, float32x8, float32x8), codegen


@intrinsic
def vany(typingctx, mask):
    """True if any lane of ``mask`` is set."""

    def codegen(context, builder, sig, args):
        reduce = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.IntType(1), [_MASK]), "llvm.vector.reduce.or.v8i1"
        )
        return builder.call(reduce, args)

    return types.boolean(mask8), codegen


def _lanewise(emit, result):
    """An intrinsic ``(a, b) -> result`` emitting ``emit(builder, a, b)``."""

    @intrinsic
    def op(typingctx, a, b):
        def codegen(context, builder, sig, args):
            return emit(builder, *args)

        return result(a, b), codegen

    return op


_ARITHMETIC = {
    operator.add: _lanewise(lambda b, x, y: b.fadd(x, y, flags=_CONTRACT), float32x8),
    operator.sub: _lanewise(lambda b, x, y: b.fsub(x, y, flags=_CONTRACT), float32x8),
    operator.mul: _lanewise(lambda b, x, y: b.fmul(x, y, flags=_CONTRACT), float32x8),
    operator.truediv: _lanewise(lambda b, x, y: b.fdiv(x, y, flags=_CONTRACT), float32x8),
    operator.lt: _lanewise(lambda b, x, y: b.fcmp_ordered("<", x, y), mask8),
    operator.ge: _lanewise(lambda b, x, y: b.fcmp_ordered(">=", x, y), mask8),
}


def _register(op, impl) -> None:
    @overload(op)
    def _vector_op(a, b):
        if a is float32x8 and b is float32x8:
            return lambda a, b: impl(a, b)


for _op, _impl in _ARITHMETIC.items():
    _register(_op, _impl)

_and = _lanewise(lambda b, x, y: b.and_(x, y), mask8)


@overload(operator.and_)
def _mask_and(a, b):
    if a is mask8 and b is mask8:
        return lambda a, b: _and(a, b)


@intrinsic
def _neg(typingctx, a):
    def codegen(context, builder, sig, args):
        return builder.fneg(args[0], flags=_CONTRACT)

    return float32x8(float32x8), codegen


@overload(operator.neg)
def _vector_neg(a):
    if a is float32x8:
        return lambda a: _neg(a)
