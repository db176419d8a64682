"""Checkpoints: plain tensors and containers only, written atomically, read with ``weights_only=True``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from shared.errors import InputError

__all__ = ["CHECKPOINT_FORMAT", "save_checkpoint", "load_checkpoint"]

#: Bumped on incompatible changes of the checkpoint contents.
CHECKPOINT_FORMAT = 2  # 2: the latent transition's layer-norm parameters

#: Entries every checkpoint of a kind holds (a training checkpoint holds more to resume from).
REQUIRED = {
    "model": ("config", "frames", "model"),
    "personalized": ("config", "frames", "model", "c_mu", "c_logvar", "subject", "points", "cells", "times"),
}


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` to ``path`` via a temporary file and an atomic rename (no torn checkpoint on a kill)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save({"format": CHECKPOINT_FORMAT, **payload}, tmp)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def load_checkpoint(path: str | Path, kind: str | None = None) -> dict[str, Any]:
    """Read a checkpoint safely (``weights_only=True``); with ``kind``, check its kind and :data:`REQUIRED` entries.

    A ``path`` that names no file but a shipped model (:mod:`learner.pretrained`, e.g. ``"anatomies"``)
    gives that model as a checkpoint of kind ``"model"``.
    """
    path = Path(path)
    if not path.is_file():
        from learner.pretrained import shipped as pretrained  # names only: not the package's training imports

        shipped = pretrained.names()
        if str(path) in shipped:
            if kind in (None, "model"):
                return pretrained.checkpoint(str(path))
            raise InputError(
                f"{path} is a shipped model, not a {kind!r} file: `learner personalize {path} ...` makes one"
            )
        raise InputError(f"checkpoint not found: {path} (nor a shipped model: {', '.join(shipped) or 'none'})")
    if path.stat().st_size == 0:
        raise InputError(f"{path} is not a readable learner checkpoint: the file is empty (0 bytes)")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unpickling errors have many types
        raise InputError(f"{path} is not a readable learner checkpoint: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(
            f"{path}: checkpoint format {data.get('format') if isinstance(data, dict) else '?'}, "
            f"this code reads format {CHECKPOINT_FORMAT}"
        )
    if kind is not None and data.get("kind") != kind:
        raise InputError(f"{path} holds a {data.get('kind')!r}, expected a {kind!r}")
    if missing := [key for key in REQUIRED.get(kind or "", ()) if key not in data]:
        raise InputError(f"{path}: the {kind!r} checkpoint lacks {missing}")
    return data
