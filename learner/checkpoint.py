"""Checkpoints: plain tensors and containers only, written atomically, read with ``weights_only=True``.

Every checkpoint carries the SHA-256 of each of its tensors and arrays by key
path (:func:`payload_digests`, entry ``digests``); reading checks them, so a
file edited or damaged after it was written is refused in one line naming what
changed.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from shared.errors import InputError

__all__ = ["CHECKPOINT_FORMAT", "DIGESTS", "payload_digests", "save_checkpoint", "load_checkpoint"]

#: Bumped on incompatible changes of the checkpoint contents.
CHECKPOINT_FORMAT = 2  # 2: the latent transition's layer-norm parameters

#: Entries every checkpoint of a kind holds (a training checkpoint holds more to resume from).
REQUIRED = {
    "model": ("config", "frames", "model"),
    "personalized": ("config", "frames", "model", "c_mu", "c_logvar", "subject", "points", "cells", "times"),
}
#: The entry holding :func:`payload_digests`.
DIGESTS = "digests"


def _arrays(value: Any, path: str) -> Iterator[tuple[str, torch.Tensor | np.ndarray]]:
    """Every tensor and array inside ``value`` (dicts and sequences walked), with its key path."""
    if isinstance(value, torch.Tensor | np.ndarray):
        yield path, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _arrays(item, f"{path}/{key}" if path else str(key))
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _arrays(item, f"{path}/{i}")


def _digest(value: torch.Tensor | np.ndarray) -> str:
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        head, data = f"{t.dtype}{tuple(t.shape)}", t.reshape(-1).view(torch.uint8).numpy()
    else:
        a = np.ascontiguousarray(value)
        head, data = f"{a.dtype.str}{a.shape}", a.reshape(-1).view(np.uint8)
    return hashlib.sha256(head.encode() + data.tobytes()).hexdigest()


def payload_digests(payload: dict[str, Any]) -> dict[str, str]:
    """The SHA-256 (hex) of every tensor and array of ``payload`` (dtype, shape and bytes), by key path; the
    entry :data:`DIGESTS` itself left out."""
    entries = {key: value for key, value in payload.items() if key != DIGESTS}
    return {path: _digest(value) for path, value in _arrays(entries, "")}


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` to ``path`` via a temporary file and an atomic rename (no torn checkpoint on a kill)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save({"format": CHECKPOINT_FORMAT, **payload, DIGESTS: payload_digests(payload)}, tmp)
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
    if DIGESTS in data:
        _check_digests(path, data)
    elif kind == "personalized":
        raise InputError(f"{path}: the personalised heart carries no digests of its arrays: personalize it again")
    return data


def _check_digests(path: Path, data: dict[str, Any]) -> None:
    """Refuse a checkpoint whose tensors differ from the digests it was written with, naming them."""
    recorded, found = data[DIGESTS], payload_digests({k: v for k, v in data.items() if k != "format"})
    if not isinstance(recorded, dict):
        raise InputError(f"{path}: its digests entry is not a mapping of array digests (the file was edited)")
    changed = sorted(k for k in set(recorded) | set(found) if recorded.get(k) != found.get(k))
    if changed:
        shown = ", ".join(changed[:5]) + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
        raise InputError(
            f"{path}: {len(changed)} array(s) differ from the digests the file was written with ({shown}): it was "
            "edited or damaged since; write it again (`learner personalize` for a personalised heart)"
        )
