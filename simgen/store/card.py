"""The dataset card of a store: a Markdown page describing what the store holds, and its short form.

:func:`dataset_card` (``simgen card STORE``) reads the store's own metadata:
the model and its constants, the solver and tissue settings with their
ranges, sizes, statistics, the canonical split, the solver work, provenance
and how to cite. :func:`short_card` is the few-line summary a build writes
into the root attribute ``summary``; it depends on the store alone, so
rewriting it on a resume changes no byte. Version-1 stores get a card too:
what they do not record is named as such.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr

from shared.capture import started_wave
from shared.config import from_mapping
from shared.mesh import Mesh
from shared.reader import check_store, integrator_of
from shared.schema import METADATA_VERSION, subject_path
from shared.tissue import FibrosisSpec, ScarSpec
from shared.units import MS_PER_TIME_UNIT, TIME_UNITS
from simgen.meshes.quality import mesh_quality
from simgen.solver.cells import CellModel
from simgen.store import location
from simgen.store.metadata import LEGACY_REGION, recorded_scar_border, simulation_attrs
from simgen.store.spec import spec_from_mapping
from simgen.store.structure import refuse_damaged
from simgen.tissue.report import fibrosis_summary, scar_summary

__all__ = ["StoreFacts", "store_facts", "short_card", "dataset_card", "CITATIONS"]

#: What to cite when using a dataset, besides its cell model's paper (the generator's version and the store's
#: spec hash are added).
CITATIONS = (
    "X. Jiang et al., *Few-shot generation of personalized neural surrogates for cardiac simulation via "
    "Bayesian meta-learning*, MICCAI 2022 (the data setting and the surrogate).",
)


@dataclass(frozen=True)
class MeshFacts:
    """Sizes of one mesh group."""

    nodes: int
    cells: int
    cell_type: str
    sites: int


@dataclass(frozen=True)
class StoreFacts:
    """The metadata a card is written from (no result array is read)."""

    attrs: dict
    meshes: dict[str, MeshFacts]
    subjects: dict[str, dict]

    @property
    def version(self) -> int:
        """Schema version of the store."""
        return int(self.attrs["schema_version"])

    @property
    def cell(self) -> CellModel:
        """The cell model the store simulates."""
        return spec_from_mapping(self.attrs["spec"]).solver.model

    @property
    def simulation(self) -> dict:
        """Root attribute ``simulation`` (derived from the spec in a version-1 store)."""
        return self.attrs.get("simulation") or simulation_attrs(spec_from_mapping(self.attrs["spec"]).solver)

    def missing(self, otherwise: str = "not recorded") -> str:
        """Why a value is absent: the store's older schema version, or ``otherwise``."""
        return f"not recorded (schema version {self.version})" if self.version < METADATA_VERSION else otherwise


def store_facts(store: str | Path, check: bool = False) -> StoreFacts:
    """Root attributes, mesh sizes and subject attributes of ``store`` (live metadata, not the consolidated copy).

    ``check``: first refuse a damaged store with :class:`~simgen.store.structure.StoreDamaged`.
    """
    store = location.store_location(store)
    attrs = check_store(store)
    if check:
        refuse_damaged(store)
    root = zarr.open_group(store, mode="r", use_consolidated=False)
    meshes = {
        mesh_id: MeshFacts(g["points"].shape[0], g["cells"].shape[0], g.attrs["cell_type"], g["stim_nodes"].shape[0])
        for mesh_id, g in sorted(root["meshes"].groups())
    }
    subjects = {subject_id: dict(g.attrs) for subject_id, g in sorted(root["subjects"].groups())}
    return StoreFacts(attrs, meshes, subjects)


def _span(values) -> str:
    """``"a"`` or ``"a-b"`` (``:g`` format) over ``values``."""
    lo, hi = min(values), max(values)
    return f"{lo:g}" if lo == hi else f"{lo:g}-{hi:g}"


#: How the card names each scar border rule (:data:`simgen.tissue.fields.SCAR_BORDERS`).
_BORDER_TEXT = {"boundary": "the core's boundary", "nodes": "the core's nodes"}


def _no_wave(facts: StoreFacts) -> str:
    """``"3 of 120 (2.5%)"`` from the subjects' ``capture`` attributes, or the missing-record note."""
    recorded = [s["capture"]["activated_fraction"] for s in facts.subjects.values() if s.get("capture")]
    if len(recorded) < len(facts.subjects):
        return facts.missing()
    total = sum(len(f) for f in recorded)
    none = sum(int((~started_wave(f)).sum()) for f in recorded)
    return f"{none} of {total} ({100 * none / max(total, 1):.1f}%)"


def _tally(words: list[str]) -> str:
    """``"euler (3), imex (2)"``: each distinct word and how often it occurs, in first-seen order."""
    counts = {w: words.count(w) for w in dict.fromkeys(words)}
    return ", ".join(f"{w} ({n})" for w, n in counts.items()) or "-"


def short_card(facts: StoreFacts) -> str:
    """Three lines: contents, model and units, provenance."""
    sim, prov = facts.simulation, facts.attrs.get("provenance") or {}
    name, interval = facts.attrs["spec"]["name"], sim["output_interval"]
    meshes = facts.meshes.values()
    if prov:
        commit, version = (prov["git_commit"] or "unknown")[:12], prov["version"] or "(version unknown)"
        written = f"Written by {prov['software']} {version} (commit {commit}) on {prov['created']}"
    else:
        written = "Provenance not recorded"
    return "\n".join(
        [
            f"{name}: {len(facts.subjects)} subjects on {len(meshes)} mesh(es) of {_span([m.nodes for m in meshes])} "
            f"nodes, {_span([m.sites for m in meshes])} stimulation sites each, {sim['frames']} frames every "
            f"{interval:g} time units ({interval * MS_PER_TIME_UNIT:.3g} ms).",
            f"{facts.cell.describe()}; u dimensionless "
            f"(V = 100 u - 80 mV), times in units of {TIME_UNITS}, lengths in mm.",
            f"{written}; schema version {facts.version}. Full card: `simgen card STORE`.",
        ]
    )


def _size(n_bytes: float) -> str:
    """Bytes in kB, MB, GB or TB (powers of 1000), three significant digits."""
    scale, unit = next(
        (10.0**e, u) for e, u in ((12, "TB"), (9, "GB"), (6, "MB"), (3, "kB"), (0, "B")) if n_bytes >= 10.0**e or e == 0
    )
    return f"{n_bytes / scale:.3g} {unit}"


def _table(header: tuple[str, ...], rows: list[tuple]) -> list[str]:
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(str(c) for c in row) + " |" for row in rows),
    ]


def _scar_text(scar: dict) -> str:
    if scar["region"] == "segments":
        where = f"AHA segments {','.join(map(str, scar['segments']))}"
    elif scar["region"] == "sphere":
        where = f"sphere of {scar['radius']:g} mm"
    else:
        where = f"wall ellipsoid {scar_summary(from_mapping(ScarSpec, scar))}"
    border = f", border {scar['border_width']:g} mm (a {scar['border']['a']:g}, D {scar['border']['D']:g})"
    return f"{where}: core a {scar['core']['a']:g}, D {scar['core']['D']:g}" + (border if scar["border_width"] else "")


def _fibres_text(meshes: list[dict]) -> str:
    """The fibre rule of each mesh of a recorded spec, or that none has fibres."""
    rules = {
        m["id"]: m["fibres"]["rule"]
        if m["fibres"]["rule"] == "file"
        else f"LDRB, helix {m['fibres']['helix_endo']:+g} to {m['fibres']['helix_epi']:+g} deg"
        for m in meshes
        if m.get("fibres")
    }
    return "; ".join(f"{mesh_id}: {rule}" for mesh_id, rule in rules.items()) or "none (isotropic)"


def _model(facts: StoreFacts) -> list[str]:
    sim = facts.simulation
    units = sim["units"]
    return [
        "## Model",
        "",
        sim["model"] + ".",
        "",
        "```",
        *sim["equations"],
        "```",
        "",
        *_table(("constant", "value"), list(sim["constants"].items())),
        "",
        f"Units: lengths in {units['length']}, time in units of {units['time']}, {units['potential']}, "
        f"diffusivity in {units['diffusivity']}.",
        "",
    ]


def _parameters(store: str, facts: StoreFacts) -> list[str]:
    sim = facts.simulation
    solvers = [s["solver"] for s in facts.subjects.values() if "solver" in s]

    def resolved(key: str) -> str:
        return _span([s[key] for s in solvers]) if solvers else facts.missing()

    radius = sim["stimulus_radius"]
    legacy = any("stimulus_region" not in s for s in solvers)  # built before the radius default was in mm
    spec_solver = facts.attrs["spec"]["solver"]
    rows = [
        ("diffusivity (mm2 per time unit)", f"{sim['diffusivity']:g}"),
        ("fibres (per mesh)", _fibres_text(facts.attrs["spec"]["meshes"])),
        (
            "ECG per simulation",
            "12-lead pseudo-ECG in mV (subject array ecg; electrodes: mesh array ecg_electrodes)"
            if facts.attrs["spec"]["output"].get("ecg")
            else "none",
        ),
        (
            "anisotropy D_l / D_t (subjects)",
            _tally([f"{s['anisotropy']:g}" if "anisotropy" in s else "isotropic" for s in solvers]),
        ),
        ("time integrator (subjects)", _tally([integrator_of(s, spec_solver) for s in solvers])),
        ("time step dt (time units, per subject)", resolved("dt")),
        ("solver steps per frame", resolved("steps_per_frame")),
        (
            "stimulus radius (mm, per mesh)",
            resolved("stimulus_radius") + (" (1.5 mean edge lengths)" if solvers and legacy and radius is None else ""),
        ),
        ("stimulus patch (subjects)", _tally([s.get("stimulus_region", LEGACY_REGION) for s in solvers])),
        ("stimulus duration (time units)", f"{sim['stimulus_duration']:g}"),
        ("scar border zones measured from", _BORDER_TEXT[recorded_scar_border(facts.attrs)]),
        ("activation threshold (u)", f"{sim['activation_threshold']:g}"),
        ("output interval (time units)", f"{sim['output_interval']:g}"),
        ("frames", sim["frames"]),
        ("simulations that start no wave (stimulus in a scar core)", _no_wave(facts)),
    ]
    settings: dict[str, list[str]] = {}
    for subject_id, attrs in facts.subjects.items():
        settings.setdefault(attrs["tissue"]["name"], []).append(subject_id)
    tissue_rows = []
    for name, ids in settings.items():
        tissue = facts.subjects[ids[0]]["tissue"]
        groups = [zarr.open_group(store, path=subject_path(i), mode="r") for i in ids]
        a = [float(f(g["a"][...])) for g in groups for f in (np.min, np.max)]
        D = [float(f(g["D"][...])) for g in groups for f in (np.min, np.max)]
        parts = [_scar_text(s) for s in tissue["scars"]]
        if tissue.get("fibrosis"):
            parts.append(f"fibrosis {fibrosis_summary(from_mapping(FibrosisSpec, tissue['fibrosis']))}")
        scars = "; ".join(parts) or "none"
        tissue_rows.append((name, len(ids), f"{tissue['healthy']['a']:g}", scars, _span(a), _span(D)))
    return [
        "## Parameters",
        "",
        *_table(("setting", "value"), rows),
        "",
        *_table(("tissue setting", "subjects", "healthy a", "scars", "a (nodes)", "D scale (nodes)"), tissue_rows),
        "",
    ]


def _sizes(store: str, facts: StoreFacts) -> list[str]:
    frames = facts.simulation["frames"]
    per_subject = [(facts.meshes[s["mesh_id"]], s) for s in facts.subjects.values()]
    values = sum(m.sites * m.nodes * (frames + 1) for m, _ in per_subject)
    steps = [m.sites * m.nodes * frames * s["solver"]["steps_per_frame"] for m, s in per_subject if "solver" in s]
    mesh_rows = [
        (mesh_id, m.nodes, m.cells, m.cell_type, m.sites, *_quality_cells(store, mesh_id))
        for mesh_id, m in facts.meshes.items()
    ]
    return [
        "## Sizes",
        "",
        f"{len(facts.subjects)} subjects, {sum(m.sites for m, _ in per_subject)} simulations of {frames} frames; "
        f"{values:,} values of u and activation ({_size(4 * values)} as float32), "
        f"{_size(location.size(store))} on disk.",
        "",
        *_table(("mesh", "nodes", "cells", "cell type", "sites", *QUALITY_COLUMNS), mesh_rows),
        "",
        "Smallest angle: dihedral (tetrahedra) or interior (triangles); radius ratio d r / R (1 for a regular "
        "cell), smallest over the cells / 1st percentile / mean (`simgen.meshes.quality`).",
        "",
        "## Cost",
        "",
        f"Solver work: {f'{sum(steps):.3g} node-steps' if len(steps) == len(per_subject) else facts.missing()}"
        " (sites x nodes x time steps). Wall-clock build time is not stored: it would make two builds of one "
        "spec differ.",
        "",
    ]


#: Quality columns of the card's mesh table.
QUALITY_COLUMNS = ("smallest angle (deg)", "radius ratio min / 1st pct / mean", "smallest altitude / mean edge")


def _quality_cells(store: str, mesh_id: str) -> tuple[str, str, str]:
    """The :data:`QUALITY_COLUMNS` of a stored mesh, from its points and cells."""
    group = zarr.open_group(store, path=f"meshes/{mesh_id}", mode="r")
    quality = mesh_quality(Mesh(group["points"][...], group["cells"][...], name=mesh_id))
    return f"{quality.min_angle:.1f}", quality.radius_text(), f"{quality.min_altitude_ratio:.3f}"


def _statistics(facts: StoreFacts) -> list[str]:
    stats = facts.attrs.get("statistics")
    if stats is None:
        return ["## Statistics", "", facts.missing("not available while chunks are pending") + ".", ""]
    units = {"u": "1 (V = 100 u - 80 mV)", "activation": TIME_UNITS}
    rows = [
        (
            name,
            units[name],
            s["count"],
            *(f"{s[k]:.6g}" if s[k] is not None else "-" for k in ("mean", "std", "min", "max")),
        )
        for name, s in stats.items()
    ]
    return [
        "## Statistics",
        "",
        "Over every finite value of the store (per subject: subject attribute `statistics`).",
        "",
        *_table(("variable", "units", "count", "mean", "std", "min", "max"), rows),
        "",
    ]


def _split(facts: StoreFacts) -> list[str]:
    parts = [s.get("split") for s in facts.subjects.values()]
    if None in parts:
        return ["## Canonical split", "", facts.missing() + ".", ""]
    rule = facts.attrs["split"]
    counts = ", ".join(f"{part} {parts.count(part)}" for part in rule["fractions"])
    return ["## Canonical split", "", f"Subjects: {counts}. Rule: {rule['method']}; fractions {rule['fractions']}.", ""]


def _provenance(facts: StoreFacts) -> list[str]:
    prov = facts.attrs.get("provenance")
    rows = (
        [
            ("software", f"{prov['software']} {prov['version'] or '(version unknown)'}"),
            ("git commit", prov["git_commit"] or "unknown"),
            ("created", prov["created"]),
        ]
        if prov
        else [("provenance", facts.missing())]
    )
    rows += [
        ("schema version", facts.version),
        ("spec hash", facts.attrs["spec_hash"]),
        ("complete", facts.attrs.get("complete")),
    ]
    for entry in facts.attrs.get("added", []):
        when = (entry.get("provenance") or {}).get("created", "date not recorded")
        rows.append((f"added mesh {entry['mesh']['id']}", f"{', '.join(entry['subjects'])} ({when})"))
    return ["## Provenance", "", *_table(("item", "value"), rows), ""]


def _citation(facts: StoreFacts) -> list[str]:
    prov = facts.attrs.get("provenance") or {}
    dataset = (
        f'The dataset: "{facts.attrs["spec"]["name"]}", generated by metaPNS simgen '
        f"{prov.get('version') or ''} (spec hash {facts.attrs['spec_hash'][:12]})."
    )
    return ["## How to cite", "", *(f"- {c}" for c in (facts.cell.citation, *CITATIONS, dataset)), ""]


def dataset_card(store: str | Path) -> str:
    """The Markdown dataset card of ``store`` (a folder or an fsspec URL); a damaged store is refused
    (:func:`~simgen.store.structure.refuse_damaged`)."""
    store = location.store_location(store)
    facts = store_facts(store, check=True)
    return "\n".join(
        [
            f"# Dataset card: {facts.attrs['spec']['name']}",
            "",
            short_card(facts),
            "",
            *_model(facts),
            *_parameters(store, facts),
            *_sizes(store, facts),
            *_statistics(facts),
            *_split(facts),
            *_provenance(facts),
            *_citation(facts),
        ]
    )
