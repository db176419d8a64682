"""The torch solver backend against the numba kernel, backend selection and its errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from shared.errors import ConfigError, InputError
from shared.tissue import TissueFields
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.solver import torch_kernel
from simgen.solver.backends import resolve_backend
from simgen.solver.cells.aliev_panfilov import APParams
from simgen.solver.simulate import Simulator, SolverConfig
from simgen.tissue import default_settings, tissue_fields

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")
NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="checks what happens where no GPU is present")

#: Largest admissible max |u_torch - u_numba| over all sites, frames and nodes. Both run float32 with the
#: same operations in the same order except the sparse sums (another order, no fused multiply-adds), so
#: they differ by rounding that grows over the steps: 0.5-1.8e-6 measured here (520 nodes, ~1,000 steps),
#: 0.2-15e-6 on 2,000-node LV and BiV meshes (2,100-3,000 steps, both variants, scars with D = 0 cores).
U_TOL = 1e-4
#: Activation times agree within this many time steps (the contract); measured: at most 2e-4 steps here,
#: 3.5e-3 on the 2,000-node meshes.
ACT_STEPS = 1.0


@pytest.fixture(scope="module")
def lv():
    return lv_ellipsoid(500, "tetra")


def scar_with_dead_core(mesh) -> TissueFields:
    """A default scar setting whose core (a = 0.5) also conducts nothing (D = 0)."""
    fields = tissue_fields(mesh, default_settings()[5])
    return TissueFields(fields.a, np.where(fields.label == 2, 0.0, fields.D), fields.label)


def assert_close(reference, other, dt: float) -> None:
    assert other.u.shape == reference.u.shape and other.u.dtype == np.float32
    assert float(np.abs(other.u - reference.u).max()) <= U_TOL
    never = np.isnan(reference.activation)
    assert np.array_equal(np.isnan(other.activation), never)
    assert float(np.abs(other.activation - reference.activation)[~never].max()) <= ACT_STEPS * dt


@pytest.mark.parametrize("variant", ["standard", "simple"])
@pytest.mark.parametrize("scar", [False, True], ids=["healthy", "scar-D0"])
def test_torch_on_cpu_matches_numba(lv, variant, scar):
    """Default window (55 frames, ~1,000 steps), 7 sites, both cell-model variants, with and without a dead scar."""
    tissue = scar_with_dead_core(lv) if scar else None
    config = SolverConfig(model=APParams(variant=variant))
    sites = np.array([0, 17, 99, 250, 311, 400, 519])
    numba_run = Simulator(lv, tissue, config).run(sites)
    sim = Simulator(lv, tissue, config, backend="torch", device="cpu")
    torch_run = sim.run(sites)
    assert_close(numba_run, torch_run, sim.dt)
    assert np.isnan(numba_run.activation).any() == scar  # the scar blocks part of the mesh
    assert np.all(torch_run.activation[np.arange(len(sites)), sites] == 0)  # stimulated: t = 0
    assert torch_run.u.ctypes.data % 4096 == 0  # builds write it with direct I/O, as numba's


def test_backend_from_config_and_argument(lv):
    config = SolverConfig(frames=4, backend="torch")
    assert Simulator(lv, config=config).backend == "torch"
    assert Simulator(lv, config=config, backend="numba").backend == "numba"  # the argument wins
    assert Simulator(lv).backend == "numba" and SolverConfig().backend is None


def test_torch_threads_are_restored(lv):
    before = torch.get_num_threads()
    Simulator(lv, config=SolverConfig(frames=2), backend="torch", device="cpu").run(np.array([3]), threads=1)
    assert torch.get_num_threads() == before


def test_failed_compile_falls_back_to_the_eager_step(lv, monkeypatch):
    """A step compiled with ``torch.compile`` that fails on its first call is replaced by the eager one."""

    def broken(*args, **kwargs):
        raise RuntimeError("no compiler")

    monkeypatch.setattr(torch_kernel.torch, "compile", lambda fn, **kw: broken)
    config = SolverConfig(frames=3)
    eager = Simulator(lv, config=config, backend="torch", device="cpu").run(np.array([5, 6]))
    sim = Simulator(lv, config=config, backend="torch", device="cpu", compile=True)
    with pytest.warns(UserWarning, match="torch.compile of the solver step failed.*no compiler"):
        fallback = sim.run(np.array([5, 6]))
    assert not sim._torch.compiled
    assert np.array_equal(eager.u, fallback.u)


@pytest.mark.parametrize(
    "make, error, match",
    [
        (lambda: SolverConfig(backend="cuda"), ConfigError, "unknown solver backend 'cuda'; allowed: 'numba', 'torch'"),
        (lambda: resolve_backend("gpu"), ConfigError, "allowed: 'numba', 'torch', 'auto'"),
        (lambda: resolve_backend("numba", "cuda"), InputError, "needs backend 'torch' or 'auto'"),
        (lambda: torch_kernel.torch_device("tpu:0"), InputError, "unknown torch device 'tpu:0'"),
        (lambda: torch_kernel.torch_device("meta"), InputError, "not supported by the torch solver"),
    ],
)
def test_bad_backend_or_device_is_refused(make, error, match):
    with pytest.raises(error, match=match):
        make()


@NO_CUDA
def test_without_a_gpu_auto_is_numba_and_cuda_is_refused(lv):
    assert resolve_backend("auto") == ("numba", None)
    assert Simulator(lv, config=SolverConfig(frames=2, backend="auto")).backend == "numba"
    with pytest.raises(InputError, match="no CUDA device"):
        Simulator(lv, config=SolverConfig(frames=2), backend="torch", device="cuda").run(np.array([0]))


def test_numba_backend_does_not_import_torch():
    code = (
        "import sys, numpy as np\n"
        "from simgen.meshes.ellipsoid import lv_ellipsoid\n"
        "from simgen.solver import Simulator, SolverConfig\n"
        "import simgen.cli, simgen.store.runner, simgen.store.worker\n"
        "Simulator(lv_ellipsoid(200, 'tetra'), config=SolverConfig(frames=2)).run(np.array([0]))\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


@CUDA
@pytest.mark.parametrize("scar", [False, True], ids=["healthy", "scar-D0"])
def test_torch_on_cuda_matches_numba(lv, scar):
    """The compiled step on the GPU; the same bounds as on the CPU."""
    tissue = scar_with_dead_core(lv) if scar else None
    sites = np.array([0, 17, 99, 250, 311, 400, 519])
    numba_run = Simulator(lv, tissue).run(sites)
    sim = Simulator(lv, tissue, backend="auto")
    assert (sim.backend, sim.device) == ("torch", "cuda")
    assert_close(numba_run, sim.run(sites), sim.dt)
    assert sim._torch.compiled
