"""`learner benchmark` end to end on the tiny store: every report file is written and parses."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from learner.cli import app
from learner.train.trainer import train

runner = CliRunner()

#: The real-data store: a geometry the models never saw (one 450-node LV), two tissue settings, three pacing
#: sites and the tiny store's solver and sock. The models run on every fold (a site left out), the BO baselines
#: on each subject's first (``baseline_folds = 1``): two subjects of three sites, not the tiny store's six of
#: twelve (of which ``real_data.sites`` used four), keep those fits few.
UNSEEN_SPEC = {
    "meshes": [{"id": "unseen", "source": "lv", "nodes": 450}],
    "tissue": ["healthy", "scar-apex"],
    "sites": {"count": 3},
    "solver": {"frames": 12, "output_interval": 2.0, "stimulus_radius": 14.0},
    "output": {"chunk_sites": 3, "sock_electrodes": 40},
}


@pytest.fixture(scope="module")
def unseen_store(tmp_path_factory):
    from simgen.store import spec_from_mapping
    from simgen.store.runner import build

    store = tmp_path_factory.mktemp("unseen") / "unseen.zarr"
    build(spec_from_mapping(UNSEEN_SPEC), store, workers=1)
    return store


def test_benchmark_writes_every_report_file(tiny_store, unseen_store, tiny_config, tmp_path):
    train(tiny_config(tiny_store, tmp_path / "meta", epochs=1), progress=False)
    train(tiny_config(tiny_store, tmp_path / "pns", kind="pns", epochs=1), progress=False)
    cfg = tmp_path / "bench.toml"
    cfg.write_text(f"""
out = "report"
store = "{tiny_store}"
metapns = "meta/best.pt"
pns = "pns/best.pt"
context = [1, 2]
context_sets = 1
max_targets = 3
context_sizes = [1, 2]
curve_sets = 1
curve_targets = 2
samples = 4
maps = 1
[baselines]
subjects = 1
max_targets = 2
budget = 8
regions = 2
[real_data]
store = "{unseen_store}"
observe = "electrodes"
baseline_folds = 1
""")
    result = runner.invoke(app, ["benchmark", str(cfg), "--device", "cpu"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "report"
    data = json.loads((out / "benchmark.json").read_text())
    table = [line for line in result.output.splitlines() if line.startswith("|")]  # printed unwrapped
    assert table and all(line.endswith("|") and line in (out / "benchmark.md").read_text() for line in table)
    assert set(data["table1_baseline_subset"]) == {"metaPNS", "PNS", "fs-bo", "vae-bo"}
    assert data["table1_baseline_subset"]["fs-bo"]["timing"]["simulator_calls"] == 8
    assert set(data["fig3"]["metaPNS"]) == {"1", "2"}
    cal = data["calibration"]
    assert 0.0 <= cal["coverage_90_c_only"] <= cal["coverage_90"] <= 1.0  # model error only widens the band
    assert cal["mean_band_width"] > cal["mean_band_width_c_only"]
    assert data["real_data"]["electrodes"] == 40 and set(data["real_data"]["methods"]) == {"metaPNS", "PNS"}
    assert "cc_spatial" in data["real_data"]["methods"]["PNS"]["target"]
    ceiling = data["real_data"]["ceiling"]["target"]  # the noise-free truth against the noisy one
    noise = data["real_data"]["noise_std"]
    assert abs(ceiling["mse"]["mean"] - noise**2) < 0.2 * noise**2  # E[(noise)^2] over 40 electrodes x frames
    assert 0 < ceiling["cc_spatial"]["mean"] < 1 and ceiling["cc_temporal"]["mean"] > 0.9
    folds = data["real_data"]["folds"]  # one target row per fold, per method and for the ceiling
    assert set(folds) == {"metaPNS", "PNS", "ceiling"}
    pairs = [(r["subject"], r["left_out"]) for r in folds["ceiling"]]
    assert [(r["subject"], r["left_out"]) for r in folds["PNS"]] == pairs and len(set(pairs)) == len(pairs)
    assert {subject for subject, _ in pairs} == set(data["real_data"]["subjects"])
    mean_cc = np.nanmean([r["cc_spatial"] for r in folds["metaPNS"]])
    assert mean_cc == pytest.approx(data["real_data"]["methods"]["metaPNS"]["target"]["cc_spatial"]["mean"])
    assert len(data["real_data_baseline_subset"]["folds"]["fs-bo"]) == len(data["real_data"]["subjects"])
    assert set(data["real_data_baseline_subset"]["methods"]) == {"metaPNS", "PNS", "fs-bo", "vae-bo"}
    md = (out / "benchmark.md").read_text()
    assert "| fs-bo |" in md and "| vae-bo |" in md and "Real-data emulation" in md
    assert md.count("| metaPNS |") == 4  # Table 1 twice, real data on every fold and on the baselines' folds
    assert md.count("| noise-free truth (ceiling) |") == 2
    for name in ("table1.md", "timing.md", "fig3_context.png", f"activation_maps-{data['maps'][0]}.png"):
        assert (out / name).stat().st_size > 0, name
