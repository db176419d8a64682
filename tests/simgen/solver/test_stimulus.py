"""Stimulus patches in mm: the ball and the legacy edge-path patch, capture at any resolution."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import ConfigError, StimulusError
from shared.mesh import Mesh
from shared.tissue import ScarSpec, TissueSpec
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.slab import strip
from simgen.solver.simulate import STIMULUS_RADIUS, Simulator, SolverConfig
from simgen.solver.stimulus import patch_mask
from simgen.tissue import tissue_fields


def u_shaped_strip() -> Mesh:
    """A 2 mm wide strip bent into a U: two straight arms 4 mm apart joined by a half circle."""
    flat = strip(60.0, 2.0, 0.5)
    s, w = flat.points[:, 0], flat.points[:, 1]
    radius = 3.0 + w  # the bend's centre line radius is 4 mm: arms 6 mm apart centre to centre
    bend = np.pi * 4.0
    arm = (60.0 - bend) / 2
    angle = np.clip(s - arm, 0.0, bend) / 4.0
    x = np.where(s < arm, s, np.where(s > arm + bend, arm - (s - arm - bend), arm + radius * np.sin(angle)))
    y = np.where(s < arm, -radius, np.where(s > arm + bend, radius, -radius * np.cos(angle)))
    return Mesh(np.stack([x, y, np.zeros_like(x)], axis=1), flat.cells, name="u-strip")


def test_the_ball_holds_the_connected_tissue_within_the_radius_and_never_crosses_a_gap():
    mesh = u_shaped_strip()
    site = int(np.argmin(np.linalg.norm(mesh.points - [10.0, -4.0, 0.0], axis=1)))
    ball = patch_mask(mesh, np.array([site]), 8.0)[:, 0]
    near = np.linalg.norm(mesh.points - mesh.points[site], axis=1) <= 8.0
    other_arm = mesh.points[:, 1] > 0
    assert (near & other_arm).any()  # the other arm lies within 8 mm, across the gap
    assert not (ball & other_arm).any()
    assert np.array_equal(ball, near & ~other_arm)


def test_the_geodesic_patch_is_the_edge_path_ball_of_stores_built_before_the_ball():
    mesh = strip(20.0, 4.0, 0.5)
    site = np.array([int(np.argmin(np.linalg.norm(mesh.points - [10.0, 2.0, 0.0], axis=1)))])
    geodesic = patch_mask(mesh, site, 3.0, region="geodesic")[:, 0]
    ball = patch_mask(mesh, site, 3.0)[:, 0]
    assert geodesic.sum() < ball.sum()  # an edge path zigzags: it is longer than the straight line
    assert not (geodesic & ~ball).any()
    with pytest.raises(StimulusError, match="region"):
        patch_mask(mesh, site, 3.0, region="sphere")
    with pytest.raises(ConfigError, match="stimulus_region"):
        SolverConfig(stimulus_region="sphere")  # type: ignore[arg-type]


def test_the_default_stimulus_is_in_mm_and_recorded_as_such():
    config = SolverConfig()
    assert config.stimulus_radius is None and config.radius == STIMULUS_RADIUS == 10.0
    assert config.region == "ball"
    assert Simulator(lv_ellipsoid(500, "tetra")).stimulus_radius == STIMULUS_RADIUS


def test_every_site_launches_a_wave_at_every_resolution():
    """The same positions paced on the LV from 500 to 10,000 nodes: a wave everywhere (the edge-path patch of
    1.5 mean edges, the default of stores built before the radius was in mm, is 4.8 mm at 10k nodes and
    launches none from 2 of these 6 sites)."""
    config = SolverConfig(frames=20)
    fine = lv_ellipsoid(10_000, "tetra")
    surface = fine.nodes("epicardium")
    positions = fine.points[surface[np.random.default_rng(1).choice(len(surface), 6, replace=False)]]
    for nodes in (500, 2000, 10_000):
        mesh = lv_ellipsoid(nodes, "tetra")
        sites = np.array([np.argmin(np.linalg.norm(mesh.points - p, axis=1)) for p in positions])
        result = Simulator(mesh, config=config).run(sites, threads=2)
        assert result.started_wave.all(), (nodes, result.activated_fraction)
        assert (result.activated_fraction > 0.95).all()


def test_a_site_in_a_scar_core_starts_no_wave_and_says_so():
    mesh = lv_ellipsoid(2000, "tetra")
    spec = TissueSpec("apex", scars=(ScarSpec("segments", segments=(13, 14, 15, 16, 17)),))
    fields = tissue_fields(mesh, spec)
    core = np.flatnonzero(fields.label == 2)
    inside = core[np.argmin(np.linalg.norm(mesh.points[core] - mesh.points[core].mean(axis=0), axis=1))]
    healthy = int(np.flatnonzero(fields.label == 0)[0])
    result = Simulator(mesh, fields, SolverConfig(frames=30)).run(np.array([inside, healthy]))
    assert result.started_wave.tolist() == [False, True]
    assert result.activated_fraction[0] < 0.05 < 0.5 < result.activated_fraction[1]
