"""The canonical train / validation / test split a store records (subject attribute ``split``).

A subject's part follows from its id alone: the first 8 bytes of the SHA-256
of the id, read as a number in [0, 1), fall into ``train`` below 0.7,
``validation`` below 0.8 and ``test`` above. Adding subjects never moves
existing ones; the fractions hold on average, not exactly, in a small store.
"""

from __future__ import annotations

import hashlib

__all__ = ["SPLIT_FRACTIONS", "canonical_part", "split_rule"]

#: Expected fraction of subjects per part, in the order the unit interval is cut.
SPLIT_FRACTIONS = {"train": 0.7, "validation": 0.1, "test": 0.2}


def canonical_part(subject_id: str) -> str:
    """``"train"``, ``"validation"`` or ``"test"``: the part of the unit interval the id hashes to."""
    position = int.from_bytes(hashlib.sha256(subject_id.encode()).digest()[:8], "big") / 2.0**64
    edge = 0.0
    for part, fraction in SPLIT_FRACTIONS.items():
        edge += fraction
        if position < edge:
            return part
    return part  # rounding of the fractions' sum


def split_rule() -> dict:
    """The rule as a root attribute: how a subject's ``split`` attribute was assigned."""
    return {
        "method": "sha256(subject id), first 8 bytes as a fraction of 2**64, cut by the fractions in order",
        "fractions": dict(SPLIT_FRACTIONS),
    }
