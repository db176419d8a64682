"""``simgen status`` runs the cheap checks: damaged groups and chunks are listed, never a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from simgen.cli import app
from simgen.store.inspect import store_health, store_status

SUBJECT = "subjects/lv-healthy"


def _flip(path: Path, at: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


DAMAGE = {
    "u shard swapped between subjects": (
        lambda s: shutil.copy(s / "subjects/lv-scar-apex/u/c/1/0/0", s / f"{SUBJECT}/u/c/1/0/0"),
        "content fingerprint differs",
    ),
    "u shards swapped between chunks": (
        lambda s: shutil.copy(s / f"{SUBJECT}/u/c/0/0/0", s / f"{SUBJECT}/u/c/1/0/0"),
        "chunk 1 (sites 3..5) holds data written for another subject or other sites",
    ),
    "activation shard deleted": (
        lambda s: (s / f"{SUBJECT}/activation/c/0/0").unlink(),
        "array activation, site 0 (file subjects/lv-healthy/activation/c/0/0): shard file missing",
    ),
    "u shard truncated": (
        lambda s: (s / f"{SUBJECT}/u/c/0/0/0").write_bytes((s / f"{SUBJECT}/u/c/0/0/0").read_bytes()[:999]),
        "shard index checksum mismatch",
    ),
    "done flag flipped": (lambda s: _flip(s / f"{SUBJECT}/done/c/1"), "done flag of chunk 1 checksum mismatch"),
    "subject metadata deleted": (
        lambda s: (s / f"{SUBJECT}/zarr.json").unlink(),
        "group metadata (subjects/lv-healthy/zarr.json) missing",
    ),
    "subject metadata garbled": (
        lambda s: (s / f"{SUBJECT}/zarr.json").write_text("{not json"),
        "group metadata (subjects/lv-healthy/zarr.json) missing or unreadable",
    ),
    "mesh array metadata deleted": (
        lambda s: (s / "meshes/lv/points/zarr.json").unlink(),
        "metadata of array points (meshes/lv/points/zarr.json) missing",
    ),
}


@pytest.fixture
def copy(reference_store, tmp_path) -> Path:
    shutil.copytree(reference_store, tmp_path / "s.zarr")
    return tmp_path / "s.zarr"


def test_a_sound_store_has_no_problem(reference_store):
    health = store_health(reference_store)
    assert health.problems == [] and all(r.chunks_done == r.chunks == 2 for r in health.rows)
    result = CliRunner().invoke(app, ["status", str(reference_store)])
    assert result.exit_code == 0 and "4/4 chunks done (100%); structure sound, chunk data not decoded" in " ".join(
        result.output.split()
    )


@pytest.mark.parametrize("kind", DAMAGE)
def test_status_lists_the_damage_and_exits_1(copy, kind):
    damage, expected = DAMAGE[kind]
    damage(copy)
    result = CliRunner().invoke(app, ["status", str(copy)])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.startswith("damaged: ")]
    assert any(expected in line for line in lines), result.output
    assert f"run `simgen repair {copy}`" in " ".join(result.output.split())
    if "mesh" not in kind:  # a damaged mesh leaves its subjects' chunks sound
        assert "(100%)" not in result.output


def test_status_counts_only_sound_chunks(copy):
    DAMAGE["u shard swapped between subjects"][0](copy)
    assert {r.subject_id: (r.chunks_done, r.damaged) for r in store_status(copy)} == {
        "lv-healthy": (1, 1),
        "lv-scar-apex": (2, 0),
    }


def test_status_decodes_every_chunk_on_request_and_never_calls_undecoded_data_sound(copy):
    _flip(copy / f"{SUBJECT}/u/c/0/0/0", at=100)  # inside a site's data: its index and stored CRC intact
    quick = CliRunner().invoke(app, ["status", str(copy)])
    assert quick.exit_code == 0 and "chunk data not decoded" in " ".join(quick.output.split())
    assert "sound" not in quick.output.replace("structure sound", "")
    full = CliRunner().invoke(app, ["status", str(copy), "--checksums"])
    assert full.exit_code == 1 and "Traceback" not in full.output, full.output
    assert any("u chunk unreadable" in line for line in full.output.splitlines() if line.startswith("damaged: "))
    assert "3/4 chunks done" in full.output and "every chunk decoded: sound" not in full.output
