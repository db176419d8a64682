"""A tissue prior: each draw a whole tissue setting, drawn from distributions that a build spec states.

A spec's ``[tissue_prior]`` table (:class:`TissuePrior`) stands for ``count``
tissue settings named ``<name>-000``, ``<name>-001``, ...; like named settings,
every mesh is simulated under every draw, so a split can hold out anatomies and
draws apart. Draw ``i`` comes from its own generator, seeded by ``(seed, i)``:
raising ``count`` adds draws and keeps the earlier ones. What one draw holds:

- healthy excitability ``a`` (uniform over ``a``) and diffusivity scale ``D``
  (log-uniform over ``D``), or a conduction velocity (uniform over ``cv``, m/s)
  turned into ``D`` on a strip (:func:`simgen.tissue.tune.diffusivity_for_speed`);
- ``apd_scale`` (uniform over ``apd_scale``; unset: the model's own duration);
- a number of scars, uniform in ``scars`` (inclusive). Each is an ellipsoid in a
  ventricle's wall (``placement = "wall"``: in the RV with probability
  ``rv_share``, at a uniform height in 0.1-0.9 and angle, the RV's within 60 degrees
  of the septal direction; with drawn ``radius``, ``elongation`` and
  ``transmural`` extent; optional, so LVs leave RV scars out) or 1 to
  ``segments[1]`` adjacent AHA segments (``"segments"``; ``"both"``: either,
  evenly), with a drawn ``border_width`` and core and border materials drawn from
  ``core_a``, ``core_D``, ``border_a`` and ``border_D``;
- diffuse patchy fibrosis with probability ``fibrosis``, of drawn ``fibrosis_density``
  and ``fibrosis_patch`` size (mm);
- ``anisotropy`` (log-uniform; meshes with fibres only).

Ranges are ``[low, high]`` (equal ends: a fixed value). :func:`draw_tissues`
returns plain :class:`~shared.tissue.TissueSpec` objects, so a store records each
draw's parameters in its spec and its subjects' ``tissue`` attribute, and its
per-node fields as every subject's ``a``, ``D`` and ``label``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from shared.errors import ConfigError, InputError
from shared.tissue import (
    A_RANGE,
    APD_SCALE_RANGE,
    D_RANGE,
    FibrosisSpec,
    Material,
    ScarSpec,
    TissueSpec,
)
from simgen.solver.simulate import SolverConfig
from simgen.tissue.defaults import SCAR_CORE

__all__ = ["TissuePrior", "draw_tissues", "MAX_DRAWS", "SEGMENT_NEIGHBOURS"]

#: Most draws one prior may stand for (names ``<name>-000`` .. ``<name>-999``).
MAX_DRAWS = 1000

Range = tuple[float, float]


def _segment_neighbours() -> dict[int, tuple[int, ...]]:
    """Adjacent AHA segments: around each ring, basal to mid by sector, mid to the apical sector it meets,
    and the apical ring to the apex."""
    rings = (range(1, 7), range(7, 13), range(13, 17))
    edges = {(r[i], r[(i + 1) % len(r)]) for r in rings for i in range(len(r))}
    edges |= {(s, s + 6) for s in range(1, 7)} | {(s, 17) for s in range(13, 17)}
    edges |= {(7, 13), (8, 14), (9, 14), (10, 15), (11, 16), (12, 16)}
    neighbours: dict[int, set[int]] = {s: set() for s in range(1, 18)}
    for a, b in edges:
        neighbours[a].add(b)
        neighbours[b].add(a)
    return {s: tuple(sorted(n)) for s, n in neighbours.items()}


#: AHA segments next to each segment (symmetric).
SEGMENT_NEIGHBOURS: dict[int, tuple[int, ...]] = _segment_neighbours()

#: Heights (0 apex, 1 base) a wall scar's centre is drawn in.
WALL_HEIGHTS = (0.1, 0.9)
#: Largest angle (degrees) from the septal direction of an RV scar's centre.
RV_ANGLE = 60.0


def _check_range(value: Range | None, name: str, lo: float, hi: float) -> None:
    if value is None:
        return
    if len(value) != 2 or not all(math.isfinite(v) for v in value) or value[0] > value[1]:
        raise ConfigError(f"[tissue_prior] {name} must be [low, high] with low <= high, got {list(value)}")
    if value[0] < lo or value[1] > hi:
        raise ConfigError(f"[tissue_prior] {name} = {list(value)} outside the admissible range [{lo:g}, {hi:g}]")


@dataclass(frozen=True)
class TissuePrior:
    """The distributions of a spec's ``[tissue_prior]`` table (module docstring); every key is optional."""

    count: int = 16
    seed: int = 0
    name: str = "draw"
    a: Range = (0.12, 0.2)
    D: Range | None = None
    cv: Range | None = None
    apd_scale: Range | None = None
    scars: tuple[int, int] = (0, 3)
    placement: Literal["wall", "segments", "both"] = "wall"
    rv_share: float = 0.25
    radius: Range = (8.0, 20.0)
    elongation: Range = (1.0, 2.0)
    transmural: Range = (0.4, 1.0)
    segments: tuple[int, int] = (1, 2)
    border_width: Range = (2.0, 8.0)
    core_a: Range = (SCAR_CORE.a, SCAR_CORE.a)
    core_D: Range = (0.02, 0.2)
    border_a: Range = (0.22, 0.35)
    border_D: Range = (0.3, 0.8)
    fibrosis: float = 0.0
    fibrosis_density: Range = (0.05, 0.3)
    fibrosis_patch: Range = (2.0, 8.0)
    anisotropy: Range | None = None

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, int) or not 1 <= self.count <= MAX_DRAWS:
            raise ConfigError(f"[tissue_prior] count must be an integer in 1..{MAX_DRAWS}, got {self.count!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"[tissue_prior] seed must be an integer >= 0, got {self.seed!r}")
        if self.placement not in ("wall", "segments", "both"):
            raise ConfigError(f"[tissue_prior] placement {self.placement!r} is not one of ['wall', 'segments', 'both']")
        if self.D is not None and self.cv is not None:
            raise ConfigError("[tissue_prior] give D (diffusivity scale) or cv (m/s), not both")
        if self.D is None and self.cv is None:
            object.__setattr__(self, "D", (0.3, 3.0))
        for name, lo, hi in (
            ("a", *A_RANGE),
            ("D", 1e-3, D_RANGE[1]),
            ("cv", 0.05, 5.0),
            ("apd_scale", *APD_SCALE_RANGE),
            ("radius", 1e-3, 200.0),
            ("elongation", 0.1, 10.0),
            ("transmural", 1e-3, 1.0),
            ("border_width", 0.0, 50.0),
            ("core_a", *A_RANGE),
            ("core_D", *D_RANGE),
            ("border_a", *A_RANGE),
            ("border_D", *D_RANGE),
            ("fibrosis_density", 0.0, 1.0),
            ("fibrosis_patch", 0.5, 100.0),
            ("anisotropy", 1.0, 100.0),
        ):
            _check_range(getattr(self, name), name, lo, hi)
        for name, lo, hi in (("scars", 0, 3), ("segments", 1, 2)):
            low, high = getattr(self, name)
            if not lo <= low <= high <= hi:
                raise ConfigError(f"[tissue_prior] {name} must be [low, high] with {lo} <= low <= high <= {hi}")
        for name in ("rv_share", "fibrosis"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ConfigError(f"[tissue_prior] {name} must be a probability in [0, 1], got {value!r}")
        if self.a[1] >= self.border_a[0] and self.scars[1] > 0:
            raise ConfigError(
                f"[tissue_prior] healthy a = {list(self.a)} reaches the border zone's {list(self.border_a)}: "
                "keep healthy tissue more excitable than the border zone"
            )

    @property
    def names(self) -> list[str]:
        """The draws' setting names."""
        return [f"{self.name}-{i:03d}" for i in range(self.count)]


def _uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(rng.uniform(*bounds)) if bounds[0] < bounds[1] else float(bounds[0])


def _log_uniform(rng: np.random.Generator, bounds: Range) -> float:
    return float(np.exp(rng.uniform(*np.log(bounds)))) if bounds[0] < bounds[1] else float(bounds[0])


def _round(value: float) -> float:
    """Drawn values as a spec keeps them: 6 significant digits, so a spec's text shows them whole."""
    return float(f"{value:.6g}")


def _material(rng: np.random.Generator, a: Range, D: Range) -> Material:
    return Material(a=_round(_uniform(rng, a)), D=_round(_uniform(rng, D)))


def _scar(prior: TissuePrior, rng: np.random.Generator) -> ScarSpec:
    wall = prior.placement == "wall" or (prior.placement == "both" and rng.random() < 0.5)
    core = _material(rng, prior.core_a, prior.core_D)
    border = _material(rng, prior.border_a, prior.border_D)
    width = _round(_uniform(rng, prior.border_width))
    if not wall:
        first = int(rng.integers(1, 18))
        chosen = [first]
        if int(rng.integers(prior.segments[0], prior.segments[1] + 1)) == 2:
            chosen.append(int(rng.choice(SEGMENT_NEIGHBOURS[first])))
        return ScarSpec(region="segments", segments=tuple(sorted(chosen)), core=core, border=border, border_width=width)
    rv = rng.random() < prior.rv_share
    angle = rng.uniform(-RV_ANGLE, RV_ANGLE) if rv else rng.uniform(-180.0, 180.0)
    return ScarSpec(
        region="wall",
        ventricle="rv" if rv else "lv",
        height=_round(rng.uniform(*WALL_HEIGHTS)),
        angle=_round(angle),
        radius=_round(_uniform(rng, prior.radius)),
        elongation=_round(_uniform(rng, prior.elongation)),
        transmural=_round(_uniform(rng, prior.transmural)),
        core=core,
        border=border,
        border_width=width,
        optional=True if rv else None,
    )


def _draw(prior: TissuePrior, index: int, solver: SolverConfig) -> TissueSpec:
    rng = np.random.default_rng((prior.seed, index))
    a = _round(_uniform(rng, prior.a))
    apd = None if prior.apd_scale is None else _round(_uniform(rng, prior.apd_scale))
    if prior.cv is not None:
        from simgen.tissue.tune import diffusivity_for_speed  # a strip simulation: only where asked for

        D = diffusivity_for_speed(_uniform(rng, prior.cv), a, solver, apd)
        if not D_RANGE[0] < D <= D_RANGE[1]:
            raise ConfigError(
                f"[tissue_prior] cv = {list(prior.cv)} m/s needs a diffusivity scale D = {D:.3g} at a = {a:g}, "
                f"outside {D_RANGE}: narrow cv or raise [solver] diffusivity"
            )
    else:
        D = _log_uniform(rng, prior.D)
    scars = tuple(_scar(prior, rng) for _ in range(int(rng.integers(prior.scars[0], prior.scars[1] + 1))))
    fibrosis = None
    if rng.random() < prior.fibrosis:
        fibrosis = FibrosisSpec(
            density=_round(_uniform(rng, prior.fibrosis_density)),
            patch=_round(_uniform(rng, prior.fibrosis_patch)),
            seed=int(rng.integers(2**31)),
        )
    anisotropy = None if prior.anisotropy is None else _round(_log_uniform(rng, prior.anisotropy))
    return TissueSpec(
        name=prior.names[index],
        healthy=Material(a=a, D=_round(D)),
        scars=scars,
        anisotropy=anisotropy,
        apd_scale=apd,
        fibrosis=fibrosis,
    )


def draw_tissues(prior: TissuePrior, solver: SolverConfig | None = None) -> list[TissueSpec]:
    """The ``prior.count`` tissue settings of ``prior`` (``solver``: the cell model and diffusivity a ``cv``
    range is measured under; unset: the defaults). Deterministic: the same prior gives the same draws."""
    solver = solver or SolverConfig()
    try:
        return [_draw(prior, i, solver) for i in range(prior.count)]
    except InputError as exc:
        raise type(exc)(f"[tissue_prior]: {exc}") from None
