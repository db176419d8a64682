"""Exception types shared by simgen and learner.

Every error raised for bad user input derives from :class:`InputError` (itself a
``ValueError``), so callers and CLIs can catch one type and print its message.
"""

from __future__ import annotations

__all__ = [
    "InputError",
    "MeshError",
    "TissueError",
    "StimulusError",
    "TimeStepError",
    "ConfigError",
    "SchemaError",
    "DamagedData",
]


class InputError(ValueError):
    """Bad input; the message names the problem."""


class MeshError(InputError):
    """A mesh is broken: non-finite points, degenerate cells, not manifold, ..."""


class TissueError(InputError):
    """A tissue (scar) specification is invalid."""


class StimulusError(InputError):
    """A stimulation site is unknown or a stimulus setting is invalid."""


class TimeStepError(InputError):
    """A user time step exceeds the explicit stability limit."""


class ConfigError(InputError):
    """A configuration file is malformed or has unknown keys."""


class SchemaError(InputError):
    """A store does not match the expected schema."""


class DamagedData(SchemaError):
    """Stored data a reader refuses: a failed checksum or content fingerprint, a missing file or subject,
    values never written; the message names the subject, array, site and file, and ``simgen repair``."""
