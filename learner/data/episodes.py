"""Meta-learning episodes read from a dataset store.

An episode is one subject: ``K`` context simulations (what the set encoder
sees, observed on a node subset) and ``M`` other target simulations of the
same subject (what the generator must predict). Sites are drawn without
replacement, so targets never include the context.

I/O contract: the store is opened lazily (inside each DataLoader worker) and
an episode reads only its ``K + M`` site rows of ``u``: in a sharded store
(schema version 3) it decodes only those sites; an older store decodes whole
build chunks, which ``chunks_per_episode`` bounds. Every chunk an episode
reads is verified first (:class:`shared.integrity.SubjectReader`: its done
flag, checksums and content fingerprint, finite values), once per chunk and
reading process; damaged or misplaced data stop with a
:class:`~shared.errors.DamagedData` naming the subject, array, site, file and
``simgen repair``, and so does a subject the store's spec implies but the
store lacks. Every random
choice of an episode comes from ``np.random.default_rng([seed, epoch,
subject_index, k])``, so an episode is a pure function of those four numbers
and training can resume exactly.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch.utils.data import IterableDataset, get_worker_info

from learner.activation_maps import ApTemplate, template_from_store
from learner.ecg import LeadField
from learner.metrics import activation_times
from shared.capture import mapped_activation
from shared.errors import InputError, SchemaError
from shared.observation import OBSERVATION_SETS, check_noise_std, check_observation_set, node_mask, observe
from shared.reader import (
    SubjectReader,
    check_store,
    checked_subject_ids,
    done_flags,
    read_index_set,
    read_mesh,
    read_sites,
    read_solver_settings,
    read_times,
    read_tissue,
    subject_array,
    subject_attrs,
)
from shared.tissue import ABNORMAL_LABELS, Material, TissueSpec, healthy_speed
from shared.units import MS_PER_TIME_UNIT

__all__ = ["OBSERVATION_SETS", "EpisodeSpec", "Episode", "EpisodeDataset", "load_episode", "tissue_truth"]


@dataclass(frozen=True)
class EpisodeSpec:
    """How episodes are drawn.

    Parameters
    ----------
    context
        ``(min, max)`` context size, both inclusive; ``K`` is uniform on it.
    targets
        Number of target simulations ``M`` per episode.
    observe
        Node set the context is observed on: one of :data:`~shared.observation.OBSERVATION_SETS`, or a
        sequence of them, one drawn uniformly per episode (e.g. ``("surface",
        "electrodes")``: the encoder learns both the whole surface and the
        sparse sock). Evaluation observes the first (:attr:`primary_observe`)
        unless told otherwise.
    noise_std
        Standard deviation of Gaussian noise added to observed context values.
    chunks_per_episode
        ``0``: draw sites from the whole subject; ``k > 0``: only from ``k``
        random build chunks, so an episode touches at most ``k`` chunk files
        of ``u`` (in an unsharded store, decodes at most ``k`` whole chunks).
    activation_maps
        Share of episodes whose context is recorded as activation-time maps
        instead of potentials (:mod:`learner.activation_maps`): each observed
        node's activation time as a mapping system records it
        (:func:`~shared.capture.mapped_activation`) with Gaussian noise of
        ``activation_noise_ms``, rendered through the action-potential template.
    activation_noise_ms
        Standard deviation of the activation-time noise of those episodes, in ms.
    ecg
        Share of episodes whose context is recorded as 12-lead ECGs instead (:mod:`learner.ecg`): the
        pseudo-ECG of each context simulation through the standard electrodes placed by the heart's axes,
        the subject's tissue weighing its conductivity; drawn after ``activation_maps``, which it overrides.
    ecg_noise
        Standard deviation of the Gaussian noise added to those ECGs, as a share of the set's largest lead value.
    """

    context: tuple[int, int] = (1, 5)
    targets: int = 20
    observe: str | tuple[str, ...] = "surface"
    noise_std: float = 0.0
    chunks_per_episode: int = 0
    activation_maps: float = 0.0
    activation_noise_ms: float = 3.0
    ecg: float = 0.0
    ecg_noise: float = 0.02

    def __post_init__(self) -> None:
        context = self.context
        if isinstance(context, (int, np.integer)) and not isinstance(context, bool):
            context = (int(context), int(context))
        if not (isinstance(context, Sequence) and len(context) == 2 and all(_is_int(c) for c in context)):
            raise InputError(f"context must be a (min, max) pair of integers, got {self.context!r}")
        lo, hi = int(context[0]), int(context[1])
        object.__setattr__(self, "context", (lo, hi))  # TOML gives lists; keep the spec hashable
        if lo < 1:
            raise InputError(f"context size must be >= 1, got context={self.context!r}")
        if hi < lo:
            raise InputError(f"context max must be >= context min, got context={self.context!r}")
        if not _is_int(self.targets) or self.targets < 0:
            raise InputError(f"targets must be a non-negative integer, got {self.targets!r}")
        sets = (self.observe,) if isinstance(self.observe, str) else self.observe
        if not isinstance(sets, (list, tuple)) or not sets or len(set(map(str, sets))) != len(sets):
            raise InputError(f"observe must be an observation set or a list of distinct ones, got {self.observe!r}")
        sets = tuple(sets)
        for name in sets:
            check_observation_set(name)
        object.__setattr__(self, "observe", sets[0] if len(sets) == 1 else sets)
        check_noise_std(self.noise_std)
        if not _is_int(self.chunks_per_episode) or self.chunks_per_episode < 0:
            raise InputError(f"chunks_per_episode must be an integer >= 0, got {self.chunks_per_episode!r}")
        if not 0.0 <= self.activation_maps <= 1.0:
            raise InputError(f"activation_maps is a share of episodes in [0, 1], got {self.activation_maps!r}")
        if not (np.isfinite(self.activation_noise_ms) and self.activation_noise_ms >= 0):
            raise InputError(f"activation_noise_ms must be a finite number >= 0, got {self.activation_noise_ms!r}")
        if not 0.0 <= self.ecg <= 1.0:
            raise InputError(f"ecg is a share of episodes in [0, 1], got {self.ecg!r}")
        if not (np.isfinite(self.ecg_noise) and 0 <= self.ecg_noise < 1):
            raise InputError(f"ecg_noise is a share of the largest lead value in [0, 1), got {self.ecg_noise!r}")

    @property
    def observe_sets(self) -> tuple[str, ...]:
        """The observation sets episodes draw from (one, or several drawn uniformly)."""
        return (self.observe,) if isinstance(self.observe, str) else self.observe

    @property
    def primary_observe(self) -> str:
        """The set evaluation observes by default: the first of :attr:`observe_sets`."""
        return self.observe_sets[0]

    @property
    def max_sites(self) -> int:
        """Most site rows one episode needs (largest context plus targets)."""
        return self.context[1] + self.targets


@dataclass(frozen=True)
class Episode:
    """One subject's context and target simulations, as tensors.

    ``K`` context, ``M`` targets, ``T`` frames, ``N`` mesh nodes. Sites are
    stimulation *node ids*; ``*_rows`` are the matching site rows of the
    subject's arrays (for reading ``activation`` etc. later).

    Attributes
    ----------
    context_sites, target_sites : LongTensor (K,), (M,)
    context_obs : FloatTensor (K, T, N)
        Observed context: ``u`` (+ noise) on observed nodes, 0 elsewhere.
    observed : BoolTensor (N,)
        Observation mask.
    context_recorded : BoolTensor (K, T, N) or None
        Where the context is recorded as activation-time maps: the values of ``context_obs`` the maps fix
        (:meth:`~learner.activation_maps.ApTemplate.fixed`); None: every frame of the observed nodes.
    context_u, target_u : FloatTensor (K, T, N), (M, T, N)
        Full ground truth (the loss covers all nodes).
    times : FloatTensor (T,)
        Frame times in time units.
    context_rows, target_rows : LongTensor (K,), (M,)
    context_ecg : FloatTensor (K, 12, T) or None
        The context also recorded as 12-lead ECGs (mV): the model then reads these (``context_obs`` stays, for
        the posterior of the training objective).
    lead_matrix, lead_density : FloatTensor (12, N), (N, 12) or None
        With ``context_ecg``: the mesh's healthy lead field (:class:`~learner.ecg.LeadField`).
    abnormal : BoolTensor (N,)
        The subject's scar core and border-zone nodes (:func:`tissue_truth`), what a tissue head is fitted to.
    cv : FloatTensor ()
        Its healthy tissue's conduction velocity in m/s (:func:`tissue_truth`).
    """

    subject_id: str
    mesh_id: str
    context_sites: torch.Tensor
    context_obs: torch.Tensor
    observed: torch.Tensor
    context_u: torch.Tensor
    target_sites: torch.Tensor
    target_u: torch.Tensor
    times: torch.Tensor
    context_rows: torch.Tensor | None = None
    target_rows: torch.Tensor | None = None
    context_ecg: torch.Tensor | None = None
    lead_matrix: torch.Tensor | None = None
    lead_density: torch.Tensor | None = None
    context_recorded: torch.Tensor | None = None
    abnormal: torch.Tensor | None = None
    cv: torch.Tensor | None = None

    @property
    def lead_field(self) -> LeadField | None:
        """The mesh's lead field, for an episode whose context is ECGs."""
        return None if self.lead_matrix is None else LeadField(self.lead_matrix, self.lead_density)

    def to(self, device: torch.device | str, non_blocking: bool = False) -> Episode:
        """A copy with every tensor moved to ``device``."""
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def _map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> Episode:
        values: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            values[f.name] = fn(value) if isinstance(value, torch.Tensor) else value
        return Episode(**values)

    def pin_memory(self) -> Episode:
        """A copy in pinned memory (``DataLoader(pin_memory=True)`` calls this)."""
        return self._map(lambda t: t.pin_memory())

    def __repr__(self) -> str:
        k, t, n = self.context_u.shape
        return (
            f"Episode(subject_id={self.subject_id!r}, mesh_id={self.mesh_id!r}, context={k}, "
            f"targets={self.target_u.shape[0]}, frames={t}, nodes={n}, observed={int(self.observed.sum())})"
        )


def _is_int(x: object) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


@dataclass(frozen=True)
class _SubjectMeta:
    """What an episode needs to know about a subject before reading ``u`` (small arrays only)."""

    subject_id: str
    mesh_id: str
    n_sites: int
    n_frames: int
    n_nodes: int
    chunk_sites: int
    stim_nodes: NDArray[np.int64]  # (site,) node id of each site row
    observed: tuple[NDArray[np.bool_], ...]  # (node,) mask of each observation set of the spec
    done: NDArray[np.bool_]  # (chunk,)

    @property
    def chunk_sizes(self) -> NDArray[np.int64]:
        """Number of site rows in each chunk (the last one may be short)."""
        starts = np.arange(0, self.n_sites, self.chunk_sites)
        return np.minimum(starts + self.chunk_sites, self.n_sites) - starts

    def chunks_of(self, rows: NDArray[np.int64]) -> NDArray[np.int64]:
        """Sorted unique chunk indices holding ``rows``."""
        return np.unique(rows // self.chunk_sites)


def _observed_mask(store: str, mesh_id: str, n_nodes: int, nodes: str) -> NDArray[np.bool_]:
    """The (node,) mask of the stored node set ``nodes`` of mesh ``mesh_id`` (``"all"``: every node)."""
    if check_observation_set(nodes) == "all":
        return np.ones(n_nodes, dtype=bool)
    return node_mask(n_nodes, read_index_set(store, mesh_id, nodes), nodes, mesh_id)


def _subject_meta(
    store: str,
    subject_id: str,
    observe: tuple[str, ...],
    mesh_cache: dict[str, tuple[NDArray, tuple[NDArray, ...]]] | None = None,
) -> _SubjectMeta:
    """Read and check a subject's metadata; raise :class:`InputError` for an unknown subject."""
    attrs = subject_attrs(store, subject_id)
    mesh_id, chunk_sites = attrs.get("mesh_id"), attrs.get("chunk_sites")
    if mesh_id is None or chunk_sites is None:
        raise SchemaError(f"subject {subject_id!r} in {store} lacks the mesh_id / chunk_sites attributes")
    n_sites, n_frames, n_nodes = subject_array(store, subject_id, "u").shape  # metadata only: no chunk is read
    done = done_flags(store, subject_id)
    cache = {} if mesh_cache is None else mesh_cache
    if mesh_id not in cache:
        masks = tuple(_observed_mask(store, mesh_id, n_nodes, name) for name in observe)
        cache[mesh_id] = (read_sites(store, mesh_id), masks)
    stim_nodes, observed = cache[mesh_id]
    if stim_nodes.shape[0] != n_sites or observed[0].shape[0] != n_nodes:
        raise SchemaError(
            f"subject {subject_id!r}: u has shape {(n_sites, n_frames, n_nodes)} but mesh {mesh_id!r} has "
            f"{stim_nodes.shape[0]} stimulation sites and {observed[0].shape[0]} nodes"
        )
    n_chunks = -(-n_sites // int(chunk_sites))
    if done.shape[0] != n_chunks:
        raise SchemaError(f"subject {subject_id!r}: {done.shape[0]} done flags for {n_chunks} chunks")
    return _SubjectMeta(
        subject_id,
        str(mesh_id),
        int(n_sites),
        int(n_frames),
        int(n_nodes),
        int(chunk_sites),
        stim_nodes,
        observed,
        done,
    )


def _refuse_missing(meta: _SubjectMeta, chunks: NDArray[np.int64] | None = None) -> None:
    """Raise :class:`SchemaError` if any of ``chunks`` (default: all) is not done."""
    chunks = np.arange(meta.done.shape[0]) if chunks is None else chunks
    missing = chunks[~meta.done[chunks]]
    if missing.size:
        raise SchemaError(
            f"subject {meta.subject_id!r} has unfinished chunk(s) {', '.join(map(str, missing.tolist()))} "
            f"(done == 0); finish the build (simgen build resumes) or leave the subject out"
        )


def _as_rows(rows: ArrayLike, name: str, n_sites: int) -> NDArray[np.int64]:
    arr = np.asarray(rows)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{name} must be a 1-D sequence of integer site rows, got {rows!r}")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n_sites):
        raise InputError(f"{name} {arr.tolist()} outside the subject's site rows [0, {n_sites})")
    if np.unique(arr).size != arr.size:
        raise InputError(f"{name} {arr.tolist()} has repeated site rows")
    return arr


def _build_episode(
    meta: _SubjectMeta,
    u: SubjectReader,
    times: NDArray[np.float64],
    context_rows: NDArray[np.int64],
    target_rows: NDArray[np.int64],
    observed: NDArray[np.bool_],
    noise_std: float,
    rng: np.random.Generator | None,
    as_map: tuple[ApTemplate, float] | None = None,
    as_ecg: tuple[LeadField, LeadField, float] | None = None,
    tissue: tuple[NDArray[np.bool_], float] | None = None,
) -> Episode:
    """An episode of the given rows; ``as_map`` = (template, noise in ms) records its context as activation maps,
    ``as_ecg`` = (the subject's lead field, the mesh's healthy one, noise share) as 12-lead ECGs; ``tissue`` is
    the subject's :func:`tissue_truth`."""
    k = context_rows.size
    data = u.rows("u", np.concatenate([context_rows, target_rows]))  # checked: done, checksums, fingerprint, finite
    context_u, target_u = data[:k], data[k:]
    ecg = {}
    if as_ecg is not None:
        subject_leads, healthy, noise = as_ecg
        ecg = {
            "context_ecg": recorded_ecg(torch.from_numpy(context_u), subject_leads, noise, rng),
            "lead_matrix": healthy.matrix,
            "lead_density": healthy.density,
        }
    recorded = None
    if as_map is None:
        obs = observe(context_u, observed, noise_std, rng)
    else:
        obs, recorded = recorded_map(context_u, times, observed, *as_map, rng)
        recorded = torch.from_numpy(recorded)
    return Episode(
        subject_id=meta.subject_id,
        mesh_id=meta.mesh_id,
        context_sites=torch.from_numpy(meta.stim_nodes[context_rows]),
        context_obs=torch.from_numpy(obs),
        observed=torch.from_numpy(observed.copy()),
        context_u=torch.from_numpy(context_u),
        target_sites=torch.from_numpy(meta.stim_nodes[target_rows]),
        target_u=torch.from_numpy(target_u),
        times=torch.from_numpy(np.asarray(times, dtype=np.float32)),
        context_rows=torch.from_numpy(context_rows),
        target_rows=torch.from_numpy(target_rows),
        context_recorded=recorded,
        abnormal=None if tissue is None else torch.from_numpy(tissue[0]),
        cv=None if tissue is None else torch.tensor(tissue[1], dtype=torch.float32),
        **ecg,
    )


@cache
def tissue_truth(store: str, subject_id: str) -> tuple[NDArray[np.bool_], float]:
    """A subject's abnormal nodes (scar core or border zone, :data:`~shared.tissue.ABNORMAL_LABELS`) and its
    healthy tissue's conduction velocity in m/s (:func:`~shared.tissue.healthy_speed`; NaN under a cell model
    other than Aliev-Panfilov, whose closed form it is); cached per process."""
    label = read_tissue(store, subject_id).label
    healthy = subject_attrs(store, subject_id)["tissue"].get("healthy") or {}
    solver = read_solver_settings(store)
    k = (solver.get("model") or {"k": 8.0}).get("k")
    tissue = TissueSpec(healthy=Material(**healthy))
    cv = float("nan") if k is None else healthy_speed(tissue, float(solver["diffusivity"]), float(k))
    return np.isin(label, ABNORMAL_LABELS), cv


def recorded_ecg(u: torch.Tensor, lead_field: LeadField, noise: float, rng: np.random.Generator | None) -> torch.Tensor:
    """The 12-lead ECGs (K, 12, T) of simulations ``u`` (K, T, N) with Gaussian noise of ``noise`` times the
    set's largest lead value."""
    ecg = lead_field.ecg(u.to(torch.float32))
    if noise > 0:
        if rng is None:
            raise InputError("ECG noise needs a random generator (rng)")
        scale = noise * float(ecg.abs().max())
        ecg = ecg + torch.from_numpy(rng.normal(0.0, scale, size=tuple(ecg.shape)).astype(np.float32))
    return ecg


@cache
def subject_lead_fields(store: str, subject_id: str, mesh_id: str) -> tuple[LeadField, LeadField]:
    """A subject's lead field (its tissue weighing the conductivity: what its ECGs are) and its mesh's healthy
    one (what a personalisation knows), through the standard electrodes of the stored mesh; cached per process."""
    mesh = read_mesh(store, mesh_id)
    return LeadField.of_mesh(mesh, scale=read_tissue(store, subject_id).D), _healthy_lead_field(store, mesh_id)


@cache
def _healthy_lead_field(store: str, mesh_id: str) -> LeadField:
    return LeadField.of_mesh(read_mesh(store, mesh_id))


def recorded_map(
    u: NDArray, times: NDArray, observed: NDArray[np.bool_], template: ApTemplate, noise_ms: float, rng
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Simulations ``u`` (K, T, N) recorded as activation-time maps at the ``observed`` nodes (noise ``noise_ms``
    ms, :func:`~shared.capture.mapped_activation`) and read back as potentials through ``template`` (0 elsewhere),
    with the values the maps fix (:meth:`~learner.activation_maps.ApTemplate.fixed`, at observed nodes)."""
    first = np.stack([activation_times(sequence, times) for sequence in u])
    mapped = mapped_activation(first, u.max(axis=1), noise_ms / MS_PER_TIME_UNIT, rng)
    return template.render(mapped, times) * observed, template.fixed(mapped, times) & observed


def load_episode(
    store: str | Path,
    subject_id: str,
    context_sites: ArrayLike,
    target_sites: ArrayLike,
    observe: str = "surface",
    noise_std: float = 0.0,
    rng: np.random.Generator | None = None,
    ecg_noise: float | None = None,
) -> Episode:
    """One episode with fixed sites (evaluation; the dataset draws its own).

    Parameters
    ----------
    store
        Dataset store path.
    subject_id
        Subject to read.
    context_sites, target_sites
        Site *rows* of the subject (indices into its ``u`` site axis, ``0 ..
        n_sites-1``), disjoint; ``target_sites`` may be empty. The episode's
        ``*_sites`` hold the matching stimulation node ids.
    observe
        Observation set (one of :data:`~shared.observation.OBSERVATION_SETS`).
    noise_std, rng
        Observation noise and its generator (required when ``noise_std > 0``).
    ecg_noise
        Record the context as 12-lead ECGs with this noise share instead (:func:`recorded_ecg`; None: don't).

    Raises
    ------
    SchemaError
        Wrong schema version, or a requested row lies in an unfinished chunk.
    InputError
        Unknown subject or observation set, bad or overlapping rows.
    """
    store = str(store)
    check_store(store)
    meta = _subject_meta(store, subject_id, (observe,))
    context_rows = _as_rows(context_sites, "context sites", meta.n_sites)
    target_rows = _as_rows(target_sites, "target sites", meta.n_sites)
    if context_rows.size < 1:
        raise InputError("context size must be >= 1, got no context sites")
    overlap = np.intersect1d(context_rows, target_rows)
    if overlap.size:
        raise InputError(f"target sites must not include context sites; both have rows {overlap.tolist()}")
    check_noise_std(noise_std)
    # Only the chunks actually read must be finished: evaluation may run on a partial store.
    _refuse_missing(meta, meta.chunks_of(np.concatenate([context_rows, target_rows])))
    u, times = SubjectReader(store, subject_id), read_times(store, subject_id)
    as_ecg = None if ecg_noise is None else (*subject_lead_fields(store, subject_id, meta.mesh_id), ecg_noise)
    truth = tissue_truth(store, subject_id)
    return _build_episode(
        meta, u, times, context_rows, target_rows, meta.observed[0], noise_std, rng, None, as_ecg, truth
    )


class EpisodeDataset(IterableDataset):
    """Stream of training episodes over a list of subjects.

    Each epoch visits the subjects in the order
    ``np.random.default_rng([seed, epoch]).permutation(len(subjects))``
    (over several training processes: grouped by cost, :meth:`order`),
    ``episodes_per_subject`` rounds over that order; DataLoader workers take
    interleaved slices of it. Episode ``k`` of ``subjects[i]`` in ``epoch``
    draws everything from ``np.random.default_rng([seed, epoch, i, k])``.
    Use ``DataLoader(dataset, batch_size=None, num_workers=...)`` and call
    :meth:`set_epoch` before each epoch; the epoch lives in shared memory, so
    persistent loader workers (``persistent_workers=True``) see it too.

    Only the store path and small metadata (site node ids, observation masks,
    done flags) live in the object, so it pickles to workers; each worker
    opens the store itself.

    Raises
    ------
    SchemaError
        Wrong schema version; a subject with an unfinished chunk.
    InputError
        No or duplicate or unknown subjects, an episode needing more sites than
        a subject has, an empty observation set, a negative seed or epoch.
    """

    def __init__(
        self,
        store: str | Path,
        subjects: Sequence[str],
        spec: EpisodeSpec,
        seed: int,
        epoch: int = 0,
        episodes_per_subject: int = 1,
        template: ApTemplate | None = None,
    ) -> None:
        super().__init__()
        if isinstance(subjects, str):
            raise InputError(f"subjects must be a list of subject ids, not the string {subjects!r}")
        self.store = str(store)
        self.subjects = list(subjects)
        self.spec = spec
        if not isinstance(spec, EpisodeSpec):
            raise InputError(f"spec must be an EpisodeSpec, got {type(spec).__name__}")
        if not _is_int(seed) or seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self._epoch = torch.zeros((), dtype=torch.int64).share_memory_()  # seen by forked loader workers
        self.set_epoch(epoch)
        self.rank, self.world_size = 0, 1
        if not _is_int(episodes_per_subject) or episodes_per_subject < 1:
            raise InputError(f"episodes_per_subject must be an integer >= 1, got {episodes_per_subject!r}")
        self.episodes_per_subject = int(episodes_per_subject)
        if not self.subjects:
            raise InputError("EpisodeDataset needs at least one subject")
        if len(set(self.subjects)) != len(self.subjects):
            raise InputError(f"duplicate subjects in {self.subjects}")

        attrs = check_store(self.store)
        self._version = int(attrs["schema_version"])
        known = set(checked_subject_ids(self.store, attrs))
        unknown = [s for s in self.subjects if s not in known]
        if unknown:
            raise InputError(f"unknown subject(s) {', '.join(unknown)} in store {self.store}")
        if spec.activation_maps and template is None:
            template = template_from_store(self.store, self.subjects)
        self.template = template
        mesh_cache: dict[str, tuple[NDArray, tuple[NDArray, ...]]] = {}
        self._meta = [_subject_meta(self.store, s, spec.observe_sets, mesh_cache) for s in self.subjects]
        for meta in self._meta:
            _refuse_missing(meta)
            available = meta.n_sites
            if spec.chunks_per_episode:
                # Worst case: the drawn chunks are the smallest ones (the last chunk may be short).
                available = int(np.sort(meta.chunk_sizes)[: spec.chunks_per_episode].sum())
            if spec.max_sites > available:
                where = (
                    f"{spec.chunks_per_episode} chunk(s) of {meta.chunk_sites} sites hold as few as {available}"
                    if spec.chunks_per_episode
                    else f"it has {available} sites"
                )
                raise InputError(
                    f"subject {meta.subject_id!r}: an episode needs up to {spec.context[1]} context + "
                    f"{spec.targets} targets = {spec.max_sites} sites, but {where}"
                )

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose episodes the next iteration yields."""
        if not _is_int(epoch) or epoch < 0:
            raise InputError(f"epoch must be a non-negative integer, got {epoch!r}")
        self._epoch.fill_(int(epoch))

    @property
    def epoch(self) -> int:
        """The epoch whose episodes the next iteration yields."""
        return int(self._epoch)

    def __len__(self) -> int:
        return len(self.subjects) * self.episodes_per_subject

    def order(self) -> list[int]:
        """Subject indices in this epoch's visiting order (before sharding over processes and workers).

        A permutation drawn from ``(seed, epoch)``. Sharded over ``W > 1``
        training processes (:meth:`shard`), the same subjects are grouped into
        steps of ``W`` episodes of similar :meth:`cost` (neighbours in cost
        order), the full steps visited in an order drawn from ``(seed, epoch)``
        and a short step last: DDP synchronises every step, so a process whose
        episode is cheaper waits for the others.
        """
        perm = np.random.default_rng([self.seed, self.epoch]).permutation(len(self.subjects))
        w = self.world_size
        if w == 1:
            return perm.tolist()
        ranked = perm[np.argsort([self.cost(i) for i in perm], kind="stable")]
        full = len(ranked) // w * w
        steps = ranked[:full].reshape(-1, w)
        steps = steps[np.random.default_rng([self.seed, self.epoch, w]).permutation(len(steps))]
        return [*steps.ravel().tolist(), *ranked[full:].tolist()]

    def cost(self, subject: int | str, k: int = 0) -> int:
        """Relative training cost of episode ``k`` of a subject: mesh nodes x sequences (context + targets)."""
        i = self._index(subject)
        (context, targets), _ = self._draw(i, k)
        return self._meta[i].n_nodes * (len(context) + len(targets))

    def draw_sites(self, subject: int | str, k: int = 0) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Site rows ``(context, targets)`` of episode ``k`` of a subject in the current epoch."""
        rows, _ = self._draw(self._index(subject), k)
        return rows

    def episode(self, subject: int | str, k: int = 0) -> Episode:
        """Episode ``k`` of a subject (index into ``subjects`` or id) in the current epoch."""
        return self._episode(self._index(subject), k, {})

    def shard(self, rank: int, world_size: int) -> None:
        """Iterate only training process ``rank``'s share of each epoch: order positions ``i * world_size + rank``.

        Every rank gets ``ceil(S / world_size)`` episodes per round, so all take
        the same number of steps; positions past the end wrap around to the
        start of the order (padding that a trainer weights 0).
        """
        if not (_is_int(rank) and _is_int(world_size) and 0 <= rank < world_size):
            raise InputError(f"shard: need 0 <= rank < world_size, got rank={rank!r}, world_size={world_size!r}")
        self.rank, self.world_size = int(rank), int(world_size)

    def __iter__(self) -> Iterator[Episode]:
        info = get_worker_info()
        worker, n_workers = (0, 1) if info is None else (info.id, info.num_workers)
        order = self.order()
        padded = -(-len(order) // self.world_size) * self.world_size
        mine = [order[p % len(order)] for p in range(self.rank, padded, self.world_size)][worker::n_workers]
        # Verified readers (metadata only) opened in this process, never stored on self: self must pickle.
        handles: dict[int, tuple[SubjectReader, NDArray[np.float64]]] = {}
        for k in range(self.episodes_per_subject):
            for i in mine:
                yield self._episode(i, k, handles)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(store={self.store!r}, subjects={len(self.subjects)}, seed={self.seed}, "
            f"epoch={self.epoch}, episodes_per_subject={self.episodes_per_subject}, spec={self.spec!r})"
        )

    def _index(self, subject: int | str) -> int:
        if isinstance(subject, str):
            if subject not in self.subjects:
                raise InputError(f"subject {subject!r} is not in this dataset")
            return self.subjects.index(subject)
        if not _is_int(subject) or not 0 <= subject < len(self.subjects):
            raise InputError(f"subject index {subject!r} outside [0, {len(self.subjects)})")
        return int(subject)

    def _draw(self, i: int, k: int) -> tuple[tuple[NDArray[np.int64], NDArray[np.int64]], np.random.Generator]:
        if not _is_int(k) or not 0 <= k < self.episodes_per_subject:
            raise InputError(f"episode index k={k!r} outside [0, {self.episodes_per_subject})")
        meta, spec = self._meta[i], self.spec
        rng = np.random.default_rng([self.seed, self.epoch, i, int(k)])
        n_context = int(rng.integers(spec.context[0], spec.context[1] + 1))
        if spec.chunks_per_episode:
            n_chunks = meta.done.shape[0]
            chunks = rng.choice(n_chunks, size=min(spec.chunks_per_episode, n_chunks), replace=False)
            pool = np.concatenate(
                [np.arange(c * meta.chunk_sites, min((c + 1) * meta.chunk_sites, meta.n_sites)) for c in chunks]
            )
        else:
            pool = np.arange(meta.n_sites)
        rows = rng.choice(pool, size=n_context + spec.targets, replace=False).astype(np.int64)
        return (rows[:n_context], rows[n_context:]), rng

    def _episode(self, i: int, k: int, handles: dict[int, tuple[SubjectReader, NDArray[np.float64]]]) -> Episode:
        (context_rows, target_rows), rng = self._draw(i, k)
        if i not in handles:
            reader = SubjectReader(self.store, self.subjects[i], self._version)
            handles[i] = (reader, read_times(self.store, self.subjects[i]))
        u, times = handles[i]
        masks = self._meta[i].observed  # one set, or draw one (after the sites: one-set episodes stay as they were)
        observed = masks[0] if len(masks) == 1 else masks[int(rng.integers(len(masks)))]
        spec = self.spec
        as_map = None
        if spec.activation_maps and rng.random() < spec.activation_maps:  # drawn only then: other episodes unchanged
            as_map = (self.template, spec.activation_noise_ms)
        as_ecg = None
        if spec.ecg and rng.random() < spec.ecg:
            meta = self._meta[i]
            as_ecg = (*subject_lead_fields(self.store, meta.subject_id, meta.mesh_id), spec.ecg_noise)
        truth = tissue_truth(self.store, self.subjects[i])
        return _build_episode(
            self._meta[i], u, times, context_rows, target_rows, observed, spec.noise_std, rng, as_map, as_ecg, truth
        )
