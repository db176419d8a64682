"""Benchmark: refining the personalisation by gradient steps, with the step count chosen on held-out recordings.

On the real heart's leave-one-site-out folds (``--real``, ``specs/realdata.toml``:
``real:tof-biv``, 3 tissue settings, 8 pacing sites, the 247-electrode sock, noise
0.02), a model (``--model``, default the shipped ``anatomies``) is personalised on
the other sites' recordings three ways: the encoder's mean (no refinement),
``learner personalize --refine-steps N`` (at most N steps, the count chosen by
leaving up to 3 recordings out in turn: :func:`learner.refine.refine_context`), and
N steps without that check (:func:`learner.refine.fit_context`). Each predicts
the left-out site; the table gives the spatial CC and activation-time error there,
the steps taken and the time to personalise.

Run::

    .venv/bin/python -m bench.refinement --real data/realdata.zarr --out report/bench

``--publish`` writes the table into the block ``refinement`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

from bench.activation_maps import NOISE_U, real_folds
from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from learner.data.episodes import load_episode
from learner.metrics import activation_error_ms, spatial_cc
from learner.models.surrogate import Posterior
from learner.observations import Observations
from learner.personalized import NoWaveWarning, personalize
from learner.refine import Refinement, fit_context, observed_nodes
from learner.store_view import StoreView
from shared.reader import read_activation


def fixed_steps(heart, obs: Observations, steps: int, refinement: Refinement) -> None:
    """Replace ``heart``'s ``c`` by ``steps`` Adam steps on all its recordings, with no held-out check."""
    sites = torch.as_tensor(np.asarray(obs.sites, np.int64))
    observed = torch.as_tensor(obs.observed)
    target = torch.as_tensor(obs.obs)[..., observed]
    mu, var = heart.posterior.mu, heart.posterior.logvar.exp()
    c, _, _ = fit_context(
        heart.model,
        mu,
        var,
        (sites, target),
        heart.hierarchy,
        heart.evidence,
        observed_nodes(observed),
        refinement,
        steps,
    )
    heart.posterior = Posterior(c, heart.posterior.logvar)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="anatomies", help="shipped model name or checkpoint")
    parser.add_argument("--real", required=True, help="real-heart store (specs/realdata.toml)")
    parser.add_argument("--steps", type=int, nargs="+", default=[10, 30], help="--refine-steps values")
    parser.add_argument("--folds", type=int, default=0, help="the first N folds of each subject only (0: all)")
    parser.add_argument("--seed", type=int, default=0)
    add_out_argument(parser, "refinement")
    add_publish_argument(parser, "refinement")
    args = parser.parse_args()
    check_publish(args.publish)
    view = StoreView(args.real)
    ways = ["none", *(f"held-out {n}" for n in args.steps), *(f"fixed {n}" for n in args.steps)]
    scores = {way: {"cc": [], "error_ms": [], "taken": [], "seconds": []} for way in ways}
    start = time.perf_counter()
    folds, per_subject = [], {}
    for subject, context, left in real_folds(args):
        per_subject[subject] = per_subject.get(subject, 0) + 1
        if not args.folds or per_subject[subject] <= args.folds:
            folds.append((subject, context, left))
    for i, (subject, context, left) in enumerate(folds):
        ep = load_episode(
            args.real, subject, context, left, "electrodes", NOISE_U, np.random.default_rng([args.seed, i])
        )
        mesh = view.mesh(view.mesh_of[subject])
        obs = Observations(
            mesh, ep.context_sites.numpy(), ep.context_obs.numpy(), ep.observed.numpy(), ep.times.numpy(), subject
        )
        truth, true_act = ep.target_u.numpy()[0], read_activation(args.real, subject, left)[0]
        for way in ways:
            kind, _, n = way.partition(" ")
            steps = int(n) if n else 0
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NoWaveWarning)
                heart = personalize(args.model, obs, refine=Refinement(steps=steps if kind == "held-out" else 0))
            if kind == "fixed":
                fixed_steps(heart, obs, steps, Refinement(steps=steps))
            seconds = time.perf_counter() - t0
            u = heart.predict(ep.target_sites.numpy()).u[0]
            row = scores[way]
            row["cc"].append(spatial_cc(u, truth))
            row["error_ms"].append(activation_error_ms(u, true_act, ep.times.numpy())[0])
            row["taken"].append(heart.refine_steps_taken if kind == "held-out" else steps)
            row["seconds"].append(seconds)
        print(f"fold {i}: " + ", ".join(f"{w} {scores[w]['cc'][-1]:.3f}" for w in ways), flush=True)
    base = np.mean(scores["none"]["cc"])
    lines = [
        f"Machine: {machine_line()}. Model `{args.model}`, {args.real}: {len(scores['none']['cc'])} leave-one-site-out "
        f"folds, 247 sock electrodes, noise {NOISE_U}.",
        "",
        "| refinement | spatial CC | vs none | folds worse than none | activation error (ms) | steps taken "
        "| personalise (s) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for way in ways:
        r = scores[way]
        worse = int(np.sum(np.asarray(r["cc"]) < np.asarray(scores["none"]["cc"]) - 1e-6))
        lines.append(
            f"| {way} | {np.mean(r['cc']):.3f} | {np.mean(r['cc']) - base:+.3f} | {worse} "
            f"| {np.nanmean(r['error_ms']):.1f} | {np.mean(r['taken']):.1f} | {np.median(r['seconds']):.2f} |"
        )
    lines += ["", f"{time.perf_counter() - start:.0f} s in all."]
    print("\n".join(lines))
    write_out(args.out, "refinement", "\n".join(lines) + "\n", {"machine": machine(), "scores": scores})
    publish_out(args.publish, "refinement", "\n".join(lines[:-2]))


if __name__ == "__main__":
    main()
