"""Shipped pretrained models: ready to personalise on a new heart without training.

Each shipped model is a folder of this package named after the model::

    learner/pretrained/<name>/
        model.safetensors   the weights only (safetensors: no pickle, nothing executed on load)
        config.json         the model config, the mesh-hierarchy recipe, the frame times, the
                            subject splits of its training store, provenance and the weights' SHA-256
        README.md           the model card: training data and spec, metrics, intended use, limits, licence

Use them by name wherever a learner command takes a checkpoint
(``learner personalize anatomies ...``, ``learner evaluate anatomies STORE``), list them with
``learner models``, and load one in Python::

    import learner.pretrained

    model = learner.pretrained.load("anatomies")  # a MetaPNS in eval mode, on the CPU

:func:`export` writes a trained checkpoint in this form (``learner export``).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from shared.errors import InputError
from shared.location import resolve_location

__all__ = [
    "SHIPPED_DIR",
    "WEIGHTS",
    "CONFIG",
    "CARD",
    "ShippedModel",
    "names",
    "info",
    "checkpoint",
    "load",
    "export",
    "resolve_reference",
]

#: The folder holding one sub-folder per shipped model.
SHIPPED_DIR = Path(__file__).resolve().parent
WEIGHTS, CONFIG, CARD = "model.safetensors", "config.json", "README.md"
#: Version of the config.json layout written by :func:`export`.
FORMAT = 1
_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*$")


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


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checkpoint(name: str, root: str | Path | None = None) -> dict[str, Any]:
    """The shipped model as a checkpoint dict of kind ``"model"``, as :func:`~learner.train.trainer.load_model` reads.

    The weights are read with :func:`safetensors.torch.load_file` after their
    SHA-256 is checked against config.json, and cast to float32.
    """
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    shipped = info(name, root)
    recorded = shipped.config["weights"]["sha256"]
    if _sha256(shipped.weights) != recorded:
        raise InputError(f"{shipped.weights} is damaged: its SHA-256 differs from config.json's {recorded[:12]}...")
    try:
        weights = load_file(shipped.weights)
    except (SafetensorError, OSError) as exc:
        raise InputError(f"{shipped.weights} is not a readable safetensors file: {exc}") from None
    return {
        "kind": "model",
        "shipped": name,
        "config": shipped.config["config"],
        "frames": int(shipped.config["frames"]),
        "splits": shipped.config.get("splits", {}),
        **({"times": list(shipped.config["times"])} if shipped.config.get("times") else {}),
        "model": {k: v.float() for k, v in weights.items()},
    }


def load(name: str, device: str | torch.device = "cpu"):
    """The shipped model ``name``, ready to personalise: a :class:`~learner.models.surrogate.MetaPNS` in eval mode.

    Its config (``model.config`` of :func:`info`) gives the mesh-hierarchy recipe:
    ``learner.graph.hierarchy.hierarchy_for_mesh(mesh, levels, coarsest)``.
    """
    from learner.train.trainer import load_model

    return load_model(name, device)[0]


def export(
    source: str | Path,
    folder: str | Path,
    summary: str,
    training_spec: str = "",
    store_spec: str = "",
) -> Path:
    """Write the training checkpoint ``source`` as a shipped model in ``folder``: weights and config.json.

    The config keeps the model, episode and training settings; the store and
    run paths are reduced to their names. The store the model was trained on
    (``data.store`` of the checkpoint) is read for its spec hash, provenance
    and frame times when it is still there. The model card (README.md) is
    written by hand next to them.
    """
    from safetensors.torch import save_file

    from learner.store_view import StoreView
    from learner.train.checkpoint import load_checkpoint

    folder = Path(folder)
    if not _NAME.match(folder.name):
        raise InputError(f"model name {folder.name!r}: use lower-case letters, digits, '-' and '_'")
    ckpt = load_checkpoint(source, kind="model")
    config = json.loads(json.dumps(ckpt["config"]))
    store = config["data"]["store"]
    config["data"]["store"] = Path(store).name
    config["out"] = Path(config["out"]).name
    config["train"]["init"] = ""
    view = StoreView(store) if Path(store).exists() else None
    weights = {k: v.detach().to("cpu", torch.float32).contiguous().clone() for k, v in ckpt["model"].items()}
    folder.mkdir(parents=True, exist_ok=True)
    save_file(weights, str(folder / WEIGHTS), metadata={"format": "pt", "model": folder.name})
    (folder / WEIGHTS).chmod(0o644)
    attrs = view.attrs if view is not None else {}
    document = {
        "format": FORMAT,
        "name": folder.name,
        "summary": summary,
        "kind": config["model"]["kind"],
        "frames": int(ckpt["frames"]),
        "times": [round(float(t), 9) for t in view.times] if view is not None else None,
        "hierarchy": {
            "levels": config["model"]["levels"],
            "coarsest": config["model"]["coarsest"],
            "builder": "learner.graph.hierarchy.hierarchy_for_mesh(mesh, levels, coarsest): graph-Voronoi "
            "clustering of the mesh's edge graph, built for each new mesh",
        },
        "config": config,
        "splits": ckpt.get("splits", {}),
        "training": {
            "spec": training_spec,
            "store_spec": store_spec,
            "store": Path(store).name,
            "store_spec_hash": attrs.get("spec_hash"),
            "store_provenance": attrs.get("provenance"),
            "seed": config["train"]["seed"],
            "epoch": int(ckpt.get("epoch", 0)),  # the epoch after which the checkpoint was written
            "validation_target_mse": ckpt.get("best_validation"),  # best so far (best.pt: this epoch's)
        },
        "weights": {
            "file": WEIGHTS,
            "dtype": "float32",
            "parameters": int(sum(v.numel() for v in weights.values())),
            "sha256": _sha256(folder / WEIGHTS),
        },
        "licence": "MIT",
    }
    (folder / CONFIG).write_text(json.dumps(document, indent=1) + "\n")
    return folder
