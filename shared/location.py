"""Store locations: a local folder or an fsspec URL such as ``s3://bucket/paper.zarr``."""

from __future__ import annotations

from pathlib import Path

__all__ = ["is_url", "resolve_location"]


def is_url(store: str | Path) -> bool:
    """``True`` for an fsspec URL (``s3://...``, ``file://...``, ``simplecache::s3://...``)."""
    return isinstance(store, str) and "://" in store


def resolve_location(location: str, base: str | Path) -> str:
    """A path relative to ``base`` made absolute; a URL, or ``""`` (unset), unchanged."""
    return location if not location or is_url(location) else str((Path(base) / location).resolve())
