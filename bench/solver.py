"""Benchmark: naive one-site-at-a-time NumPy loop vs the batched fused solver.

Both integrate the same Aliev-Panfilov monodomain model with explicit Euler on
the same mesh, time step, stimulus and output frames:

* ``naive``   - float64, scipy CSR matvec + NumPy reaction update, one site
  after the other (written out below; it is the baseline, not project code);
* ``batched`` - ``Simulator(mesh).run(sites, threads=T)``: float32, RCM-ordered,
  fused numba kernel over an N x S state, for T = 1 and 2.

The ratio it exists to show is the speed-up per simulation of the batched
solver over the naive loop, measured in the same run. Also printed: ns per
node-step, the effective state bandwidth (24 B per node-site-step: u and v
read, u_new and v written, float32) to compare with what the 2-core VMs stream
from DRAM (~27 GB/s one thread, ~53 GB/s two), and max |u_naive - u_batched|.

Run: ``.venv/bin/python bench/solver.py [--quick] [--out DIR]`` (DIR gets solver.md and solver.json).
The table is published in docs/performance.md ("Solver speed") with its machine and command.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numba
import numpy as np
import scipy.sparse as sp

from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.solver.fem import diffusion_operator
from simgen.solver.simulate import BLOCK_SIZE, Simulator
from simgen.solver.stimulus import patch_mask

MESHES = [(2000, "tetra"), (2000, "triangle"), (10000, "tetra")]
STATE_BYTES = 24  # u, v read + u_new, v written per node-site-step (float32)


def naive_run(sim: Simulator, A: sp.csr_matrix, site: int) -> np.ndarray:
    """One site, float64, scipy CSR ``A`` + NumPy: returns the (frames, N) u snapshots."""
    cfg, m, mesh = sim.config, sim.config.model, sim.mesh
    a = np.asarray(sim.tissue.a, float)
    dt, k = sim.dt, m.k
    mask = patch_mask(mesh, np.array([site]), sim.stimulus_radius)[:, 0]
    stim_steps = int(round(cfg.stimulus_duration / dt))
    u = mask.astype(float)
    v = np.zeros_like(u)
    frames = np.empty((cfg.frames, mesh.n_nodes))
    for step in range(cfg.frames * sim.steps_per_frame):
        eps = m.eps0 + m.mu1 * v / (u + m.mu2) if m.variant == "standard" else m.eps_simple
        u_new = u + dt * (A @ u + k * u * (1 - u) * (u - a) - u * v)
        v += dt * eps * (-v - k * u * (u - a - 1))
        if step < stim_steps:
            u_new[mask] = 1.0
        u = u_new
        if (step + 1) % sim.steps_per_frame == 0:
            frames[(step + 1) // sim.steps_per_frame - 1] = u
    return frames


def bench_mesh(
    n_nodes: int, kind: str, n_naive: int, n_batch: int, threads: list[int], block: int, repeat: int
) -> dict:
    """Time the naive loop and the batched solver on one mesh; return raw numbers."""
    mesh = lv_ellipsoid(n_nodes, kind)
    t0 = time.perf_counter()
    sim = Simulator(mesh)
    setup_s = time.perf_counter() - t0
    n = mesh.n_nodes
    steps = sim.config.frames * sim.steps_per_frame
    sites = np.random.default_rng(0).choice(n, size=max(n_batch, n_naive), replace=False)
    row = {
        "mesh": f"lv_ellipsoid({n_nodes}, {kind!r})",
        "nodes": n,
        "nnz_per_row": len(sim._data) / n + 1,
        "dt": sim.dt,
        "steps": steps,
        "setup_s": setup_s,
        "variants": [],
    }

    def record(name: str, n_sites: int, wall: float) -> dict:
        ns = wall / (steps * n * n_sites) * 1e9
        entry = {
            "variant": name,
            "sites": n_sites,
            "wall_s": wall,
            "sims_per_s": n_sites / wall,
            "ns_per_node_step": ns,
            "state_GB_per_s": STATE_BYTES / ns,
        }
        row["variants"].append(entry)
        return entry

    A = diffusion_operator(mesh, sim.config.diffusivity * np.asarray(sim.tissue.D, float))
    naive_u, naive_s = [], []
    for s in sites[:n_naive]:  # the fastest site stands for the loop: the least disturbed by other load
        t0 = time.perf_counter()
        naive_u.append(naive_run(sim, A, s))
        naive_s.append(time.perf_counter() - t0)
    naive_u = np.stack(naive_u)
    base = record("naive numpy f64 (best site)", 1, min(naive_s))
    base["state_GB_per_s"] = None  # float64 + temporaries: the 24 B model does not apply

    sim.run(sites[:2], threads=max(threads))  # JIT compile (or load the cache) and warm up
    max_diff = 0.0
    for t in threads:
        walls = []
        for _ in range(repeat):  # best of `repeat` runs, as for the naive loop
            t0 = time.perf_counter()
            res = sim.run(sites[:n_batch], threads=t, block_size=block)
            walls.append(time.perf_counter() - t0)
        record(f"batched f32, {t} thread{'s' * (t > 1)}", n_batch, min(walls))
        max_diff = max(max_diff, float(np.abs(res.u[:n_naive] - naive_u).max()))
    for entry in row["variants"]:
        entry["speedup"] = base["ns_per_node_step"] / entry["ns_per_node_step"]
    row["max_abs_du"] = max_diff
    return row


def markdown(rows: list[dict]) -> str:
    """Two Markdown tables: mesh settings, then timings with the speed-up over naive."""
    out = [
        "| mesh | nodes | nnz/row | dt | steps | Simulator setup (s) | max abs(u_naive - u_batched) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        out.append(
            f"| {r['mesh']} | {r['nodes']} | {r['nnz_per_row']:.1f} | {r['dt']:.4g} | {r['steps']} "
            f"| {r['setup_s']:.2f} | {r['max_abs_du']:.1e} |"
        )
    out += [
        "",
        "| mesh | variant | sites | wall (s) | sims/s | ns/node-step | state GB/s | speed-up vs naive |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        for v in r["variants"]:
            gbs = "-" if v["state_GB_per_s"] is None else f"{v['state_GB_per_s']:.0f}"
            out.append(
                f"| {r['mesh']} | {v['variant']} | {v['sites']} | {v['wall_s']:.2f} | {v['sims_per_s']:.1f} "
                f"| {v['ns_per_node_step']:.3f} | {gbs} | {v['speedup']:.1f}x |"
            )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="only the 2k-node meshes")
    p.add_argument("--naive-sites", type=int, default=3, help="sites for the naive loop (default 3)")
    p.add_argument("--batch", type=int, default=200, help="sites for the batched solver (default 200, one subject)")
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="thread counts (default 1 2)")
    p.add_argument("--repeat", type=int, default=2, help="timed runs of the batched solver; best kept (default 2)")
    p.add_argument("--block-size", type=int, default=BLOCK_SIZE, help=f"sites per block (default {BLOCK_SIZE})")
    p.add_argument("--out", type=Path, help="folder for solver.md (the table) and solver.json (raw numbers)")
    args = p.parse_args(argv)

    meshes = [m for m in MESHES if m[0] <= 2000] if args.quick else MESHES
    load_before = os.getloadavg()[0]
    t_start = time.perf_counter()
    rows = [
        bench_mesh(n, kind, args.naive_sites, args.batch, args.threads, args.block_size, args.repeat)
        for n, kind in meshes
    ]
    total = time.perf_counter() - t_start
    header = (
        f"Solver bench: {platform.machine()}, {os.cpu_count()} CPUs, numba {numba.__version__} "
        f"({numba.config.NUMBA_NUM_THREADS} threads), block size {args.block_size}; total {total:.0f} s; "
        f"1-min load average before the run {load_before:.1f}\n"
    )
    if load_before > 0.5:  # our own threads are not running yet, so this is someone else's work
        header += "WARNING: other processes may have been using the CPUs; timings (2 threads above all) may be slow.\n"
    table = header + "\n" + markdown(rows) + "\n"
    print(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "solver.md").write_text(table)
        meta = {
            "machine": platform.machine(),
            "cpus": os.cpu_count(),
            "numba": numba.__version__,
            "block_size": args.block_size,
            "total_s": total,
            "load_average_before": load_before,
            "meshes": rows,
        }
        (args.out / "solver.json").write_text(json.dumps(meta, indent=2))


if __name__ == "__main__":
    main()
