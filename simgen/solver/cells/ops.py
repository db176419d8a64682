"""The few operations a cell model's rates are written in, for every kind of number a backend passes.

A cell model's rate function (:mod:`simgen.solver.cells`) is one Python
function over ``+ - * /``, unary ``-`` and the operations here, so that the
same text runs:

* compiled by numba on float32 scalars and on the SIMD vectors of
  :mod:`simgen.solver.simd` (``fma`` is ``llvm.fma``, one rounding; ``select``
  a lane-wise ``select``), inside the fused kernels of every integrator;
* in Python on numpy arrays or torch tensors (the torch backend), where
  ``fma`` rounds twice and ``select`` is ``where``.

The kernels pass the model's constants as one named tuple of float32
(:meth:`CellModel.constants`); :func:`splat` turns it into the same tuple of
vectors, and :func:`cell_rates` calls the rates registered for its class. In
numba that choice is made at compile time from the tuple's type, so a kernel
compiles (and caches) once per cell model.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

from simgen.solver.numba_internals import get_or_insert_function
from simgen.solver.simd import float32_vector, lane_mask, vfma, vsplat

__all__ = ["fma", "select", "splat", "cell_rates", "register_rates"]

#: The rate function of each cell model, by the class of its constants tuple.
_RATES: dict[type, Callable] = {}


def register_rates(constants: type, rates: Callable) -> None:
    """Make ``rates(u, v, lap, a, c)`` the rates of cell models whose constants are a ``constants`` tuple."""
    _RATES[constants] = rates


def cell_rates(u, v, lap, a, c):
    """``(du/dt, dv/dt)`` of the cell model whose constants tuple is ``c``, with the diffusion term ``lap``
    added to ``du/dt`` (``None``: the reaction alone, as IMEX takes it; ``a``: the node's excitability).

    In numba the rates compile as a function of their own (LLVM inlines them), so that a ``lap is None``
    branch is pruned by type."""
    return _RATES[type(c)](u, v, lap, a, c)


@overload(cell_rates)
def _cell_rates(u, v, lap, a, c):
    rates = _RATES.get(getattr(c, "instance_class", None))
    if rates is None:
        raise TypeError(f"no cell model takes constants of type {c}")
    return rates


def fma(a, b, c):
    """``a * b + c``: one rounding in numba (lane-wise for vectors), two on arrays and tensors."""
    return a * b + c


@intrinsic
def _fma32(typingctx, a, b, c):
    """Float32 ``a * b + c`` with one rounding (``llvm.fma.f32``)."""

    def codegen(context, builder, sig, args):
        f32 = ir.FloatType()
        fn = get_or_insert_function(builder.module, ir.FunctionType(f32, [f32] * 3), "llvm.fma.f32")
        return builder.call(fn, args)

    return types.float32(types.float32, types.float32, types.float32), codegen


@overload(fma, inline="always")
def _fma(a, b, c):
    if a is float32_vector:
        return lambda a, b, c: vfma(a, b, c)
    return lambda a, b, c: _fma32(a, b, c)


def select(mask, a, b):
    """``a`` where ``mask`` holds, else ``b`` (lane-wise; ``np.where`` / ``torch.where`` outside numba)."""
    if isinstance(mask, np.ndarray | np.bool_ | bool):
        return np.where(mask, a, b)
    import torch

    return torch.where(mask, a, b)


@intrinsic
def _vselect(typingctx, mask, a, b):
    """Lane-wise ``a`` where ``mask`` is set, else ``b``."""

    def codegen(context, builder, sig, args):
        return builder.select(*args)

    return float32_vector(lane_mask, float32_vector, float32_vector), codegen


@overload(select, inline="always")
def _select(mask, a, b):
    if mask is lane_mask:
        return lambda mask, a, b: _vselect(mask, a, b)
    return lambda mask, a, b: a if mask else b


def splat(c):
    """The constants tuple ``c`` with every float32 in all :data:`~simgen.solver.simd.LANES` lanes (numba only)."""
    raise NotImplementedError("splat is compiled by numba")


@overload(splat, inline="always")
def _splat(c):
    cls = c.instance_class
    fields = ", ".join(f"vsplat(c[{i}])" for i in range(len(c)))
    namespace = {"cls": cls, "vsplat": vsplat}
    exec(f"def impl(c):\n    return cls({fields})", namespace)  # noqa: S102 - a fixed template over field indices
    return namespace["impl"]
