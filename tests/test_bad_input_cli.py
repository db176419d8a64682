"""Bad input to the real ``simgen`` and ``learner`` command lines: exit code 2, a message naming it, no traceback.

Every case runs the CLI in a subprocess (``python -m simgen`` / ``python -m
learner``) and fails before any simulation, Dask cluster or training starts.
Each number option has a range (checked here once for all), so one case per
kind of check is enough.
"""

from __future__ import annotations

import importlib
import json
import os
import socket
import subprocess
import sys
import typing
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from learner.cli import _context_range
from shared.errors import InputError
from simgen.build.lock import StoreLock

ROOT = Path(__file__).resolve().parents[1]
SPEC = """tissue = ["healthy"]
[[meshes]]
id = "lv"
nodes = 500
[sites]
count = 4
[solver]
frames = {frames}
[output]
chunk_sites = 2
sock_electrodes = 30
"""
as_root = os.geteuid() == 0  # root writes into read-only folders


def run_cli(package: str, *args: object) -> tuple[int, str]:
    """Exit code and stdout + stderr of ``python -m package args``."""
    proc = subprocess.run(
        [sys.executable, "-m", package, *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    return proc.returncode, proc.stdout + proc.stderr


def flat(output: str) -> str:
    """``output`` on one line, without the frame typer draws around usage errors."""
    return " ".join(output.translate(str.maketrans("│╭╮╰╯─", "      ")).split())


@pytest.fixture(scope="module")
def d(tmp_path_factory) -> Iterator[Path]:
    """A folder of inputs: specs, a learner config, a plain file, stores locked by others."""
    d = tmp_path_factory.mktemp("bad-input")
    (d / "spec.toml").write_text(SPEC.format(frames=6))
    (d / "frames0.toml").write_text(SPEC.format(frames=0))
    (d / "train.toml").write_text('out = "run"\n[data]\nstore = "missing.zarr"\n')
    (d / "afile").write_text("not a folder")
    for name in ("other.zarr", "other-forced.zarr"):
        (d / name).mkdir()
        (d / name / ".lock").write_text(json.dumps({"host": "elsewhere.example", "pid": 7, "start": 1, "token": "t"}))
    readonly = d / "readonly"
    (readonly / "gone.zarr").mkdir(parents=True)
    (readonly / "gone.zarr/.lock").write_text(json.dumps({"host": socket.gethostname(), "pid": 999_999_999}))
    for folder in (readonly / "gone.zarr", readonly):
        folder.chmod(0o555)
    yield d
    for folder in (readonly, readonly / "gone.zarr"):
        folder.chmod(0o755)


@pytest.fixture(scope="module")
def held(d) -> Iterator[Path]:
    """A store locked by this (running) test process."""
    with StoreLock(d / "held.zarr"):
        yield d / "held.zarr"


def usage(option: str) -> str:
    """The start of typer's message for an out-of-range ``option``."""
    return f"Invalid value for '{option}'"


BUILD = ("simgen", "build", "{d}/spec.toml", "--store", "{d}/s.zarr")
A_FILE = ("afile", "(a file where a folder is expected)")
# id: (argv, substrings of the message); "{d}" is the input folder, "{held}" a store this process locks
CASES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "workers 0": ((*BUILD, "--workers", "0"), (usage("--workers"),)),
    "workers negative": ((*BUILD, "--workers", "-2"), (usage("--workers"),)),
    "retries -1": ((*BUILD, "--retries", "-1"), (usage("--retries"),)),
    "threads 0": (("simgen", "simulate", "{d}/o", "--threads", "0"), (usage("--threads"),)),
    "duplicate sites": (("simgen", "simulate", "{d}/o", "--sites", "3,0,3"), ("--sites: [3] given more than once",)),
    "frames 0": (
        ("simgen", "build", "{d}/frames0.toml", "--store", "{d}/f.zarr"),
        ("frames must be a positive integer, got 0",),
    ),
    "unlock a running build": (
        ("simgen", "unlock", "{held}"),
        ("still running (pid {pid} on this host): stop it with Ctrl-C", "kill -INT {pid}"),
    ),
    "unlock another host": (
        ("simgen", "unlock", "{d}/other.zarr"),
        ("cannot check (host elsewhere.example, pid 7)", "simgen unlock --force"),
    ),
    "build store is a file": (("simgen", "build", "{d}/spec.toml", "--store", "{d}/afile"), A_FILE),
    "unlock store is a file": (("simgen", "unlock", "{d}/afile"), A_FILE),
    "build in a read-only folder": (
        ("simgen", "build", "{d}/spec.toml", "--store", "{d}/readonly/s.zarr"),
        ("readonly/s.zarr", "Permission denied"),
    ),
    "unlock in a read-only store": (
        ("simgen", "unlock", "{d}/readonly/gone.zarr"),
        ("gone.zarr/.lock", "Permission denied"),
    ),
    "epochs 0": (("learner", "train", "{d}/train.toml", "--epochs", "0"), (usage("--epochs"),)),
    "train out is a file": (("learner", "train", "{d}/train.toml", "--out", "{d}/afile"), A_FILE),
    "train out in a read-only folder": (
        ("learner", "train", "{d}/train.toml", "--out", "{d}/readonly/run"),
        ("readonly/run", "Permission denied"),
    ),
    "samples 1": (
        ("learner", "predict", "{d}/p.pt", "--sites", "1", "--samples", "1"),
        (usage("--samples"), "one draw gives no spread"),
    ),
    "samples -1": (("learner", "predict", "{d}/p.pt", "--sites", "1", "--samples", "-1"), (usage("--samples"),)),
}
READ_ONLY = {case for case in CASES if "read-only" in case}  # root writes there all the same


@pytest.fixture(scope="module")
def outputs(d, held) -> dict[str, tuple[int, str, dict]]:
    """Exit code, output and placeholders of every case, run side by side (each spends a second or more starting)."""
    fill = {"d": d, "held": held, "pid": os.getpid()}
    todo = [case for case in CASES if not (as_root and case in READ_ONLY)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        runs = {case: pool.submit(run_cli, *(a.format(**fill) for a in CASES[case][0])) for case in todo}
    return {case: (*run.result(), fill) for case, run in runs.items()}


@pytest.mark.parametrize("case", CASES)
def test_bad_input_exits_2_with_a_message(case, outputs):
    if case not in outputs:
        pytest.skip("root ignores folder permissions")
    code, output, fill = outputs[case]
    assert code == 2, output
    assert "Traceback" not in output
    expected = [text.format(**fill) for text in CASES[case][1]]
    if expected[0].startswith("Invalid value"):  # typer's usage error, framed
        assert all(text in flat(output) for text in expected), output
    else:  # ours: one line
        errors = [line for line in output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and all(text in errors[0] for text in expected), output


def test_unlock_force_removes_another_hosts_lock(d):
    code, output = run_cli("simgen", "unlock", d / "other-forced.zarr", "--force")
    assert code == 0, output
    assert "removed the lock of host elsewhere.example, pid 7" in flat(output)
    assert not (d / "other-forced.zarr/.lock").exists()


# (package, command function, parameter) of numbers whose range typer cannot state
UNRANGED = {("simgen", "simulate", "dt")}  # > 0, an open bound: SolverConfig refuses it with a message


def numeric(hint: object) -> bool:
    """Whether a parameter annotation is ``int`` or ``float``, optional or not."""
    kinds = set(typing.get_args(hint) or [hint]) - {type(None)}
    return bool(kinds) and kinds <= {int, float}


@pytest.mark.parametrize("package", ["simgen", "learner"])
def test_every_number_option_has_a_range(package):
    app = importlib.import_module(f"{package}.cli").app
    for command in app.registered_commands:
        hints = typing.get_type_hints(command.callback, include_extras=True)
        hints.pop("return")
        for name, hint in hints.items():
            base, *info = typing.get_args(hint) if typing.get_origin(hint) is typing.Annotated else (hint,)
            if numeric(base) and (package, command.callback.__name__, name) not in UNRANGED:
                assert info and info[0].min is not None, f"{package} {command.callback.__name__} {name}: no min="


@pytest.mark.parametrize("text", ["5,1", "0,3", "1,2,3", "two", ""])
def test_context_range_is_checked(text):
    with pytest.raises(InputError, match="--context: expected 'min,max'"):
        _context_range(text)


def test_context_range_takes_one_size_or_two():
    assert _context_range("3") == (3, 3) and _context_range("1,5") == (1, 5)
