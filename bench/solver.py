"""Benchmark: naive one-site-at-a-time NumPy loop vs the batched fused solver, numba and torch backends.

All integrate the same Aliev-Panfilov monodomain model with explicit Euler on
the same mesh, time step, stimulus and output frames:

* ``naive``   - float64, scipy CSR matvec + NumPy reaction update, one site
  after the other (written out below; it is the baseline, not project code);
* ``batched`` - ``Simulator(mesh).run(sites, threads=T)``: float32, RCM-ordered,
  fused numba kernel over an N x S state, for T = 1 and 2;
* ``torch``   - ``--backend torch``: ``Simulator(mesh, backend="torch", device=D)``,
  the same steps as a torch CSR product and an elementwise step over the
  N x S state (``--compile``: through torch.compile), on the CPU for each T or
  once on CUDA.

With ``--integrator euler rkc`` each mesh is also integrated with the RKC2
integrator (``SolverConfig(integrator="rkc")``: the accuracy step with the
stages the mesh's stiffness needs; the naive loop is Euler only), and the
table gives each integrator's dt and stages, and the RKC run's wall time
and largest differences from Euler's (u, activation times in time units).
``--real NAME`` benches shipped real meshes (``real:tof-biv``) instead of LVs.

The ratio it exists to show is the speed-up per simulation of the batched
solver over the naive loop, measured in the same run, and with ``--backend
numba torch`` torch's over the fastest numba run. Also printed: ns per
node-step, the effective state bandwidth (24 B per node-site-step: u and v
read, u_new and v written, float32) to compare with what the 2-core VMs stream
from DRAM (~27 GB/s one thread, ~53 GB/s two), max |u_naive - u_batched|, and
for torch the bytes a step moves at least (:func:`torch_step_bytes`) per second,
on CUDA as a share of the GPU's peak memory bandwidth (:func:`peak_bandwidth`),
and its largest differences from numba (u, activation times in steps).

Run: ``.venv/bin/python -m bench.solver [--quick] [--out DIR]`` (DIR gets solver.md and solver.json);
``--backend numba torch --device cuda --nodes 2000 10000 50000 --naive-sites 0`` on a GPU machine;
``--integrator euler rkc --real real:tof-biv --nodes 1000 --batch 8 --threads 1 --naive-sites 0``.
``--publish [SECTION]`` writes the tables into the block SECTION of docs/results.md with the command
and the machine: by default ``solver`` (the batched solver against the naive loop), or
``solver.torch-cpu`` (torch against numba on the CPU) when ``--backend`` includes torch.
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np
import scipy.sparse as sp

from bench.common import (
    add_out_argument,
    add_publish_argument,
    best_of,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from shared.fem import diffusion_operator
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.heart import load_heart
from simgen.solver.integrators import INTEGRATORS
from simgen.solver.simulate import BLOCK_SIZE, SimulationResult, Simulator, SolverConfig
from simgen.solver.stimulus import patch_mask

MESHES = [(2000, "tetra"), (2000, "triangle"), (10000, "tetra")]
STATE_BYTES = 24  # u, v read + u_new, v written per node-site-step (float32)
#: Peak memory bandwidth (bytes/s) by a part of torch.cuda.get_device_name(); others are measured.
PEAK_BANDWIDTH = {"H200": 4.8e12, "H100 80GB HBM3": 3.35e12, "A100-SXM4-80GB": 2.04e12}


def torch_step_bytes(n: int, nnz: int, sites: int) -> int:
    """Bytes one torch step moves at least: the CSR operator (float32 values, int32 column indices and
    row pointers, diagonal included), u read by the product and its result written, then the fused
    step reading u, v, the product, the activation times and a, and writing u, v and activation."""
    return 8 * nnz + 4 * (n + 1) + 4 * n + 4 * 9 * n * sites


def peak_bandwidth(device: str) -> tuple[float, str]:
    """``(bytes/s, source)`` of a CUDA device: :data:`PEAK_BANDWIDTH`, else a timed 1 GiB device copy."""
    import torch

    name = torch.cuda.get_device_name(device)
    for key, value in PEAK_BANDWIDTH.items():
        if key in name:
            return value, f"{name}: {value / 1e12:g} TB/s (datasheet)"
    x = torch.empty(2**28, dtype=torch.float32, device=device)
    y = torch.empty_like(x)
    y.copy_(x)
    torch.cuda.synchronize(device)
    t0 = time.perf_counter()
    for _ in range(10):
        y.copy_(x)
    torch.cuda.synchronize(device)
    value = 10 * 2 * x.nbytes / (time.perf_counter() - t0)
    return value, f"{name}: {value / 1e12:.2f} TB/s (measured device copy)"


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
    mesh: Mesh, label: str, integrator: str, args: argparse.Namespace
) -> tuple[dict, dict[str, SimulationResult]]:
    """Time the naive loop (Euler only) and each backend of the batched solver with ``integrator`` on one
    mesh; return raw numbers and the results by backend."""
    config = SolverConfig(integrator=integrator)
    t0 = time.perf_counter()
    sim = Simulator(mesh, config=config)
    setup_s = time.perf_counter() - t0
    n = mesh.n_nodes
    steps = sim.config.frames * sim.steps_per_frame
    applications = steps * sim.stages  # products with the operator: ns per node-step counts these
    n_batch, n_naive = args.batch, args.naive_sites if integrator == "euler" else 0
    sites = np.random.default_rng(0).choice(n, size=max(n_batch, args.naive_sites), replace=False)
    row = {
        "mesh": label,
        "nodes": n,
        "nnz_per_row": len(sim._data) / n + 1,
        "integrator": integrator,
        "dt": sim.dt,
        "stages": sim.stages,
        "steps": steps,
        "setup_s": setup_s,
        "variants": [],
    }

    def record(name: str, n_sites: int, wall: float) -> dict:
        ns = wall / (applications * n * n_sites) * 1e9
        entry = {
            "variant": name,
            "sites": n_sites,
            "wall_s": wall,
            "sims_per_s": n_sites / wall,
            "ns_per_node_step": ns,
            "state_GB_per_s": STATE_BYTES / ns if integrator == "euler" else None,  # 24 B: an Euler step's
        }
        row["variants"].append(entry)
        return entry

    def best_run(simulator: Simulator, threads: int) -> tuple[float, object]:  # best of `repeat`, as the naive loop
        return best_of(lambda: simulator.run(sites[:n_batch], threads=threads, block_size=args.block_size), args.repeat)

    naive_u, naive_s = [], []
    if n_naive:
        A = diffusion_operator(mesh, sim.config.diffusivity * np.asarray(sim.tissue.D, float))
        for s in sites[:n_naive]:  # the fastest site stands for the loop: the least disturbed by other load
            t0 = time.perf_counter()
            naive_u.append(naive_run(sim, A, s))
            naive_s.append(time.perf_counter() - t0)
        base = record("naive numpy f64 (best site)", 1, min(naive_s))
        base["state_GB_per_s"] = None  # float64 + temporaries: the 24 B model does not apply

    results = {}
    if "numba" in args.backend:
        sim.run(sites[:2], threads=max(args.threads))  # JIT compile (or load the cache) and warm up
        for t in args.threads:
            wall, results["numba"] = best_run(sim, t)
            record(f"batched f32, {t} thread{'s' * (t > 1)}", n_batch, wall)
    if "torch" in args.backend:
        bench_torch(mesh, config, args, row, record, best_run, results)
    if "numba" in results and "torch" in results:
        a, b = results["numba"], results["torch"]
        row["torch_vs_numba"] = {
            "max_abs_du": float(np.abs(a.u - b.u).max()),
            "max_activation_steps": float(np.nanmax(np.abs(a.activation - b.activation)) / sim.dt),
            "same_never_activated": bool(np.array_equal(np.isnan(a.activation), np.isnan(b.activation))),
        }
    numba_ns = [v["ns_per_node_step"] for v in row["variants"] if v["variant"].startswith("batched")]
    for entry in row["variants"]:
        entry["speedup"] = row["variants"][0]["ns_per_node_step"] / entry["ns_per_node_step"] if n_naive else None
        entry["vs_numba"] = min(numba_ns) / entry["ns_per_node_step"] if numba_ns else None
    last = results.get("numba", results.get("torch"))
    row["max_abs_du"] = float(np.abs(last.u[:n_naive] - np.stack(naive_u)).max()) if n_naive else None
    return row, results


def compare_integrators(euler: tuple[dict, dict], rkc: tuple[dict, dict]) -> dict:
    """The RKC row's differences from the Euler row of the same mesh (same backend, same sites) and
    its speed-up in wall time (fastest variant of each)."""
    (e_row, e_results), (r_row, r_results) = euler, rkc
    backend = "numba" if "numba" in e_results else "torch"
    a, b = e_results[backend], r_results[backend]
    diff = np.abs(a.activation - b.activation)
    return {
        "backend": backend,
        "max_abs_du": float(np.abs(a.u - b.u).max()),
        "max_activation_diff": float(np.nanmax(diff)),
        "p99_activation_diff": float(np.nanpercentile(diff, 99)),
        "same_never_activated": bool(np.array_equal(np.isnan(a.activation), np.isnan(b.activation))),
        "speedup": fastest(e_row) / fastest(r_row),
    }


def fastest(row: dict) -> float:
    """Wall time (s) of the fastest batched variant of a row (the naive loop excluded)."""
    return min(v["wall_s"] for v in row["variants"] if not v["variant"].startswith("naive"))


def bench_torch(
    mesh, config: SolverConfig, args: argparse.Namespace, row: dict, record, best_run, results: dict
) -> None:
    """The torch backend's variants on ``args.device``: each thread count on the CPU, one run on CUDA."""
    compile_ = {"auto": None, "on": True, "off": False}[args.compile]
    sim = Simulator(mesh, config=config, backend="torch", device=args.device, compile=compile_)
    t0 = time.perf_counter()
    sim.run(np.arange(2), threads=max(args.threads))  # torch.compile (where chosen) and warm-up
    row["torch_first_run_s"] = time.perf_counter() - t0
    kernel = sim._torch
    how = "compiled" if kernel.compiled else "eager"
    on_cuda = kernel.device.type == "cuda"
    for t in [1] if on_cuda else args.threads:
        wall, results["torch"] = best_run(sim, t)
        name = f"torch f32 {kernel.device}, {how}" + ("" if on_cuda else f", {t} thread{'s' * (t > 1)}")
        entry = record(name, args.batch, wall)
        if row["integrator"] != "euler":  # the byte count is an Euler step's
            continue
        step_s = wall / row["steps"]
        entry["moved_GB_per_s"] = torch_step_bytes(mesh.n_nodes, kernel.nnz, args.batch) / step_s / 1e9
        if on_cuda:
            peak, source = peak_bandwidth(str(kernel.device))
            entry["peak_share"] = entry["moved_GB_per_s"] * 1e9 / peak
            row["peak_bandwidth"] = source


def markdown(rows: list[dict]) -> str:
    """Markdown tables: mesh settings, timings with the speed-ups, and torch's differences from numba."""
    out = [
        "| mesh | nodes | nnz/row | integrator | dt | steps | stages | Simulator setup (s) "
        "| max abs(u_naive - u_batched) |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        du = "-" if r["max_abs_du"] is None else f"{r['max_abs_du']:.1e}"
        out.append(
            f"| {r['mesh']} | {r['nodes']} | {r['nnz_per_row']:.1f} | {r['integrator']} | {r['dt']:.4g} "
            f"| {r['steps']} | {r['stages']} | {r['setup_s']:.2f} | {du} |"
        )
    out += [
        "",
        "ns/node-step: per node, site and product with the operator (a step of Euler, a stage of RKC).",
        "",
        "| mesh | integrator | variant | sites | wall (s) | sims/s | ns/node-step | state GB/s | torch bytes GB/s "
        "| share of peak | speed-up vs naive | vs fastest numba |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def cell(value, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    for r in rows:
        for v in r["variants"]:
            out.append(
                f"| {r['mesh']} | {r['integrator']} | {v['variant']} | {v['sites']} | {v['wall_s']:.2f} "
                f"| {v['sims_per_s']:.1f} "
                f"| {v['ns_per_node_step']:.3f} | {cell(v['state_GB_per_s'], '.0f')} "
                f"| {cell(v.get('moved_GB_per_s'), '.1f')} | {cell(v.get('peak_share'), '.1%')} "
                f"| {cell(v['speedup'], '.1f')} | {cell(v['vs_numba'], '.2f')} |"
            )
    compared = [r for r in rows if "torch_vs_numba" in r]
    if compared:
        out += [
            "",
            "| mesh | integrator | torch first run (s) | max abs(u_torch - u_numba) "
            "| max activation difference (steps) | same never-activated nodes |",
            "|---|---|---:|---:|---:|---|",
        ]
        for r in compared:
            d = r["torch_vs_numba"]
            out.append(
                f"| {r['mesh']} | {r['integrator']} | {r['torch_first_run_s']:.1f} | {d['max_abs_du']:.1e} "
                f"| {d['max_activation_steps']:.1e} | {d['same_never_activated']} |"
            )
    compared = [r for r in rows if "vs_euler" in r]
    if compared:
        out += [
            "",
            "| mesh | dt Euler / RKC | RKC stages | wall Euler / RKC (s) | RKC speed-up | max abs(u_rkc - u_euler) "
            "| activation difference max / p99 (time units) | same never-activated nodes |",
            "|---|---:|---:|---:|---:|---:|---:|---|",
        ]
        euler = {r["mesh"]: r for r in rows if r["integrator"] == "euler"}
        for r in compared:
            d, e = r["vs_euler"], euler[r["mesh"]]
            out.append(
                f"| {r['mesh']} | {e['dt']:.3g} / {r['dt']:.3g} | {r['stages']} | {fastest(e):.2f} / {fastest(r):.2f} "
                f"| {d['speedup']:.1f} | {d['max_abs_du']:.2g} | {d['max_activation_diff']:.2g} / "
                f"{d['p99_activation_diff']:.2g} | {d['same_never_activated']} |"
            )
    if any("peak_bandwidth" in r for r in rows):
        out += ["", f"Peak bandwidth: {next(r['peak_bandwidth'] for r in rows if 'peak_bandwidth' in r)}"]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="only the 2k-node meshes")
    p.add_argument("--naive-sites", type=int, default=3, help="sites for the naive loop (default 3)")
    p.add_argument("--batch", type=int, default=200, help="sites for the batched solver (default 200, one subject)")
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="thread counts (default 1 2)")
    p.add_argument("--repeat", type=int, default=2, help="timed runs of the batched solver; best kept (default 2)")
    p.add_argument("--block-size", type=int, default=BLOCK_SIZE, help=f"sites per block (default {BLOCK_SIZE})")
    p.add_argument(
        "--backend", nargs="+", choices=["numba", "torch"], default=["numba"], help="solver backends (default numba)"
    )
    p.add_argument("--device", default="cpu", help="torch device of the torch backend: cpu, cuda, cuda:N")
    p.add_argument(
        "--compile", choices=["auto", "on", "off"], default="auto", help="torch.compile the torch step (auto: CUDA)"
    )
    p.add_argument(
        "--integrator", nargs="+", choices=INTEGRATORS, default=["euler"], help="time integrators (default euler)"
    )
    p.add_argument("--nodes", type=int, nargs="+", help="tetra LV sizes instead of the default meshes")
    p.add_argument(
        "--real", nargs="+", metavar="NAME", help="shipped real meshes (real:tof-biv) at each --nodes size (1000)"
    )
    add_out_argument(p, "solver")
    add_publish_argument(p, "solver")
    args = p.parse_args(argv)
    if args.publish == "solver" and "torch" in args.backend:
        args.publish = "solver.torch-cpu"  # the block of torch runs
    check_publish(args.publish)

    if args.real:
        meshes = [(n, "tetra", name) for name in args.real for n in args.nodes or [1000]]
    else:
        meshes = [(n, "tetra", "lv") for n in args.nodes] if args.nodes else [(n, k, "lv") for n, k in MESHES]
    meshes = [m for m in meshes if m[0] <= 2000] if args.quick else meshes
    load_before = os.getloadavg()[0]
    t_start = time.perf_counter()
    rows = []
    for n, kind, source in meshes:
        if source == "lv":
            mesh, label = lv_ellipsoid(n, kind), f"lv_ellipsoid({n}, {kind!r})"
        else:
            mesh, label = load_heart(source, n, kind), f"{source} ({n}, {kind!r})"
        runs = {integrator: bench_mesh(mesh, label, integrator, args) for integrator in args.integrator}
        if "euler" in runs and "rkc" in runs:
            runs["rkc"][0]["vs_euler"] = compare_integrators(runs["euler"], runs["rkc"])
        rows += [row for row, _ in runs.values()]
    total = time.perf_counter() - t_start
    torch_note = ""
    if "torch" in args.backend:
        import torch

        torch_note = f" (torch {torch.__version__} on {args.device}, compile {args.compile})"
    header = (
        f"Solver bench: {machine_line()}, numba {numba.__version__} "
        f"({numba.config.NUMBA_NUM_THREADS} threads), block size {args.block_size}; backends "
        f"{' '.join(args.backend)}{torch_note}; integrators {' '.join(args.integrator)}; total {total:.0f} s; "
        f"1-min load average before the run {load_before:.1f}\n"
    )
    if load_before > 0.5:  # our own threads are not running yet, so this is someone else's work
        header += "WARNING: other processes may have been using the CPUs; timings (2 threads above all) may be slow.\n"
    table = header + "\n" + markdown(rows) + "\n"
    print(table)
    publish_out(args.publish, "solver", table)
    if args.out:
        meta = {
            **machine(),
            "numba": numba.__version__,
            "block_size": args.block_size,
            "backends": args.backend,
            "integrators": args.integrator,
            "device": args.device,
            "compile": args.compile,
            "total_s": total,
            "load_average_before": load_before,
            "meshes": rows,
        }
        write_out(args.out, "solver", table, meta, indent=2)


if __name__ == "__main__":
    main()
