"""Physical units of the dimensionless Aliev-Panfilov model (store times are in model time units)."""

from __future__ import annotations

__all__ = ["MS_PER_TIME_UNIT", "to_millivolts"]

#: Milliseconds per dimensionless time unit.
MS_PER_TIME_UNIT = 12.9


def to_millivolts(u):
    """Transmembrane potential in mV from the dimensionless ``u``: ``V = 100 u - 80``."""
    return 100.0 * u - 80.0
