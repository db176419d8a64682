"""Physical units of the dimensionless Aliev-Panfilov model (store times are in model time units)."""

from __future__ import annotations

__all__ = ["MS_PER_TIME_UNIT", "TIME_UNITS", "U_RANGE", "MV_RANGE", "to_millivolts", "from_millivolts"]

#: Milliseconds per dimensionless time unit.
MS_PER_TIME_UNIT = 12.9

#: The model time unit as a UDUNITS string (a scaled millisecond), for CF ``units`` attributes.
TIME_UNITS = f"{MS_PER_TIME_UNIT:g} ms"

#: Admissible range of the dimensionless potential ``u`` (rest 0, peak ~1, with margin).
U_RANGE = (-0.5, 1.5)

#: :data:`U_RANGE` in mV.
MV_RANGE = (-130.0, 70.0)


def to_millivolts(u):
    """Transmembrane potential in mV from the dimensionless ``u``: ``V = 100 u - 80``."""
    return 100.0 * u - 80.0


def from_millivolts(v):
    """The dimensionless ``u`` from a transmembrane potential in mV: ``u = (V + 80) / 100``."""
    return (v + 80.0) / 100.0
