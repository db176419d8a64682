"""The shipped models' folders: their names, config.json facts, weights as checkpoints, names in config files.

The package :mod:`learner.pretrained` re-exports all of it; this module imports nothing else of
the learner, so :mod:`learner.checkpoint` and :mod:`learner.config` resolve shipped names
through it without importing the training code that :func:`learner.pretrained.load` uses.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shared.errors import InputError
from shared.location import resolve_location

__all__ = [
    "SHIPPED_DIR",
    "WEIGHTS",
    "CONFIG",
    "CARD",
    "FORMAT",
    "ShippedModel",
    "names",
    "info",
    "checkpoint",
    "resolve_reference",
    "file_sha256",
    "config_digest",
    "UNSIGNED",
]

#: The folder holding one sub-folder per shipped model.
SHIPPED_DIR = Path(__file__).resolve().parent
WEIGHTS, CONFIG, CARD = "model.safetensors", "config.json", "README.md"
#: Version of the config.json layout that :func:`learner.pretrained.export` writes.
FORMAT = 1


@dataclass(frozen=True)
class ShippedModel:
    """A shipped model's folder and the facts of its config.json."""

    name: str
    folder: Path
    config: dict[str, Any]

    @property
    def weights(self) -> Path:
        return self.folder / WEIGHTS

    @property
    def card(self) -> Path:
        return self.folder / CARD

    @property
    def summary(self) -> str:
        return str(self.config.get("summary", ""))

    @property
    def parameters(self) -> int:
        return int(self.config["weights"]["parameters"])


def names(root: str | Path | None = None) -> list[str]:
    """Names of the models shipped in ``root`` (default: this package), sorted."""
    base = Path(root) if root is not None else SHIPPED_DIR
    return sorted(p.name for p in base.iterdir() if (p / WEIGHTS).is_file() and (p / CONFIG).is_file())


def info(name: str, root: str | Path | None = None) -> ShippedModel:
    """The shipped model ``name``; an unknown name is bad input that lists the shipped ones."""
    base = Path(root) if root is not None else SHIPPED_DIR
    if name not in names(base):
        shipped = ", ".join(names(base)) or "none"
        raise InputError(f"no shipped model named {name!r} (shipped: {shipped}; `learner models` lists them)")
    folder = base / name
    try:
        config = json.loads((folder / CONFIG).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{folder / CONFIG} is not readable JSON: {exc}") from None
    if not isinstance(config, dict) or config.get("format") != FORMAT:
        raise InputError(f"{folder / CONFIG}: format {config.get('format')!r}, this code reads format {FORMAT}")
    return ShippedModel(name, folder, config)


def resolve_reference(reference: str, base: str | Path) -> str:
    """A checkpoint named in a config file: a shipped model's name stays a name (unless ``base`` holds
    a file of that name); anything else is a location resolved against ``base``."""
    if reference in names() and not (Path(base) / reference).is_file():
        return reference
    return resolve_location(reference, base)


def file_sha256(path: Path) -> str:
    """SHA-256 of a file, as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


#: config.json entries outside the digest that the weights file records: the weights' own SHA-256 and the
#: card's measured figures (written after export).
UNSIGNED = ("weights", "card")


def config_digest(config: dict[str, Any]) -> str:
    """SHA-256 of config.json's content bar :data:`UNSIGNED` (canonical JSON: sorted keys, no spaces)."""
    signed = {key: value for key, value in config.items() if key not in UNSIGNED}
    return hashlib.sha256(json.dumps(signed, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def checkpoint(name: str, root: str | Path | None = None) -> dict[str, Any]:
    """The shipped model as a checkpoint dict of kind ``"model"``, as :func:`~learner.train.trainer.load_model` reads.

    The model is checked whole: the weights' SHA-256 against config.json, config.json's content against
    the digest the weights file records (:func:`config_digest`), every weight finite. The weights are
    read with :func:`safetensors.torch.load_file` and cast to float32.
    """
    import torch
    from safetensors import SafetensorError, safe_open
    from safetensors.torch import load_file

    shipped = info(name, root)
    recorded = shipped.config.get("weights", {}).get("sha256", "")
    if file_sha256(shipped.weights) != recorded:
        raise InputError(f"{shipped.weights} is damaged: its SHA-256 differs from config.json's {recorded[:12]}...")
    try:
        weights = load_file(shipped.weights)
        with safe_open(shipped.weights, "pt") as handle:
            signed = (handle.metadata() or {}).get("config_sha256")
    except (SafetensorError, OSError) as exc:
        raise InputError(f"{shipped.weights} is not a readable safetensors file: {exc}") from None
    if signed != config_digest(shipped.config):
        raise InputError(
            f"{shipped.folder / CONFIG} does not match {WEIGHTS}: its content (bar {', '.join(UNSIGNED)}) differs "
            f"from the digest the weights record ({(signed or 'none')[:12]}...); restore the file or export the model "
            "again (`learner export`)"
        )
    bad = [key for key, value in weights.items() if not torch.isfinite(value).all()]
    if bad:
        raise InputError(f"{shipped.weights}: {len(bad)} weight tensor(s) hold NaN or inf, first {bad[0]!r}")
    return {
        "kind": "model",
        "shipped": name,
        "config": shipped.config["config"],
        "frames": int(shipped.config["frames"]),
        "splits": shipped.config.get("splits", {}),
        **({"times": list(shipped.config["times"])} if shipped.config.get("times") else {}),
        **({"ap_template": shipped.config["ap_template"]} if shipped.config.get("ap_template") else {}),
        "model": {k: v.float() for k, v in weights.items()},
    }
