"""Recordings checked for what their physics allows: units, scale and order mistakes refused in one line."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from learner.activation_maps import ApTemplate
from learner.observations import Observations, UnmappedWarning, observations_from_file, read_mesh_file
from shared.ecg import ELECTRODES, LEADS, Electrodes, leads
from shared.errors import InputError
from shared.sites import SiteLabels
from simgen.meshes import get_mesh, save_mesh
from simgen.meshes.regions import site_labels

MS = 12.9
MODEL_TIMES = 0.6 * np.arange(1, 56)
TEMPLATE = ApTemplate(np.array([-1.0, 0.0, 1.0]), np.array([0.0, 0.5, 1.0]))


@pytest.fixture(scope="module")
def lv():
    return get_mesh("lv", 300)


def _map(lv) -> np.ndarray:
    """Two activation maps (2, N) in ms: a front along x, 10-90 ms."""
    x = lv.points[:, 0]
    return np.tile(10.0 + 80.0 * (x - x.min()) / np.ptp(x), (2, 1))


def _write(path, lv, **arrays):
    np.savez(path, points=lv.points, cells=lv.cells, sites=np.array([0, 5]), **arrays)
    return path


def test_frame_times_in_ms_given_as_model_units_are_refused(lv):
    times_ms = np.arange(0.0, 430.0, 5.0)
    obs = Observations(
        lv, np.array([0, 5]), np.zeros((2, len(times_ms), lv.n_nodes)), np.ones(lv.n_nodes, bool), times_ms
    )
    with pytest.raises(InputError, match=r"times in ms given as model time units .* give milliseconds as times_ms"):
        obs.at_frames(MODEL_TIMES, lambda: TEMPLATE)
    ok = Observations(
        lv, np.array([0, 5]), np.zeros((2, len(times_ms), lv.n_nodes)), np.ones(lv.n_nodes, bool), times_ms / MS
    )
    assert ok.at_frames(MODEL_TIMES, lambda: TEMPLATE).obs.shape == (2, 55, lv.n_nodes)


@pytest.mark.parametrize("scale, message", [(1e-3, "all zero, or seconds"), (0.0, "all zero, or seconds")])
def test_maps_in_seconds_or_all_zero_are_refused(tmp_path, lv, scale, message):
    with pytest.raises(InputError, match=message):
        observations_from_file(_write(tmp_path / "maps.npz", lv, activation_ms=_map(lv) * scale))


def test_a_map_after_the_window_is_refused_naming_the_window(tmp_path, lv):
    obs = observations_from_file(_write(tmp_path / "late.npz", lv, activation_ms=_map(lv) + 1000.0))
    with pytest.raises(InputError, match=r"after the model's window of 8-426 ms after the stimulus"):
        obs.at_frames(MODEL_TIMES, lambda: TEMPLATE)


def _surface_patch(lv) -> np.ndarray:
    """About ten epicardial nodes around one: a patch the map's other nodes enclose."""
    epi = lv.nodes("epicardium")
    centre = lv.points[epi[len(epi) // 2]]
    return epi[np.argsort(np.linalg.norm(lv.points[epi] - centre, axis=1))[:10]]


def test_an_unmapped_patch_enclosed_by_the_map_warns_and_bipolar_voltage_marks_it_scar(tmp_path, lv):
    act, patch = _map(lv), _surface_patch(lv)
    act[:, patch] = np.nan
    with pytest.warns(
        UnmappedWarning, match=r"10 node\(s\) in 1 region\(s\) enclosed by mapped nodes .* mark them \+inf"
    ):
        obs = observations_from_file(_write(tmp_path / "holes.npz", lv, activation_ms=act))
    assert not obs.observed[patch].any()
    volts = np.full(lv.n_nodes, 3.0)
    volts[patch] = 0.2  # dense scar: never activated
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        marked = observations_from_file(_write(tmp_path / "scar.npz", lv, activation_ms=act, bipolar_mv=volts))
        no_capture = np.isin(np.arange(lv.n_nodes), patch)
        same = observations_from_file(_write(tmp_path / "nc.npz", lv, activation_ms=act, no_capture=no_capture))
    assert marked.observed.all() and np.isinf(marked.activation[:, patch]).all()
    np.testing.assert_array_equal(same.activation, marked.activation)
    act[0, patch[0]] = 30.0
    with pytest.raises(InputError, match=r"no_capture marks 1 node\(s\) that have an activation time"):
        observations_from_file(_write(tmp_path / "bad.npz", lv, activation_ms=act, no_capture=no_capture))


def _ecgs(rng: np.random.Generator, t: int = 80) -> np.ndarray:
    """Two 12-lead ECGs (2, 12, T) in mV from smooth electrode potentials (leads relate as Einthoven says)."""
    s = np.linspace(0.0, 1.0, t)
    centres, widths = rng.uniform(0.2, 0.8, (2, len(ELECTRODES), 1)), rng.uniform(0.05, 0.15, (2, len(ELECTRODES), 1))
    potentials = rng.normal(0.0, 1.0, (2, len(ELECTRODES), 1)) * np.exp(-(((s - centres) / widths) ** 2))
    return leads(potentials, Electrodes(tuple(ELECTRODES), np.zeros((len(ELECTRODES), 3))))


def _ecg_obs(lv, ecg: np.ndarray, electrodes: Electrodes | None = None) -> Observations:
    n = lv.n_nodes
    times = np.linspace(0.0, 420.0, ecg.shape[-1]) / MS
    return Observations(lv, np.array([0, 5]), None, np.zeros(n, bool), times, ecg=ecg, electrodes=electrodes)


def test_ecgs_whose_leads_break_einthoven_or_are_zero_are_refused(lv):
    rng = np.random.default_rng(0)
    ecg = _ecgs(rng)
    _ecg_obs(lv, ecg + rng.normal(0.0, 0.02, ecg.shape))  # noisy but consistent: read
    shuffled = ecg.copy()
    shuffled[:, [LEADS.index("II"), LEADS.index("V3")]] = ecg[:, [LEADS.index("V3"), LEADS.index("II")]]
    with pytest.raises(InputError, match=r"breaks I \+ III = II \(Einthoven\) .* mislabelled or out of order"):
        _ecg_obs(lv, shuffled)
    zero = ecg.copy()
    zero[1] = 0.0
    with pytest.raises(InputError, match="recording 1 is zero in every lead"):
        _ecg_obs(lv, zero)


@pytest.mark.parametrize("where, message", [("far", "positions in another unit"), ("point", "all at one point")])
def test_electrodes_out_of_scale_or_at_one_point_are_refused(lv, where, message):
    rng = np.random.default_rng(1)
    centre = lv.points.mean(axis=0)
    positions = centre + rng.normal(0.0, 150.0, (len(ELECTRODES), 3))
    positions = positions * 1000.0 if where == "far" else np.tile(centre + 200.0, (len(ELECTRODES), 1))
    with pytest.raises(InputError, match=message):
        _ecg_obs(lv, _ecgs(rng), Electrodes(tuple(ELECTRODES), positions))


def test_points_out_of_a_hearts_scale_are_refused(tmp_path, lv):
    path = tmp_path / "m.npz"
    np.savez(path, points=lv.points * 1000.0, cells=lv.cells, sites=np.array([0, 5]), activation_ms=_map(lv))
    with pytest.raises(InputError, match=r"points span .* a heart spans 20-400 mm: points in another unit"):
        observations_from_file(path)


@pytest.mark.parametrize("fill", [True, False])
def test_a_surface_mask_of_every_node_or_none_is_refused(lv, fill):
    arrays = site_labels(lv).arrays()
    arrays["epicardium"] = np.full(lv.n_nodes, int(fill), np.uint8)
    with pytest.raises(InputError, match=f"epicardium marks {'every' if fill else 'no'} node of the {lv.n_nodes}"):
        SiteLabels.from_arrays(arrays)


def test_a_mesh_file_of_simgen_mesh_keeps_its_long_axis(tmp_path, lv):
    mesh, labels = read_mesh_file(save_mesh(lv, tmp_path / "heart.vtu", point_data=site_labels(lv).arrays()))
    np.testing.assert_allclose(mesh.axis.apex, lv.axis.apex)
    np.testing.assert_allclose(mesh.axis.base, lv.axis.base)
    assert labels is not None
