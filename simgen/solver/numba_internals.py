"""Numba beyond its public API, in one module: the LLVM code-generation helpers the SIMD intrinsics use.

:mod:`simgen.solver.simd` (vector loads, stores, fused multiply-adds and
reductions) and :mod:`simgen.solver.cells.ops` (the scalar fused multiply-add)
build LLVM IR inside ``@intrinsic`` functions. The intrinsic decorator and the
data models are public (``numba.extending``); the two helpers below live in
``numba.core.cgutils``, which Numba does not promise to keep. pyproject.toml
bounds numba to the releases ``tests/contracts/test_numba_internals.py`` passes
on (``make contracts`` runs it against the newest numba on PyPI).
"""

from __future__ import annotations

from numba.core.cgutils import create_struct_proxy, get_or_insert_function

__all__ = ["create_struct_proxy", "get_or_insert_function"]
