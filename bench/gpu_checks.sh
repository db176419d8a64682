#!/usr/bin/env bash
# Every GPU figure in one run, on a machine with one CUDA GPU and a Python that has torch for it
# (docs/solver-backends.md, "Not measured on a GPU"; docs/results.md collects the tables).
#
#   bash bench/gpu_checks.sh OUT_DIR [WHEEL_DIR]
#
# WHEEL_DIR: wheels of the project's dependencies the machine lacks (zarr, dask, trimesh, ...),
# installed with --no-deps into a private folder first. Each step has its own time limit, so one
# failure does not lose the others. At most 9 minutes. OUT_DIR gets five files: log.txt (every
# step's output and exit status), solver/solver.md and solver.json, eval_cuda.md, eval_cpu.md.
set -uo pipefail
out=${1:?usage: bench/gpu_checks.sh OUT_DIR [WHEEL_DIR]}
wheels=${2:-}
mkdir -p "$out"
python=${PYTHON:-python3}
if [[ -n "$wheels" ]]; then
    $python -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "$wheels"/*.whl
    export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1

log="$out/log.txt"
step() {  # step NAME SECONDS COMMAND...: run COMMAND with a limit, its output appended to log.txt
    local name=$1 limit=$2
    shift 2
    local start=$SECONDS
    echo "== $name" >>"$log"
    timeout "$limit" "$@" 2>&1 | tr '\r' '\n' >>"$log"
    echo "== $name: exit ${PIPESTATUS[0]} in $((SECONDS - start)) s" | tee -a "$log"
}

step machine 60 bash -c "nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader; nproc; \
    $python -c 'import torch, numba, numpy; print(torch.__version__, torch.cuda.get_device_name(), numba.__version__, numpy.__version__)'"

# 1. The CUDA tests: torch on CUDA against numba, the GPU-worker build.
step tests 100 $python -m pytest -q -p no:cacheprovider tests/simgen/solver/test_torch_backend.py \
    tests/simgen/store/test_gpu_build.py
# 2. Solver speed: Euler and IMEX (CG solves at these sizes) on CUDA next to numba on the host's threads.
step solver 200 $python -m bench.solver --backend numba torch --device cuda --integrator euler imex \
    --nodes 2000 10000 50000 --batch 64 --naive-sites 0 --threads 16 --repeat 1 --out "$out/solver"
# 3. Training on the GPU against the CPU: the demo store, the same epochs, time and held-out accuracy.
step demo_store 40 $python -m simgen build specs/demo.toml --store "$out/work/demo.zarr"
for device in cuda cpu; do
    step "train_$device" $([[ $device == cuda ]] && echo 60 || echo 90) $python -m learner train specs/train-demo.toml --fresh --epochs 5 \
        --store "$out/work/demo.zarr" --out "$out/work/train-$device" --device "$device"
    step "evaluate_$device" 20 $python -m learner evaluate "$out/work/train-$device/best.pt" \
        "$out/work/demo.zarr" --out "$out/work/eval-$device" --device "$device"
    cp "$out/work/eval-$device"/*.md "$out/eval_$device.md" 2>/dev/null
done
rm -rf "$out/work"
