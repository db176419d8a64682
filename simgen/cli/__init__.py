"""The ``simgen`` command line: thin wrappers around library functions, one module per group of commands.

:mod:`simgen.cli.options` holds the app, the options the commands share and how bad input is refused;
:mod:`~simgen.cli.meshes` (``mesh``, ``tissues``), :mod:`~simgen.cli.simulation` (``simulate``, ``demo``),
:mod:`~simgen.cli.builds` (``build``, ``add-subject``, ``regenerate``, ``repair``) and
:mod:`~simgen.cli.stores` (``status``, ``sites``, ``unlock``, ``verify``, ``card``, ``export-vtk``) register
their commands on it. Each command parses its options, calls the library function that does the work and
prints what it returns.
"""

from __future__ import annotations

from simgen.cli import builds, meshes, simulation, stores  # noqa: F401 - each registers its commands
from simgen.cli.options import app

__all__ = ["app"]
