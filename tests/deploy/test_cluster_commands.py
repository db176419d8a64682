"""A build through ``simgen build --scheduler`` on a cluster started with the deploy files' own commands.

The scheduler, the two workers and the build job run the commands of
deploy/docker/compose.yaml (read from it), as separate processes on
127.0.0.1; only addresses, ports and paths differ. The store is then checked
with ``simgen verify`` and ``simgen status``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
SINGLE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def _local(argv: list[str]) -> list[str]:
    """The command with its program taken from this environment (``dask`` -> ``.venv/bin/dask``)."""
    return [str(BIN / argv[0]), *argv[1:]]


def _spawn(argv: list[str], log: Path) -> subprocess.Popen:
    with open(log, "wb") as out:
        return subprocess.Popen(argv, env={**os.environ, **SINGLE_THREAD}, stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _run(argv: list[str], timeout: float = 240) -> subprocess.CompletedProcess:
    env = {**os.environ, **SINGLE_THREAD, "COLUMNS": "200"}
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)


def _wait_for(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.1)


@pytest.fixture
def cluster(compose_commands, with_options, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes, as the compose file starts them."""
    scheduler, worker = compose_commands["scheduler"], compose_commands["worker"]
    sched_file = tmp_path / "scheduler.json"
    argv = with_options(scheduler, host="127.0.0.1", port="0", dashboard_address="127.0.0.1:0")
    procs = [_spawn(_local(argv) + ["--scheduler-file", str(sched_file)], tmp_path / "scheduler.log")]
    try:
        _wait_for(lambda: sched_file.exists() and sched_file.stat().st_size > 0, 60, "the scheduler file")
        address = json.loads(sched_file.read_text())["address"]
        argv = [address if a == "tcp://scheduler:8786" else a for a in worker]
        procs += [_spawn(_local(argv), tmp_path / f"worker{i}.log") for i in range(2)]
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=90)
            info = client.scheduler_info(n_workers=-1)["workers"].values()
            assert [w["nthreads"] for w in info] == [1, 1]  # --nthreads 1, --nworkers 1
        yield address
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)


def test_cli_build_with_the_compose_commands(cluster, compose_commands, with_options, tiny_spec_toml, tmp_path):
    spec, store = tmp_path / "tiny.toml", tmp_path / "out" / "tiny.zarr"
    spec.write_text(tiny_spec_toml)
    job = compose_commands["build"]
    assert job[:2] == ["simgen", "build"] and job[job.index("--scheduler") + 1] == "tcp://scheduler:8786"
    argv = with_options(job, store=str(store), scheduler=cluster)
    argv[2] = str(spec)
    result = _run(_local(argv))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "4/4 chunks, 12 simulations" in result.stdout

    verify = _run(_local(["simgen", "verify", str(store), "--sample", "1"]))
    assert verify.returncode == 0, verify.stdout + verify.stderr
    assert "4 chunks read, 2 recomputed, 0 problem(s)" in verify.stdout
    status = _run(_local(["simgen", "status", str(store)]))
    assert "4/4 chunks done (100%)" in status.stdout

    again = _run(_local(argv))  # the same job, rerun: a resume with nothing left
    assert again.returncode == 0 and "nothing to do, all 4 chunks done" in again.stdout
