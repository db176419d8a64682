"""The working graph: a fine mesh seen as clusters, values carried both ways, and a model run on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.config import ModelConfig
from learner.graph.hierarchy import MeshHierarchy, hierarchy_for_mesh, midpoint_graph, working_clusters
from learner.metrics import spatial_cc
from learner.models.surrogate import build_model
from shared.mesh import Mesh
from simgen.meshes import get_mesh
from simgen.solver.simulate import Simulator, SolverConfig

WORKING = 300


@pytest.fixture(scope="module")
def fine() -> Mesh:
    return get_mesh("lv", 3000, "tetra")


@pytest.fixture(scope="module")
def hierarchy(fine: Mesh) -> MeshHierarchy:
    return hierarchy_for_mesh(fine, 4, 20, None, WORKING)


def test_a_finer_mesh_runs_on_clusters_a_coarser_one_on_itself(fine, hierarchy):
    assert hierarchy.working is not None and hierarchy.mesh_nodes == fine.n_nodes
    assert hierarchy.sizes[0] <= WORKING and hierarchy.working.working_nodes == hierarchy.sizes[0]
    coarse = get_mesh("lv", 250, "tetra")
    own = hierarchy_for_mesh(coarse, 4, 20, None, WORKING)
    assert own.working is None and own.sizes[0] == coarse.n_nodes == own.mesh_nodes


def test_the_midpoint_graph_adds_each_edges_midpoint_joined_to_its_ends_and_its_cells_midpoints():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])  # two tetrahedra sharing the face 1-2-3
    edges = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3], [1, 4], [2, 4], [3, 4]])
    fine, links = midpoint_graph(points, edges, cells)
    assert len(fine) == 5 + 9
    np.testing.assert_allclose(fine[5 + 3], [0.5, 0.5, 0])  # the midpoint of edge 1-2, the 4th sorted edge
    pairs = {tuple(e) for e in links.tolist()}
    assert {(1, 8), (2, 8)} <= pairs and (0, 8) not in pairs  # joined to its own edge's ends only
    assert (5, 8) in pairs and (5, 13) not in pairs  # midpoints of one cell joined, of two cells apart not
    assert len(links) == 9 * 2 + 2 * 15 - 3  # ends, then 15 pairs per cell less the shared face's 3


def test_a_coarse_mesh_is_clustered_as_a_fine_mesh_of_the_same_heart():
    """Under 8 nodes per cluster the seeds are spread on the midpoint-refined graph: the working graph of
    a 1,000-node LV then has the edge lengths of the 5,000-node LV's (farthest-point seeds on the coarse
    nodes alone sit about 6% farther apart), and its nodes keep their clusters."""
    fine_mesh, coarse = get_mesh("lv", 5000, "tetra"), get_mesh("lv", 1000, "tetra")

    def mean_edge(mesh: Mesh, cells) -> float:
        assign, positions, edges = working_clusters(mesh.points, mesh.edges(), WORKING, cells)
        assert assign.shape == (mesh.n_nodes,) and len(positions) == WORKING
        return float(np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1).mean())

    reference = mean_edge(fine_mesh, fine_mesh.cells)
    assert abs(mean_edge(coarse, coarse.cells) / reference - 1) < 0.03
    assert mean_edge(coarse, None) / reference - 1 > 0.04


def test_a_simulation_pooled_onto_the_working_graph_and_expanded_back_keeps_its_pattern(fine, hierarchy):
    u = Simulator(fine, config=SolverConfig(frames=20)).run(np.array([0, 1500]), threads=2).u
    back = hierarchy.working.expand(hierarchy.working.pool(torch.from_numpy(u))).numpy()
    assert back.shape == u.shape
    assert spatial_cc(back, u) > 0.995


def test_expansion_rows_are_weights_of_the_own_and_adjacent_clusters(fine, hierarchy):
    w = hierarchy.working
    dense = w.expansion.to_dense().numpy()
    np.testing.assert_allclose(dense.sum(axis=1), 1.0, rtol=1e-5)
    assert (dense >= 0).all()
    own = dense[np.arange(fine.n_nodes), w.assign.numpy()]
    assert (own > 0).all() and (own >= 0.5 * dense.max(axis=1)).mean() > 0.9  # mostly the own cluster leads


def test_observations_are_the_means_of_each_clusters_observed_nodes(hierarchy):
    w = hierarchy.working
    n, k = w.mesh_nodes, w.working_nodes
    observed = torch.zeros(n, dtype=torch.bool)
    observed[::7] = True
    obs = torch.randn(2, 3, n) * observed
    pooled, seen = w.observations(obs, observed)
    a = w.assign.numpy()
    for cluster in (0, k // 2, k - 1):
        members = np.flatnonzero((a == cluster) & observed.numpy())
        assert bool(seen[cluster]) == bool(members.size)
        expected = obs[..., members].mean(dim=-1) if members.size else torch.zeros(2, 3)
        torch.testing.assert_close(pooled[..., cluster], expected)


def test_a_mask_per_value_pools_each_frame_over_its_own_recorded_nodes(hierarchy):
    w = hierarchy.working
    n = w.mesh_nodes
    observed = torch.zeros(n, dtype=torch.bool)
    observed[::3] = True
    obs = torch.randn(2, 3, n) * observed
    every = observed.expand(2, 3, n)
    pooled, seen = w.observations(obs, every)  # every frame recorded: the node mask's pooling, per value
    expected, expected_seen = w.observations(obs, observed)
    torch.testing.assert_close(pooled, expected)
    assert torch.equal(seen, expected_seen.expand(2, 3, -1))
    recorded = every.clone()
    recorded[1, 2] = False  # the second recording fixes nothing at its last frame
    pooled, seen = w.observations(obs, recorded)
    assert not seen[1, 2].any() and torch.equal(pooled[0], expected[0]) and not pooled[1, 2].any()


def test_the_hierarchy_with_its_map_round_trips_through_arrays_and_the_cache(fine, hierarchy, tmp_path):
    again = MeshHierarchy.from_arrays(hierarchy.arrays())
    assert again.sizes == hierarchy.sizes
    torch.testing.assert_close(again.working.assign, hierarchy.working.assign)
    torch.testing.assert_close(again.working.expansion.to_dense(), hierarchy.working.expansion.to_dense())
    first = hierarchy_for_mesh(fine, 4, 20, tmp_path, WORKING)
    cached = hierarchy_for_mesh(fine, 4, 20, tmp_path, WORKING)
    torch.testing.assert_close(cached.working.assign, first.working.assign)
    assert hierarchy_for_mesh(fine, 4, 20, tmp_path, None).working is None  # another cache entry


def test_points_in_no_cell_take_the_cluster_of_their_nearest_node():
    mesh = get_mesh("lv", 400, "tetra")
    extra = mesh.points[[5, 17]] + 0.1
    padded = Mesh(np.vstack([mesh.points, extra]), mesh.cells, name="unused")
    h = hierarchy_for_mesh(padded, 4, 20, None, 500)
    assert h.mesh_nodes == mesh.n_nodes + 2 and h.sizes[0] == mesh.n_nodes  # the used nodes, each its own
    assign = h.working.assign.numpy()
    assert assign[-2] == assign[5] and assign[-1] == assign[17]


def test_a_model_on_a_working_graph_predicts_and_learns_on_the_mesh_nodes(fine, hierarchy):
    config = ModelConfig(
        channels=(4, 8, 8), hidden=16, latent=8, levels=4, coarsest=20, coarse_blocks=1, working_nodes=WORKING
    )
    model = build_model(config, 6)
    sites = torch.tensor([3, 2000])
    observed = torch.zeros(fine.n_nodes, dtype=torch.bool)
    observed[::5] = True
    obs = torch.rand(2, 6, fine.n_nodes) * observed
    posterior = model.embed(obs, observed, hierarchy)
    u = model.generate(sites, hierarchy, posterior.mu)
    assert u.shape == (2, 6, fine.n_nodes)
    u.square().mean().backward()
    assert all(p.grad is not None for p in model.decoder.parameters() if p.requires_grad)
