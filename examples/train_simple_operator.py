"""Train a small model on a dataset store with :class:`shared.dataset.SimulationDataset`.

The model maps, node by node, the position, the geodesic distance from the
stimulated node and the tissue parameters ``a`` and ``D`` to the activation
time: an MLP shared by every node of every mesh, so meshes of any size
batch together (:func:`shared.dataset.collate_graphs`). Targets are
standardised with the training subjects' statistics, so predicting their
mean scores a mean squared error of about 1.

Usage::

    python examples/train_simple_operator.py demo.zarr --epochs 5
    python examples/train_simple_operator.py data/default.zarr --epochs 3 --workers 2

It trains on the store's ``train`` split, reports the ``validation`` split
after every epoch (when the store has one) and prints one line per epoch.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from functools import partial

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra
from torch import nn
from torch.utils.data import DataLoader

from shared.dataset import NODE_AXES, SimulationDataset, collate_graphs, subset_statistics
from shared.graph import edge_length_graph
from shared.reader import read_split

#: Node features: position (3, centred and scaled), geodesic distance from the site, a, D.
FEATURES = 6


class NodeFeatures:
    """Dataset transform adding ``features`` (N, 6) to an item (needs ``edges=True``).

    Lengths are divided by the diagonal of the mesh's bounding box, so
    features are about 0-1 on any heart; the edge-length graph of each mesh
    is built once per process.
    """

    def __init__(self) -> None:
        self._graphs: dict[str, tuple] = {}

    def __call__(self, item: dict) -> dict:
        points = item["points"].astype(np.float64)
        if item["mesh"] not in self._graphs:
            diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
            self._graphs[item["mesh"]] = (edge_length_graph(points, item["edges"]), points.mean(axis=0), diagonal)
        graph, centre, diagonal = self._graphs[item["mesh"]]
        distance = dijkstra(graph, indices=item["site"]) / diagonal
        position = (points - centre) / diagonal
        features = np.column_stack([position, distance, item["a"], item["D"]])
        return {**item, "features": features.astype(np.float32)}


def make_model(hidden: int = 64) -> nn.Module:
    """Per-node MLP: features (nodes, 6) -> standardised activation time (nodes,)."""
    return nn.Sequential(
        nn.Linear(FEATURES, hidden),
        nn.GELU(),
        nn.Linear(hidden, hidden),
        nn.GELU(),
        nn.Linear(hidden, 1),
        nn.Flatten(0),
    )


def loader(dataset: SimulationDataset, batch_size: int, workers: int, shuffle: bool) -> DataLoader:
    """Batches of whole simulations joined into one graph each."""
    collate = partial(collate_graphs, node_axes={**NODE_AXES, "features": 0})
    return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, num_workers=workers, collate_fn=collate)


def run_epoch(model: nn.Module, batches: DataLoader, optimiser: torch.optim.Optimizer | None, device: str) -> float:
    """Mean squared error over the nodes that activate (a training step per batch with ``optimiser``)."""
    model.train(optimiser is not None)
    total, count = 0.0, 0
    with torch.set_grad_enabled(optimiser is not None):
        for batch in batches:
            target = batch["activation"].to(device)
            active = torch.isfinite(target)
            error = (model(batch["features"].to(device))[active] - target[active]) ** 2
            if optimiser is not None:
                optimiser.zero_grad()
                error.mean().backward()
                optimiser.step()
            total, count = total + float(error.detach().sum()), count + int(active.sum())
    return total / max(count, 1)


def main(argv: Sequence[str] | None = None) -> list[dict]:
    """Train and report; returns one record per epoch (losses, simulations per second)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store", help="dataset store built by `simgen build`")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--batch-size", type=int, default=8, help="simulations per batch")
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)

    torch.manual_seed(args.seed)
    split = read_split(args.store)
    stats = subset_statistics(args.store, [sid for sid, part in split.items() if part == "train"])  # no leak
    make = partial(
        SimulationDataset, args.store, normalize=True, statistics=stats, edges=True, transform=NodeFeatures()
    )
    train = make(split="train")
    parts = {"train": loader(train, args.batch_size, args.workers, shuffle=True)}
    if "validation" in split.values():
        parts["validation"] = loader(make(split="validation"), args.batch_size, args.workers, shuffle=False)
    model = make_model().to(args.device)
    optimiser = torch.optim.Adam(model.parameters(), lr=args.lr)
    print(train)
    history = []
    for epoch in range(1, args.epochs + 1):
        start = time.perf_counter()
        record = {"epoch": epoch, "train_mse": run_epoch(model, parts["train"], optimiser, args.device)}
        record["simulations_per_s"] = len(train) / (time.perf_counter() - start)
        if "validation" in parts:
            record["validation_mse"] = run_epoch(model, parts["validation"], None, args.device)
        history.append(record)
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in record.items()))
    return history


if __name__ == "__main__":
    main()
