"""What ``simgen simulate`` and ``simgen mesh`` write, as functions (docs/formats.md).

:func:`simulate_files` simulates stimulation sites (node ids of the mesh's file, points in mm, region
names) on one mesh and tissue setting and writes into a folder: ``simulation.npz`` (potential in mV,
activation times in ms), ``activation.png``, and with ``observe`` the recordings
``learner personalize`` reads (``observations.npz``; for ``"ecg"`` also ``ecg.npz`` and ``ecg.png``), with
``vtk`` a ParaView time series per site. :func:`write_mesh` writes a mesh file with its node sets, region
labels and (with ``fibres``) rule-based fibres. The command line only parses options and prints what
these return.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from shared.capture import mapped_activation, started_wave
from shared.ecg import ELECTRODES, LEADS, PseudoECG, leads, read_electrodes, standard_electrodes
from shared.errors import InputError
from shared.mesh import Mesh
from shared.observation import node_mask
from shared.observation import observe as observe_field
from shared.sites import SITE_TOLERANCE, nearest_nodes, refuse_repeated, region_nodes, site_names
from shared.tissue import LABEL_HEALTHY
from shared.units import MS_PER_TIME_UNIT, to_millivolts
from shared.vtk import write_time_series
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fibres import HELIX_ENDO, HELIX_EPI, with_rule_fibres
from simgen.meshes.io import save_mesh
from simgen.meshes.regions import site_labels
from simgen.solver.cells import APParams, cell_model
from simgen.solver.integrators import AUTO
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig
from simgen.solver.stimulus import IN_SCAR, RESOLVED_SCAR_EDGE, check_sites, patch_mask, scar_share
from simgen.tissue import named_setting, tissue_fields

__all__ = ["RECORDINGS", "OBSERVE_NODE_SETS", "SimulationFiles", "simulate_files", "write_mesh"]

#: What ``observe`` records: potentials or activation-time maps.
RECORDINGS = ("potential", "activation")
#: Node sets ``observe`` records on (besides ``all``, the sock's ``electrodes`` and ``ecg``).
OBSERVE_NODE_SETS = ("surface", "epicardium", "endocardium")


@dataclass
class SimulationFiles:
    """What :func:`simulate_files` simulated and wrote: the mesh, the sites (the mesh's node ids and the file's),
    the result, how it ran, and notes worth a reader's attention (a site that starts no wave, one paced in a scar
    on a coarse mesh, the ECG's cost)."""

    mesh: Mesh
    sites: NDArray[np.int64]
    file_sites: NDArray[np.int64]
    result: SimulationResult
    run: str  # integrator, step and backend
    out: Path
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """One line: how many simulations of which mesh, how they ran, the latest activation, where written."""
        latest = np.nanmax(self.result.activation) * MS_PER_TIME_UNIT
        return (
            f"{len(self.sites)} simulation(s) on {self.mesh.name} ({self.mesh.n_nodes} nodes), {self.run}, "
            f"latest activation {latest:.0f} ms -> {self.out}"
        )


def simulate_files(
    out: str | Path,
    source: str = "lv",
    nodes: int | None = None,
    kind: str | None = None,
    heart: bool = True,
    units: str | None = None,
    fibres: bool = False,
    helix: tuple[float, float] = (HELIX_ENDO, HELIX_EPI),
    filler: str | None = None,
    anisotropy: float | None = None,
    sheet_anisotropy: float | None = None,
    tissue: str = "healthy",
    sites: Sequence[int] | None = None,
    site_xyz: NDArray[np.float64] | None = None,
    site_region: Sequence[str] | None = None,
    site_tolerance: float = SITE_TOLERANCE,
    threads: int = 2,
    dt: float | None = None,
    integrator: str = AUTO,
    cell: str = APParams.name,
    backend: str = "numba",
    device: str | None = None,
    observe: str | None = None,
    electrodes: str | Path | None = None,
    record: str = "potential",
    noise: float = 0.0,
    seed: int = 0,
    vtk: str | Path | None = None,
) -> SimulationFiles:
    """Simulate and write ``out`` as ``simgen simulate`` does (module docstring; the options are its).

    ``sites``: node ids of the mesh's file (default ``[0]`` when neither ``site_xyz`` (K, 3) mm nor
    ``site_region`` names any). Bad input is an :class:`~shared.errors.InputError`; an unwritable ``out`` an
    :class:`OSError`.
    """
    if record not in RECORDINGS:
        raise InputError(f"--record: {record!r} is not one of {', '.join(RECORDINGS)}")
    out = Path(out)
    m = get_mesh(source, nodes, kind, units=units, heart=heart, filler=filler)  # type: ignore[arg-type]
    if fibres and m.fibres is None:
        m = with_rule_fibres(m, helix)[0]
    site_ids, centres = stimulation_sites(m, sites, site_xyz, site_region, site_tolerance, heart)
    observed = None if observe in (None, "ecg") else observed_nodes(m, observe)
    spec = named_setting(tissue)
    config = SolverConfig(
        dt=dt,
        integrator=integrator,  # type: ignore[arg-type]
        anisotropy=anisotropy,
        sheet_anisotropy=sheet_anisotropy,
        model=cell_model(cell),
    )
    fields = tissue_fields(m, spec)
    started = time.perf_counter()
    sim = Simulator(m, fields, config, backend=backend, device=device)
    result = sim.run(site_ids, threads=threads, centres=centres)
    seconds = time.perf_counter() - started
    notes: list[str] = []
    ecg = None if observe != "ecg" else ecg_arrays(m, fields, config, result, seconds, electrodes, notes)
    act_ms = result.activation * MS_PER_TIME_UNIT
    file_sites, times_ms = m.file_ids(site_ids), result.times * MS_PER_TIME_UNIT
    _write(out, m, spec.name, site_ids, file_sites, centres, result, heart, observed, record, noise, seed, ecg)
    if vtk is not None:
        for site, u, act in zip(file_sites, result.u, act_ms):
            frames = {"V_mV": to_millivolts(u), "u": u}
            write_time_series(vtk, f"site-{int(site)}", m.points, m.cells, times_ms, frames, {"activation_ms": act})
    notes += no_wave_notes(site_ids, result.activated_fraction)
    notes += scar_pacing_notes(m, fields.label, site_ids, centres, sim.stimulus_radius)
    where = sim.backend if sim.device is None else f"{sim.backend} on {sim.device}"
    run = f"{sim.integrator} dt={sim.dt:.4g}, {where}"
    return SimulationFiles(m, site_ids, file_sites, result, run, out, notes)


def _write(
    out: Path,
    m: Mesh,
    tissue: str,
    site_ids: NDArray[np.int64],
    file_sites: NDArray[np.int64],
    centres: NDArray[np.float64],
    result: SimulationResult,
    heart: bool,
    observed: NDArray[np.bool_] | None,
    record: str,
    noise: float,
    seed: int,
    ecg: dict[str, NDArray] | None,
) -> None:
    """The files of :func:`simulate_files` but the ParaView series."""
    from simgen.plot import plot_activation_maps, plot_ecg

    act_ms, times_ms = result.activation * MS_PER_TIME_UNIT, result.times * MS_PER_TIME_UNIT
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        out / "simulation.npz",
        sites=file_sites,
        site_xyz=centres,
        times_ms=times_ms,
        v_mv=to_millivolts(m.to_file(result.u)).astype(np.float32),
        activation_ms=m.to_file(act_ms).astype(np.float32),
        activated_fraction=result.activated_fraction,
    )
    titles = [f"{tissue} site {s}" for s in file_sites]
    plot_activation_maps(m, act_ms, titles, out / "activation.png", stim_nodes=site_ids)
    if observed is not None:
        recording = recording_arrays(result, observed, record, noise, np.random.default_rng(seed))
        write_observations(out, m, result.sites, centres, heart, observed=observed, **recording)
    if ecg is None:
        return
    np.savez_compressed(out / "ecg.npz", sites=file_sites, **ecg)
    if "ecg_mv" in ecg:
        recorded = ecg["ecg_mv"] + np.random.default_rng(seed).normal(0.0, noise, ecg["ecg_mv"].shape)
        keep = ("leads", "ecg_times_ms", "electrodes", "electrode_xyz_mm")
        recording = {"ecg_mv": recorded.astype(np.float32), **{name: ecg[name] for name in keep}}
        write_observations(out, m, result.sites, centres, heart, **recording)
        plot_ecg(times_ms, ecg["ecg_mv"][0], LEADS, out / "ecg.png", f"{m.name}: pseudo-ECG, site {file_sites[0]}")


def write_mesh(
    out: str | Path,
    source: str = "lv",
    nodes: int | None = None,
    kind: str | None = None,
    heart: bool = True,
    units: str | None = None,
    fibres: bool = False,
    helix: tuple[float, float] = (HELIX_ENDO, HELIX_EPI),
    filler: str | None = None,
) -> Mesh:
    """Write the mesh ``source`` (at ``nodes``, ``kind``) to the file ``out`` as ``simgen mesh`` does: its node sets
    and, for a heart, its region labels as point data; with ``fibres`` its rule-based fibres, the ventricular
    coordinates they come from and a picture of them (``out`` with suffix ``.fibres.png``)."""
    out = Path(out)
    m = get_mesh(source, nodes, kind, units=units, heart=heart, filler=filler)  # type: ignore[arg-type]
    m, coordinates = with_rule_fibres(m, helix) if fibres else (m, {})
    out.parent.mkdir(parents=True, exist_ok=True)
    save_mesh(m, out, {**(site_labels(m).arrays() if heart else {}), **coordinates})
    if fibres:
        from simgen.plot import plot_fibres

        plot_fibres(m, out.with_suffix(".fibres.png"), f"{m.name}: fibres on the epicardium")
    return m


def stimulation_sites(
    m: Mesh,
    ids: Sequence[int] | None,
    xyz: NDArray[np.float64] | None,
    regions: Sequence[str] | None,
    tolerance: float,
    heart: bool,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The stimulation nodes of ``m`` and the points their stimuli are centred on, from node ids of the mesh's
    file, points (each itself) and region names (:mod:`shared.sites`); a node named twice is refused."""
    if ids is None and xyz is None and regions is None:
        ids = [0]  # no site named: node 0
    nodes, centres = [], []
    file_ids = np.asarray([] if ids is None else ids, np.int64)
    if ids is not None:
        given = check_sites(m, m.from_file(file_ids))
        nodes.append(given)
        centres.append(m.points[given])
    if xyz is not None:
        nodes.append(nearest_nodes(m.points, xyz, tolerance))
        centres.append(np.asarray(xyz, np.float64))
    if regions is not None:
        named = region_nodes(site_labels(m) if heart else None, m.points, regions)
        nodes.append(named)
        centres.append(m.points[named])
    sites = np.concatenate(nodes)
    refuse_repeated(sites, site_names(file_ids, xyz, regions or []))
    return sites, np.concatenate(centres)


def observed_nodes(m: Mesh, observe: str) -> NDArray[np.bool_]:
    """(N,) bool: the nodes of ``observe`` on mesh ``m`` (:data:`OBSERVE_NODE_SETS`, ``electrodes``, ``all``)."""
    from simgen.observe import Sock

    if observe == "all":
        return np.ones(m.n_nodes, dtype=bool)
    if observe == "electrodes":
        ids = Sock().indices(m)
    elif observe in OBSERVE_NODE_SETS:
        ids = m.nodes(observe)
    else:
        raise InputError(
            f"--observe: unknown node set {observe!r}; use {', '.join(OBSERVE_NODE_SETS)}, electrodes or all"
        )
    return node_mask(m.n_nodes, ids, observe, m.name)


def ecg_arrays(
    m: Mesh, fields, config: SolverConfig, result, seconds: float, file: str | Path | None, notes: list[str]
) -> dict[str, NDArray]:
    """The arrays of ``ecg.npz`` (docs/formats.md): the electrodes' potentials and, where they make them, the
    12 leads of every site's simulation, in mV against ms; the ECG's cost against the simulation's goes to
    ``notes``."""
    started = time.perf_counter()
    electrodes = standard_electrodes(m) if file is None else read_electrodes(file)
    operator = PseudoECG.assemble(m, electrodes, fields.D, config.anisotropy, config.sheet_anisotropy)
    assembled = time.perf_counter()
    potentials = operator.potentials(result.u)
    twelve = set(ELECTRODES) <= set(electrodes.names)
    ecg = {"ecg_mv": leads(potentials, electrodes).astype(np.float32), "leads": np.array(LEADS)} if twelve else {}
    done = time.perf_counter()
    notes.append(
        f"pseudo-ECG: operator {assembled - started:.2f} s, {len(result.u)} ECG(s) {1e3 * (done - assembled):.1f} ms "
        f"(the simulation: {seconds:.2f} s)"
    )
    return {
        **ecg,
        "potentials_mv": potentials.astype(np.float32),
        "ecg_times_ms": result.times * MS_PER_TIME_UNIT,
        "electrodes": np.array(electrodes.names),
        "electrode_xyz_mm": electrodes.positions,
    }


def recording_arrays(result, observed: NDArray[np.bool_], record: str, noise: float, rng: np.random.Generator) -> dict:
    """The recording arrays of an observation file (docs/formats.md): ``obs_mv`` and ``times_ms``, or
    ``activation_ms`` as a mapping system records it (:func:`shared.capture.mapped_activation`), NaN unobserved."""
    if record == "potential":
        mv = np.where(observed, to_millivolts(observe_field(result.u, observed, noise / 100.0, rng)), np.nan)
        return {"obs_mv": mv.astype(np.float32), "times_ms": result.times * MS_PER_TIME_UNIT}
    mapped = mapped_activation(result.activation * MS_PER_TIME_UNIT, result.u.max(axis=1), noise, rng)
    return {"activation_ms": np.where(observed, mapped, np.nan).astype(np.float32)}


def write_observations(out: Path, m: Mesh, sites: NDArray, centres: NDArray, heart: bool, **recording: NDArray) -> None:
    """``observations.npz`` (docs/formats.md): the mesh, the sites, its region labels (of a heart) and the
    recording arrays."""
    labels = site_labels(m).arrays() if heart else {}
    np.savez_compressed(
        out / "observations.npz", points=m.points, cells=m.cells, sites=sites, site_xyz=centres, **recording, **labels
    )


def no_wave_notes(sites: NDArray, fraction: NDArray) -> list[str]:
    """One line per site whose stimulus started no propagating wave (:mod:`shared.capture`)."""
    return [
        f"site {int(site)} starts no propagating wave: {100 * share:.1f}% of the nodes activate (its stimulus "
        "patch): the site lies in or against a scar core"
        for site, share in zip(sites, fraction)
        if not started_wave(share)
    ]


def scar_pacing_notes(m: Mesh, label: NDArray, sites: NDArray, centres: NDArray, radius: float) -> list[str]:
    """One line per site paced in a scar (:data:`~simgen.solver.stimulus.IN_SCAR`) on a mesh too coarse for a wave
    leaving a scar to converge (mean edge over :data:`~simgen.solver.stimulus.RESOLVED_SCAR_EDGE`)."""
    if not (label != LABEL_HEALTHY).any() or (edge := m.mean_edge_length()) <= RESOLVED_SCAR_EDGE:
        return []
    shares = scar_share(m, label, patch_mask(m, sites, radius, centres=centres))
    return [
        f"site {int(site)} is paced in a scar: {100 * share:.0f}% of its stimulus patch lies in scar core or border "
        f"zone; on this mesh's {edge:.1f} mm edges whether and when its wave leaves the scar depends on the "
        f"resolution (it converges at mean edges of {RESOLVED_SCAR_EDGE:g} mm and less: docs/method.md, "
        "'Convergence under mesh refinement')"
        for site, share in zip(m.file_ids(sites), shares)
        if share >= IN_SCAR
    ]
