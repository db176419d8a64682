"""The batched solver: equivalence, determinism, scars, default scaling and bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shared.errors import InputError, StimulusError, TimeStepError, TissueError
from shared.fem import diffusion_operator
from shared.tissue import ScarSpec, TissueFields, TissueSpec
from simgen.meshes.biventricular import biv_ellipsoid
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.slab import strip
from simgen.solver.cells.aliev_panfilov import APParams, reaction
from simgen.solver.simd import LANES
from simgen.solver.simulate import Simulator, SolverConfig, healthy_fields, simulate
from simgen.solver.stimulus import patch_mask
from simgen.solver.timestep import stability_limit
from simgen.tissue import default_settings, tissue_fields

SHORT = SolverConfig(frames=10, output_interval=0.5)


@pytest.fixture(scope="module")
def lv():
    return lv_ellipsoid(500, "tetra")


def test_batched_equals_one_at_a_time(lv):
    sim = Simulator(lv, config=SHORT)
    sites = np.array([0, 17, 99, 250, 400, 511])
    batch = sim.run(sites, threads=2, block_size=4)
    for s, site in enumerate(sites):
        single = sim.run(np.array([site]))
        np.testing.assert_allclose(batch.u[s], single.u[0], rtol=0, atol=1e-6)
        np.testing.assert_allclose(batch.activation[s], single.activation[0], rtol=0, atol=1e-5, equal_nan=True)


def test_deterministic_bitwise_across_runs_threads_and_blocks(lv):
    sim = Simulator(lv, config=SHORT)
    sites = np.arange(0, 500, 37)
    first = sim.run(sites, threads=1)
    again = Simulator(lv, config=SHORT).run(sites, threads=2, block_size=3)
    assert np.array_equal(first.u, again.u)
    assert np.array_equal(first.activation, again.activation, equal_nan=True)


def test_output_starts_on_a_page_so_builds_write_it_without_a_copy(lv):
    assert Simulator(lv, config=SHORT).run(np.arange(5), threads=1).u.ctypes.data % 4096 == 0


def test_wide_blocks_padded_to_whole_vectors_give_the_same_result(lv):
    """65 sites in one block run 72 columns wide (7 unstimulated padding columns): same as narrow blocks."""
    sim = Simulator(lv, config=SHORT)
    sites = np.arange(0, 520, 8)[:65]
    wide = sim.run(sites, threads=1, block_size=128)
    narrow = sim.run(sites, threads=1, block_size=13)
    assert wide.u.shape == (65, SHORT.frames, lv.n_nodes)
    assert np.array_equal(wide.u, narrow.u)
    assert np.array_equal(wide.activation, narrow.activation, equal_nan=True)


@pytest.mark.parametrize("n_vectors", [1, 2, 3, 4, 5, 7])
def test_every_vector_tail_matches_the_scalar_path(lv, n_vectors):
    """Rows end in a pass of 1, 2 or 3 vectors (alone or after a full pass of 4) of this host's
    LANES columns; each column equals the same site integrated alone on the scalar path, bitwise.
    One site short of whole vectors exercises the padding."""
    sim = Simulator(lv, config=SHORT)
    sites = np.arange(0, 500, 3)[: n_vectors * LANES - 1]
    block = sim.run(sites, threads=1, block_size=128)
    scalar = sim.run(sites, threads=1, block_size=1)
    assert np.array_equal(block.u, scalar.u)
    assert np.array_equal(block.activation, scalar.activation, equal_nan=True)


def test_matches_float64_numpy_reference(lv):
    """The fused float32 kernel agrees with a plain float64 explicit Euler loop."""
    sim = Simulator(lv, config=SHORT)
    site = np.array([42])
    result = sim.run(site)
    A = diffusion_operator(lv, SHORT.diffusivity * np.ones(lv.n_nodes))
    a = np.full(lv.n_nodes, 0.15)
    stim = patch_mask(lv, site, sim.stimulus_radius)[:, 0]
    u, v = stim.astype(float), np.zeros(lv.n_nodes)
    stim_steps = round(SHORT.stimulus_duration / sim.dt)
    frames = []
    for step in range(SHORT.frames * sim.steps_per_frame):
        du, dv = reaction(u, v, a, APParams())
        u, v = u + sim.dt * (A @ u + du), v + sim.dt * dv
        if step < stim_steps:
            u[stim] = 1.0
        if (step + 1) % sim.steps_per_frame == 0:
            frames.append(u.copy())
    np.testing.assert_allclose(result.u[0], np.array(frames), atol=2e-4)


def test_scar_core_blocks_conduction():
    mesh = strip(30.0, 2.0, 0.25)
    x = mesh.points[:, 0]
    core = (x > 12.0) & (x < 16.0)
    tissue = TissueFields(np.where(core, 0.5, 0.15), np.where(core, 0.1, 1.0), core.astype(np.int8) * 2)
    cfg = SolverConfig(diffusivity=1.0, output_interval=1.0, frames=40)
    result = Simulator(mesh, tissue, cfg).run_patches((x <= 1.0)[:, None])
    healthy = Simulator(mesh, None, cfg).run_patches((x <= 1.0)[:, None])
    assert np.all(np.isfinite(healthy.activation[0]))
    assert np.all(np.isnan(result.activation[0, x > 17.0]))
    assert np.all(np.isfinite(result.activation[0, x < 11.0]))


def test_lv_scar_delays_or_blocks_activation_behind_it():
    mesh = lv_ellipsoid(2000, "tetra")
    spec = TissueSpec("septal-scar", scars=(ScarSpec("segments", segments=(8, 9, 14)),))
    fields = tissue_fields(mesh, spec)
    core = fields.label == 2
    site = np.array([int(np.argmax(mesh.points[:, 0] < -20))])  # lateral side, opposite the septal scar
    scarred = simulate(mesh, site, fields).activation[0]
    healthy = simulate(mesh, site).activation[0]
    assert np.all(np.isfinite(healthy))
    never = np.isnan(scarred[core])
    assert never.mean() > 0.4  # most of the core does not activate at all
    assert np.median(scarred[core][~never] - healthy[core][~never]) > 0.25  # its rim activates late


@pytest.mark.parametrize("make", [lambda: lv_ellipsoid(2000, "tetra"), lambda: biv_ellipsoid(2000, "tetra")])
def test_default_scaling_activates_whole_heart_within_window(make):
    mesh = make()
    sim = Simulator(mesh)
    sites = np.random.default_rng(0).choice(mesh.n_nodes, 12, replace=False)
    result = sim.run(sites, threads=2)
    assert np.all(np.isfinite(result.activation))
    # the whole heart is active by mid-window; repolarisation starts before its end
    assert np.nanmax(result.activation) < 0.5 * sim.config.duration
    assert np.all(result.u[:, -1].min(axis=1) < 0.9)


def test_default_front_spans_several_edges():
    """Front width = speed x upstroke duration (u 0.1 -> 0.9) measured on the default mesh."""
    mesh = lv_ellipsoid(2000, "tetra")
    cfg = SolverConfig(output_interval=0.05, frames=200)
    result = Simulator(mesh, config=cfg).run(np.array([0]))
    u, t = result.u[0], result.times
    reached = (u >= 0.9).any(axis=0) & (u[0] < 0.1)
    t10 = np.array([np.interp(0.1, u[:, i], t) for i in np.where(reached)[0]])
    t90 = np.array([np.interp(0.9, u[:, i], t) for i in np.where(reached)[0]])
    rise = np.median(t90 - t10)
    width = 1.4 * np.sqrt(cfg.diffusivity) * rise  # front speed x rise time
    assert width > 3 * mesh.mean_edge_length()


def test_every_default_site_launches_a_wave_on_coarse_meshes():
    for mesh in (lv_ellipsoid(500, "tetra"), lv_ellipsoid(500, "triangle")):
        sites = np.arange(0, mesh.n_nodes, 5)
        result = Simulator(mesh, config=SolverConfig(frames=30)).run(sites, threads=2)
        assert np.isfinite(result.activation).all(axis=1).mean() == 1.0


def test_default_tissue_settings_simulate(lv):
    for spec in default_settings()[:4]:
        result = simulate(lv, np.array([3]), tissue_fields(lv, spec), SHORT)
        assert np.isfinite(result.u).all()


def test_unstable_user_time_step_is_refused_with_the_limit(lv):
    sim = Simulator(lv)
    limit = stability_limit(sim.lambda_max, 8.0)
    with pytest.raises(TimeStepError, match=f"{limit:.4g}"):
        Simulator(lv, config=dataclasses.replace(SHORT, dt=1.01 * limit, integrator="euler"))
    ok = Simulator(lv, config=dataclasses.replace(SHORT, dt=0.95 * limit)).run(np.array([5]))
    assert np.isfinite(ok.u).all() and ok.u.max() <= 1.0 + 1e-5
    assert sim.dt < limit
    auto = Simulator(lv, config=dataclasses.replace(SHORT, dt=1.5 * limit))  # the default takes it with IMEX
    assert auto.integrator == "imex" and limit < auto.dt <= 1.5 * limit


@pytest.mark.parametrize(
    "sites, match", [([10_000], "unknown stimulation node"), ([-1], "unknown"), ([1.5], "integer"), ([], "non-empty")]
)
def test_bad_sites_are_refused(lv, sites, match):
    with pytest.raises(StimulusError, match=match):
        Simulator(lv, config=SHORT).run(np.array(sites))


def test_bad_configuration_and_tissue_are_refused(lv):
    with pytest.raises(InputError, match="diffusivity"):
        SolverConfig(diffusivity=float("nan"))
    with pytest.raises(InputError, match="frames"):
        SolverConfig(frames=0)
    with pytest.raises(InputError, match="variant"):
        APParams(variant="fitzhugh")
    with pytest.raises(TissueError, match="nodes"):
        Simulator(lv, healthy_fields(lv.n_nodes - 1))
    with pytest.raises(TissueError, match="NaN"):
        TissueFields(np.full(3, np.nan), np.ones(3), np.zeros(3, np.int8))
    with pytest.raises(InputError, match="mask"):
        Simulator(lv, config=SHORT).run_patches(np.ones((lv.n_nodes, 0), bool))
