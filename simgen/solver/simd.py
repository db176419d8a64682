"""Float32 vectors of one register (LLVM ``<16 x float>`` with AVX-512, else ``<8 x float>``) for numba kernels.

Numba's auto-vectoriser handles simple loops, but a sparse row times a block
of columns needs several accumulators kept in registers across the row's
neighbours, with one scalar weight broadcast to all lanes; written as loops
over columns it pays runtime alias checks and loop set-up for every row and
group of neighbours. These intrinsics let a kernel say it directly::

    acc = vsplat(d) * vload(u, row + c)  # LANES columns of row i
    acc = vfma(vsplat(w), vload(u, j * b + c), acc)
    vstore(lap, c, acc)

``vload``/``vstore`` address a C-contiguous array by flat element offset and
check nothing: the caller keeps ``offset + LANES`` within the array. ``vfma`` is
the fused multiply-add ``llvm.fma`` (one rounding), the same operation that
``fastmath={"contract"}`` gives a scalar ``acc + w * x``, so a scalar tail
written that way rounds exactly like the vector lanes.

Vectors also take ``+ - * /``, unary ``-`` and ``< >=`` (lane masks, combined
with ``&`` and reduced by :func:`vany`), emitted with the same ``contract``
flag as numba's scalar code under ``fastmath={"contract"}``: one function
written over these operators, e.g. the reaction term, compiles for float32
scalars and for vectors and rounds the same way in both. Every lane sums in
the same order whatever :data:`LANES` is, so results do not depend on the
host's vector width either.
"""

from __future__ import annotations

import operator

import llvmlite.binding as llvm
from llvmlite import ir
from numba import config, types
from numba.extending import intrinsic, models, overload, register_model

from simgen.solver.numba_internals import create_struct_proxy, get_or_insert_function

__all__ = ["LANES", "float32_vector", "lane_mask", "vload", "vstore", "vsplat", "vfma", "vany"]


def _host_lanes() -> int:
    """16 where numba compiles for this host and it has AVX-512F (one zmm register), else 8 (one AVX2 ymm)."""
    if config.CPU_NAME not in (None, "host"):  # a named, portable target (NUMBA_CPU_NAME): AVX2-width vectors
        return 8
    return 16 if llvm.get_host_cpu_features().get("avx512f") else 8


#: float32 lanes of one vector. With AVX-512 the solver's 2,000-node bench ran 10-25% faster on
#: 16 lanes than on 8 (bench/solver.py, 2 threads, alternated runs; 10k nodes 5-8%).
LANES = _host_lanes()
_VECTOR = ir.VectorType(ir.FloatType(), LANES)


class Float32Vector(types.Type):
    """Numba type of a :data:`LANES`-lane float32 vector held in a register."""

    def __init__(self) -> None:
        super().__init__(name=f"float32x{LANES}")


class LaneMask(types.Type):
    """Numba type of :data:`LANES` lane flags (a vector comparison's result)."""

    def __init__(self) -> None:
        super().__init__(name=f"mask{LANES}")


float32_vector = Float32Vector()
lane_mask = LaneMask()
_MASK = ir.VectorType(ir.IntType(1), LANES)
_CONTRACT = ("contract",)


@register_model(Float32Vector)
class _Float32VectorModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _VECTOR)


@register_model(LaneMask)
class _LaneMaskModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _MASK)


def _address(context, builder, array_type, array, offset):
    """Pointer to element ``offset`` of a C-contiguous array, as a vector pointer."""
    data = create_struct_proxy(array_type)(context, builder, value=array).data
    return builder.bitcast(builder.gep(data, [offset]), _VECTOR.as_pointer())


def _check_array(array) -> None:
    if not (isinstance(array, types.Array) and array.dtype == types.float32 and array.layout == "C"):
        raise TypeError(f"expected a C-contiguous float32 array, got {array}")


@intrinsic
def vload(typingctx, array, offset):
    """Elements ``offset .. offset + LANES - 1`` of the C-contiguous float32 ``array`` (flat index)."""
    _check_array(array)

    def codegen(context, builder, sig, args):
        return builder.load(_address(context, builder, sig.args[0], *args), align=4)

    return float32_vector(array, types.intp), codegen


@intrinsic
def vstore(typingctx, array, offset, vector):
    """Write ``vector`` to elements ``offset .. offset + LANES - 1`` of ``array`` (flat index)."""
    _check_array(array)

    def codegen(context, builder, sig, args):
        builder.store(args[2], _address(context, builder, sig.args[0], args[0], args[1]), align=4)
        return context.get_dummy_value()

    return types.none(array, types.intp, float32_vector), codegen


@intrinsic
def vsplat(typingctx, x):
    """``x`` (float32) in every lane."""

    def codegen(context, builder, sig, args):
        lane0 = builder.insert_element(ir.Constant(_VECTOR, ir.Undefined), args[0], ir.Constant(ir.IntType(32), 0))
        zeros = ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES)
        return builder.shuffle_vector(lane0, ir.Constant(_VECTOR, ir.Undefined), zeros)

    return float32_vector(types.float32), codegen


@intrinsic
def vfma(typingctx, a, b, c):
    """Lane-wise ``a * b + c`` with a single rounding."""

    def codegen(context, builder, sig, args):
        signature = ir.FunctionType(_VECTOR, [_VECTOR] * 3)
        fma = get_or_insert_function(builder.module, signature, f"llvm.fma.v{LANES}f32")
        return builder.call(fma, args)

    return float32_vector(float32_vector, float32_vector, float32_vector), codegen


@intrinsic
def vany(typingctx, mask):
    """True if any lane of ``mask`` is set."""

    def codegen(context, builder, sig, args):
        reduce = get_or_insert_function(
            builder.module, ir.FunctionType(ir.IntType(1), [_MASK]), f"llvm.vector.reduce.or.v{LANES}i1"
        )
        return builder.call(reduce, args)

    return types.boolean(lane_mask), codegen


def _lanewise(emit, result):
    """An intrinsic ``(a, b) -> result`` emitting ``emit(builder, a, b)``."""

    @intrinsic
    def op(typingctx, a, b):
        def codegen(context, builder, sig, args):
            return emit(builder, *args)

        return result(a, b), codegen

    return op


_ARITHMETIC = {
    operator.add: _lanewise(lambda b, x, y: b.fadd(x, y, flags=_CONTRACT), float32_vector),
    operator.sub: _lanewise(lambda b, x, y: b.fsub(x, y, flags=_CONTRACT), float32_vector),
    operator.mul: _lanewise(lambda b, x, y: b.fmul(x, y, flags=_CONTRACT), float32_vector),
    operator.truediv: _lanewise(lambda b, x, y: b.fdiv(x, y, flags=_CONTRACT), float32_vector),
    operator.lt: _lanewise(lambda b, x, y: b.fcmp_ordered("<", x, y), lane_mask),
    operator.ge: _lanewise(lambda b, x, y: b.fcmp_ordered(">=", x, y), lane_mask),
}


def _register(op, impl) -> None:
    @overload(op)
    def _vector_op(a, b):
        if a is float32_vector and b is float32_vector:
            return lambda a, b: impl(a, b)


for _op, _impl in _ARITHMETIC.items():
    _register(_op, _impl)

_and = _lanewise(lambda b, x, y: b.and_(x, y), lane_mask)


@overload(operator.and_)
def _mask_and(a, b):
    if a is lane_mask and b is lane_mask:
        return lambda a, b: _and(a, b)


@intrinsic
def _neg(typingctx, a):
    def codegen(context, builder, sig, args):
        return builder.fneg(args[0], flags=_CONTRACT)

    return float32_vector(float32_vector), codegen


@overload(operator.neg)
def _vector_neg(a):
    if a is float32_vector:
        return lambda a: _neg(a)
