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

import json
import re
from pathlib import Path

import torch

from learner.pretrained.shipped import (
    CARD,
    CONFIG,
    FORMAT,
    SHIPPED_DIR,
    WEIGHTS,
    ShippedModel,
    checkpoint,
    config_digest,
    file_sha256,
    info,
    names,
    resolve_reference,
)
from shared.errors import InputError

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

_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*$")


def load(name: str, device: str | torch.device = "cpu"):
    """The shipped model ``name``, ready to personalise: a :class:`~learner.models.surrogate.MetaPNS` in eval mode.

    Its config (``model.config`` of :func:`info`) gives the mesh-hierarchy recipe:
    ``learner.graph.hierarchy.hierarchy_for_mesh(mesh, levels, coarsest, None, working_nodes)``.
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
    run paths are reduced to their names (a warm start's to its run's and file's). The store the model was trained on
    (``data.store`` of the checkpoint) is read for its spec hash, provenance
    and frame times when it is still there. The model card (README.md) is
    written by hand next to them.
    """
    from safetensors.torch import save_file

    from learner.checkpoint import load_checkpoint
    from learner.store_view import StoreView

    folder = Path(folder)
    if not _NAME.match(folder.name):
        raise InputError(f"model name {folder.name!r}: use lower-case letters, digits, '-' and '_'")
    ckpt = load_checkpoint(source, kind="model")
    config = json.loads(json.dumps(ckpt["config"]))
    store = config["data"]["store"]
    config["data"]["store"] = Path(store).name
    config["out"] = Path(config["out"]).name
    init = Path(config["train"]["init"])
    config["train"]["init"] = str(Path(init.parent.name, init.name)) if init.name else ""  # its run and file
    view = StoreView(store) if Path(store).exists() else None
    weights = {k: v.detach().to("cpu", torch.float32).contiguous().clone() for k, v in ckpt["model"].items()}
    folder.mkdir(parents=True, exist_ok=True)
    attrs = view.attrs if view is not None else {}
    document = {
        "format": FORMAT,
        "name": folder.name,
        "summary": summary,
        "kind": config["model"]["kind"],
        "frames": int(ckpt["frames"]),
        "times": [round(float(t), 9) for t in view.times] if view is not None else None,
        "ap_template": _template(store, ckpt, view),
        "hierarchy": {
            "levels": config["model"]["levels"],
            "coarsest": config["model"]["coarsest"],
            "working_nodes": config["model"].get("working_nodes"),
            "builder": "learner.graph.hierarchy.hierarchy_for_mesh(mesh, levels, coarsest, None, working_nodes): "
            "a mesh of more than working_nodes nodes seen as that many clusters (learner.graph.working), then "
            "graph-Voronoi clustering, built for each new mesh",
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
        "licence": "MIT",
    }
    metadata = {"format": "pt", "model": folder.name, "config_sha256": config_digest(document)}
    save_file(weights, str(folder / WEIGHTS), metadata=metadata)
    (folder / WEIGHTS).chmod(0o644)
    document["weights"] = {
        "file": WEIGHTS,
        "dtype": "float32",
        "parameters": int(sum(v.numel() for v in weights.values())),
        "sha256": file_sha256(folder / WEIGHTS),
    }
    (folder / CONFIG).write_text(json.dumps(document, indent=1) + "\n")
    return folder


def _template(store: str, ckpt: dict, view) -> dict | None:
    """The action-potential template of the training subjects (:mod:`learner.activation_maps`) as config.json
    records it: the checkpoint's, else computed from the training store; None without either."""
    from learner.activation_maps import template_from_store

    if ckpt.get("ap_template") is not None or view is None:
        return ckpt.get("ap_template")
    return template_from_store(store, list(ckpt.get("splits", {}).get("train", []))).to_dict()
