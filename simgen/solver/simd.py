"""Eight-lane float32 vectors (LLVM ``<8 x float>``, one AVX2 register) for numba kernels.

Numba's auto-vectoriser handles simple loops, but a sparse row times a block
of columns needs several accumulators kept in registers across the row's
neighbours, with one scalar weight broadcast to all lanes; written as loops
over columns it pays runtime alias checks and loop set-up for every row and
group of neighbours. These intrinsics let a kernel say it directly::

    acc = vmul(vsplat(d), vload(u, row + c))      # 8 columns of row i
    acc = vfma(vsplat(w), vload(u, j * b + c), acc)
    vstore(lap, c, acc)

``vload``/``vstore`` address a C-contiguous array by flat element offset and
check nothing: the caller keeps ``offset + 8`` within the array. ``vfma`` is
the fused multiply-add ``llvm.fma`` (one rounding), the same operation that
``fastmath={"contract"}`` gives a scalar ``acc + w * x``, so a scalar tail
written that way rounds exactly like the vector lanes.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, register_model

__all__ = ["LANES", "float32x8", "vload", "vstore", "vsplat", "vmul", "vfma"]

#: float32 lanes of one vector
LANES = 8
_VECTOR = ir.VectorType(ir.FloatType(), LANES)


class Float32x8(types.Type):
    """Numba type of an eight-lane float32 vector held in a register."""

    def __init__(self) -> None:
        super().__init__(name="float32x8")


float32x8 = Float32x8()


@register_model(Float32x8)
class _Float32x8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _VECTOR)


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
def vmul(typingctx, a, b):
    """Lane-wise ``a * b``."""

    def codegen(context, builder, sig, args):
        return builder.fmul(*args)

    return float32x8(float32x8, float32x8), codegen


@intrinsic
def vfma(typingctx, a, b, c):
    """Lane-wise ``a * b + c`` with a single rounding."""

    def codegen(context, builder, sig, args):
        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_VECTOR, [_VECTOR] * 3), "llvm.fma.v8f32")
        return builder.call(fma, args)

    return float32x8(float32x8, float32x8, float32x8), codegen
