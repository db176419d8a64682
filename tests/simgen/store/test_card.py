"""The dataset card: its sections from the store's metadata, and the short form a build stores."""

from __future__ import annotations

import zarr

from shared.mesh import Mesh
from simgen.meshes.quality import mesh_quality
from simgen.store.card import dataset_card, short_card, store_facts


def test_card_describes_model_parameters_sizes_statistics_split_provenance(reference_store):
    card = dataset_card(reference_store)
    root = zarr.open_group(str(reference_store), mode="r")
    for heading in (
        "# Dataset card: dataset",
        "## Model",
        "## Parameters",
        "## Sizes",
        "## Cost",
        "## Statistics",
        "## Canonical split",
        "## Provenance",
        "## How to cite",
    ):
        assert heading in card
    assert "du/dt = div(D grad u) + k u (1 - u)(u - a) - u v" in card and "| k | 8.0 |" in card
    dt = root["subjects/lv-healthy"].attrs["solver"]["dt"]
    assert f"| time step dt (time units, per subject) | {dt:g} |" in card
    scar = "AHA segments 17: core a 0.5, D 0.1, border 5 mm (a 0.3, D 0.5)"
    assert f"| scar-apex | 1 | 0.15 | {scar} | 0.15-0.5 | 0.1-1 |" in card
    assert "2 subjects, 12 simulations of 8 frames" in card and "| lv | 520 |" in card
    u = root.attrs["statistics"]["u"]
    assert f"| u | 1 (V = 100 u - 80 mV) | {u['count']} | {u['mean']:.6g} | {u['std']:.6g} |" in card
    parts = [root[f"subjects/{s}"].attrs["split"] for s in ("lv-healthy", "lv-scar-apex")]
    assert f"Subjects: train {parts.count('train')}, validation {parts.count('validation')}" in card
    assert "| created | 2024-01-01T00:00:00+00:00 |" in card and "Aliev and A. V. Panfilov" in card


def test_card_reports_the_quality_of_each_mesh(reference_store):
    card = dataset_card(reference_store)
    group = zarr.open_group(str(reference_store), mode="r")["meshes/lv"]
    q = mesh_quality(Mesh(group["points"][...], group["cells"][...]))
    assert "| smallest angle (deg) | radius ratio min / 1st pct / mean | smallest altitude / mean edge |" in card
    row = next(line for line in card.splitlines() if line.startswith("| lv | 520 |"))
    assert row.endswith(f"| {q.min_angle:.1f} | {q.radius_text()} | {q.min_altitude_ratio:.3f} |")
    assert 0 < q.min_angle < 70.6 and 0 < q.min_altitude_ratio < 0.82


def test_build_stores_the_short_card(reference_store):
    summary = zarr.open_group(str(reference_store), mode="r").attrs["summary"]
    assert summary == short_card(store_facts(reference_store))
    assert summary.splitlines()[0] == (
        "dataset: 2 subjects on 1 mesh(es) of 520 nodes, 6 stimulation sites each, "
        "8 frames every 0.6 time units (7.74 ms)."
    )
    assert len(summary.splitlines()) == 3 and "on 2024-01-01T00:00:00+00:00; schema version 3" in summary
