"""Seeded random anatomies: shape parameters drawn from their ranges, and their meshes.

Sample ``i`` of ``(family, seed)`` uses its own generator
``default_rng([seed, i])``, so it does not depend on ``count``, and draws
every ranged parameter uniformly within its range (:mod:`simgen.meshes.shapes`)
in declaration order, then the perturbation seed. Fixed parameters replace
their draws afterwards, so fixing one parameter leaves the others' values as
they were.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np

from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.shapes import SHAPES, LVShape, parameter_ranges, shape_from_params

__all__ = ["Anatomy", "sample_shapes", "sample_anatomies"]


class Anatomy(NamedTuple):
    """One sampled anatomy: its complete shape parameters and its mesh."""

    params: dict[str, float | int]
    mesh: Mesh


def sample_shapes(family: str, count: int, seed: int, fixed: dict[str, Any] | None = None) -> list[LVShape]:
    """``count`` random shapes of ``family`` (``"lv"``, ``"biv"``); ``fixed`` parameters are not drawn."""
    fixed = dict(fixed or {})
    shape_from_params(family, fixed)  # refuse an unknown family or bad fixed parameters before drawing
    ranges = parameter_ranges(SHAPES[family])
    shapes = []
    for i in range(count):
        rng = np.random.default_rng([seed, i])
        drawn: dict[str, Any] = {name: float(rng.uniform(r.lo, r.hi)) for name, r in ranges.items()}
        drawn["bump_seed"] = int(rng.integers(2**31))
        shapes.append(shape_from_params(family, {**drawn, **fixed}))
    return shapes


def sample_anatomies(
    family: str,
    count: int,
    seed: int,
    nodes: int = 2000,
    kind: Literal["tetra", "triangle"] = "tetra",
    fixed: dict[str, Any] | None = None,
) -> list[Anatomy]:
    """``count`` random anatomies of ``family`` with about ``nodes`` nodes each, named ``<family>-<i:03d>``."""
    anatomies = []
    for i, shape in enumerate(sample_shapes(family, count, seed, fixed)):
        params = shape.params()
        anatomies.append(Anatomy(params, get_mesh(family, nodes, kind, f"{family}-{i:03d}", shape_params=params)))
    return anatomies
