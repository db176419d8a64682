"""Training diagnostics: what every step of a run does, for one or more seeds.

Per optimiser step it records the loss terms (target and context MSE, both KL
terms), the gradient norm before clipping in total and per top-level module,
and the size of the latent state before the transition's normalisation
(``max |z|`` of the first and of the last frame). Per epoch it prints a Markdown
row: mean and maximum training target MSE, median and maximum gradient norm,
the largest latent state, and the validation target MSE. docs/training.md is
written from its output.

Any key of the training config can be overridden (``--set model.latent_norm=false``
gives the reference transition), so a change is weighed against the default by
running both.

``--probe CHECKPOINT ...`` instead asks what trained models predict on their
validation episodes: the target MSE next to that of the per-frame mean of the
training data (a predictor that ignores site and context), the context effect
(the squared change of the prediction when the context set is replaced by that
of another validation subject on the same mesh, relative to the squared error of
predicting each target by the mean of the context sequences: near 0 when the
context is ignored), the spread of the predictions over sites relative to the
truth's, and the posterior's mean log-variance next to the spread of its means
between subjects. It also measures what the targets add to ``c``: the target MSE
of validation and of (up to 12) training subjects with ``c`` the mean of
p(c | Y) (the context alone, as at test time) and of q(c | Y u X) (the context
and ``train.posterior_targets`` targets, as training draws it with
``train.c_from = "posterior"``).

Run: ``.venv/bin/python -m bench.training_stability --store data/default.zarr --seeds 0 1 --epochs 12
[--config specs/train-default.toml] [--set SECTION.KEY=VALUE ...] [--out DIR]``; each seed trains
on one thread, in its own process when several seeds are given. Probe:
``.venv/bin/python -m bench.training_stability --store data/default.zarr --probe runs/seed0/last.pt``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tomllib
from collections import defaultdict
from pathlib import Path

import torch

from bench.common import add_out_argument, write_out
from learner.config import LearnerConfig, config_from_mapping, load_config
from learner.data.episodes import Episode, EpisodeDataset
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS
from learner.store_view import StoreView
from learner.train.trainer import VALIDATION_EPOCH, Trainer, load_model

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "specs" / "train-default.toml"
MODULES = ("stimulus_encoder", "coarse_blocks", "initial_state", "transition", "decoder", "context_encoder")


def _override(mapping: dict, assignment: str) -> None:
    """Apply ``section.key=value`` (value in TOML syntax) to a config mapping."""
    key, _, value = assignment.partition("=")
    *sections, name = key.split(".")
    for section in sections:
        mapping = mapping.setdefault(section, {})
    mapping[name] = tomllib.loads(f"v = {value}")["v"]


def run_seed(args: argparse.Namespace, seed: int) -> None:
    """Train one seed, writing ``steps-<seed>.jsonl`` and ``epochs-<seed>.jsonl`` to ``args.out``."""
    torch.set_num_threads(1)
    mapping = load_config(args.config).to_dict()
    for assignment in args.set:
        _override(mapping, assignment)
    _override(mapping, f"train.seed={seed}")
    _override(mapping, f"train.epochs={args.epochs}")
    _override(mapping, "train.max_minutes=0")
    _override(mapping, "train.validate_every=1")
    mapping["data"]["store"] = str(Path(args.store).resolve())
    mapping["out"] = str(args.out / f"run-{seed}")
    shutil.rmtree(mapping["out"], ignore_errors=True)  # a fresh run, not a resumed one
    trainer = Trainer(config_from_mapping(mapping), progress=False)
    model = trainer.model
    latent: list[float] = []  # max |z| of each frame's state before normalisation, in order

    def record(_module, inputs) -> None:
        latent.append(float(inputs[0].detach().abs().max()))

    model.transition.norm.register_forward_pre_hook(record)
    steps = (args.out / f"steps-{seed}.jsonl").open("w")
    count = [0]

    def on_step(episode, terms, grad_norm: float) -> None:
        unclip = max(1.0, grad_norm / trainer.config.train.grad_clip)  # clipping scaled every gradient alike
        modules = {
            name: unclip
            * float(torch.sqrt(sum((p.grad**2).sum() for p in getattr(model, name).parameters() if p.grad is not None)))
            for name in MODULES
            if hasattr(model, name)
        }
        count[0] += 1
        row = {
            "epoch": trainer.epoch + 1,
            "step": count[0],
            "subject": episode.subject_id,
            **terms.as_floats(),
            "grad_norm": grad_norm,
            **{f"grad_{k}": v for k, v in modules.items()},
            "latent_first": latent[0],
            "latent_last": latent[-1],
        }
        steps.write(json.dumps(row) + "\n")
        steps.flush()
        latent.clear()

    def on_epoch(row: dict) -> None:
        latent.clear()  # validation passes are not training steps
        with (args.out / f"epochs-{seed}.jsonl").open("a") as fh:
            fh.write(json.dumps(row) + "\n")

    (args.out / f"epochs-{seed}.jsonl").unlink(missing_ok=True)
    trainer.fit(on_epoch=on_epoch, on_step=on_step)
    steps.close()


def summary(out: Path, seed: int) -> str:
    """Markdown table, one row per epoch, from a seed's step and epoch logs."""
    steps = [json.loads(line) for line in (out / f"steps-{seed}.jsonl").open()]
    epochs = {json.loads(line)["epoch"]: json.loads(line) for line in (out / f"epochs-{seed}.jsonl").open()}
    by_epoch: dict[int, list[dict]] = defaultdict(list)
    for row in steps:
        by_epoch[row["epoch"]].append(row)
    lines = [
        f"seed {seed}",
        "",
        "| epoch | train target MSE mean | max | grad norm median | max | max latent, last frame | val target MSE |",
        "|---|---|---|---|---|---|---|",
    ]
    for epoch, rows in sorted(by_epoch.items()):
        mse = [r["target_mse"] for r in rows]
        norms = [r["grad_norm"] for r in rows]
        val = epochs.get(epoch, {}).get("val_target_mse")
        lines.append(
            f"| {epoch} | {statistics.mean(mse):.4f} | {max(mse):.3g} | {statistics.median(norms):.3g} | "
            f"{max(norms):.3g} | {max(r['latent_last'] for r in rows):.3g} | "
            f"{'' if val is None else f'{val:.4f}'} |"
        )
    return "\n".join(lines)


@torch.no_grad()
def probe(checkpoint: Path, store: str) -> dict[str, float]:
    """What a trained model predicts on its validation episodes (the quantities of the module docstring)."""
    torch.set_num_threads(1)
    model, cfg, ckpt = load_model(checkpoint)
    view = StoreView(store)
    frame_mean = torch.from_numpy(view.frame_means(ckpt["splits"]["train"])).float()[None, :, None]
    episodes = list(
        EpisodeDataset(
            store, ckpt["splits"]["validation"], cfg.data.episodes, seed=cfg.train.seed, epoch=VALIDATION_EPOCH
        )
    )
    hier = {ep.mesh_id: view.hierarchy(ep.mesh_id, cfg.model.levels, cfg.model.coarsest) for ep in episodes}
    post = [model.embed(ep.context_obs, ep.observed, hier[ep.mesh_id], ep.context_recorded) for ep in episodes]
    rows = []
    for i, ep in enumerate(episodes):
        truth = ep.target_u
        evidence = SiteEvidence.of(ep)
        pred = model.generate(ep.target_sites, hier[ep.mesh_id], post[i].mu, evidence=evidence)
        row = {
            "val_target_mse": float(((pred - truth) ** 2).mean()),
            "frame_mean_mse": float(((frame_mean - truth) ** 2).mean()),
            "site_spread_ratio": float(pred.std(0).mean() / truth.std(0).mean()),
            "posterior_logvar": float(post[i].logvar.mean()),
        }
        other = next((j for j, o in enumerate(episodes) if j != i and o.mesh_id == ep.mesh_id), None)
        if other is not None:
            elsewhere = SiteEvidence.of(episodes[other])
            swapped = model.generate(ep.target_sites, hier[ep.mesh_id], post[other].mu, evidence=elsewhere)
            naive = float(((truth - ep.context_u.mean(0)) ** 2).mean())
            row["context_effect"] = float(((pred - swapped) ** 2).mean()) / naive
            row["posterior_mean_spread"] = float((post[i].mu - post[other].mu).abs().mean())
        rows.append(row)
    found = {key: statistics.mean(r[key] for r in rows if key in r) for key in rows[0] | rows[-1]}
    train = EpisodeDataset(
        store, ckpt["splits"]["train"][:12], cfg.data.episodes, seed=cfg.train.seed, epoch=VALIDATION_EPOCH
    )
    for split, eps in (("val", episodes), ("train", list(train))):
        context_c, posterior_c = _c_sources(model, cfg, view, eps)
        found |= {f"{split}_mse_context_c": context_c, f"{split}_mse_posterior_c": posterior_c}
    return found


def _c_sources(model: MetaPNS, cfg: LearnerConfig, view: StoreView, episodes: list[Episode]) -> tuple[float, float]:
    """Mean target MSE of ``episodes`` with c = mean of p(c | Y), and of q(c | Y u X)."""
    context_c, posterior_c = [], []
    for ep in episodes:
        hier = view.hierarchy(ep.mesh_id, cfg.model.levels, cfg.model.coarsest)
        extra = ep.target_u[: cfg.train.posterior_targets or None] * ep.observed.to(ep.target_u.dtype)
        prior, posterior = model.embed_prior_and_posterior(ep.context_obs, extra, ep.observed, hier)
        for c, out in ((prior.mu, context_c), (posterior.mu, posterior_c)):
            pred = model.generate(ep.target_sites, hier, c, evidence=SiteEvidence.of(ep))
            out.append(float(((pred - ep.target_u) ** 2).mean()))
    return statistics.mean(context_c), statistics.mean(posterior_c)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", required=True, help="dataset store (simgen build)")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config key (TOML value), e.g. model.latent_norm=false",
    )
    add_out_argument(parser, "training_stability", Path("report/training-stability"))
    parser.add_argument("--probe", type=Path, nargs="+", metavar="CHECKPOINT", help="probe trained models instead")
    parser.add_argument("--one-seed", action="store_true", help=argparse.SUPPRESS)  # a child process's run
    args = parser.parse_args()
    if args.probe:
        for checkpoint in args.probe:
            found = probe(checkpoint, str(Path(args.store).resolve()))
            print(f"{checkpoint}: " + ", ".join(f"{k} {v:.4g}" for k, v in found.items()))
        return
    args.out.mkdir(parents=True, exist_ok=True)
    if args.one_seed or len(args.seeds) == 1:
        run_seed(args, args.seeds[0])
    else:
        base = [
            sys.executable,
            "-m",
            "bench.training_stability",
            "--one-seed",
            "--store",
            args.store,
            "--config",
            str(args.config),
            "--epochs",
            str(args.epochs),
            "--out",
            str(args.out),
        ] + [f"--set={s}" for s in args.set]
        children = [subprocess.Popen(base + ["--seeds", str(seed)]) for seed in args.seeds]
        if any(child.wait() for child in children):
            sys.exit("a seed's run failed (its error is above)")
    if not args.one_seed:
        tables = "\n\n".join(summary(args.out, seed) for seed in args.seeds)
        write_out(args.out, "training_stability", tables + "\n")
        print(tables)


if __name__ == "__main__":
    main()
