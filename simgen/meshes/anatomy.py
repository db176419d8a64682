"""Seeded random anatomies: shape parameters drawn from their ranges, and their meshes.

Sample ``i`` of ``(family, seed)`` uses its own generator
``default_rng([seed, i])``, so it does not depend on ``count``, and draws
every ranged parameter uniformly within its default sampling interval
(:attr:`simgen.meshes.shapes.Range.draw`, or the interval ``ranges`` gives
it) in declaration order, then the perturbation seed. Fixed parameters replace
their draws afterwards, so fixing one parameter leaves the others' values as
they were.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np

from shared.errors import ConfigError, MeshError
from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.shapes import SHAPES, LVShape, parameter_ranges, shape_from_params

__all__ = ["Anatomy", "sample_shapes", "sample_anatomies", "sampling_intervals"]


class Anatomy(NamedTuple):
    """One sampled anatomy: its complete shape parameters and its mesh."""

    params: dict[str, float | int]
    mesh: Mesh


def sample_shapes(
    family: str,
    count: int,
    seed: int,
    fixed: dict[str, Any] | None = None,
    ranges: dict[str, Any] | None = None,
) -> list[LVShape]:
    """``count`` random shapes of ``family`` (``"lv"``, ``"biv"``).

    ``fixed`` parameters are not drawn; ``ranges`` maps parameters to the
    ``(lo, hi)`` interval to draw them from instead of their default one
    (:func:`sampling_intervals`).
    """
    fixed = dict(fixed or {})
    shape_from_params(family, fixed)  # refuse an unknown family or bad fixed parameters before drawing
    intervals = sampling_intervals(family, ranges)
    shapes = []
    for i in range(count):
        rng = np.random.default_rng([seed, i])
        drawn: dict[str, Any] = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in intervals.items()}
        drawn["bump_seed"] = int(rng.integers(2**31))
        shapes.append(shape_from_params(family, {**drawn, **fixed}))
    return shapes


def sampling_intervals(family: str, ranges: dict[str, Any] | None = None) -> dict[str, tuple[float, float]]:
    """Each ranged parameter's sampling interval: its default, or the one ``ranges`` gives.

    An interval must be two numbers ``lo <= hi`` within the parameter's
    admissible range (else :class:`MeshError`); unknown parameters and
    malformed intervals raise :class:`ConfigError`.
    """
    admissible = parameter_ranges(SHAPES[family])
    ranges = dict(ranges or {})
    unknown = sorted(set(ranges) - set(admissible))
    if unknown:
        raise ConfigError(
            f"shape_ranges: unknown parameter(s) {', '.join(unknown)}; ranged ones are {', '.join(admissible)}"
        )
    intervals = {name: r.draw for name, r in admissible.items()}
    for name, value in ranges.items():
        r = admissible[name]
        if (
            not isinstance(value, (list, tuple))
            or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        ):
            raise ConfigError(f"shape_ranges: {name} must be [lo, hi], two numbers, got {value!r}")
        lo, hi = float(value[0]), float(value[1])
        if not (r.lo <= lo <= hi <= r.hi):
            raise MeshError(
                f"shape_ranges: {name} = [{lo:g}, {hi:g}] must satisfy lo <= hi within the admissible "
                f"range {r.lo:g}..{r.hi:g}{' ' + r.unit if r.unit else ''}"
            )
        intervals[name] = (lo, hi)
    return intervals


def sample_anatomies(
    family: str,
    count: int,
    seed: int,
    nodes: int = 2000,
    kind: Literal["tetra", "triangle"] = "tetra",
    fixed: dict[str, Any] | None = None,
    ranges: dict[str, Any] | None = None,
) -> list[Anatomy]:
    """``count`` random anatomies of ``family`` with about ``nodes`` nodes each, named ``<family>-<i:03d>``."""
    anatomies = []
    for i, shape in enumerate(sample_shapes(family, count, seed, fixed, ranges)):
        params = shape.params()
        anatomies.append(Anatomy(params, get_mesh(family, nodes, kind, f"{family}-{i:03d}", shape_params=params)))
    return anatomies
