"""The demo sweep writes figures and a summary."""

from __future__ import annotations

import json

from simgen.demo import run_demo


def test_demo_writes_figures_and_summary(tmp_path):
    rows = run_demo(tmp_path, geometries=("lv",), n_nodes=500, settings=("healthy", "scar-apex"), n_sites=2)
    assert len(rows) == 2
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [r["setting"] for r in summary] == ["healthy", "scar-apex"]
    assert "| mesh | setting |" in (tmp_path / "summary.md").read_text()
    for row in rows:
        assert (tmp_path / row.figure).read_bytes()[:4] == b"\x89PNG"
    healthy = rows[0]
    assert all(0 < t < 300 for t in healthy.total_activation_ms)  # whole LV activates within 300 ms
