"""Sites by position: nearest nodes within a tolerance, regions of a heart, and the capture rule."""

from __future__ import annotations

import numpy as np
import pytest

from shared.capture import CAPTURE_SHARE, activated_fraction, recorded_fraction, started_wave
from shared.errors import StimulusError
from shared.sites import SiteLabels, nearest_nodes, parse_points, parse_regions, region_nodes
from simgen.meshes import get_mesh
from simgen.meshes.aha import aha_segments
from simgen.meshes.regions import site_labels


@pytest.fixture(scope="module")
def biv():
    return get_mesh("biv", 1500)


def test_a_point_is_its_nearest_node_within_the_tolerance_and_refused_beyond_it(biv):
    node = 123
    assert nearest_nodes(biv.points, biv.points[node] + 0.3)[0] == node
    far = np.array([[0.0, 0.0, -120.0]])  # below the apex
    gap = np.linalg.norm(biv.points - far, axis=1).min()
    with pytest.raises(StimulusError, match=f"no node within 5 mm .* {gap:.1f} mm away"):
        nearest_nodes(biv.points, far, 5.0)
    assert nearest_nodes(biv.points, [[0.0, 0.0, 1000.0]], tolerance=1e4).shape == (1,)


def test_points_and_regions_parse_with_errors_naming_the_option():
    np.testing.assert_array_equal(parse_points("1,2,3; 4,5.5,-6"), [[1, 2, 3], [4, 5.5, -6]])
    assert parse_regions("aha-5, apex:endo,rv-free-wall") == ["aha-5", "apex:endo", "rv-free-wall"]
    for bad in ("1,2", "1,2,x", ""):
        with pytest.raises(StimulusError, match="--site-xyz"):
            parse_points(bad)
    for bad in ("aha-18", "apex:mid", "septum"):
        with pytest.raises(StimulusError, match="unknown region"):
            parse_regions(bad)


def test_regions_name_the_node_at_the_centre_of_their_surface_patch(biv):
    labels = site_labels(biv)
    segments = aha_segments(biv)
    for k in (1, 7, 13):
        site = region_nodes(labels, biv.points, [f"aha-{k}"])[0]
        assert segments[site] == k and labels.epicardium[site]
    endo = region_nodes(labels, biv.points, ["aha-7:endo"])[0]
    assert labels.endocardium[endo] and segments[endo] == 7
    free = region_nodes(labels, biv.points, ["rv-free-wall", "rv-free-wall:endo"])
    assert labels.rv_free_wall[free].all() and labels.epicardium[free[0]] and labels.endocardium[free[1]]
    assert biv.points[free[0], 0] > 30  # the procedural RV wraps the LV on the +x side
    assert not labels.rv_free_wall[biv.nodes("lv_endocardium")].any()
    apex = region_nodes(labels, biv.points, ["apex"])[0]
    assert np.linalg.norm(biv.points[apex] - biv.axis.apex) < 8.0


def test_labels_travel_as_arrays_and_a_mesh_without_them_names_the_remedy(biv):
    labels = site_labels(biv)
    again = SiteLabels.from_arrays(labels.arrays())
    np.testing.assert_array_equal(again.segment, labels.segment)
    np.testing.assert_array_equal(again.rv_free_wall, labels.rv_free_wall)
    assert SiteLabels.from_arrays({"aha_segment": labels.segment}) is None
    with pytest.raises(StimulusError, match="simgen mesh"):
        region_nodes(None, biv.points, ["aha-1"])
    lv = get_mesh("lv", 500)
    with pytest.raises(StimulusError, match="no node of this mesh"):
        region_nodes(site_labels(lv), lv.points, ["rv-free-wall"])
    assert not labels.epicardium[labels.segment == 8].any()  # a biventricle's septum faces the cavities only
    with pytest.raises(StimulusError, match="'aha-8:endo'"):
        region_nodes(labels, biv.points, ["aha-8"])


def test_a_wave_is_more_than_a_fifth_of_the_nodes_activated():
    activation = np.full((3, 100), np.nan)
    activation[0] = 1.0  # every node
    activation[1, :3] = 0.0  # the stimulus patch alone
    activation[2, : int(100 * CAPTURE_SHARE) + 1] = 2.0
    np.testing.assert_allclose(activated_fraction(activation), [1.0, 0.03, 0.21])
    assert started_wave(activated_fraction(activation)).tolist() == [True, False, True]
    obs = np.zeros((2, 4, 10), np.float32)
    obs[0, 2] = 1.0
    obs[1, 0, 0] = 1.0
    observed = np.zeros(10, bool)
    observed[:5] = True
    np.testing.assert_allclose(recorded_fraction(obs, observed), [1.0, 0.2])
