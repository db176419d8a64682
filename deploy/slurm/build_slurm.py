"""Run a simgen build on a SLURM cluster through dask-jobqueue (one worker = one 1-CPU job).

Run it where jobs can be submitted (a login node inside tmux/screen, or a small
long-running job of its own), from an environment with the project and the
``deploy`` extra installed (``pip install ".[deploy]"``), on a file system the
compute nodes share:

    python deploy/slurm/build_slurm.py specs/default.toml --store /scratch/$USER/paper.zarr \
        --jobs 32 --memory 2GiB --walltime 01:00:00 --account myproj --partition cpu

    python deploy/slurm/build_slurm.py specs/default.toml --store ... --dry-run   # print the job script

The scheduler runs in this process; the address and the dashboard link are
printed first (tunnel the dashboard: ``ssh -L 8787:localhost:8787 login-node``).
Workers retire before their job's walltime (``--lifetime``, staggered so they
do not all leave at once) and the adaptive cluster submits fresh jobs in their
place: a task cut short is rerun elsewhere, and a task is only ever recorded
done after its chunk is written. Interrupt this script and run it again to
resume: finished chunks are kept.
"""

from __future__ import annotations

import argparse
import sys

#: Every worker process runs one task at a time on one core: BLAS and numba pinned to one thread.
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")

#: Memory a job asks for beyond the worker's limit: the nanny process that watches the worker.
NANNY_MIB = 128


def _minutes(walltime: str) -> int:
    """Whole minutes of a SLURM time: ``MM``, ``MM:SS``, ``HH:MM:SS``, ``D-HH``, ``D-HH:MM[:SS]``."""
    days, _, clock = walltime.rpartition("-")
    parts = [int(p) for p in clock.split(":")]
    if days:
        hours, minutes, seconds = (parts + [0, 0])[:3]
    elif len(parts) < 3:
        hours, minutes, seconds = 0, parts[0], (parts + [0])[1]
    else:
        hours, minutes, seconds = parts
    return int(days or 0) * 24 * 60 + hours * 60 + minutes + seconds // 60


def make_cluster(args: argparse.Namespace):
    """The SLURMCluster: one single-threaded worker per job, retired before its walltime."""
    from dask.utils import parse_bytes
    from dask_jobqueue import SLURMCluster

    wall = _minutes(args.walltime)
    stagger = max(1, wall // 12)
    # Leave the walltime's last tenth (at least 2 stagger spans) to retire gracefully.
    lifetime = max(1, wall - max(wall // 10, 2 * stagger))
    prologue = [f"export {name}=1" for name in THREAD_ENV]
    if args.venv:
        prologue.append(f"source {args.venv}/bin/activate")
    return SLURMCluster(
        queue=args.partition,
        account=args.account,
        cores=1,  # one CPU per job ...
        processes=1,  # ... one worker process, one thread: the solver runs single-threaded
        memory=args.memory,  # the worker's memory limit ...
        job_mem=f"{parse_bytes(args.memory) // 2**20 + NANNY_MIB}M",  # ... and SLURM's --mem: + the nanny
        walltime=args.walltime,
        job_name="simgen-worker",
        interface=args.interface,
        local_directory=args.local_directory,
        log_directory=args.log_directory,
        job_script_prologue=prologue,
        job_extra_directives=args.sbatch or [],
        # Retire before SLURM kills the job; no --lifetime-restart: the job ends with its walltime,
        # adapt() below submits a fresh one instead.
        worker_extra_args=["--lifetime", f"{lifetime}m", "--lifetime-stagger", f"{stagger}m"],
        scheduler_options={"dashboard_address": f":{args.dashboard_port}"},
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("spec", help="build spec (TOML)")
    p.add_argument("--store", required=True, help="store folder on a shared file system, or an s3:// URL")
    p.add_argument("--jobs", type=int, default=16, help="most worker jobs at once (default 16)")
    p.add_argument("--min-jobs", type=int, default=1, help="fewest worker jobs kept (default 1)")
    p.add_argument("--memory", default="2GiB", help="memory limit per worker (deploy/README.md: sizing)")
    p.add_argument("--walltime", default="01:00:00", help="walltime per worker job (default 01:00:00)")
    p.add_argument("--partition", default=None, help="SLURM partition (queue)")
    p.add_argument("--account", default=None, help="SLURM account")
    p.add_argument("--interface", default=None, help="network interface for Dask, e.g. ib0")
    p.add_argument("--local-directory", default="${TMPDIR:-/tmp}", help="node-local scratch for the workers")
    p.add_argument("--log-directory", default="logs/slurm", help="where the jobs' output goes")
    p.add_argument("--venv", default=None, help="virtual environment activated in each job")
    p.add_argument("--sbatch", action="append", help="extra #SBATCH option, e.g. --sbatch=--qos=long (repeat)")
    p.add_argument("--dashboard-port", type=int, default=8787)
    p.add_argument("--retries", type=int, default=2, help="retries per failing task")
    p.add_argument("--dry-run", action="store_true", help="print the worker job script and exit")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from shared.errors import InputError
    from simgen.store import load_spec
    from simgen.store.runner import build

    spec = load_spec(args.spec)  # a bad spec fails here, before any job is submitted
    with make_cluster(args) as cluster:
        if args.dry_run:
            print(cluster.job_script())
            return 0
        print(f"scheduler: {cluster.scheduler_address}", flush=True)
        print(f"dashboard: {cluster.dashboard_link}", flush=True)
        cluster.adapt(minimum_jobs=args.min_jobs, maximum_jobs=args.jobs)
        try:
            report = build(spec, args.store, scheduler=cluster.scheduler_address, retries=args.retries,
                           on_start=lambda n, _: print(f"{n} tasks to run", flush=True))
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    print(f"{report.store}: {report.tasks_run}/{report.tasks_total} chunks, {report.simulations} simulations "
          f"in {report.seconds:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
