"""The Numba internals simgen/solver/numba_internals.py relies on: each check names the API it found changed.

pyproject.toml bounds numba to the releases these checks pass on; ``make contracts`` runs them
against the newest numba on PyPI.
"""

from __future__ import annotations

import inspect

import numba
import numpy as np
import pytest
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from simgen.solver import numba_internals


def _fma_intrinsic() -> bool:
    """``get_or_insert_function(module, fnty, name)`` declares an LLVM intrinsic a jitted function calls."""

    @intrinsic
    def fma(typingctx, a, b, c):
        def codegen(context, builder, signature, args):
            f32 = ir.FloatType()
            fn = numba_internals.get_or_insert_function(builder.module, ir.FunctionType(f32, [f32] * 3), "llvm.fma.f32")
            return builder.call(fn, args)

        return types.float32(types.float32, types.float32, types.float32), codegen

    run = numba.njit(lambda a, b, c: fma(a, b, c))
    return bool(run(np.float32(2), np.float32(3), np.float32(1)) == np.float32(7))


def _array_data_pointer() -> bool:
    """``create_struct_proxy(array_type)(context, builder, value=array).data`` is an array's data pointer."""

    @intrinsic
    def first(typingctx, array):
        def codegen(context, builder, signature, args):
            data = numba_internals.create_struct_proxy(signature.args[0])(context, builder, value=args[0]).data
            return builder.load(data)

        return types.float32(array), codegen

    run = numba.njit(lambda a: first(a))
    return bool(run(np.array([4.5, 1.0], np.float32)) == np.float32(4.5))


def _signatures() -> bool:
    return list(inspect.signature(numba_internals.get_or_insert_function).parameters)[:3] == ["module", "fnty", "name"]


CHECKS = {
    "numba.core.cgutils.get_or_insert_function(module, fnty, name)": _signatures,
    "get_or_insert_function declaring llvm.fma.f32 in an @intrinsic": _fma_intrinsic,
    "numba.core.cgutils.create_struct_proxy(array type)(...).data": _array_data_pointer,
}


@pytest.mark.parametrize("api", list(CHECKS))
def test_numba_api_the_simd_kernels_rely_on(api):
    try:
        ok = CHECKS[api]()
    except Exception as exc:  # an attribute or keyword gone: the same news
        ok = f"{type(exc).__name__}: {exc}"
    if ok is not True:
        pytest.fail(
            f"numba {numba.__version__} changed {api}, which simgen/solver/numba_internals.py relies on "
            f"({ok if isinstance(ok, str) else 'not as expected'}): adapt it before raising the numba bound",
            pytrace=False,
        )
