"""The build spec: what a dataset contains, read strictly from a TOML file.

A :class:`BuildSpec` names the meshes, the tissue settings simulated on every
mesh, how stimulation sites are chosen, the solver settings and the output
layout. It is pure data: :func:`spec_to_dict` and :func:`spec_from_mapping`
round-trip it through JSON/TOML, and :func:`spec_hash` fingerprints it so that
a store can refuse a different spec. Everything that can be checked without a
mesh is checked here; the rest (mesh files, scars on a mesh, the time step)
is checked by :func:`simgen.store.manifest.validate_plan`.

Example (TOML)::

    name = "demo"
    seed = 0
    tissue = ["healthy", "scar-apex"]

    [[meshes]]
    id = "lv"
    source = "lv"  # or "biv", "real:tof-biv" (docs/anatomies.md), or a mesh file (relative to the spec file)
    nodes = 1000

    [[meshes]]  # 12 random BiV anatomies, ids "biv-000" .. "biv-011"
    id = "biv"
    source = "biv"
    shape = "random"  # or "default" (shape_params, if any, override the defaults)
    count = 12
    seed = 3
    [meshes.shape_params]
    wall_thickness = 9.0  # fixed; the others are drawn (docs/anatomies.md)
    [meshes.shape_ranges]
    rv_width = [24.0, 36.0]  # drawn from this interval instead of the default one

    [tissue_prior]  # 8 more settings "draw-000" .. "draw-007", drawn (docs/dataset.md, Tissue prior)
    count = 8
    cv = [0.4, 1.2]  # m/s; or D = [0.3, 3.0], a diffusivity scale
    scars = [0, 2]

    [sites]
    count = 20

    [solver]
    frames = 55
    # backend = "torch"  # or "auto"; unset: numba, and out of the hash (docs/solver-backends.md)

    [output]
    chunk_sites = 10
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import ConfigError, InputError, StimulusError
from shared.mesh import NODE_SETS, OPTIONAL_NODE_SETS
from shared.tissue import TissueSpec
from simgen.meshes.anatomy import sample_shapes
from simgen.meshes.catalog import GENERATORS
from simgen.meshes.fibres import HELIX_ENDO, HELIX_EPI, SHEET_ENDO, SHEET_EPI
from simgen.meshes.fillers import FILLERS
from simgen.meshes.heart import LANDMARKS
from simgen.meshes.shapes import shape_from_params
from simgen.meshes.shipped import is_real, real_mesh_file
from simgen.meshes.units import MM_PER_UNIT
from simgen.solver.simulate import SolverConfig
from simgen.tissue.defaults import default_settings
from simgen.tissue.prior import TissuePrior, draw_tissues

__all__ = [
    "MeshEntry",
    "SiteSelection",
    "OutputSpec",
    "BuildSpec",
    "SITE_NODE_SETS",
    "COMPRESSION_LEVELS",
    "load_spec",
    "spec_from_mapping",
    "spec_to_dict",
    "spec_hash",
    "recorded_hashes",
]

#: Identifiers that become store group names (mesh ids, setting names, subject ids).
_ID = re.compile(r"[A-Za-z0-9_-]+")

#: Node sets stimulation sites may be chosen from (``"all"`` = every node).
SITE_NODE_SETS = ("all", *NODE_SETS, *OPTIONAL_NODE_SETS)

#: Most anatomies one ``shape = "random"`` mesh table may stand for (ids ``<id>-000`` .. ``<id>-999``).
MAX_ANATOMIES = 1000

#: Admissible compression level per compressor (inclusive); ``"none"`` ignores it.
COMPRESSION_LEVELS = {"zstd": (1, 22), "blosc": (0, 9), "none": (0, 22)}


def _check_id(value: Any, what: str) -> None:
    if not isinstance(value, str) or not _ID.fullmatch(value):
        raise ConfigError(f"{what} {value!r} is not a valid identifier: use letters, digits, '_' and '-' only")


def _check_int(value: Any, lo: int, what: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ConfigError(f"{what} must be an integer >= {lo}, got {value!r}")


@dataclass(frozen=True)
class FibreRule:
    """The fibres and sheets of a mesh (``[meshes.fibres]``): ``rule = "ldrb"``, the rule of Bayer et al. 2012
    on a ventricular volume (:func:`simgen.meshes.fibres.ldrb_frames`) with helix angles ``helix_endo`` and
    ``helix_epi`` and sheet angles ``sheet_endo`` and ``sheet_epi`` (degrees, at the endocardium and the
    epicardium), or ``"file"``, the mesh file's own point data ``fibre`` (and ``sheet`` where it has it; a
    resampled file's: each node takes its nearest file node's)."""

    rule: Literal["ldrb", "file"] = "ldrb"
    helix_endo: float = HELIX_ENDO
    helix_epi: float = HELIX_EPI
    sheet_endo: float = SHEET_ENDO
    sheet_epi: float = SHEET_EPI

    def __post_init__(self) -> None:
        if self.rule not in ("ldrb", "file"):
            raise ConfigError(f"fibres: rule {self.rule!r} is not one of ['ldrb', 'file']")
        for name in ("helix_endo", "helix_epi", "sheet_endo", "sheet_epi"):
            value = getattr(self, name)
            if not (math.isfinite(value) and -90.0 <= value <= 90.0):
                raise ConfigError(f"fibres: {name} = {value!r} must be an angle in [-90, 90] degrees")


@dataclass(frozen=True)
class MeshEntry:
    """One geometry of the dataset.

    ``source`` is a procedural geometry (``"lv"``, ``"biv"``) generated with
    about ``nodes`` nodes of cell ``kind``, a shipped real mesh
    (``"real:<name>"``, :mod:`simgen.meshes.shipped`) or the path of a mesh
    file (relative paths are resolved against the spec file's folder by
    :func:`load_spec`); real meshes and files are resampled to about ``nodes``
    nodes of ``kind`` when they have more, and get detected node sets and
    axis (:func:`simgen.meshes.heart.load_heart`). ``id`` names the mesh in
    the store and prefixes its subjects' ids. ``shape_params`` (procedural
    sources only; ``None``: the default geometry) are the anatomy's shape
    parameters (:mod:`simgen.meshes.shapes`), completed with the defaults of
    those not given. For real meshes and files only: ``units`` of the file
    (``None``: the file's, else inferred), ``axis`` landmark points in mm
    (``apex``, ``base``, optional ``septum``) replacing the detected long axis,
    and ``node_set_arrays`` (node set -> the file's 0/1 point-data array)
    replacing detected sets; ``heart = false`` accepts a mesh that is no heart
    (a slab: no node sets detected, no sock, so ``[output] sock_electrodes = 0``),
    which is refused otherwise; ``filler`` fills a surface with tetrahedra
    (:data:`~simgen.meshes.fillers.FILLERS`; unset: ``"auto"``, TetGen where
    installed and the surface is clean, else fTetWild). Unset keys stay out of
    the spec's hash. ``fibres`` (:class:`FibreRule`; unset: none, the mesh conducts
    isotropically) gives the mesh fibres, which the store keeps (mesh array ``fibre``)
    and an ``anisotropy`` (``[solver]`` or a tissue setting's) conducts along.
    """

    id: str
    source: str = "lv"
    nodes: int = 2000
    kind: Literal["tetra", "triangle"] = "tetra"
    shape_params: dict[str, int | float] | None = field(default=None, hash=False)
    units: Literal["mm", "cm", "m"] | None = None
    axis: dict[str, tuple[float, float, float]] | None = field(default=None, hash=False)
    node_set_arrays: dict[str, str] | None = field(default=None, hash=False)
    heart: bool | None = None
    filler: Literal["auto", "ftetwild", "tetgen"] | None = None
    fibres: FibreRule | None = None

    def __post_init__(self) -> None:
        _check_id(self.id, "[[meshes]] id")
        if self.fibres is not None and self.kind != "tetra":
            raise ConfigError(f"mesh {self.id!r}: fibres need a volume mesh (kind = 'tetra'), not {self.kind!r}")
        if self.fibres is not None and self.fibres.rule == "file" and self.source in GENERATORS:
            raise ConfigError(f"mesh {self.id!r}: fibre rule 'file' needs a mesh file, not {self.source!r}")
        if not isinstance(self.source, str) or not self.source:
            raise ConfigError(
                f"mesh {self.id!r}: source must be 'lv', 'biv', 'real:<name>' or a mesh file path, got {self.source!r}"
            )
        self._check_file_keys()
        _check_int(self.nodes, 1, f"mesh {self.id!r}: nodes")
        if self.kind not in ("tetra", "triangle"):
            raise ConfigError(f"mesh {self.id!r}: kind {self.kind!r} is not one of ['tetra', 'triangle']")
        if self.shape_params is not None:
            try:
                shape = shape_from_params(self.source, self.shape_params)
            except InputError as exc:
                raise type(exc)(f"mesh {self.id!r}: {exc}") from None
            object.__setattr__(self, "shape_params", shape.params())

    def _check_file_keys(self) -> None:
        """``units``, ``axis``, ``node_set_arrays``, ``heart`` and ``filler``: real meshes and files only, with known
        names."""
        given = [k for k in ("units", "axis", "node_set_arrays", "heart", "filler") if getattr(self, k) is not None]
        if given and self.source in GENERATORS:
            raise ConfigError(f"mesh {self.id!r}: {given} apply to mesh files and real meshes, not to {self.source!r}")
        if is_real(self.source):
            try:
                real_mesh_file(self.source)
            except InputError as exc:
                raise ConfigError(f"mesh {self.id!r}: {exc}") from None
        if self.filler is not None and self.filler not in FILLERS:
            raise ConfigError(f"mesh {self.id!r}: filler {self.filler!r} is not one of {list(FILLERS)}")
        if self.units is not None and self.units not in MM_PER_UNIT:
            raise ConfigError(f"mesh {self.id!r}: units {self.units!r} is not one of {list(MM_PER_UNIT)}")
        if self.axis is not None and not ({"apex", "base"} <= set(self.axis) <= set(LANDMARKS)):
            raise ConfigError(
                f"mesh {self.id!r}: axis needs apex and base (and optionally septum) points, got {sorted(self.axis)}"
            )
        sets = (*NODE_SETS[1:], *OPTIONAL_NODE_SETS)
        unknown = sorted(set(self.node_set_arrays or {}) - set(sets))
        if unknown:
            raise ConfigError(f"mesh {self.id!r}: node_set_arrays {unknown} are not node sets; use {list(sets)}")


@dataclass(frozen=True)
class SiteSelection:
    """Stimulation sites of each mesh, shared by all subjects of that mesh.

    ``method = "farthest"`` spreads ``count`` sites over the node set
    ``node_set`` by farthest-point sampling (deterministic, in selection order,
    so any prefix is itself well spread); ``"random"`` draws them uniformly
    without replacement from a generator seeded by the spec seed and the mesh
    id (sorted). Explicit ``nodes`` override ``count`` and ``method`` and are
    used in the given order on every mesh.
    """

    count: int = 200
    node_set: str = "surface"
    method: Literal["farthest", "random"] = "farthest"
    nodes: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        _check_int(self.count, 1, "[sites] count")
        if self.node_set not in SITE_NODE_SETS:
            raise ConfigError(f"[sites] node_set {self.node_set!r} is not one of {list(SITE_NODE_SETS)}")
        if self.method not in ("farthest", "random"):
            raise ConfigError(f"[sites] method {self.method!r} is not one of ['farthest', 'random']")
        object.__setattr__(self, "nodes", tuple(self.nodes))
        for node in self.nodes:
            if isinstance(node, bool) or not isinstance(node, int) or node < 0:
                raise StimulusError(f"[sites] nodes: stimulation node {node!r} must be an integer >= 0")
        if len(set(self.nodes)) != len(self.nodes):
            dup = sorted({n for n in self.nodes if self.nodes.count(n) > 1})
            raise StimulusError(f"[sites] nodes: duplicate stimulation nodes {dup}")


@dataclass(frozen=True)
class OutputSpec:
    """Store layout: sites per chunk (= per build task), compression, sock size.

    Every chunk ends in a CRC32C checksum. ``compressor = "none"`` (the
    default) is the cheapest to write: workers write those chunk files
    straight from the simulation's memory, ~5.5 ms of CPU for a 29 MB chunk
    against ~35 ms through blosc-lz4, which stores ``u`` in ~0.71 of the bytes
    (bench/build.py). ``sock_electrodes = 0`` stores no sock electrodes.
    ``ecg = true`` stores each simulation's 12-lead pseudo-ECG (subject array
    ``ecg``, the electrodes in the mesh group; :mod:`shared.ecg`);
    unset (or false): none, and out of the spec's hash.
    """

    chunk_sites: int = 25
    compressor: Literal["zstd", "blosc", "none"] = "none"
    level: int = 3
    sock_electrodes: int = 247
    ecg: bool | None = None

    def __post_init__(self) -> None:
        _check_int(self.chunk_sites, 1, "[output] chunk_sites")
        if self.compressor not in COMPRESSION_LEVELS:
            raise ConfigError(f"[output] compressor {self.compressor!r} is not one of {list(COMPRESSION_LEVELS)}")
        lo, hi = COMPRESSION_LEVELS[self.compressor]
        if isinstance(self.level, bool) or not isinstance(self.level, int) or not lo <= self.level <= hi:
            raise ConfigError(
                f"[output] level {self.level!r} out of range for compressor {self.compressor!r}: use {lo}..{hi}"
            )
        _check_int(self.sock_electrodes, 0, "[output] sock_electrodes")
        if self.ecg is False:  # the default written out: unset, out of the hash
            object.__setattr__(self, "ecg", None)


@dataclass(frozen=True)
class BuildSpec:
    """A whole dataset: meshes x tissue settings, sites, solver and output settings.

    ``tissue`` names settings of :func:`simgen.tissue.default_settings`
    (``"default"`` selects all 16); ``custom_tissue`` adds inline settings, and
    the draws of a spec file's ``[tissue_prior]`` table (:mod:`simgen.tissue.prior`).
    Every mesh is simulated under every setting; subject ids are
    ``f"{mesh_id}-{setting_name}"``.
    """

    name: str = "dataset"
    seed: int = 0
    meshes: tuple[MeshEntry, ...] = (MeshEntry("lv"),)
    tissue: tuple[str, ...] = ("default",)
    custom_tissue: tuple[TissueSpec, ...] = ()
    sites: SiteSelection = field(default_factory=SiteSelection)
    solver: SolverConfig = field(default_factory=SolverConfig)
    output: OutputSpec = field(default_factory=OutputSpec)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"name must be a non-empty string, got {self.name!r}")
        _check_int(self.seed, 0, "seed")
        object.__setattr__(self, "meshes", tuple(self.meshes))
        object.__setattr__(self, "tissue", tuple(self.tissue))
        object.__setattr__(self, "custom_tissue", tuple(self.custom_tissue))
        if not self.meshes:
            raise ConfigError("the spec has no meshes: add at least one [[meshes]] table")
        ids = [m.id for m in self.meshes]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ConfigError(f"duplicate mesh ids {dup}: every [[meshes]] id must be unique")
        names = [s.name for s in self.settings()]
        if not names:
            raise ConfigError("the spec has no tissue settings: set tissue = [...] or add [[custom_tissue]] tables")
        for s in self.custom_tissue:
            _check_id(s.name, "[[custom_tissue]] name")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError(f"duplicate tissue setting names {dup}: each setting may appear once")
        surfaces = [m.id for m in self.meshes if m.kind != "tetra"]
        if self.output.ecg and surfaces:
            raise ConfigError(
                f"[output] ecg: the pseudo-ECG integrates over the heart's volume, and meshes {surfaces} are "
                "surfaces: use kind = 'tetra'"
            )
        anisotropic = self.solver.anisotropy is not None or self.solver.sheet_anisotropy is not None
        anisotropic = anisotropic or any(s.anisotropy for s in self.settings())
        plain = [m.id for m in self.meshes if m.fibres is None]
        if anisotropic and plain:
            raise ConfigError(
                f"anisotropy (in [solver] or a tissue setting) conducts along fibres, and meshes {plain} have "
                "none: give each a [meshes.fibres] table (rule = 'ldrb', or 'file' for a file's own)"
            )
        subjects = [f"{m}-{s}" for m in ids for s in names]
        dup = sorted({s for s in subjects if subjects.count(s) > 1})
        if dup:
            raise ConfigError(f"subject ids {dup} are ambiguous: rename a mesh id or a tissue setting")

    def settings(self) -> list[TissueSpec]:
        """The tissue settings in order: named defaults as listed, then the custom ones."""
        defaults = {s.name: s for s in default_settings()}
        chosen: list[TissueSpec] = []
        for name in self.tissue:
            if name == "default":
                chosen.extend(defaults.values())
            elif name in defaults:
                chosen.append(defaults[name])
            else:
                raise ConfigError(
                    f"unknown tissue setting {name!r}; allowed: 'default' (all 16) or one of {list(defaults)}; "
                    "define other settings in [[custom_tissue]] tables"
                )
        return [*chosen, *self.custom_tissue]


def _resolve_sources(data: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """``data`` with relative mesh-file sources made absolute against ``base_dir``."""
    meshes = data.get("meshes")
    if not isinstance(meshes, list):
        return data
    resolved = []
    for entry in meshes:
        source = entry.get("source") if isinstance(entry, dict) else None
        if (
            isinstance(source, str)
            and source not in GENERATORS
            and not is_real(source)
            and not Path(source).is_absolute()
        ):
            entry = {**entry, "source": str((base_dir / source).resolve())}
        resolved.append(entry)
    return {**data, "meshes": resolved}


def _expand_meshes(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with every ``shape = "random"`` mesh table replaced by its ``count`` anatomies."""
    meshes = data.get("meshes")
    if not isinstance(meshes, list):
        return data
    return {**data, "meshes": [table for entry in meshes for table in _expand_entry(entry)]}


def _expand_entry(entry: Any) -> list[Any]:
    """One ``[[meshes]]`` table as the tables it stands for (ids ``<id>-000``, ... for random shapes).

    ``shape``, ``count``, ``seed`` and ``shape_ranges`` are consumed here;
    each random anatomy gets its complete drawn parameters as ``shape_params``
    (:func:`simgen.meshes.anatomy.sample_shapes`, fixed ones from the table's
    ``shape_params``, sampling intervals from its ``shape_ranges``).
    """
    if not isinstance(entry, dict) or not {"shape", "count", "seed", "shape_ranges"} & entry.keys():
        return [entry]
    table = dict(entry)
    shape, count, seed = table.pop("shape", "default"), table.pop("count", None), table.pop("seed", None)
    ranges = table.pop("shape_ranges", None)
    _check_id(table.get("id"), "[[meshes]] id")
    where = f"mesh {table['id']!r}"
    if shape == "default":
        if count is not None or seed is not None or ranges is not None:
            raise ConfigError(f"{where}: count, seed and shape_ranges apply to shape = 'random' only")
        return [table]
    if shape != "random":
        raise ConfigError(f"{where}: shape {shape!r} is not one of ['default', 'random']")
    source = table.get("source", "lv")
    if source not in GENERATORS:
        raise ConfigError(f"{where}: shape = 'random' needs source 'lv' or 'biv', got {source!r}")
    count = 1 if count is None else count
    _check_int(count, 1, f"{where}: count")
    if count > MAX_ANATOMIES:
        raise ConfigError(f"{where}: count must be at most {MAX_ANATOMIES}, got {count}")
    seed = 0 if seed is None else seed
    _check_int(seed, 0, f"{where}: seed")
    fixed = table.get("shape_params", {})
    if not isinstance(fixed, dict):
        raise ConfigError(f"{where}: shape_params must be a table, got {fixed!r}")
    if ranges is not None and not isinstance(ranges, dict):
        raise ConfigError(f"{where}: shape_ranges must be a table, got {ranges!r}")
    try:
        shapes = sample_shapes(source, count, seed, fixed, ranges)
    except InputError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    return [
        {**table, "source": source, "id": f"{table['id']}-{i:03d}", "shape_params": shape.params()}
        for i, shape in enumerate(shapes)
    ]


def _expand_tissue(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with its ``[tissue_prior]`` table (or ``[[tissue_prior]]`` tables, each with its own ``name``)
    replaced by the ``[[custom_tissue]]`` tables of its draws (:func:`simgen.tissue.prior.draw_tissues`, after any
    given ones); without a ``tissue`` key, a spec with a prior simulates its draws alone."""
    if "tissue_prior" not in data:
        return data
    data = dict(data)
    tables = data.pop("tissue_prior")
    tables = tables if isinstance(tables, list) else [tables]
    priors = [
        from_mapping(TissuePrior, t, f"tissue_prior[{i}]" if len(tables) > 1 else "tissue_prior")
        for i, t in enumerate(tables)
    ]
    names = [p.name for p in priors]
    if len(set(names)) != len(names):
        raise ConfigError(f"[[tissue_prior]] tables need distinct names (their draws' prefixes), got {names}")
    solver = from_mapping(SolverConfig, data.get("solver", {}), "solver")
    custom = data.get("custom_tissue", [])
    if not isinstance(custom, list):
        raise ConfigError(f"custom_tissue must be a list of tables, got {custom!r}")
    draws = [to_mapping(t) for prior in priors for t in draw_tissues(prior, solver)]
    return {**data, "tissue": data.get("tissue", []), "custom_tissue": [*custom, *draws]}


def spec_from_mapping(data: dict[str, Any], base_dir: Path | None = None) -> BuildSpec:
    """A :class:`BuildSpec` from a TOML/JSON mapping, strictly.

    Unknown keys and wrong types raise :class:`ConfigError` naming the key path
    (e.g. ``solver.frame``); invalid values raise the matching
    :class:`~shared.errors.InputError` subclass. With ``base_dir``, relative
    mesh-file sources are resolved against it. ``shape = "random"`` mesh
    tables are expanded into their anatomies first, and a ``[tissue_prior]``
    into its draws, so the spec (and its hash) lists every anatomy and every
    tissue with its parameters.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"build spec: expected a table, got {type(data).__name__}")
    data = _expand_tissue(_expand_meshes(data))
    if base_dir is not None:
        data = _resolve_sources(data, Path(base_dir))
    return from_mapping(BuildSpec, data)


def load_spec(path: str | Path) -> BuildSpec:
    """Read a build spec TOML file; mesh-file sources are relative to its folder."""
    path = Path(path)
    data = load_toml(path)
    try:
        return spec_from_mapping(data, base_dir=path.resolve().parent)
    except InputError as exc:
        raise type(exc)(f"{path}: {exc}") from None


def spec_to_dict(spec: BuildSpec) -> dict[str, Any]:
    """JSON-able dict of ``spec`` with every field explicit; ``spec_from_mapping`` inverts it."""
    return to_mapping(spec)


def recorded_hashes(attrs: dict[str, Any]) -> set[str]:
    """The hashes a store's root attributes answer to: the recorded ``spec_hash`` and the hash of the recorded
    ``spec`` as this version reads it (a spec that wrote a default out, e.g. ``integrator = "auto"``, was
    hashed apart from the spec that leaves it unset; read again, the two are one spec)."""
    hashes = {str(attrs["spec_hash"])} if attrs.get("spec_hash") else set()
    try:
        hashes.add(spec_hash(spec_from_mapping(attrs["spec"])))
    except (KeyError, InputError, TypeError, ValueError):  # no recorded spec, or one this version cannot read
        pass
    return hashes


def spec_hash(spec: BuildSpec) -> str:
    """SHA-256 (hex) of the canonical JSON of :func:`spec_to_dict` (sorted keys, no whitespace).

    It fingerprints the spec only, not the content of mesh files it names.
    """
    text = json.dumps(spec_to_dict(spec), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()
