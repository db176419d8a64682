"""Bad input to the real ``simgen`` and ``learner`` command lines: exit code 2, a message naming it, no traceback.

A table of cases by category (spec, mesh, store, lock, CLI number, checkpoint,
observation, output path). Each case runs the real app (``tests/cli_batch.py``
runs batches of command lines in a subprocess that serves the whole module, so
each package is imported once per process) and must exit with code 2 and one
line naming the problem (typer's framed usage error for an out-of-range
option), without a traceback. A case that reads a store gets its own copy of a tiny store built
once per module, damaged first where the case says so, and must leave it
byte-identical.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import os
import queue
import shutil
import socket
import subprocess
import sys
import tempfile
import typing
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from learner.cli import _context_range
from shared.errors import InputError
from simgen.store.lock import StoreLock

ROOT = Path(__file__).resolve().parents[1]
SPEC = """tissue = ["healthy", "scar-apex"]
[[meshes]]
id = "lv"
nodes = 300
[sites]
count = 4
[solver]
frames = 6
[output]
chunk_sites = 2
sock_electrodes = 20
"""
#: A training config whose episodes fit the store of SPEC (4 sites), a small model, one epoch.
TRAIN_SMALL = """out = "run-small"
[data]
store = "missing.zarr"
workers = 0
[data.split]
validation = 0.0
test = 0.0
[data.episodes]
context = [1, 1]
targets = 2
[model]
channels = [4, 8]
hidden = 16
latent = 8
levels = 3
coarsest = 10
coarse_blocks = 1
[train]
epochs = 1
"""
as_root = os.geteuid() == 0  # root writes into read-only folders


def spec(old: str, new: str) -> str:
    """:data:`SPEC` with ``old`` replaced by ``new`` (which must occur)."""
    assert old in SPEC
    return SPEC.replace(old, new)


#: Spec files written into the input folder, by file stem.
SPECS = {
    "good": SPEC,
    "unknown-key": spec("frames = 6", "frame = 6"),
    "wrong-type": spec("nodes = 300", 'nodes = "many"'),
    "frames0": spec("frames = 6", "frames = 0"),
    "chunk0": spec("chunk_sites = 2", "chunk_sites = 0"),
    "unknown-tissue": spec('"scar-apex"', '"scar-nowhere"'),
    "duplicate-mesh": SPEC + '[[meshes]]\nid = "lv"\nnodes = 300\n',
    "bad-id": spec('id = "lv"', 'id = "l v"'),
    "too-many-sites": spec("count = 4", "count = 100000"),
    "site-out-of-range": spec("count = 4", "nodes = [99999]"),
    "duplicate-sites": spec("count = 4", "nodes = [1, 5, 1]"),
    "unknown-compressor": spec("chunk_sites = 2", 'chunk_sites = 2\ncompressor = "lzma"'),
    "level-range": spec("chunk_sites = 2", 'chunk_sites = 2\ncompressor = "zstd"\nlevel = 30'),
    "toml-syntax": spec("frames = 6", "frames = = 6"),
    "unstable-dt": spec("frames = 6", "frames = 6\ndt = 10.0"),
    "anisotropic": spec("frames = 6", "frames = 6\nanisotropy = 4.0"),
    "negative-diffusivity": spec("frames = 6", "frames = 6\ndiffusivity = -1.0"),
    "nan-diffusivity": spec("frames = 6", "frames = 6\ndiffusivity = nan"),
    "no-meshes": 'meshes = []\ntissue = ["healthy"]\n',
    "random-count0": spec("nodes = 300", 'nodes = 300\nshape = "random"\ncount = 0'),
    "missing-mesh-file": spec("nodes = 300", 'source = "missing.vtu"'),
    "bad-cells-mesh-file": spec("nodes = 300", 'source = "badcells.vtu"'),
    "cube-hexahedra": spec("nodes = 300", 'source = "cube-hex.vtu"'),
    "cube-tetrahedra": spec("nodes = 300", 'source = "cube-tet.vtu"'),
    "slab-with-sock": spec("nodes = 300", 'source = "cube-tet.vtu"\nheart = false'),
    "garbage-mesh-file": spec("nodes = 300", 'source = "garbage.vtu"'),
    "nan-mesh-file": spec("nodes = 300", 'source = "nan.vtu"'),
    "out-of-memory": spec("frames = 6", "frames = 1000000000"),
    "other": spec("count = 4", "count = 3"),
}


class Case(NamedTuple):
    """A command line (``{d}``: input folder, ``{s}``: the case's store copy, ``{held}``: a store this
    process locks), substrings of its error message (``{pid}``: this process), and what to damage
    in the store copy before the run."""

    argv: tuple[str, ...]
    expect: tuple[str, ...]
    damage: Callable[[Path], None] | None = None


def usage(option: str, *more: str) -> tuple[str, ...]:
    """The start of typer's message for an out-of-range ``option``."""
    return (f"Invalid value for '{option}'", *more)


def build(name: str, *options: str) -> tuple[str, ...]:
    """``simgen build`` of spec ``name`` into a fresh store."""
    return ("simgen", "build", f"{{d}}/{name}.toml", "--store", "{d}/new.zarr", *options)


def corrupt(relative: str) -> Callable[[Path], None]:
    """Damage: flip 8 bytes near the start of the store file ``relative`` (the first site's data)."""

    def damage(store: Path) -> None:
        path = store / relative
        data = bytearray(path.read_bytes())
        data[100:108] = bytes(b ^ 0xFF for b in data[100:108])
        path.write_bytes(bytes(data))

    return damage


def swap(a: str, b: str) -> Callable[[Path], None]:
    """Damage: exchange the store files ``a`` and ``b`` (each intact, each in the other's place)."""

    def damage(store: Path) -> None:
        data_a, data_b = (store / a).read_bytes(), (store / b).read_bytes()
        (store / a).write_bytes(data_b)
        (store / b).write_bytes(data_a)

    return damage


def delete(relative: str) -> Callable[[Path], None]:
    """Damage: delete the store file ``relative``."""
    return lambda store: (store / relative).unlink()


def duplicate(relative: str, copy: str) -> Callable[[Path], None]:
    """Damage: copy the store folder ``relative`` to ``copy`` (a member the spec does not imply)."""
    return lambda store: shutil.copytree(store / relative, store / copy)


def truncate(relative: str) -> Callable[[Path], None]:
    """Damage: cut the store file ``relative`` to half its length (a full disk, a killed copy)."""

    def damage(store: Path) -> None:
        data = (store / relative).read_bytes()
        (store / relative).write_bytes(data[: len(data) // 2])

    return damage


def flip_last(relative: str) -> Callable[[Path], None]:
    """Damage: flip the last byte of the store file ``relative`` (a small array's checksum)."""

    def damage(store: Path) -> None:
        data = bytearray((store / relative).read_bytes())
        data[-1] ^= 0xFF
        (store / relative).write_bytes(bytes(data))

    return damage


def users_file_in_an_extra_array(store: Path) -> None:
    """Damage: an extra Zarr array holding a user's figure."""
    shutil.copytree(store / "subjects/lv-healthy/x", store / "subjects/lv-healthy/w")
    (store / "subjects/lv-healthy/w/figure.png").write_bytes(b"a user's figure")


def lock_folder(store: Path) -> None:
    """Damage: a folder where the store's lock file goes."""
    (store / ".lock").mkdir()


A_FILE = ("afile", "(a file where a folder is expected)")
READ_ONLY = ("readonly/", "Permission denied")
PREDICT = ("learner", "predict", "{d}/personalized.pt", "--sites", "1")
PERSONALIZE = ("learner", "personalize", "{d}/model.pt", "--out", "{d}/p.pt", "--observations")
EXPORT = ("simgen", "export-vtk", "{s}", "lv-healthy", "0", "--out")
TRAIN = ("learner", "train", "{d}/train-small.toml", "--store", "{s}", "--out")
U0, U1 = "subjects/lv-healthy/u/c/0/0/0", "subjects/lv-healthy/u/c/1/0/0"
OTHER_U0 = "subjects/lv-scar-apex/u/c/0/0/0"
REPAIR = "run `simgen repair {s}`"
MOVED = "holds data written for another subject or other sites"
CASES: dict[str, dict[str, Case]] = {
    "spec": {
        "unknown key": Case(build("unknown-key"), ("solver: unknown key(s) ['frame']",)),
        "wrong type": Case(build("wrong-type"), ("meshes", "nodes", "many")),
        "frames 0": Case(build("frames0"), ("frames must be a positive integer, got 0",)),
        "chunk_sites 0": Case(build("chunk0"), ("[output] chunk_sites must be an integer >= 1, got 0",)),
        "unknown tissue": Case(build("unknown-tissue"), ("unknown tissue setting 'scar-nowhere'",)),
        "duplicate mesh ids": Case(build("duplicate-mesh"), ("duplicate mesh ids ['lv']",)),
        "bad mesh id": Case(build("bad-id"), ("'l v' is not a valid identifier",)),
        "more sites than nodes": Case(build("too-many-sites"), ("cannot choose 100000 sites",)),
        "site out of range": Case(build("site-out-of-range"), ("stimulation node 99999 is out of range",)),
        "duplicate site nodes": Case(build("duplicate-sites"), ("duplicate stimulation nodes [1]",)),
        "unknown compressor": Case(build("unknown-compressor"), ("'lzma' is not one of",)),
        "level out of range": Case(build("level-range"), ("level 30 out of range for compressor 'zstd'",)),
        "TOML syntax": Case(build("toml-syntax"), ("toml-syntax.toml",)),
        "unstable dt": Case(build("unstable-dt"), ("dt=10 is unstable",)),
        "negative diffusivity": Case(build("negative-diffusivity"), ("diffusivity must be finite and > 0",)),
        "NaN diffusivity": Case(build("nan-diffusivity"), ("solver.diffusivity: expected a finite number, got nan",)),
        "empty meshes": Case(build("no-meshes"), ("the spec has no meshes",)),
        "random anatomies count 0": Case(build("random-count0"), ("count must be an integer >= 1, got 0",)),
        "spec file missing": Case(build("missing"), ("missing.toml",)),
        "spec is a folder": Case(("simgen", "build", "{d}", "--store", "{d}/new.zarr"), ("{d}",)),
        "task outgrows the workers' memory": Case(
            build("out-of-memory", "--workers", "1"), ("a task needs ~", "TiB but a worker may use", "GiB")
        ),
        "dry run of a bad spec": Case(build("unstable-dt", "--dry-run"), ("dt=10 is unstable",)),
        "dry run of another spec on a store": Case(
            ("simgen", "build", "{d}/other.toml", "--store", "{s}", "--dry-run"),
            ("was built from a different spec", "--force"),
        ),
        "dry run on a damaged store": Case(
            ("simgen", "build", "{d}/good.toml", "--store", "{s}", "--dry-run"),
            ("is damaged", "group metadata (subjects/lv-healthy/zarr.json) missing", "Run `simgen repair {s}`"),
            delete("subjects/lv-healthy/zarr.json"),
        ),
        "another spec on a store": Case(
            ("simgen", "build", "{d}/other.toml", "--store", "{s}"), ("was built from a different spec", "--force")
        ),
    },
    "mesh": {
        "mesh file missing": Case(build("missing-mesh-file"), ("missing.vtu",)),
        "mesh file with a cell index out of range": Case(
            build("bad-cells-mesh-file"),
            ("badcells.vtu: cell node index out of range [0, 316): 1 cell(s), first cell 3",),
        ),
        "a heart of no inferable size": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "{d}/tiny-heart.ply"),
            ("tiny-heart.ply: cannot infer the length unit", "--units mm|cm|m"),
        ),
        "a heart read in a unit that makes it 1.6 m long": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "{d}/tiny-heart.ply", "--units", "m"),
            ("read as a heart 1593 mm across", "--units mm|cm|m"),
        ),
        "an unknown length unit": Case(
            ("simgen", "simulate", "{d}/o", "--mesh", "{d}/tiny-heart.ply", "--units", "inch"), ("'inch'",)
        ),
        "a length unit for a procedural mesh": Case(
            ("simgen", "simulate", "{d}/o", "--mesh", "lv", "--units", "cm"), ("procedural mesh 'lv' takes no units",)
        ),
        "anisotropy in a build spec": Case(build("anisotropic"), ("conducts along fibres", "[meshes.fibres]")),
        "anisotropy on a mesh without fibres": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--anisotropy", "4"), ("has no fibres", "--fibres")
        ),
        "two fibre arrays that differ": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "{d}/two-fibres.vtu"),
            ("point data 'fibre' and 'fiber' both give a direction per node and differ",),
        ),
        "two disconnected copies of a heart": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "{d}/two-hearts.vtu"),
            ("two-hearts.vtu: the mesh is 2 disconnected pieces of [416, 416] nodes", "a heart is one"),
        ),
        "a folded LV surface": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "{d}/folded.vtu"),
            ("folded.vtu: its surface passes through itself",),
        ),
        "a 50 mm cube of hexahedra": Case(build("cube-hexahedra"), ("cube-hex.vtu: not a heart", "heart = false")),
        "a 50 mm cube of tetrahedra": Case(build("cube-tetrahedra"), ("cube-tet.vtu: not a heart", "heart = false")),
        "a cube as a slab with a sock": Case(
            build("slab-with-sock"), ("[output] sock_electrodes = 20: mesh 'lv' has no epicardium",)
        ),
        "no conduction anywhere": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--tissue", "{d}/blocked.toml"),
            ("tissue 'blocked': D = 0 at every node",),
        ),
        "mesh file of garbage": Case(build("garbage-mesh-file"), ("garbage.vtu",)),
        "mesh file with a NaN point": Case(build("nan-mesh-file"), ("nan",)),
        "unknown procedural mesh": Case(("simgen", "simulate", "{d}/o", "--mesh", "heart"), ("heart",)),
        "unknown cell kind": Case(("simgen", "mesh", "{d}/m.vtu", "--kind", "hexa"), ("hexa",)),
        "mesh out in a read-only folder": Case(
            ("simgen", "mesh", "{d}/readonly/m.vtu", "--nodes", "300"), ("readonly/m.vtu", "Permission denied")
        ),
        "add-subject of a missing mesh": Case(
            ("simgen", "add-subject", "{s}", "--mesh", "{d}/missing.vtu", "--id", "p", "--tissue", "healthy"),
            ("missing.vtu",),
        ),
    },
    "store": {
        "repair without its root metadata": Case(
            ("simgen", "repair", "{s}", "--workers", "1"),
            ("root metadata (zarr.json) is missing", "`simgen repair {s} --spec SPEC`"),
            delete("zarr.json"),
        ),
        "repair with the spec of another store": Case(
            ("simgen", "repair", "{s}", "--spec", "{d}/other.toml", "--workers", "1"),
            ("other.toml is not the spec of store", "stim_nodes has shape (4,), the spec implies (3,)"),
            delete("zarr.json"),
        ),
        "repair with another spec while its root metadata are there": Case(
            ("simgen", "repair", "{s}", "--spec", "{d}/other.toml", "--workers", "1"),
            ("other.toml is not the spec of store", "nothing was changed", "`--rescope`"),
        ),
        "repair re-scoped to other sites": Case(
            ("simgen", "repair", "{s}", "--spec", "{d}/other.toml", "--rescope", "--workers", "1"),
            ("other.toml has other [sites] settings than store", "nothing was changed"),
        ),
        "repair with a spec file that is not there": Case(
            ("simgen", "repair", "{s}", "--spec", "{d}/nope.toml", "--workers", "1"), ("nope.toml",)
        ),
        "repair with an unparsable spec": Case(
            ("simgen", "repair", "{s}", "--spec", "{d}/toml-syntax.toml", "--workers", "1"), ("toml-syntax.toml",)
        ),
        "repair of a folder that is no store": Case(
            ("simgen", "repair", "{d}", "--workers", "1"), ("is not a simgen store", "nothing was changed")
        ),
        "repair of a mistyped path": Case(
            ("simgen", "repair", "{d}/mistyped.zarr", "--workers", "1"), ("mistyped.zarr: no store there",)
        ),
        "repair of a store holding an array its spec does not imply": Case(
            ("simgen", "repair", "{s}", "--workers", "1"),
            ("subjects/lv-healthy/w", "--remove-extra", "nothing was changed"),
            duplicate("subjects/lv-healthy/x", "subjects/lv-healthy/w"),
        ),
        "repair removing an extra array that holds a user's file": Case(
            ("simgen", "repair", "{s}", "--remove-extra", "--workers", "1"),
            ("removing subjects/lv-healthy/w would delete 1 file(s)", "subjects/lv-healthy/w/figure.png"),
            users_file_in_an_extra_array,
        ),
        "train on a store whose done flag is corrupted": Case(
            (*TRAIN, "{d}/run-flag"),
            ("subject lv-healthy, array done, site of chunk 1 (file subjects/lv-healthy/done/c/1)", "checksum", REPAIR),
            flip_last("subjects/lv-healthy/done/c/1"),
        ),
        "sites of a store whose mesh chunk is gone": Case(
            ("simgen", "sites", "{s}", "lv-healthy"),
            ("mesh lv: points chunk file meshes/lv/points/c/0/0 missing", "simgen repair {s}"),
            delete("meshes/lv/points/c/0/0"),
        ),
        "export of a store whose node set chunk is gone": Case(
            ("simgen", "export-vtk", "{s}", "lv-healthy", "0", "--out", "{d}/vtk-gone"),
            ("mesh lv: surface chunk file meshes/lv/surface/c/0 missing", "simgen repair {s}"),
            delete("meshes/lv/surface/c/0"),
        ),
        "export of a store whose tissue field chunk is gone": Case(
            ("simgen", "export-vtk", "{s}", "lv-scar-apex", "0", "--out", "{d}/vtk-gone"),
            ("subject lv-scar-apex: label chunk file subjects/lv-scar-apex/label/c/0 missing", "simgen repair {s}"),
            delete("subjects/lv-scar-apex/label/c/0"),
        ),
        "card of a store whose subjects group is gone": Case(
            ("simgen", "card", "{s}"),
            (
                "is damaged (1 problem(s)): store: group metadata (subjects/zarr.json) missing",
                "Run `simgen repair {s}`",
            ),
            delete("subjects/zarr.json"),
        ),
        "status of a missing store": Case(("simgen", "status", "{d}/missing.zarr"), ("missing.zarr",)),
        "status of a folder that is no store": Case(("simgen", "status", "{d}/readonly"), ("readonly",)),
        "verify a plain file": Case(("simgen", "verify", "{d}/afile"), ("afile",)),
        "export an unknown subject": Case(
            ("simgen", "export-vtk", "{s}", "lv-nobody", "0", "--out", "{d}/vtk"), ("lv-nobody",)
        ),
        "export a site out of range": Case(
            ("simgen", "export-vtk", "{s}", "lv-healthy", "99", "--out", "{d}/vtk"), ("99",)
        ),
        "export a corrupted chunk": Case(
            (*EXPORT, "{d}/vtk-corrupt"),
            ("subject lv-healthy, array u, site 0 (file subjects/lv-healthy/u/c/0/0/0)", "checksum", "simgen repair"),
            corrupt("subjects/lv-healthy/u/c/0/0/0"),
        ),
        "regenerate an unknown subject": Case(
            ("simgen", "regenerate", "{s}", "--subjects", "lv-nobody"), ("lv-nobody",)
        ),
        "add-subject of an unknown tissue": Case(
            ("simgen", "add-subject", "{s}", "--mesh", "lv", "--id", "p", "--tissue", "scar-nowhere"),
            ("unknown tissue setting 'scar-nowhere'",),
        ),
        "evaluate on a folder that is no store": Case(
            ("learner", "evaluate", "{d}/model.pt", "{d}/readonly"), ("readonly",)
        ),
    },
    "damaged data read": {
        "export a u shard of another subject": Case(
            (*EXPORT, "{d}/vtk-swap"),
            ("subject lv-healthy, array u, site 0 (file subjects/lv-healthy/u/c/0/0/0)", MOVED, REPAIR),
            swap(U0, OTHER_U0),
        ),
        "export a deleted activation shard": Case(
            (*EXPORT, "{d}/vtk-deleted"),
            ("array activation, site 0 (file subjects/lv-healthy/activation/c/0/0): shard file missing", REPAIR),
            delete("subjects/lv-healthy/activation/c/0/0"),
        ),
        "export a truncated shard": Case(
            (*EXPORT, "{d}/vtk-truncated"),
            ("array u, site 0 (file subjects/lv-healthy/u/c/0/0/0): shard index checksum mismatch", REPAIR),
            truncate(U0),
        ),
        "export with a subject's metadata deleted": Case(
            (*EXPORT, "{d}/vtk-no-subject"),
            ("subject(s) lv-scar-apex implied by its spec are missing", REPAIR),
            delete("subjects/lv-scar-apex/zarr.json"),
        ),
        "train on a u shard of another subject": Case(
            (*TRAIN, "{d}/run-swap"), ("subject lv-", "array u", MOVED, REPAIR), swap(U0, OTHER_U0)
        ),
        "train on shards swapped between sites": Case(
            (*TRAIN, "{d}/run-sites"), ("subject lv-healthy, array u", MOVED, REPAIR), swap(U0, U1)
        ),
        "train on a deleted u shard": Case(
            (*TRAIN, "{d}/run-deleted"),
            ("subject lv-healthy, array u", "(file subjects/lv-healthy/u/c/1/0/0): shard file missing", REPAIR),
            delete(U1),
        ),
        "train on a truncated shard": Case(
            (*TRAIN, "{d}/run-truncated"), ("(file subjects/lv-healthy/u/c/0/0/0)", "truncated", REPAIR), truncate(U0)
        ),
        "train without a subject's metadata": Case(
            (*TRAIN, "{d}/run-no-subject"),
            ("subject(s) lv-healthy implied by its spec are missing", REPAIR),
            delete("subjects/lv-healthy/zarr.json"),
        ),
    },
    "lock": {
        "unlock a running build": Case(
            ("simgen", "unlock", "{held}"), ("still running (pid {pid} on this host): stop it with Ctrl-C", "kill -INT")
        ),
        "unlock another host": Case(
            ("simgen", "unlock", "{d}/other.zarr"), ("cannot check (host elsewhere.example, pid 7)", "--force")
        ),
        "unlock store is a file": Case(("simgen", "unlock", "{d}/afile"), A_FILE),
        "unlock in a read-only store": Case(
            ("simgen", "unlock", "{d}/readonly/gone.zarr"), ("gone.zarr/.lock", "Permission denied")
        ),
        "build a store another build holds": Case(
            ("simgen", "build", "{d}/good.toml", "--store", "{held}"), ("held.zarr", "pid {pid}")
        ),
        "dry run of a store another build holds": Case(
            ("simgen", "build", "{d}/good.toml", "--store", "{held}", "--dry-run"), ("held.zarr", "pid {pid}")
        ),
        "build store is a file": Case(("simgen", "build", "{d}/good.toml", "--store", "{d}/afile"), A_FILE),
        "build in a read-only folder": Case(
            ("simgen", "build", "{d}/good.toml", "--store", "{d}/readonly/s.zarr"),
            ("readonly/s.zarr", "Permission denied"),
        ),
        "lock path is a folder": Case(("simgen", "build", "{d}/good.toml", "--store", "{s}"), (".lock",), lock_folder),
        "regenerate a held store": Case(("simgen", "regenerate", "{held}", "--subjects", "lv-healthy"), ("pid {pid}",)),
    },
    "number": {
        "workers 0": Case(build("good", "--workers", "0"), usage("--workers")),
        "workers negative": Case(build("good", "--workers", "-2"), usage("--workers")),
        "retries -1": Case(build("good", "--retries", "-1"), usage("--retries")),
        "threads 0": Case(("simgen", "simulate", "{d}/o", "--threads", "0"), usage("--threads")),
        "a mesh file resampled to 5 nodes": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "real:tof-biv", "--nodes", "5"),
            ("n_nodes=5 outside the supported range 200..200000",),
        ),
        "a mesh file resampled to 10^8 nodes": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--mesh", "real:tof-biv", "--nodes", "100000000"),
            ("n_nodes=100000000 outside the supported range 200..200000",),
        ),
        "a dt of a billion steps": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--dt", "1e-7"),
            ("dt=1e-07 implies 330,000,000 steps", "more than 1,000,000 is refused"),
        ),
        "unknown recording kind": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--observe", "surface", "--record", "lat"),
            ("--record: 'lat' is not one of potential, activation",),
        ),
        "nodes 0": Case(("simgen", "mesh", "{d}/m.vtu", "--nodes", "0"), usage("--nodes")),
        "a billion prediction draws": Case((*PREDICT, "--samples", "1000000000"), usage("--samples")),
        "helix angle without fibres": Case(
            ("simgen", "mesh", "{d}/m.vtu", "--helix-endo", "50"), ("--helix-endo has no effect without --fibres",)
        ),
        "filler without nodes": Case(
            ("simgen", "simulate", "{d}/o", "--mesh", "{d}/tiny-heart.ply", "--filler", "ftetwild"),
            ("--filler has no effect without --nodes",),
        ),
        "rescope without a spec": Case(
            ("simgen", "repair", "{s}", "--rescope", "--dry-run"), ("--rescope has no effect without --spec",)
        ),
        "demo sites 0": Case(
            ("simgen", "demo", "--out", "{d}/demo", "--sites-per-setting", "0"), usage("--sites-per-setting")
        ),
        "duplicate sites": Case(
            ("simgen", "simulate", "{d}/o", "--sites", "3,0,3"), ("--sites: [3] given more than once",)
        ),
        "two regions naming one site": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--site-region", "apex,aha-17"),
            ("sites region apex and region aha-17 are one stimulation node", "give each site once"),
        ),
        "a site by id and by point alike": Case(
            ("simgen", "simulate", "{d}/o", "--nodes", "300", "--sites", "0", "--site-xyz", "3.058,0,-56.572"),
            ("sites node 0 and point (3.058, 0, -56.572) are one stimulation node",),
        ),
        "negative site": Case(("simgen", "simulate", "{d}/o", "--sites", "2,-1"), ("--sites: [-1] must be >= 0",)),
        "site not a number": Case(
            ("simgen", "simulate", "{d}/o", "--sites", "1,x"), ("--sites: expected comma-separated",)
        ),
        "no site": Case(("simgen", "simulate", "{d}/o", "--sites", ","), ("--sites: give at least one integer",)),
        "dt NaN": Case(("simgen", "simulate", "{d}/o", "--dt", "nan"), usage("--dt", "nan is not a finite number")),
        "dt inf": Case(("simgen", "simulate", "{d}/o", "--dt", "inf"), usage("--dt", "inf is not a finite number")),
        "dt negative": Case(("simgen", "simulate", "{d}/o", "--dt", "-1"), ("dt=-1.0 must be finite and > 0",)),
        "verify sample -1": Case(("simgen", "verify", "{s}", "--sample", "-1"), usage("--sample")),
        "export site -1": Case((*EXPORT[:4], "--out", "{d}/vtk", "--", "-1"), usage("site_index")),
        "regenerate duplicate sites": Case(
            ("simgen", "regenerate", "{s}", "--subjects", "lv-healthy", "--site-index", "1,1"),
            ("--site-index: [1] given more",),
        ),
        "lr NaN in a config": Case(
            ("learner", "train", "{d}/train-lr-nan.toml", "--store", "{d}/missing.zarr"),
            ("train.lr: expected a finite number, got nan",),
        ),
        "targets 0 in a config": Case(
            ("learner", "train", "{d}/train-targets0.toml", "--store", "{d}/missing.zarr"),
            ("data.episodes.targets must be >= 1",),
        ),
        "epochs 0": Case(("learner", "train", "{d}/train.toml", "--epochs", "0"), usage("--epochs")),
        "max-minutes NaN": Case(("learner", "train", "{d}/train.toml", "--max-minutes", "nan"), usage("--max-minutes")),
        "max-minutes inf": Case(
            ("learner", "train", "{d}/train.toml", "--max-minutes", "inf"),
            usage("--max-minutes", "not a finite number"),
        ),
        "max-minutes negative": Case(
            ("learner", "train", "{d}/train.toml", "--max-minutes", "-1"), usage("--max-minutes")
        ),
        "seed -1": Case(("learner", "train", "{d}/train.toml", "--seed", "-1"), usage("--seed")),
        "evaluate sets 0": Case(("learner", "evaluate", "{d}/model.pt", "{s}", "--sets", "0"), usage("--sets")),
        "evaluate context 5,1": Case(
            ("learner", "evaluate", "{d}/model.pt", "{s}", "--context", "5,1"), ("--context: expected 'min,max'",)
        ),
        "evaluate observe sock": Case(
            ("learner", "evaluate", "{d}/model.pt", "{s}", "--observe", "sock"), ("unknown observation set 'sock'",)
        ),
        "evaluate a checkpoint without splits": Case(
            ("learner", "evaluate", "{d}/model.pt", "{s}"), ("unknown split 'test'; the checkpoint has []",)
        ),
        "evaluate noise -1": Case(("learner", "evaluate", "{d}/model.pt", "{s}", "--noise", "-1"), usage("--noise")),
        "samples 1": Case((*PREDICT, "--samples", "1"), usage("--samples", "one draw gives no spread")),
        "samples -1": Case((*PREDICT, "--samples", "-1"), usage("--samples")),
        "compare a missing prediction": Case(
            ("learner", "compare", "{d}/missing.npz", "{d}/obs.npz"), ("prediction file not found",)
        ),
        "compare what is not a prediction": Case(
            ("learner", "compare", "{d}/obs.npz", "{d}/obs.npz"), ("obs.npz is not a prediction file: it lacks",)
        ),
        "compare a prediction with itself": Case(
            ("learner", "compare", "{d}/predicted.npz", "{d}/predicted.npz"),
            ("hold the same v_mv: a file compared with itself",),
        ),
        "compare on a renumbered mesh": Case(
            ("learner", "compare", "{d}/predicted.npz", "{d}/sim-renumbered.npz"),
            ("site 1 is at", "the files number the nodes of different meshes"),
        ),
        "compare a simulation whose v_mv holds u": Case(
            ("learner", "compare", "{d}/predicted.npz", "{d}/sim-u.npz"),
            ("sim-u.npz: v_mv ranges from", "never near rest"),
        ),
        "predict site out of range": Case(
            ("learner", "predict", "{d}/personalized.pt", "--sites", "999"), ("stimulation nodes [999]",)
        ),
    },
    "checkpoint": {
        "missing": Case(("learner", "predict", "{d}/missing.pt", "--sites", "1"), ("checkpoint not found",)),
        "garbage bytes": Case(
            ("learner", "predict", "{d}/garbage.pt", "--sites", "1"),
            ("garbage.pt is not a readable learner checkpoint",),
        ),
        "pickled code": Case(
            ("learner", "predict", "{d}/evil.pt", "--sites", "1"), ("evil.pt is not a readable learner checkpoint",)
        ),
        "older format": Case(("learner", "predict", "{d}/format1.pt", "--sites", "1"), ("checkpoint format 1",)),
        "not a dict": Case(("learner", "predict", "{d}/list.pt", "--sites", "1"), ("checkpoint format ?",)),
        "model where a personalised one is expected": Case(
            ("learner", "predict", "{d}/model.pt", "--sites", "1"), ("holds a 'model', expected a 'personalized'",)
        ),
        "incomplete model": Case(
            ("learner", "personalize", "{d}/incomplete.pt", "--out", "{d}/p.pt", "--observations", "{d}/obs.npz"),
            ("incomplete.pt", "config"),
        ),
        "an edited personalised heart": Case(
            ("learner", "predict", "{d}/edited.pt", "--sites", "1"),
            ("edited.pt: 1 array(s) differ from the digests the file was written with (points)",),
        ),
        "empty file": Case(
            ("learner", "predict", "{d}/empty.pt", "--sites", "1"),
            ("empty.pt is not a readable learner checkpoint: the file is empty (0 bytes)",),
        ),
        "evaluate a garbage checkpoint": Case(
            ("learner", "evaluate", "{d}/garbage.pt", "{s}"), ("garbage.pt is not a readable learner checkpoint",)
        ),
    },
    "observation": {
        "file missing": Case((*PERSONALIZE, "{d}/missing.npz"), ("observation file not found",)),
        "not an npz": Case((*PERSONALIZE, "{d}/garbage.pt"), ("garbage.pt is not an .npz archive",)),
        "a single .npy array": Case((*PERSONALIZE, "{d}/single.npy"), ("holds a single array",)),
        "truncated npz": Case((*PERSONALIZE, "{d}/obs-truncated.npz"), ("obs-truncated.npz",)),
        "missing arrays": Case((*PERSONALIZE, "{d}/obs-no-times.npz"), ("lacks array(s) ['times_ms or times']",)),
        "obs of strings": Case((*PERSONALIZE, "{d}/obs-strings.npz"), ("obs must be a 3-D array of float or integer",)),
        "obs 2-D": Case((*PERSONALIZE, "{d}/obs-2d.npz"), ("obs must be a 3-D array", "got 2-D")),
        "float cells": Case((*PERSONALIZE, "{d}/obs-float-cells.npz"), ("cells must be a 2-D array of integer",)),
        "NaN at an observed node": Case((*PERSONALIZE, "{d}/obs-nan.npz"), ("NaN or inf at observed nodes",)),
        "no observed node": Case((*PERSONALIZE, "{d}/obs-unobserved.npz"), ("no observed node",)),
        "observed not 0/1": Case((*PERSONALIZE, "{d}/obs-observed2.npz"), ("observed must hold 0/1",)),
        "NaN point": Case((*PERSONALIZE, "{d}/obs-nan-point.npz"), ("points contains NaN or inf",)),
        "sites do not fit obs": Case((*PERSONALIZE, "{d}/obs-extra-site.npz"), ("observations do not fit together",)),
        "site out of range": Case((*PERSONALIZE, "{d}/obs-far-site.npz"), ("are not nodes of the 316-node mesh",)),
        "cell index out of range": Case((*PERSONALIZE, "{d}/obs-bad-cells.npz"), ("cell node index out of range",)),
        "obs scaled x1000": Case(
            (*PERSONALIZE, "{d}/obs-x1000.npz"), ("observations range from 0.", "to 99", "outside [-0.5, 1.5]")
        ),
        "obs in millivolts": Case(
            (*PERSONALIZE, "{d}/obs-millivolts.npz"), ("observations range from -79.9", "or millivolts as obs_mv")
        ),
        "obs_mv given as u": Case(
            (*PERSONALIZE, "{d}/obs-mv-as-u.npz"), ("obs_mv ranges from 0", "or never near rest")
        ),
        "obs and obs_mv": Case((*PERSONALIZE, "{d}/obs-both.npz"), ("give one of obs_mv and obs (recordings)",)),
        "times and times_ms": Case((*PERSONALIZE, "{d}/obs-two-clocks.npz"), ("give one of times_ms and times",)),
        "frame times not increasing": Case((*PERSONALIZE, "{d}/obs-backwards.npz"), ("must increase strictly",)),
        "negative activation time": Case(
            (*PERSONALIZE, "{d}/obs-negative-lat.npz"), ("activation_ms has 1 negative time(s), down to -4",)
        ),
        "duplicate site": Case((*PERSONALIZE, "{d}/obs-duplicate-site.npz"), ("recorded more than once",)),
        "frame times in ms given as model time units": Case(
            (*PERSONALIZE, "{d}/obs-ms-as-times.npz"), ("times in ms given as model time units", "times_ms")
        ),
        "activation maps 1000 ms late": Case(
            (*PERSONALIZE, "{d}/obs-late-lat.npz"),
            ("ms (median), after the model's window of 8-46 ms",),
        ),
        "a no-capture node with a time": Case(
            (*PERSONALIZE, "{d}/obs-no-capture.npz"), ("no_capture marks 316 node(s) that have an activation time",)
        ),
        "activation maps in seconds": Case((*PERSONALIZE, "{d}/obs-seconds.npz"), ("all zero, or seconds?",)),
        "activation maps all zero": Case((*PERSONALIZE, "{d}/obs-zero-lat.npz"), ("spread over 0 ms",)),
        "points scaled x1000": Case((*PERSONALIZE, "{d}/obs-points-x1000.npz"), ("points span", "in another unit")),
        "an epicardium of every node": Case(
            (*PERSONALIZE, "{d}/obs-all-epicardium.npz"), ("epicardium marks every node of the 316",)
        ),
        "an all-zero ECG": Case((*PERSONALIZE, "{d}/ecg-zero.npz"), ("ecg: recording 1 is zero in every lead",)),
        "ECG lead names shuffled": Case(
            (*PERSONALIZE, "{d}/ecg-shuffled.npz"), ("breaks I + III = II (Einthoven)", "mislabelled or out of order")
        ),
        "ECG electrodes 1000x outside the heart": Case(
            (*PERSONALIZE, "{d}/ecg-far.npz"), ("electrode_xyz_mm: electrode", "positions in another unit")
        ),
        "ECG electrodes all at one point": Case((*PERSONALIZE, "{d}/ecg-one-point.npz"), ("all at one point?",)),
        "neither file nor store": Case(PERSONALIZE[:-1], ("give either --observations FILE or --store",)),
        "unknown subject in a store": Case(
            (
                "learner",
                "personalize",
                "{d}/model.pt",
                "--out",
                "{d}/p.pt",
                "--store",
                "{s}",
                "--subject",
                "lv-x",
                "--sites",
                "1",
            ),
            ("lv-x",),
        ),
    },
    "path": {
        "simulate out is a file": Case(("simgen", "simulate", "{d}/afile/o", "--nodes", "300"), A_FILE),
        "simulate out in a read-only folder": Case(
            ("simgen", "simulate", "{d}/readonly/o", "--nodes", "300"), READ_ONLY
        ),
        "demo out is a file": Case(("simgen", "demo", "--out", "{d}/afile", "--nodes", "300"), A_FILE),
        "export out is a file": Case((*EXPORT, "{d}/afile"), A_FILE),
        "export out in a read-only folder": Case((*EXPORT, "{d}/readonly/vtk"), READ_ONLY),
        "card out in a read-only folder": Case(("simgen", "card", "{s}", "--out", "{d}/readonly/card.md"), READ_ONLY),
        "card out in a missing folder": Case(
            ("simgen", "card", "{s}", "--out", "{d}/nofolder/card.md"), ("nofolder/card.md: folder", "does not exist")
        ),
        "train out is a file": Case(
            ("learner", "train", "{d}/train.toml", "--store", "{s}", "--out", "{d}/afile"), A_FILE
        ),
        "train out in a read-only folder": Case(
            ("learner", "train", "{d}/train.toml", "--store", "{s}", "--out", "{d}/readonly/run"), READ_ONLY
        ),
        "personalize out in a read-only folder": Case(
            ("learner", "personalize", "{d}/model.pt", "--out", "{d}/readonly/p.pt", "--observations", "{d}/obs.npz"),
            READ_ONLY,
        ),
        "predict out in a read-only folder": Case((*PREDICT, "--out", "{d}/readonly/pred.npz"), READ_ONLY),
        "predict out is a folder": Case(
            (*PREDICT, "--out", "{d}/folder.npz"), ("folder.npz", "(a folder where a file is expected)")
        ),
        "predict vtk is a file": Case((*PREDICT, "--out", "{d}/pred.npz", "--vtk", "{d}/afile"), A_FILE),
        "curves out in a read-only folder": Case(
            ("learner", "curves", "{d}/run", "--out", "{d}/readonly/c.png"), READ_ONLY
        ),
        "card out on a full disk": Case(
            ("simgen", "card", "{s}", "--out", "/dev/full"), ("/dev/full", "No space left")
        ),
        "curves of a malformed log": Case(
            ("learner", "curves", "{d}/bad-run", "--out", "{d}/c.png"), ("log.jsonl", "line 2")
        ),
    },
}
FLAT = {f"{category}: {name}": case for category, cases in CASES.items() for name, case in cases.items()}
#: Cases that rely on folder permissions, which root ignores.
PERMISSIONS = {key for key, case in FLAT.items() if "Permission denied" in case.expect}


class Evil:
    """Pickled, it would run a shell command when loaded."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def write_observations(d: Path, mesh) -> None:
    """A valid observation file ``obs.npz`` on ``mesh`` and one broken variant per observation case."""
    from simgen.meshes.regions import site_labels

    n = mesh.n_nodes
    rng = np.random.default_rng(0)
    good = {
        "points": mesh.points,
        "cells": mesh.cells,
        "sites": np.array([0, 5]),
        "obs": rng.random((2, 6, n), np.float32),
        "observed": np.isin(np.arange(n), mesh.nodes("surface")),
        "times": 0.6 * np.arange(1, 7),
    }
    nan_obs = good["obs"].copy()
    nan_obs[1, 2, mesh.nodes("surface")[0]] = np.nan
    nan_points = good["points"].copy()
    nan_points[3, 1] = np.nan
    lat = np.full((2, n), 30.0)
    lat[1, 4] = -4.0
    x = mesh.points[:, 0]
    front = np.tile(10.0 + 80.0 * (x - x.min()) / np.ptp(x), (2, 1))
    labels = site_labels(mesh).arrays()
    variants = {
        "obs": {},
        "obs-no-times": {"times": None},
        "obs-strings": {"obs": np.full((2, 6, n), "u")},
        "obs-2d": {"obs": good["obs"][0]},
        "obs-float-cells": {"cells": good["cells"] + 0.5},
        "obs-nan": {"obs": nan_obs},
        "obs-unobserved": {"observed": np.zeros(n, bool)},
        "obs-observed2": {"observed": 2 * good["observed"].astype(int)},
        "obs-nan-point": {"points": nan_points},
        "obs-extra-site": {"sites": np.array([0, 5, 9])},
        "obs-far-site": {"sites": np.array([0, n + 50])},
        "obs-bad-cells": {"cells": np.where(good["cells"] == 0, n + 7, good["cells"])},
        "obs-x1000": {"obs": good["obs"] * 1000},
        "obs-millivolts": {"obs": 100 * good["obs"] - 80},
        "obs-mv-as-u": {"obs": None, "obs_mv": good["obs"]},
        "obs-both": {"obs_mv": 100 * good["obs"] - 80},
        "obs-two-clocks": {"times_ms": 7.74 * np.arange(1, 7)},
        "obs-backwards": {"times": 0.6 * np.array([1, 2, 4, 3, 5, 6])},
        "obs-negative-lat": {"obs": None, "times": None, "observed": None, "activation_ms": lat},
        "obs-duplicate-site": {"sites": np.array([5, 5])},
        "obs-seconds": {"obs": None, "times": None, "observed": None, "activation_ms": 1e-3 * front},
        "obs-zero-lat": {"obs": None, "times": None, "observed": None, "activation_ms": 0 * front},
        "obs-points-x1000": {"points": 1000 * mesh.points},
        "obs-ms-as-times": {"times": 7.74 * np.arange(1, 7)},
        "obs-late-lat": {"obs": None, "times": None, "observed": None, "activation_ms": front + 1000.0},
        "obs-no-capture": {
            "obs": None,
            "times": None,
            "observed": None,
            "activation_ms": front,
            "no_capture": np.ones(n, bool),
        },
        "obs-all-epicardium": {**labels, "epicardium": np.ones(n, np.uint8)},
        **ecg_variants(mesh, rng),
    }
    for name, patch in variants.items():
        arrays = {k: v for k, v in {**good, **patch}.items() if v is not None}
        np.savez(d / f"{name}.npz", **arrays)
    data = (d / "obs.npz").read_bytes()
    (d / "obs-truncated.npz").write_bytes(data[: len(data) // 2])
    np.save(d / "single.npy", good["obs"])


def ecg_variants(mesh, rng: np.random.Generator) -> dict[str, dict]:
    """Observation-file patches of 12-lead ECGs: all zero in one recording, leads shuffled, electrodes 1000x out
    or all at one point."""
    from shared.ecg import ELECTRODES, LEADS, Electrodes, leads

    s = np.linspace(0.0, 1.0, 60)
    potentials = rng.normal(0.0, 1.0, (2, len(ELECTRODES), 1)) * np.exp(
        -(((s - rng.uniform(0.2, 0.8, (2, len(ELECTRODES), 1))) / 0.1) ** 2)
    )
    ecg = leads(potentials, Electrodes(tuple(ELECTRODES), np.zeros((len(ELECTRODES), 3))))
    base = {"obs": None, "times": None, "observed": None, "ecg_mv": ecg, "ecg_times_ms": np.linspace(0, 450, 60)}
    zero = ecg.copy()
    zero[1] = 0.0
    centre = mesh.points.mean(axis=0)
    at = centre + rng.normal(0.0, 150.0, (len(ELECTRODES), 3))
    placed = {"electrodes": np.array(ELECTRODES)}
    swapped = list(LEADS)
    swapped[0], swapped[8] = swapped[8], swapped[0]  # I and V3 named each other
    return {
        "ecg-zero": {**base, "ecg_mv": zero},
        "ecg-shuffled": {**base, "leads": np.array(swapped)},
        "ecg-far": {**base, **placed, "electrode_xyz_mm": 1000.0 * at},
        "ecg-one-point": {**base, **placed, "electrode_xyz_mm": np.tile(centre + 200.0, (len(ELECTRODES), 1))},
    }


def write_checkpoints(d: Path, mesh) -> None:
    """A model (random weights), a personalised surrogate from it and broken checkpoints."""
    import torch

    from learner.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
    from learner.config import config_from_mapping
    from learner.models.surrogate import build_model
    from learner.observations import observations_from_file
    from learner.personalized import personalize

    config = config_from_mapping(
        {
            "out": str(d / "run"),
            "data": {"store": str(d / "store.zarr")},
            "model": {"channels": [4, 8], "hidden": 16, "latent": 8, "levels": 3, "coarsest": 10, "coarse_blocks": 1},
        }
    )
    model = build_model(config.model, 6)
    times = torch.as_tensor(0.6 * np.arange(1, 7))  # the model's frame times (time units), as shipped models record
    model_payload = {"kind": "model", "config": config.to_dict(), "frames": 6, "model": model.state_dict()}
    save_checkpoint(d / "model.pt", {**model_payload, "times": times})
    save_checkpoint(d / "incomplete.pt", {"kind": "model"})
    heart = personalize(d / "model.pt", observations_from_file(d / "obs.npz"), d / "personalized.pt")
    edited = torch.load(d / "personalized.pt", weights_only=True)
    edited["points"] = edited["points"] + 1000.0
    torch.save(edited, d / "edited.pt")
    prediction = heart.predict([1, 2]).arrays()  # its potentials a wave, not the random model's: compare reads them
    t, x = prediction["times_ms"][None, :, None], mesh.points[None, None, :, 0] - mesh.points[:, 0].min()
    wave = 1.0 / (1.0 + np.exp(-(t - 2.0 * x - np.array([0.0, 5.0])[:, None, None]) / 3.0))
    prediction["v_mv"] = (100.0 * wave - 80.0).astype(np.float32)
    np.savez(d / "predicted.npz", **prediction)  # not pred.npz: the predict cases write that
    renumbered = {**prediction, "v_mv": prediction["v_mv"] + 1.0, "site_xyz": prediction["site_xyz"] + 20.0}
    np.savez(d / "sim-renumbered.npz", **renumbered)
    np.savez(d / "sim-u.npz", **{**prediction, "v_mv": (prediction["v_mv"] + 80.0) / 100.0})
    (d / "garbage.pt").write_bytes(b"not a checkpoint at all\n" * 10)
    (d / "empty.pt").write_bytes(b"")
    torch.save({"format": CHECKPOINT_FORMAT, "kind": "model", "config": Evil(d / "pwned")}, d / "evil.pt")
    torch.save({"format": 1, "kind": "personalized"}, d / "format1.pt")
    torch.save([1, 2, 3], d / "list.pt")


def write_meshes(d: Path, mesh) -> None:
    """Mesh files: ``garbage.vtu`` (not a mesh), ``nan.vtu`` (a NaN coordinate), ``badcells.vtu`` (a cell refers
    to a node past the last), ``cube-hex.vtu`` and ``cube-tet.vtu`` (50 mm cubes: no heart), ``tiny-heart.ply``
    (a heart 1.6 units long, no unit metadata) and ``folded.vtu`` (an LV surface folded through itself)."""
    import meshio

    from simgen.meshes.slab import slab

    (d / "garbage.vtu").write_text("<VTKFile>not really</VTKFile>\n")
    points = mesh.points.copy()
    points[7, 2] = np.nan
    meshio.write(d / "nan.vtu", meshio.Mesh(points, [("tetra", mesh.cells)]))
    cells = mesh.cells.copy()
    cells[3, 1] = mesh.n_nodes + 7
    meshio.write(d / "badcells.vtu", meshio.Mesh(mesh.points, [("tetra", cells)]))
    cube = slab(50.0, 50.0, 50.0, 10.0)
    meshio.write(d / "cube-tet.vtu", meshio.Mesh(cube.points, [("tetra", cube.cells)]))
    x = np.linspace(0.0, 50.0, 6)
    grid = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1).reshape(-1, 3)
    corner = np.arange(6**3).reshape(6, 6, 6)[:-1, :-1, :-1].ravel()
    offsets = np.array([0, 36, 42, 6, 1, 37, 43, 7])  # the 8 corners of each grid cube
    meshio.write(d / "cube-hex.vtu", meshio.Mesh(grid, [("hexahedron", corner[:, None] + offsets)]))
    from simgen.meshes.catalog import get_mesh

    lv = get_mesh("lv", 400, "triangle")
    meshio.write(d / "tiny-heart.ply", meshio.Mesh(lv.points * 0.02, [("triangle", lv.cells)]))
    folded = lv.points.copy()
    folded[folded[:, 0] > 0.5 * folded[:, 0].max(), 0] *= -0.9
    meshio.write(d / "folded.vtu", meshio.Mesh(folded, [("triangle", lv.cells)]))
    tet = get_mesh("lv", 400)
    along, across = np.tile([1.0, 0.0, 0.0], (tet.n_nodes, 1)), np.tile([0.0, 1.0, 0.0], (tet.n_nodes, 1))
    fibres = meshio.Mesh(tet.points, [("tetra", tet.cells)], point_data={"fibre": along, "fiber": across})
    meshio.write(d / "two-fibres.vtu", fibres)
    two = np.vstack([tet.points, tet.points + [5000.0, 0.0, 0.0]])
    meshio.write(d / "two-hearts.vtu", meshio.Mesh(two, [("tetra", np.vstack([tet.cells, tet.cells + tet.n_nodes]))]))


@pytest.fixture(scope="module")
def d(tmp_path_factory) -> Iterator[Path]:
    """A folder of inputs: specs, meshes, observation files, checkpoints, runs, locked and read-only stores."""
    from simgen.meshes.catalog import get_mesh

    d = tmp_path_factory.mktemp("bad-input")
    for name, text in SPECS.items():
        (d / f"{name}.toml").write_text(text)
    (d / "train.toml").write_text('out = "run"\n[data]\nstore = "missing.zarr"\n')
    (d / "train-small.toml").write_text(TRAIN_SMALL)
    (d / "train-lr-nan.toml").write_text(TRAIN_SMALL.replace("epochs = 1", "epochs = 1\nlr = nan"))
    (d / "train-targets0.toml").write_text(TRAIN_SMALL.replace("targets = 2", "targets = 0"))
    (d / "blocked.toml").write_text('name = "blocked"\n[healthy]\nD = 0.0\n')
    (d / "afile").write_text("not a folder")
    (d / "folder.npz").mkdir()
    mesh = get_mesh("lv", 300)
    write_observations(d, mesh)
    write_checkpoints(d, mesh)
    write_meshes(d, mesh)
    for run, log in (
        ("run", '{"epoch": 1, "target_mse": 0.5}\n'),
        ("bad-run", '{"epoch": 1, "target_mse": 0.5}\n{epoch\n'),
    ):
        (d / run).mkdir(exist_ok=True)
        (d / run / "log.jsonl").write_text(log)
    (d / "other.zarr").mkdir()
    (d / "other.zarr/.lock").write_text(json.dumps({"host": "elsewhere.example", "pid": 7, "start": 1, "token": "t"}))
    readonly = d / "readonly"
    (readonly / "gone.zarr").mkdir(parents=True)
    (readonly / "gone.zarr/.lock").write_text(json.dumps({"host": socket.gethostname(), "pid": 999_999_999}))
    for folder in (readonly / "gone.zarr", readonly):
        folder.chmod(0o555)
    yield d
    for folder in (readonly, readonly / "gone.zarr"):
        folder.chmod(0o755)


@pytest.fixture(scope="module")
def store(d) -> Path:
    """The tiny store of :data:`SPEC`, built once."""
    from simgen.store import load_spec
    from simgen.store.runner import build

    build(load_spec(d / "good.toml"), d / "store.zarr", workers=1)
    return d / "store.zarr"


@pytest.fixture(scope="module")
def held(d, store) -> Iterator[Path]:
    """A copy of the store, locked by this (running) test process."""
    shutil.copytree(store, d / "held.zarr")
    with StoreLock(d / "held.zarr"):
        yield d / "held.zarr"


def digest(store: Path) -> dict[str, str]:
    """SHA-256 of every file of ``store`` by relative path."""
    return {
        str(p.relative_to(store)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(store.rglob("*"))
        if p.is_file()
    }


class BatchProcess:
    """A ``tests/cli_batch.py --serve`` subprocess: it imports the packages once and runs batch after batch."""

    def __init__(self) -> None:
        self.stderr = tempfile.TemporaryFile("w+")  # a file, not a pipe: a full pipe would stall the process
        self.proc = subprocess.Popen(
            [sys.executable, "-P", str(ROOT / "tests" / "cli_batch.py"), "--serve"],  # -P: tests/simgen must not
            stdin=subprocess.PIPE,  # shadow simgen
            stdout=subprocess.PIPE,
            stderr=self.stderr,
            cwd=ROOT,
            text=True,
        )

    def run(self, argvs: list[list[str]]) -> list[tuple[int, str]]:
        try:
            self.proc.stdin.write(json.dumps(argvs) + "\n")
            self.proc.stdin.flush()
            answer = self.proc.stdout.readline()
        except BrokenPipeError:
            answer = ""
        if not answer:  # the process died
            self.proc.wait(timeout=60)
            self.stderr.seek(0)
            raise AssertionError(f"cli_batch.py exited with code {self.proc.returncode}:\n{self.stderr.read()}")
        return [tuple(result) for result in json.loads(answer)]

    def finish(self) -> None:
        """Tell the process to exit (it does when its stdin closes)."""
        with contextlib.suppress(OSError):  # a process that died already
            self.proc.stdin.close()

    def close(self) -> None:
        self.finish()
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.proc.stdout.close()
        self.stderr.close()


#: The module's idle batch processes (at most two run at once): started on demand, closed after the module.
_IDLE: queue.SimpleQueue[BatchProcess] = queue.SimpleQueue()
_STARTED: list[BatchProcess] = []


def run_batch(argvs: list[list[str]]) -> list[tuple[int, str]]:
    """``tests/cli_batch.py`` on ``argvs`` in a subprocess, one of the module's (:class:`BatchProcess`)."""
    try:
        process = _IDLE.get_nowait()
    except queue.Empty:
        process = BatchProcess()
        _STARTED.append(process)
    try:
        results = process.run(argvs)
    except BaseException:
        process.close()
        _STARTED.remove(process)
        raise
    _IDLE.put(process)
    return results


@pytest.fixture(scope="module", autouse=True)
def _close_batch_processes() -> Iterator[None]:
    yield
    for process in _STARTED:  # all told to exit first: they exit together
        process.finish()
    while _STARTED:
        _STARTED.pop().close()
    while not _IDLE.empty():
        _IDLE.get_nowait()


class Outcome(NamedTuple):
    """What a case did: exit code, output, the placeholders, its store copy's digests before and after."""

    code: int
    output: str
    fill: dict
    before: dict | None
    after: dict | None


BATCHES = 4  # batches, two at a time, on the module's two batch processes (each imports the packages once)


@pytest.fixture(scope="module")
def outcomes(d, store, held) -> dict[str, Outcome]:
    """Every case run, its store copy hashed before and after."""
    todo = [key for key in FLAT if not (as_root and key in PERMISSIONS)]
    fills, before = {}, {}
    for i, key in enumerate(todo):
        fills[key] = {"d": d, "held": held, "pid": os.getpid(), "s": d / "stores" / f"{i}.zarr"}
        if any("{s}" in arg for arg in FLAT[key].argv):
            shutil.copytree(store, fills[key]["s"])
            if FLAT[key].damage:
                FLAT[key].damage(fills[key]["s"])
            before[key] = digest(fills[key]["s"])
    argvs = {key: [arg.format(**fills[key]) for arg in FLAT[key].argv] for key in todo}
    batches = [todo[i::BATCHES] for i in range(BATCHES)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda batch: run_batch([argvs[key] for key in batch]), batches))
    out = {}
    for batch, result in zip(batches, results):
        for key, (code, output) in zip(batch, result):
            after = digest(fills[key]["s"]) if key in before else None
            out[key] = Outcome(code, output, fills[key], before.get(key), after)
    return out


def flat(output: str) -> str:
    """``output`` on one line, without the frame typer draws around usage errors."""
    return " ".join(output.translate(str.maketrans("│╭╮╰╯─", "      ")).split())


@pytest.mark.parametrize("key", FLAT)
def test_bad_input_exits_2_with_a_message(key, outcomes):
    if key not in outcomes:
        pytest.skip("root ignores folder permissions")
    code, output, fill, before, after = outcomes[key]
    assert code == 2, output
    assert "Traceback" not in output
    expected = [text.format(**fill) for text in FLAT[key].expect]
    if expected[0].startswith("Invalid value"):  # typer's usage error, framed
        assert all(text in flat(output) for text in expected), output
    else:  # ours: one line
        errors = [line for line in output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and all(text in errors[0] for text in expected), output
    assert before == after, "the store changed"


def test_the_suite_covers_every_category():
    assert len(FLAT) >= 60 and all(len(cases) >= 5 for cases in CASES.values())


def test_pickled_code_never_ran(d, outcomes):
    assert not (d / "pwned").exists()


#: Metadata of each kind of group and array, deleted, then restored by ``simgen repair``: what it reports.
DELETED_METADATA = {
    "subjects/lv-healthy/zarr.json": "group metadata written anew (members kept): subjects/lv-healthy",
    "subjects/zarr.json": "group metadata written anew (members kept): subjects",
    "subjects/lv-scar-apex/activation/zarr.json": (
        "array metadata written anew (chunk files kept): subjects/lv-scar-apex/activation"
    ),
    "meshes/lv/zarr.json": "group metadata written anew (members kept): meshes/lv",
    "meshes/lv/cells/zarr.json": "arrays written anew from the spec: meshes/lv/cells",
}


def test_repair_restores_deleted_metadata_byte_identical(d, store):
    copies = {}
    for i, metadata in enumerate(DELETED_METADATA):
        copies[metadata] = d / "repair" / f"{i}.zarr"
        shutil.copytree(store, copies[metadata])
        (copies[metadata] / metadata).unlink()
    results = run_batch([["simgen", "repair", str(copy), "--workers", "1"] for copy in copies.values()])
    for (metadata, copy), (code, output) in zip(copies.items(), results):
        assert code == 0 and "Traceback" not in output, output
        assert f"plan: {DELETED_METADATA[metadata]}" in flat(output) and "nothing was damaged" not in output
        assert f"repaired: {DELETED_METADATA[metadata]}" in flat(output)
        assert "chunks marked not done" not in output  # no simulation lost
        assert digest(copy) == digest(store), metadata


def test_repair_restores_every_damage_of_the_suite_or_refuses_it_unchanged(d, store):
    """Each store damage of :data:`CASES`, then ``simgen repair``: the clean build's bytes (exit 0), or a
    refusal (exit 2) that names the reason and leaves the store as it was. Two repairs at a time share one
    cluster: stores with the same subject ids never take each other's chunks (Dask keys name the store)."""
    damages = {case.damage: key for key, case in FLAT.items() if case.damage is not None}
    copies = {}
    for i, (damage, key) in enumerate(damages.items()):
        copies[key] = d / "repair-suite" / f"{i}.zarr"
        shutil.copytree(store, copies[key])
        damage(copies[key])
    before = {key: digest(copy) for key, copy in copies.items()}
    from distributed import LocalCluster

    from simgen.store.runner import single_thread_env

    with (  # one worker for every repair that computes chunks again: no cluster started per repair
        single_thread_env(),
        LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
    ):
        argvs = [["simgen", "repair", str(copy), "--scheduler", cluster.scheduler_address] for copy in copies.values()]
        with ThreadPoolExecutor(max_workers=2) as pool:  # two subprocesses
            halves = list(pool.map(run_batch, [argvs[::2], argvs[1::2]]))
    results = [halves[i % 2][i // 2] for i in range(len(argvs))]
    refused = []
    for (key, copy), (code, output) in zip(copies.items(), results):
        assert code in (0, 2) and "Traceback" not in output, (key, output)
        if code == 2:
            refused.append(key)
            assert digest(copy) == before[key], key
        else:
            assert digest(copy) == digest(store), key
    # the root metadata gone (no --spec), an extra array (one of them holding a user's file), the lock a folder
    assert len(refused) <= 5, refused


def test_unlock_force_removes_another_hosts_lock(d):
    (d / "forced.zarr").mkdir()
    (d / "forced.zarr/.lock").write_text(json.dumps({"host": "elsewhere.example", "pid": 7, "start": 1, "token": "t"}))
    [(code, output)] = run_batch([["simgen", "unlock", str(d / "forced.zarr"), "--force"]])
    assert code == 0, output
    assert "removed the lock of host elsewhere.example, pid 7" in flat(output)
    assert not (d / "forced.zarr/.lock").exists()


def test_dry_run_prints_the_plan_and_writes_nothing(d, tmp_path):
    (tmp_path / "default.toml").write_text('name = "no meshes"\n')  # the default mesh, all 16 settings
    [(code, output), (code_good, output_good)] = run_batch(
        [
            ["simgen", "build", str(tmp_path / "default.toml"), "--store", str(tmp_path / "s.zarr"), "--dry-run"],
            [
                "simgen",
                "build",
                str(d / "good.toml"),
                "--store",
                str(tmp_path / "t.zarr"),
                "--dry-run",
                "--workers",
                "1",
            ],
        ]
    )
    assert code == 0 and code_good == 0, output + output_good
    assert "meshes: lv (2049 nodes, 200 sites)" in output and "subjects: 16 (1 mesh(es) x 16" in output
    assert "simulations: 3200 in 128 task(s), 55 frames each" in output
    for line in ("disk: ~", "memory per worker: ~", "time: ~", "on 1 worker(s)", "dry run: nothing written"):
        assert line in output_good, output_good
    assert list(tmp_path.iterdir()) == [tmp_path / "default.toml"]


# (package, command function, parameter) of numbers whose range typer cannot state
UNRANGED = {("simgen", "simulate", "dt")}  # > 0, an open bound: SolverConfig refuses it with a message
#: Counts bounded where they are used, with a message naming the bound: a site of the store, a mesh's node count
#: (200-200,000, the range of the procedural meshes and of resampling).
UNBOUNDED = {("simgen", "export_vtk", "site_index")} | {
    ("simgen", command, "nodes") for command in ("mesh", "simulate", "demo", "add_subject")
}


def numeric(hint: object) -> set[type]:
    """The number types of a parameter annotation (``int``, ``float``), optional or not; empty otherwise."""
    kinds = set(typing.get_args(hint) or [hint]) - {type(None)}
    return kinds if kinds and kinds <= {int, float} else set()


@pytest.mark.parametrize("package", ["simgen", "learner"])
def test_every_number_option_has_a_range_and_floats_are_finite(package):
    from shared.cli import finite

    app = importlib.import_module(f"{package}.cli").app
    for command in app.registered_commands:
        hints = typing.get_type_hints(command.callback, include_extras=True)
        hints.pop("return")
        for name, hint in hints.items():
            base, *info = typing.get_args(hint) if typing.get_origin(hint) is typing.Annotated else (hint,)
            where = f"{package} {command.callback.__name__} {name}"
            if numeric(base) and (package, command.callback.__name__, name) not in UNRANGED:
                assert info and info[0].min is not None, f"{where}: no min="
            if int in numeric(base) and (package, command.callback.__name__, name) not in UNBOUNDED:
                assert info and info[0].max is not None, f"{where}: a count without max="
            if float in numeric(base):
                assert info and info[0].callback is finite, f"{where}: NaN and inf not refused"


@pytest.mark.parametrize("text", ["5,1", "0,3", "1,2,3", "two", ""])
def test_context_range_is_checked(text):
    with pytest.raises(InputError, match="--context: expected 'min,max'"):
        _context_range(text)


def test_context_range_takes_one_size_or_two():
    assert _context_range("3") == (3, 3) and _context_range("1,5") == (1, 5)
