"""The RKC2 time integrator: coefficients, stage count, accuracy against Euler, order, settings and stores."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from shared.config import from_mapping, to_mapping
from shared.errors import ConfigError, InputError, TimeStepError
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.slab import slab, strip
from simgen.plugin import AlievPanfilovPlugin
from simgen.solver.cells.aliev_panfilov import APParams
from simgen.solver.rkc_kernel import DAMPING, coefficients, run_blocks_rkc, stability_bound
from simgen.solver.simulate import Simulator, SolverConfig, healthy_fields
from simgen.solver.timestep import DT_ACCURACY, choose_rkc_step, rkc_stages, stability_limit
from simgen.solver.verification import measured_front_speed, planar_run, speed_error
from simgen.store.metadata import simulation_attrs
from simgen.store.spec import spec_from_mapping, spec_hash, spec_to_dict

RKC = SolverConfig(integrator="rkc")

#: The tiny build spec of tests/simgen/store/conftest.py and its hash from before ``backend`` and
#: ``integrator`` existed: a spec that leaves both unset keeps it.
TINY_SPEC = {
    "meshes": [{"id": "lv", "source": "lv", "nodes": 500}],
    "tissue": ["healthy", "scar-apex"],
    "sites": {"count": 6},
    "solver": {"frames": 8},
    "output": {"chunk_sites": 3, "sock_electrodes": 40},
}
HASH_BEFORE_INTEGRATOR = "7d55045e476bf96c9ded876072caadcd10f31090368bc96aeade3e16f1d4c252"


@pytest.fixture(scope="module")
def lv():
    return lv_ellipsoid(500, "tetra")


def amplification(s: int, z: float) -> float:
    """One RKC2 step on ``y' = lambda y`` (``z = dt lambda``) from :func:`coefficients`, in float64."""
    rows = coefficients(s)
    y = [1.0]
    for j, (c0, mu, nu, mu_t, gamma_t) in enumerate(rows, 1):
        y.append(c0 * y[0] + mu * y[j - 1] + nu * y[max(j - 2, 0)] + mu_t * z * y[j - 1] + gamma_t * z * y[0])
    return y[-1]


@pytest.mark.parametrize("s", [2, 3, 5, 10, 25])
def test_coefficients_give_a_second_order_polynomial_bounded_on_the_stability_interval(s):
    beta = stability_bound(s)
    assert max(abs(amplification(s, z)) for z in np.linspace(-beta, 0.0, 801)) <= 1.0 + 1e-12
    z = 1e-3  # R(z) = 1 + z + z^2/2 + O(z^3)
    assert abs(amplification(s, z) - (1 + z + z * z / 2)) < z**3


def test_stability_bound_grows_like_0653_s_squared():
    assert stability_bound(2) == pytest.approx((2 + DAMPING / 4) / (1 + DAMPING / 4))
    assert stability_bound(50) / 50**2 == pytest.approx(0.653, rel=2e-3)
    with pytest.raises(ValueError, match="at least 2 stages"):
        stability_bound(1)


def test_stage_count_is_the_fewest_that_cover_the_stiffness_and_grows_like_its_square_root():
    k = 8.0
    for lam in (10.0, 300.0, 4678.0, 53348.0):
        s = rkc_stages(DT_ACCURACY, lam, k)
        need = DT_ACCURACY * (lam + k) / 0.8
        assert stability_bound(s) >= need and (s == 2 or stability_bound(s - 1) < need)
    small, large = rkc_stages(0.05, 1000.0, 0.0), rkc_stages(0.05, 16000.0, 0.0)  # 16x the stiffness
    assert large == pytest.approx(4 * small, abs=2)


def test_rkc_step_is_the_accuracy_step_fitted_to_frames_and_may_exceed_the_euler_limit():
    lam, k = 4678.0, 8.0  # real:tof-biv at 1,000 nodes: Euler's limit 4.3e-4
    dt, steps, stages = choose_rkc_step(lam, k, None, 0.6)
    assert (dt, steps, stages) == (pytest.approx(0.05), 12, 22)
    dt, steps, stages = choose_rkc_step(lam, k, 0.07, 0.6)
    assert dt > 100 * stability_limit(lam, k) and steps == 9 and dt == pytest.approx(0.6 / 9)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(TimeStepError, match="finite and > 0"):
            choose_rkc_step(lam, k, bad, 0.6)


def test_rkc_is_closer_to_a_fine_euler_reference_than_euler_at_its_stable_step(lv):
    """500-node LV, 6 sites, 33 time units. Euler is first order: at its stable step (0.033) it is 0.12 in u and
    0.08 time units in activation from Euler at a quarter of it (0.0083), whose own error is then ~1/4 of that.
    RKC2 at 0.05 was measured 0.039 and 0.026 from that reference: bounds 0.08 in u (a front shifted by a
    fraction of a step moves u by ~2-3 per time unit there) and one RKC step (0.05) in activation."""
    sites = np.array([0, 17, 99, 250, 400, 511])
    euler = Simulator(lv, config=SolverConfig())
    fine = Simulator(lv, config=SolverConfig(dt=euler.dt / 4)).run(sites)
    rkc_sim = Simulator(lv, config=RKC)
    assert (rkc_sim.dt, rkc_sim.stages, euler.stages) == (pytest.approx(0.05), 3, 1)
    rkc, coarse = rkc_sim.run(sites), euler.run(sites)
    never = np.isnan(fine.activation)
    assert np.array_equal(np.isnan(rkc.activation), never) and not never.any()
    u_err, act_err = np.abs(rkc.u - fine.u).max(), np.abs(rkc.activation - fine.activation).max()
    assert u_err < 0.08 and act_err < 0.05
    assert u_err < np.abs(coarse.u - fine.u).max() and act_err < np.abs(coarse.activation - fine.activation).max()


def test_rkc_results_do_not_depend_on_threads_or_blocks(lv):
    """Vector columns, the one-by-one tail (a block of 1 site) and threads round alike: bitwise (simgen verify)."""
    sim = Simulator(lv, config=SolverConfig(integrator="rkc", frames=10, output_interval=0.5))
    sites = np.arange(0, 500, 37)
    first = sim.run(sites, threads=1)
    for threads, block in ((2, 1), (2, 5), (1, 128)):
        again = sim.run(sites, threads=threads, block_size=block)
        assert np.array_equal(first.u, again.u)
        assert np.array_equal(first.activation, again.activation, equal_nan=True)


@pytest.mark.parametrize("a", [0.15, 0.3])
def test_strip_front_speed_within_10_percent(a):
    """tests/simgen/solver/test_conduction.py's check, with RKC2 (dt 0.05, 4 stages; Euler 0.011)."""
    assert abs(speed_error(strip(30.0, 1.0, 0.25), a, integrator="rkc")) < 0.10


def test_slab_front_speed_within_10_percent():
    assert abs(speed_error(slab(20.0, 1.0, 1.0, 0.5), 0.15, integrator="rkc")) < 0.10


def test_flat_tetrahedra_rkc_at_the_accuracy_step_matches_euler_at_its_tiny_one():
    """A 12 x 1 x 0.02 slab of 576 flat tetrahedra: lambda_max 5.3e4, so Euler's step is 3e-5 (1,600x smaller
    than 0.05). RKC2 at dt 0.05 (72 stages) and 0.02 (46) stays finite and was measured within 2.5e-3 of Euler
    in u and 3.5e-3 time units in activation (the planar stimulus excites no stiff mode): bounds 0.01 both."""
    base = slab(12.0, 1.0, 1.0, 0.5)
    mesh = Mesh(base.points * np.array([1.0, 1.0, 0.02]), base.cells, name="flat-slab")
    euler = planar_run(mesh, 0.15, frames=12, integrator="euler")
    assert euler.dt < 1e-4
    for dt in (0.05, 0.02):
        rkc = planar_run(mesh, 0.15, frames=12, integrator="rkc", dt=dt)
        assert rkc.dt == pytest.approx(dt) and np.all(np.isfinite(rkc.u))
        assert np.abs(rkc.u - euler.u).max() < 0.01
        assert np.array_equal(np.isnan(rkc.activation), np.isnan(euler.activation))
        assert np.nanmax(np.abs(rkc.activation - euler.activation)) < 0.01
    assert measured_front_speed(mesh, rkc) == pytest.approx(measured_front_speed(mesh, euler), rel=0.01)


def test_second_order_convergence_on_smooth_reaction_diffusion(smooth_problem):
    """The smooth problem (conftest.py): the kernel at dt 0.4, 0.2, 0.1 with a fixed 6 stages against the
    float64 DOP853 solution at t = 1.2: the error falls 4x per halving (measured 4.36, 4.43)."""
    A, a, u0, end, exact = (
        smooth_problem.A,
        smooth_problem.a,
        smooth_problem.u0,
        smooth_problem.end,
        smooth_problem.exact,
    )
    n, p = len(u0), APParams()
    off = sp.csr_matrix(A, dtype=np.float32)
    diag = off.diagonal().astype(np.float32)
    off.setdiag(0)
    off.eliminate_zeros()
    table = coefficients(6).astype(np.float32)
    f32 = np.float32

    def error(dt: float) -> float:
        steps = round(end / dt)
        frames, act = np.empty((1, 1, 1, n), f32), np.full((1, n, 1), -1, f32)
        run_blocks_rkc(
            off.indptr.astype(np.int64), off.indices.astype(np.int64), off.data, diag, np.full(n, a, f32),
            u0.astype(f32).reshape(1, n, 1), np.zeros((1, n, 1), bool), (0, steps, steps),
            (f32(dt), f32(0.5), f32(0.0)), p.constants(), np.arange(n), frames, act, table,
        )  # fmt: skip
        return float(np.abs(frames[0, 0, 0] - exact).max())

    errors = [error(dt) for dt in (0.4, 0.2, 0.1)]
    assert errors[-1] > 1e-4  # far above float32 rounding
    for coarse, fine in zip(errors, errors[1:]):
        assert 3.5 < coarse / fine < 5.0


def test_torch_backend_runs_the_same_stages(lv):
    """torch (CPU) against numba, RKC2: within the torch backend's test bounds (1e-4 in u, one step)."""
    config = SolverConfig(integrator="rkc", frames=20)
    sites = np.array([0, 99, 311, 519])
    numba_run = Simulator(lv, config=config).run(sites)
    torch_run = Simulator(lv, config=config, backend="torch", device="cpu").run(sites)
    never = np.isnan(numba_run.activation)
    assert np.abs(torch_run.u - numba_run.u).max() < 1e-4
    assert np.array_equal(np.isnan(torch_run.activation), never)
    assert np.abs(torch_run.activation - numba_run.activation)[~never].max() < numba_run.dt


def test_unset_integrator_keeps_the_spec_hash_and_a_set_one_changes_it():
    spec = spec_from_mapping(TINY_SPEC)
    assert spec.solver.integrator is None and "integrator" not in spec_to_dict(spec)["solver"]
    assert spec_hash(spec) == HASH_BEFORE_INTEGRATOR
    rkc = spec_from_mapping({**TINY_SPEC, "solver": {"frames": 8, "integrator": "rkc"}})
    euler = spec_from_mapping({**TINY_SPEC, "solver": {"frames": 8, "integrator": "euler"}})
    assert len({spec_hash(spec), spec_hash(rkc), spec_hash(euler)}) == 3
    assert spec_from_mapping(spec_to_dict(rkc)) == rkc


def test_integrator_reaches_the_simulator_backend_of_the_baselines(lv):
    """FS-BO and VAE-BO simulate through shared.simulator with the store's spec["solver"] table."""
    solver = to_mapping(SolverConfig(integrator="rkc", frames=4))
    assert from_mapping(SolverConfig, solver).integrator == "rkc"
    sites = np.array([3, 250])
    u = AlievPanfilovPlugin().simulate(lv, healthy_fields(lv.n_nodes), sites, solver)
    assert np.array_equal(u, Simulator(lv, config=SolverConfig(integrator="rkc", frames=4)).run(sites).u)
    assert not np.array_equal(u, Simulator(lv, config=SolverConfig(frames=4)).run(sites).u)


def test_unknown_integrator_is_refused_naming_the_allowed_ones():
    with pytest.raises(InputError, match=r"unknown time integrator 'rk4'; allowed: 'euler', 'rkc', 'imex', 'auto'"):
        SolverConfig(integrator="rk4")
    with pytest.raises(ConfigError, match=r"solver.integrator: 'rk4' is not one of \['euler', 'rkc', 'imex', 'auto'\]"):
        spec_from_mapping({**TINY_SPEC, "solver": {"integrator": "rk4"}})


def test_store_metadata_names_the_integrator():
    assert simulation_attrs(SolverConfig(integrator="euler"))["model"].endswith("forward Euler")
    assert "per subject (subject attribute solver.integrator)" in simulation_attrs(SolverConfig())["model"]
    assert simulation_attrs(RKC)["model"].endswith("Runge-Kutta-Chebyshev (RKC2)")


def test_rkc_store_is_verified_bitwise_with_its_integrator(tmp_path):
    """``simgen verify`` recomputes sampled chunks with the spec's solver settings, integrator included."""
    from simgen.store.runner import build
    from simgen.store.verify import verify_store

    spec = spec_from_mapping(
        {
            "meshes": [{"id": "lv", "source": "lv", "nodes": 500}],
            "tissue": ["healthy"],
            "sites": {"count": 4},
            "solver": {"frames": 4, "integrator": "rkc"},
            "output": {"chunk_sites": 2, "sock_electrodes": 0},
        }
    )
    store = tmp_path / "rkc.zarr"
    build(spec, store, workers=1)
    report = verify_store(store, sample=10)
    assert report.ok, report.problems
    assert report.chunks_recomputed == 2
