"""Training on two processes (gloo on 127.0.0.1, real processes): sharding, averaged gradients, exact resume,
a killed rank, and validation that does not depend on the number of processes."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from learner.checkpoint import load_checkpoint
from learner.config import config_from_mapping, load_config
from learner.data.episodes import EpisodeDataset
from learner.train.distributed import KILL_AT_ENV, World
from learner.train.trainer import Trainer

#: Gradients of one 2-process step against the mean of one process's over the same episodes.
GRAD_RTOL, GRAD_ATOL = 1e-5, 1e-7


def _config(folder: Path, store: Path, tiny_toml, epochs: int = 2, grad_clip: float = 10.0) -> Path:
    """A tiny run of 3 training subjects (an odd count: the last step of each epoch is padded on 2 ranks)."""
    path = folder / "train.toml"
    train = f"epochs = {epochs}\nvalidate_every = 1\nloss_frames = 6\ngrad_clip = {grad_clip}"
    path.write_text(tiny_toml(store, validation=0.2, test=0.34, train=train))
    return path


def _run(*args: str | Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *map(str, args)],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        timeout=600,
    )


def _rows(run: Path) -> list[dict]:
    rows = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    return [{k: v for k, v in row.items() if k != "seconds"} for row in rows]


def test_ranks_share_every_epoch_once_with_the_last_step_padded(tiny_store, tiny_config, tmp_path):
    subjects = ["lv-healthy", "lv-scar-apex", "lv-b-healthy"]
    spec = tiny_config(tiny_store, tmp_path).data.episodes
    ds = EpisodeDataset(tiny_store, subjects, spec, seed=3, epoch=1)
    shares = []
    for rank in (0, 1):
        ds.shard(rank, 2)
        shares.append([ep.subject_id for ep in ds])
    order = [subjects[i] for i in ds.order()]
    assert shares == [[order[0], order[2]], [order[1], order[0]]]  # rank 1 repeats order[0] as padding
    weights = [[World(rank, 2).weight(step, 3) for step in range(2)] for rank in (0, 1)]
    assert weights == [[1.0, 2.0], [1.0, 0.0]]  # step means over 2 real episodes, then over 1


def test_steps_of_several_processes_pair_episodes_of_similar_cost(tiny_store, tiny_config, tmp_path):
    subjects = ["lv-healthy", "lv-scar-apex", "lv-b-healthy", "lv-b-scar-apex"]
    spec = dataclasses.replace(tiny_config(tiny_store, tmp_path).data.episodes, context=(1, 3))
    for epoch in range(4):
        ds = EpisodeDataset(tiny_store, subjects, spec, seed=0, epoch=epoch)
        single = ds.order()
        ds.shard(1, 2)
        order = ds.order()
        assert sorted(order) == sorted(single)  # the same episodes, each once
        costs = [ds.cost(i) for i in order]
        spread = sum(abs(costs[j] - costs[j + 1]) for j in (0, 2))
        ranked = sorted(costs)
        assert spread == ranked[1] - ranked[0] + ranked[3] - ranked[2]  # neighbours in cost share a step


def test_two_processes_average_the_gradients_of_one(tiny_store, tiny_toml, tmp_path):
    """Each DDP step's gradient is the mean of the single-process gradients of its episodes (odd last step too)."""
    cfg_path = _config(tmp_path, tiny_store, tiny_toml, epochs=1, grad_clip=1e6)  # clipping leaves the gradients alone
    script = Path(__file__).with_name("ddp_gradients.py")
    launcher = ("-m", "torch.distributed.run", "--nnodes=1", "--nproc-per-node=2", "--rdzv-backend=c10d")
    done = _run(*launcher, "--rdzv-endpoint=127.0.0.1:0", script, cfg_path, tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    got = [torch.load(tmp_path / f"grads-{rank}.pt") for rank in (0, 1)]

    config = load_config(cfg_path)
    reference = Trainer(config, progress=False)
    reference.model.set_output_mean(reference.training_mean())
    episodes = EpisodeDataset(tiny_store, reference.splits["train"], config.data.episodes, seed=config.train.seed)
    episodes.shard(0, 2)
    order = episodes.order()
    assert len(order) == 3 and len(got[0]) == len(got[1]) == 2
    for step, group in enumerate((order[:2], order[2:])):
        reference.optimizer.zero_grad()
        for i in group:
            (reference.episode_terms(episodes.episode(i)).total / len(group)).backward()
        expected = [p.grad for p in reference.model.parameters()]
        for rank in (0, 1):
            torch.testing.assert_close(got[rank][step], expected, rtol=GRAD_RTOL, atol=GRAD_ATOL)
        reference.optimizer.step()


def test_a_killed_rank_leaves_a_checkpoint_that_resumes_exactly(tiny_store, tiny_toml, tmp_path):
    """2 epochs straight == epoch 1, rank 1 killed during epoch 2, then resumed; validation as on one process."""
    cfg = _config(tmp_path, tiny_store, tiny_toml, epochs=2)
    train = ("-m", "learner", "train", cfg, "--nproc", "2", "--device", "cpu", "--out")
    straight = _run(*train, tmp_path / "a")
    assert straight.returncode == 0, straight.stdout + straight.stderr

    killed = _run(*train, tmp_path / "b", env={KILL_AT_ENV: "1:3"})  # rank 1's first step of epoch 2
    assert killed.returncode != 0
    message = killed.stdout.strip().splitlines()[-1]
    assert "rank 1 was killed by SIGKILL" in message and "last.pt resumes it" in message, killed.stdout
    assert "Traceback" not in killed.stdout
    assert load_checkpoint(tmp_path / "b" / "last.pt")["epoch"] == 1

    resumed = _run(*train, tmp_path / "b")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert _rows(tmp_path / "a") == _rows(tmp_path / "b")
    a, b = load_checkpoint(tmp_path / "a" / "last.pt"), load_checkpoint(tmp_path / "b" / "last.pt")
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])

    single = Trainer(config_from_mapping(a["config"]), progress=False)  # one process validates the model alike
    single.resume(tmp_path / "a" / "last.pt")
    assert single.validate() == pytest.approx(_rows(tmp_path / "a")[-1]["val_target_mse"], rel=1e-6)
