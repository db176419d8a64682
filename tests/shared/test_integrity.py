"""Readers verify what they read: checksums, content fingerprints, done flags, missing files and subjects."""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path

import crc32c
import numpy as np
import pytest
import zarr

from learner.data.episodes import EpisodeDataset, EpisodeSpec, load_episode
from shared.dataset import SimulationDataset
from shared.errors import DamagedData, InputError
from shared.integrity import SubjectReader, chunk_fingerprint, crc32c_combine
from shared.reader import checked_subject_ids, implied_subject_ids, read_activation, read_u

SID, OTHER = "lv-healthy", "lv-scar-apex"
U = f"subjects/{SID}/u/c"


def test_crc32c_combine_is_the_checksum_of_the_concatenation():
    rng = np.random.default_rng(0)
    for length in (1, 7, 4096, 1000):
        pieces = [rng.bytes(length) for _ in range(5)]
        assert crc32c_combine([crc32c.crc32c(p) for p in pieces], length) == crc32c.crc32c(b"".join(pieces))


def test_a_sound_store_reads_as_zarr_stores_it(tiny_store):
    g = zarr.open_group(str(tiny_store), path=f"subjects/{SID}", mode="r")
    np.testing.assert_array_equal(read_u(tiny_store, SID, [9, 0, 5]), g["u"].oindex[[9, 0, 5]])
    np.testing.assert_array_equal(read_activation(tiny_store, SID), g["activation"][...])
    reader = SubjectReader(tiny_store, SID)
    reader.rows("u", [0, 5])
    assert reader._checked == {0, 1}  # one check per chunk read, then remembered


def _swap(a: str, b: str) -> Callable[[Path], None]:
    def damage(store: Path) -> None:
        data_a, data_b = (store / a).read_bytes(), (store / b).read_bytes()
        (store / a).write_bytes(data_b)
        (store / b).write_bytes(data_a)

    return damage


def _flip(relative: str) -> Callable[[Path], None]:
    def damage(store: Path) -> None:
        data = bytearray((store / relative).read_bytes())
        data[100] ^= 0xFF
        (store / relative).write_bytes(bytes(data))

    return damage


def _truncate(relative: str) -> Callable[[Path], None]:
    def damage(store: Path) -> None:
        data = (store / relative).read_bytes()
        (store / relative).write_bytes(data[: len(data) // 2])

    return damage


#: damage -> (site row read, substrings of the error)
DAMAGE = {
    "swapped between subjects": (
        _swap(f"{U}/1/0/0", f"subjects/{OTHER}/u/c/1/0/0"),
        5,
        ("array u, site 5 (file subjects/lv-healthy/u/c/1/0/0)", "another subject or other sites"),
    ),
    "swapped between sites": (
        _swap(f"{U}/0/0/0", f"{U}/1/0/0"),
        1,
        ("array u, site 1 (file subjects/lv-healthy/u/c/0/0/0)", "content fingerprint differs"),
    ),
    "activation swapped": (
        _swap(f"subjects/{SID}/activation/c/0/0", f"subjects/{OTHER}/activation/c/0/0"),
        2,
        ("site 2", "content fingerprint differs"),
    ),
    "deleted": (lambda s: (s / f"{U}/2/0/0").unlink(), 9, ("site 9 (file subjects/lv-healthy/u/c/2/0/0)", "missing")),
    "truncated": (_truncate(f"{U}/0/0/0"), 0, ("site 0 (file subjects/lv-healthy/u/c/0/0/0)", "truncated")),
    "corrupted": (_flip(f"{U}/0/0/0"), 0, ("site 0 (file subjects/lv-healthy/u/c/0/0/0)", "checksum mismatch")),
}


@pytest.fixture
def copy(tiny_store, tmp_path) -> Path:
    shutil.copytree(tiny_store, tmp_path / "s.zarr")
    return tmp_path / "s.zarr"


def _readers(store: Path, row: int) -> dict[str, Callable[[], object]]:
    """Every read path of a site row of subject SID."""
    spec = EpisodeSpec(context=(1, 1), targets=11)
    dataset = SimulationDataset(store, subjects=[SID])
    return {
        "read_u": lambda: read_u(store, SID, [row]),
        "SimulationDataset": lambda: dataset[row],
        "load_episode": lambda: load_episode(store, SID, [row], []),
        "EpisodeDataset": lambda: list(EpisodeDataset(store, [SID], spec, seed=0)),
    }


@pytest.mark.parametrize("kind", DAMAGE)
def test_every_reader_refuses_damaged_data_naming_subject_array_site_file(copy, kind):
    damage, row, expected = DAMAGE[kind]
    damage(copy)
    for name, read in _readers(copy, row).items():
        if kind == "activation swapped" and name != "SimulationDataset":
            continue  # u alone is read there; its chunk's fingerprint covers activation too, checked below
        with pytest.raises(DamagedData) as info:
            read()
        message = str(info.value)
        assert f"subject {SID}" in message and f"simgen repair {copy}" in message, (name, message)
        if name == "EpisodeDataset":  # it reads the chunk's sites in a drawn order: the first one read is named
            expected = [re.sub(r"site \d+ ", "site ", text) for text in expected]
            message = re.sub(r"site \d+ ", "site ", message)
        assert all(text in message for text in expected), (name, message)
        assert "\n" not in message


def test_activation_swap_is_found_reading_u(copy):
    _swap(f"subjects/{SID}/activation/c/0/0", f"subjects/{OTHER}/activation/c/0/0")(copy)
    with pytest.raises(DamagedData, match="content fingerprint differs"):
        read_u(copy, SID, [0])
    read_u(copy, SID, [4])  # other chunks still read


def test_a_pending_chunk_is_refused_unless_asked_for_nan(copy):
    done = zarr.open_array(str(copy / f"subjects/{SID}/done"), mode="r+")
    done[1] = 0
    with pytest.raises(DamagedData, match=r"chunk 1 is not done \(sites 4..7 never written"):
        read_u(copy, SID)
    u = read_u(copy, SID, allow_pending=True)
    assert np.isnan(u[4:8]).all() and np.isfinite(u[:4]).all()


def test_a_missing_subject_the_spec_implies_is_an_error(copy):
    attrs = dict(zarr.open_group(str(copy), mode="r").attrs)
    assert sorted(implied_subject_ids(attrs)) == checked_subject_ids(copy)
    (copy / f"subjects/{OTHER}/zarr.json").unlink()
    for read in (
        lambda: checked_subject_ids(copy),
        lambda: SimulationDataset(copy),
        lambda: EpisodeDataset(copy, [SID], EpisodeSpec(context=(1, 1), targets=2), seed=0),
    ):
        with pytest.raises(DamagedData, match=f"subject.s. {OTHER} implied by its spec are missing"):
            read()


def test_default_tissue_implies_the_16_settings():
    attrs = {"spec": {"meshes": [{"id": "lv"}], "tissue": ["default"], "custom_tissue": [{"name": "x"}]}}
    ids = implied_subject_ids(attrs)
    assert len(ids) == 17 and ids[0] == "lv-healthy" and ids[-1] == "lv-x"


def test_fingerprint_of_crcs_equals_the_one_of_the_data(tiny_store):
    g = zarr.open_group(str(tiny_store), path=f"subjects/{SID}", mode="r")
    u, activation = g["u"][4:8], g["activation"][4:8]
    assert int(g["fingerprint"][1]) == chunk_fingerprint(SID, 1, 4, 8, u, activation)


def test_an_unknown_subject_stays_an_input_error(tiny_store):
    with pytest.raises(InputError, match="unknown subject 'nobody'"):
        SubjectReader(tiny_store, "nobody")
