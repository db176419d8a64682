"""Fixtures for the data tests: editable copies of the shared tiny store."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture
def store_copy(tiny_store: Path, tmp_path: Path) -> Path:
    """A private copy of ``tiny_store`` that a test may damage."""
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, copy)
    return copy
