"""The build plan: subjects, stimulation sites and tasks, deterministically from a spec.

A subject is one mesh under one tissue setting; a task is one chunk of
``output.chunk_sites`` consecutive sites of one subject, the unit of work and
of storage. :func:`make_plan` loads every mesh once and chooses its sites and
sock electrodes; the result depends on the spec alone (not on the machine,
the thread count or the order of calls). :func:`validate_plan` checks
everything that can fail before anything is written.

Site selection on a mesh (node set ``P`` = ``spec.sites.node_set``):

* ``"farthest"``: farthest-point sampling over the coordinates of ``P``,
  starting at the node of ``P`` closest to the centroid of ``P`` (ties to the
  lowest node id); sites are kept in selection order.
* ``"random"``: ``default_rng((seed, crc32(mesh_id))).choice(P, count,
  replace=False)``, sorted.
* explicit ``nodes``: used as given, on every mesh.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError, MeshError, StimulusError
from shared.fem import element_gradients
from shared.mesh import Mesh
from shared.tissue import TissueFields, TissueSpec
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fibres import ldrb_frames
from simgen.meshes.topology import edge_graph
from simgen.observe.sock import Sock, farthest_point_sampling
from simgen.solver.cells import with_apd_scale
from simgen.solver.simulate import SolverConfig, assemble
from simgen.store.spec import BuildSpec, MeshEntry, SiteSelection
from simgen.tissue.fields import SCAR_BORDERS, tissue_fields

__all__ = ["Subject", "SubjectSetup", "Task", "Plan", "make_plan", "validate_plan", "select_sites", "sock_electrodes"]


@dataclass(frozen=True)
class Subject:
    """One mesh under one tissue setting; ``id = f"{mesh_id}-{tissue.name}"``."""

    id: str
    mesh_id: str
    tissue: TissueSpec


class SubjectSetup(NamedTuple):
    """What checking a subject found: its tissue fields and the solver settings resolved on its mesh."""

    fields: TissueFields
    dt: float
    steps_per_frame: int
    stimulus_radius: float
    integrator: str


@dataclass(frozen=True)
class Task:
    """Sites ``[start, stop)`` of the mesh's site list for one subject: chunk ``chunk`` of its arrays."""

    subject_id: str
    chunk: int
    start: int
    stop: int

    @property
    def key(self) -> str:
        """``"<subject_id>/<chunk>"``: a stable name for schedulers and messages."""
        return f"{self.subject_id}/{self.chunk}"


@dataclass(frozen=True, eq=False)
class Plan:
    """Everything a build does, in a fixed order.

    ``sites[mesh_id]`` (S,) int64 and ``electrodes[mesh_id]`` (sorted, int64,
    empty with ``sock_electrodes = 0``) are node ids
    of ``meshes[mesh_id]``. ``subjects`` run over meshes in spec order, then
    tissue settings in spec order; ``tasks`` over subjects, then chunks.
    """

    spec: BuildSpec
    meshes: dict[str, Mesh]
    sites: dict[str, NDArray[np.int64]]
    electrodes: dict[str, NDArray[np.int64]]
    subjects: list[Subject]
    tasks: list[Task]
    _by_id: dict[str, Subject] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_id", {s.id: s for s in self.subjects})

    def subject(self, subject_id: str) -> Subject:
        """The subject named ``subject_id``."""
        try:
            return self._by_id[subject_id]
        except KeyError:
            raise InputError(f"unknown subject {subject_id!r}; the plan has {list(self._by_id)}") from None

    def n_chunks(self, subject_id: str) -> int:
        """Number of chunks (tasks) of a subject: ``ceil(S / chunk_sites)``."""
        n_sites = len(self.sites[self.subject(subject_id).mesh_id])
        return -(-n_sites // self.spec.output.chunk_sites)


def _node_set(mesh: Mesh, name: str) -> NDArray[np.int64]:
    if name == "all":
        return np.arange(mesh.n_nodes, dtype=np.int64)
    return np.unique(mesh.nodes(name)).astype(np.int64)


def select_sites(mesh: Mesh, selection: SiteSelection, seed: int, mesh_id: str) -> NDArray[np.int64]:
    """Stimulation node ids of ``mesh`` (see the module docstring for the rules).

    Raises :class:`StimulusError` for an explicit node out of range and
    :class:`InputError` when ``count`` exceeds the node set.
    """
    if selection.nodes:
        nodes = np.asarray(selection.nodes, dtype=np.int64)
        bad = nodes[(nodes < 0) | (nodes >= mesh.n_nodes)]
        if bad.size:
            raise StimulusError(
                f"stimulation node {int(bad[0])} is out of range for mesh {mesh_id!r} "
                f"({mesh.n_nodes} nodes, valid ids 0..{mesh.n_nodes - 1})"
            )
        return nodes
    pool = _node_set(mesh, selection.node_set)
    if selection.count > len(pool):
        raise InputError(
            f"mesh {mesh_id!r}: cannot choose {selection.count} sites from node set {selection.node_set!r} "
            f"of {len(pool)} nodes; lower [sites] count or use a finer mesh"
        )
    if selection.method == "random":
        rng = np.random.default_rng((seed, zlib.crc32(mesh_id.encode())))
        return np.sort(rng.choice(pool, selection.count, replace=False)).astype(np.int64)
    pts = mesh.points[pool]
    start = int(np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
    return pool[farthest_point_sampling(pts, selection.count, start)]


def sock_electrodes(mesh: Mesh, n_electrodes: int) -> NDArray[np.int64]:
    """Sock electrode node ids (sorted); empty for ``n_electrodes = 0``.

    Raises :class:`InputError` naming ``[output] sock_electrodes`` when the
    mesh cannot hold them: no epicardium (a mesh that is no heart), or fewer
    epicardial nodes than electrodes.
    """
    if n_electrodes == 0:
        return np.zeros(0, dtype=np.int64)
    if "epicardium" not in mesh.node_sets:
        raise InputError(
            f"[output] sock_electrodes = {n_electrodes}: mesh {mesh.name!r} has no epicardium to place them on "
            "(a mesh that is no heart); set [output] sock_electrodes = 0"
        )
    return Sock(n_electrodes=n_electrodes).indices(mesh).astype(np.int64)


def subject_solver(solver: SolverConfig, tissue: TissueSpec) -> SolverConfig:
    """The solver settings of a subject of ``tissue``: its own ``anisotropy`` and ``apd_scale`` where it sets
    them (the cell model's :meth:`apd_scaled`)."""
    if tissue.anisotropy is not None:
        solver = replace(solver, anisotropy=tissue.anisotropy)
    return replace(solver, model=with_apd_scale(solver.model, tissue.apd_scale))


def entry_mesh(entry: MeshEntry) -> Mesh:
    """The mesh of a ``[[meshes]]`` entry, named by its id, with the fibres and sheets its ``fibres`` rule gives
    (in float32, as the store keeps them) and none without one (a file's own are then left out)."""
    mesh = get_mesh(
        entry.source,
        entry.nodes,
        entry.kind,
        name=entry.id,
        shape_params=entry.shape_params,
        units=entry.units,
        landmarks=entry.axis,
        node_set_arrays=entry.node_set_arrays,
        heart=entry.heart is not False,
        filler=entry.filler,
    )
    rule = entry.fibres
    if rule is None:
        return replace(mesh, fibres=None, sheets=None)
    if rule.rule == "file":
        if mesh.fibres is None:
            raise MeshError(f"mesh {entry.id!r}: fibre rule 'file', but {entry.source} has no point data 'fibre'")
        fibres, sheets = mesh.fibres, mesh.sheets
    else:
        fibres, sheets, _ = ldrb_frames(mesh, rule.helix_endo, rule.helix_epi, rule.sheet_endo, rule.sheet_epi)
    return replace(mesh, fibres=_float32(fibres), sheets=None if sheets is None else _float32(sheets))


def _float32(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vectors as the store keeps them (float32), so that a mesh read back conducts the same."""
    return np.asarray(vectors, np.float32).astype(np.float64)


def make_plan(spec: BuildSpec) -> Plan:
    """The build plan of ``spec``: load meshes, choose sites and electrodes, list subjects and tasks.

    Raises :class:`~shared.errors.MeshError` for an unknown or broken mesh
    source, :class:`StimulusError` / :class:`InputError` for impossible sites.
    """
    meshes: dict[str, Mesh] = {}
    sites: dict[str, NDArray[np.int64]] = {}
    electrodes: dict[str, NDArray[np.int64]] = {}
    for entry in spec.meshes:
        mesh = entry_mesh(entry)
        meshes[entry.id] = mesh
        sites[entry.id] = select_sites(mesh, spec.sites, spec.seed, entry.id)
        electrodes[entry.id] = sock_electrodes(mesh, spec.output.sock_electrodes)

    settings = spec.settings()
    subjects = [Subject(f"{m.id}-{s.name}", m.id, s) for m in spec.meshes for s in settings]
    size = spec.output.chunk_sites
    tasks = [
        Task(subject.id, chunk, start, min(start + size, len(sites[subject.mesh_id])))
        for subject in subjects
        for chunk, start in enumerate(range(0, len(sites[subject.mesh_id]), size))
    ]
    return Plan(spec, meshes, sites, electrodes, subjects, tasks)


def validate_plan(plan: Plan, scar_border: str = SCAR_BORDERS[0]) -> dict[str, SubjectSetup]:
    """Check every subject before anything is written; its tissue fields and solver settings, by subject id.

    ``scar_border``: where border zones are measured from
    (:data:`~simgen.tissue.fields.SCAR_BORDERS`): a new store's default, or the
    rule an existing store recorded (:func:`~simgen.store.metadata.recorded_scar_border`).

    Builds the tissue fields (:class:`~shared.errors.TissueError`) and
    assembles the operator of every subject (largest eigenvalue and time step:
    :class:`~shared.errors.TimeStepError` for an unstable ``dt``), and
    checks that sites and electrodes are node ids of their mesh
    (:class:`StimulusError`). Messages name the subject and mesh.
    """
    for mesh_id, mesh in plan.meshes.items():
        for what, ids in (("stimulation node", plan.sites[mesh_id]), ("electrode", plan.electrodes[mesh_id])):
            bad = ids[(ids < 0) | (ids >= mesh.n_nodes)]
            if bad.size:
                raise StimulusError(f"{what} {int(bad[0])} is out of range for mesh {mesh_id!r} ({mesh.n_nodes} nodes)")
    per_mesh = {}  # what every subject of a mesh shares: element gradients, edge graph
    setups = {}
    solver = plan.spec.solver
    for subject in plan.subjects:
        mesh = plan.meshes[subject.mesh_id]
        if subject.mesh_id not in per_mesh:
            per_mesh[subject.mesh_id] = element_gradients(mesh.points, mesh.cells), edge_graph(mesh)
        geometry, graph = per_mesh[subject.mesh_id]
        try:
            fields = tissue_fields(mesh, subject.tissue, graph=graph, border=scar_border)
            assembly = assemble(mesh, fields, subject_solver(solver, subject.tissue), geometry)
        except InputError as exc:
            raise type(exc)(f"subject {subject.id!r} (mesh {subject.mesh_id!r}): {exc}") from exc
        setups[subject.id] = SubjectSetup(
            fields, assembly.dt, assembly.steps_per_frame, solver.radius, assembly.integrator
        )
    return setups
