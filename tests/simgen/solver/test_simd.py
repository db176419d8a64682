"""The 8-lane vector intrinsics used by the solver kernel."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from simgen.solver.simd import LANES, vany, vfma, vload, vsplat, vstore


@njit
def _axpy_rows(x, y, w, out):
    """out[r, 8:16] = w * x[r, 8:16] + y[r, 8:16] through the intrinsics, rows addressed by flat offset."""
    b = x.shape[1]
    for r in range(x.shape[0]):
        vstore(out, r * b + LANES, vfma(vsplat(w), vload(x, r * b + LANES), vload(y, r * b + LANES)))


@njit
def _scale(x, d, out):
    vstore(out, 0, vsplat(d) * vload(x, 0))


def test_load_fma_store_match_numpy_and_touch_only_their_lanes():
    rng = np.random.default_rng(0)
    x, y = rng.standard_normal((3, 24), dtype=np.float32), rng.standard_normal((3, 24), dtype=np.float32)
    out = np.full((3, 24), np.float32(7))
    _axpy_rows(x, y, np.float32(0.5), out)
    np.testing.assert_allclose(out[:, 8:16], np.float32(0.5) * x[:, 8:16] + y[:, 8:16], rtol=1e-6)
    assert np.all(out[:, :8] == 7) and np.all(out[:, 16:] == 7)
    scaled = np.zeros(8, np.float32)
    _scale(x[0], np.float32(3), scaled)
    np.testing.assert_array_equal(scaled, np.float32(3) * x[0, :8])


def test_fma_rounds_once():
    """(1 + 2^-12)^2 - (1 + 2^-11) is 2^-24 exactly; a separate multiply would round it away to 0."""
    a = np.full(8, 1 + 2.0**-12, np.float32)
    c = np.full(8, -(1 + 2.0**-11), np.float32)
    assert np.float32(a[0] * a[0]) + c[0] == 0  # two roundings

    @njit
    def fused(a, c, out):
        vstore(out, 0, vfma(vload(a, 0), vload(a, 0), vload(c, 0)))

    out = np.zeros(8, np.float32)
    fused(a, c, out)
    np.testing.assert_array_equal(out, np.float32(2.0**-24))


def test_rejects_arrays_it_cannot_address():
    @njit
    def load(x):
        return vload(x, 0)

    with pytest.raises(TypeError, match="C-contiguous float32"):
        load(np.zeros(8))  # float64
    with pytest.raises(TypeError, match="C-contiguous float32"):
        load(np.zeros((8, 2), np.float32)[:, 0])  # strided view


def test_operators_masks_and_vany_match_numpy():
    @njit(fastmath={"contract"})
    def combine(x, y, out):
        a, b = vload(x, 0), vload(y, 0)
        vstore(out, 0, -a * b + a / b - (a - b))
        return vany((a < b) & (a >= b)), vany((a < b) & (b >= a))

    x = np.array([1, 2, 3, 4, 5, 6, 7, 8], np.float32)
    y = np.full(8, 3, np.float32)
    out = np.zeros(8, np.float32)
    never, some = combine(x, y, out)
    np.testing.assert_allclose(out, -x * y + x / y - (x - y), rtol=1e-6)
    assert not never and some
