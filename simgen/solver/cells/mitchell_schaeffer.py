"""The Mitchell-Schaeffer cell model (Mitchell & Schaeffer 2003), on the same node fields as Aliev-Panfilov.

.. math::

    \\partial_t u = \\nabla\\cdot(D\\nabla u) + \\frac{h u^2 (1-u)}{\\tau_{in}} - \\frac{u}{\\tau_{out}}, \\qquad
    \\partial_t h = \\begin{cases} (1-h)/\\tau_{open} & u < v_{gate} \\\\ -h/\\tau_{close} & u \\ge v_{gate}\\end{cases}

``u`` is the normalised membrane potential (rest 0, peak 1; ``V = 100 u - 80`` mV as for
Aliev-Panfilov), ``h`` the gate of the inward current (1 at rest); the solver's second state
variable ``v`` holds ``h``. The tissue's excitability ``a`` is the excitation threshold of rested
tissue in both models: here ``tau_out = tau_in / (a (1 - a))``, so that ``u (1-u) h / tau_in - 1/tau_out``
vanishes at ``u = a`` when ``h = 1``. The published ``tau_out = 6 ms`` (with ``tau_in = 0.3 ms``) is
``a = 0.053``; the healthy ``a = 0.15`` gives 2.35 ms, and a scar core's ``a = 0.5`` is not excitable
(no upper rest state). Closed forms (rested tissue, ``tau_in`` much shorter than the other times):
the planar front speed ``sqrt(D / (2 tau_in)) (1 - 3a)`` and the action potential duration
``tau_close ln(1 / (4 a (1 - a)))`` (the time ``h`` takes to fall to ``4 tau_in / tau_out``).
Times are given in ms and run in the solver's time unit (12.9 ms).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, Literal, NamedTuple

import numpy as np

from shared.errors import InputError
from shared.units import MS_PER_TIME_UNIT
from simgen.solver.cells.ops import fma, register_rates, select

__all__ = ["MSParams", "MSConstants"]


class MSConstants(NamedTuple):
    """The kernels' constants (float32): 1, the rates ``1/tau_in``, ``1/tau_open``, ``1/tau_close``
    (per time unit), and ``v_gate``."""

    one: np.float32
    r_in: np.float32
    r_open: np.float32
    r_close: np.float32
    v_gate: np.float32


def rates(u, v, lap, a, c):
    """``(du/dt, dh/dt)`` with the diffusion term ``lap`` (``None``: none; ``v`` is the gate ``h``)."""
    one, r_in, r_open, r_close, v_gate = c
    current = fma(v * u, one - u, -(a * (one - a)))  # h u (1 - u) - tau_in / tau_out
    du = r_in * u * current if lap is None else fma(r_in * u, current, lap)
    return du, select(u < v_gate, r_open * (one - v), -(r_close * v))


register_rates(MSConstants, rates)


@dataclass(frozen=True)
class MSParams:
    """Mitchell-Schaeffer time constants in ms (the published defaults) and the gate threshold.

    ``cell`` names the model in a spec's ``[solver.model]`` table (an Aliev-Panfilov table may leave it out).
    """

    name: ClassVar[str] = "mitchell-schaeffer"
    title: ClassVar[str] = "Mitchell-Schaeffer (2003)"
    citation: ClassVar[str] = (
        "C. C. Mitchell and D. G. Schaeffer, *A two-current model for the dynamics of cardiac membrane*, "
        "Bulletin of Mathematical Biology 65(5), 2003 (the cell model)."
    )
    equations: ClassVar[tuple[str, ...]] = (
        "du/dt = div(D grad u) + h u^2 (1 - u) / tau_in - u / tau_out,   tau_out = tau_in / (a (1 - a))",
        "dh/dt = (1 - h) / tau_open where u < v_gate, else -h / tau_close   (h: the solver's v)",
    )
    resting_v: ClassVar[float] = 1.0
    #: Time step (time units) for the fast inward current: 0.1 ms, a third of ``tau_in``.
    dt_accuracy: ClassVar[float] = 0.1 / MS_PER_TIME_UNIT

    cell: Literal["mitchell-schaeffer"] = "mitchell-schaeffer"
    tau_in: float = 0.3
    tau_open: float = 120.0
    tau_close: float = 150.0
    v_gate: float = 0.13

    def __post_init__(self) -> None:
        for name in ("tau_in", "tau_open", "tau_close"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"Mitchell-Schaeffer parameter {name}={value} must be finite and > 0 ms")
        if not (np.isfinite(self.v_gate) and 0 < self.v_gate < 1):
            raise InputError(f"Mitchell-Schaeffer parameter v_gate={self.v_gate} must be in (0, 1)")

    def constants(self) -> MSConstants:
        """The kernels' float32 constants, rates per time unit."""
        per = MS_PER_TIME_UNIT
        return MSConstants(
            *map(np.float32, (1.0, per / self.tau_in, per / self.tau_open, per / self.tau_close)),
            np.float32(self.v_gate),
        )

    @property
    def max_rate(self) -> float:
        """A bound of the reaction's stiffness (per time unit): ``|d/du (h u^2 (1-u))| <= 1`` on [0, 1] and
        ``a (1 - a) <= 1/4``, so ``1.25 / tau_in``."""
        return 1.25 * MS_PER_TIME_UNIT / self.tau_in

    def front_speed(self, D: float, a: float) -> float:
        """Planar front speed into rested tissue (mm per time unit): ``sqrt(D / (2 tau_in)) (1 - 3a)``."""
        return float(np.sqrt(D * MS_PER_TIME_UNIT / (2.0 * self.tau_in)) * (1.0 - 3.0 * a))

    def action_potential_duration(self, a: float) -> float:
        """The closed-form action potential duration (ms): ``tau_close ln(1 / (4 a (1 - a)))``."""
        return float(self.tau_close * np.log(1.0 / (4.0 * a * (1.0 - a))))

    def apd_scaled(self, scale: float) -> MSParams:
        """The model with ``scale`` times its action-potential duration: ``tau_close`` multiplied."""
        return replace(self, tau_close=self.tau_close * scale)

    def describe(self) -> str:
        """One line for a dataset card."""
        return f"Mitchell-Schaeffer model (tau_in = {self.tau_in:g} ms, tau_close = {self.tau_close:g} ms)"
