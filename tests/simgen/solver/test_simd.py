"""The vector intrinsics used by the solver kernel (LANES = 8 or 16, whatever this host has)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from simgen.solver.simd import LANES, vany, vfma, vload, vsplat, vstore


@njit
def _axpy_rows(x, y, w, out):
    """out[r, L:2L] = w * x[r, L:2L] + y[r, L:2L] (L = LANES) through the intrinsics, rows addressed by flat offset."""
    b = x.shape[1]
    for r in range(x.shape[0]):
        vstore(out, r * b + LANES, vfma(vsplat(w), vload(x, r * b + LANES), vload(y, r * b + LANES)))


@njit
def _scale(x, d, out):
    vstore(out, 0, vsplat(d) * vload(x, 0))


def test_load_fma_store_match_numpy_and_touch_only_their_lanes():
    rng = np.random.default_rng(0)
    L = LANES
    x, y = rng.standard_normal((3, 3 * L), dtype=np.float32), rng.standard_normal((3, 3 * L), dtype=np.float32)
    out = np.full((3, 3 * L), np.float32(7))
    _axpy_rows(x, y, np.float32(0.5), out)
    np.testing.assert_allclose(out[:, L : 2 * L], np.float32(0.5) * x[:, L : 2 * L] + y[:, L : 2 * L], rtol=1e-6)
    assert np.all(out[:, :L] == 7) and np.all(out[:, 2 * L :] == 7)
    scaled = np.zeros(L, np.float32)
    _scale(x[0], np.float32(3), scaled)
    np.testing.assert_array_equal(scaled, np.float32(3) * x[0, :L])


def test_fma_rounds_once():
    """(1 + 2^-12)^2 - (1 + 2^-11) is 2^-24 exactly; a separate multiply would round it away to 0."""
    a = np.full(LANES, 1 + 2.0**-12, np.float32)
    c = np.full(LANES, -(1 + 2.0**-11), np.float32)
    assert np.float32(a[0] * a[0]) + c[0] == 0  # two roundings

    @njit
    def fused(a, c, out):
        vstore(out, 0, vfma(vload(a, 0), vload(a, 0), vload(c, 0)))

    out = np.zeros(LANES, np.float32)
    fused(a, c, out)
    np.testing.assert_array_equal(out, np.float32(2.0**-24))


def test_rejects_arrays_it_cannot_address():
    @njit
    def load(x):
        return vload(x, 0)

    with pytest.raises(TypeError, match="C-contiguous float32"):
        load(np.zeros(LANES))  # float64
    with pytest.raises(TypeError, match="C-contiguous float32"):
        load(np.zeros((LANES, 2), np.float32)[:, 0])  # strided view


def test_operators_masks_and_vany_match_numpy():
    @njit(fastmath={"contract"})
    def combine(x, y, out):
        a, b = vload(x, 0), vload(y, 0)
        vstore(out, 0, -a * b + a / b - (a - b))
        return vany((a < b) & (a >= b)), vany((a < b) & (b >= a))

    x = np.arange(1, LANES + 1, dtype=np.float32)
    y = np.full(LANES, 3, np.float32)
    out = np.zeros(LANES, np.float32)
    never, some = combine(x, y, out)
    np.testing.assert_allclose(out, -x * y + x / y - (x - y), rtol=1e-6)
    assert not never and some
