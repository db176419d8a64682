"""The shipped build specs keep their hashes, so the stores built from them resume and verify."""

from __future__ import annotations

from pathlib import Path

import pytest

from simgen.store.spec import load_spec, spec_hash

SPECS = Path(__file__).resolve().parents[3] / "specs"

#: Hashes of specs written before tissue could be drawn ([tissue_prior], wall scars, fibrosis, apd_scale).
HASHES = {
    "demo.toml": "3b21bbe86055bc41bd040633e5047946afb6817e7ff516c5cdfe7c1485dc03c0",
    "default.toml": "8fb34cef111693b8b3765791140289069495eb107067365aaba16a5d702495a0",
    "pretrained.toml": "5ec3fb21e8b80bc697b50dd5e3e6ebbb8a5403c43e6eff3dee5b6176309dca4a",
    "pretrained-fibres.toml": "ecc1ab53ad032566ebf1555d3b8b875219b46f5dcb73921c0cee4ec72124c4ec",
    "realdata.toml": "7bc01fd96ddabe1eb52b9b4254005a2c278ec5668724c89faa86b5aa4648991c",
}


@pytest.mark.parametrize("name", sorted(HASHES))
def test_a_shipped_spec_keeps_its_hash(name: str) -> None:
    assert spec_hash(load_spec(SPECS / name)) == HASHES[name]
