"""How well the context set tells whether a stimulus in scar starts a wave: the capture gate's evidence.

For every scar site (border zone and core) of every scarred subject of a
store, the script asks two things of the stored simulations:

* does stimulating there start a wave (more than half the mesh ever above
  ``u = 0.5``)?
* what does a context set of ``K`` other sites of the same subject show at
  that node: :class:`~learner.models.site_evidence.SiteEvidence`, the peak of
  ``u`` there over the ``K`` sequences, observed on the surface?

It prints per site tissue and ``K`` the share of sites that start a wave, the
mean peak of both groups, and the AUC of the peak as a score for "starts a
wave" (0.5: no information, 1: a threshold separates the groups). That is
what ``model.capture_evidence`` adds to the capture gate (docs/method.md).

Run::

    .venv/bin/python -m bench.site_evidence data/default.zarr [--contexts 1 3 5] [--out DIR]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.stats import rankdata

from bench.common import add_out_argument, write_out
from learner.metrics import wave_started
from learner.models.site_evidence import SiteEvidence
from shared.reader import read_index_set, read_sites, read_tissue, read_u, subject_attrs, subject_ids
from shared.tissue import LABEL_BORDER, LABEL_CORE

LABELS = {LABEL_BORDER: "border zone", LABEL_CORE: "scar core"}


def auc(score: NDArray, positive: NDArray[np.bool_]) -> float:
    """Area under the ROC curve of ``score`` for ``positive`` (Mann-Whitney U over the pair count)."""
    n1, n0 = int(positive.sum()), int((~positive).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[positive].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def scar_sites(store: str, contexts: list[int], seed: int = 0) -> dict[int, list[tuple[int, bool, float]]]:
    """Per context size: (site label, starts a wave, evidence peak) for every scar site of every subject."""
    out: dict[int, list[tuple[int, bool, float]]] = {k: [] for k in contexts}
    rng = np.random.default_rng(seed)
    for subject in subject_ids(store):
        mesh_id = subject_attrs(store, subject)["mesh_id"]
        sites = read_sites(store, mesh_id)
        labels = read_tissue(store, subject).label[sites]
        rows = np.flatnonzero(np.isin(labels, list(LABELS)))
        if rows.size == 0:
            continue
        u = read_u(store, subject)  # (S, T, N)
        starts = wave_started(u)
        observed = np.zeros(u.shape[-1], dtype=bool)
        observed[read_index_set(store, mesh_id, "surface")] = True
        for row in rows:
            others = rng.permutation(np.setdiff1d(np.arange(len(sites)), [row]))
            for k in contexts:
                ctx = others[:k]
                ev = SiteEvidence.from_context(
                    torch.from_numpy(u[ctx] * observed), torch.from_numpy(observed), torch.from_numpy(sites[ctx])
                )
                peak = float(ev.at(torch.tensor([sites[row]]))[0, 0])
                out[k].append((int(labels[row]), bool(starts[row]), peak))
    return out


def evidence_table(found: dict[int, list[tuple[int, bool, float]]]) -> str:
    """Markdown: per site tissue and context size, wave share, mean peaks and AUC."""
    lines = [
        "| site tissue | context sequences | sites | start a wave | mean peak, wave | mean peak, no wave | AUC |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for label, name in LABELS.items():
        for k, rows in found.items():
            a = np.array([(s, p) for lab, s, p in rows if lab == label])
            if a.size == 0:
                continue
            starts, peak = a[:, 0].astype(bool), a[:, 1]
            wave = f"{peak[starts].mean():.2f}" if starts.any() else "-"
            none = f"{peak[~starts].mean():.2f}" if (~starts).any() else "-"
            lines.append(
                f"| {name} | {k} | {len(a)} | {starts.mean():.0%} | {wave} | {none} | {auc(peak, starts):.2f} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="a dataset store (simgen build)")
    parser.add_argument("--contexts", nargs="+", type=int, default=[1, 3, 5], help="context set sizes")
    parser.add_argument("--seed", type=int, default=0, help="seed of the context draws")
    add_out_argument(parser, "site_evidence")
    args = parser.parse_args()
    table = evidence_table(scar_sites(args.store, args.contexts, args.seed))
    print(table)
    write_out(args.out, "site_evidence", table + "\n")


if __name__ == "__main__":
    main()
