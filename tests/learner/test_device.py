"""``--device`` on every learner command that runs a model: the CPU everywhere, CUDA where a GPU is present."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from learner.cli import app
from learner.runtime import resolve_device
from shared.errors import ConfigError
from shared.reader import read_sites

runner = CliRunner()
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")


def _train_config(folder, text: str) -> str:
    path = folder / "train.toml"
    path.write_text(text)
    return str(path)


def _every_command(device: str, store, folder, toml: str) -> None:
    """Train (loader worker process, pinned memory on CUDA), evaluate, personalise and predict on ``device``."""
    result = runner.invoke(app, ["train", _train_config(folder, toml), "--device", device])
    assert result.exit_code == 0, result.output
    best = str(folder / "run" / "best.pt")
    result = runner.invoke(
        app, ["evaluate", best, str(store), "--out", str(folder / "eval"), "--sets", "1", "--device", device]
    )
    assert result.exit_code == 0, result.output
    sites = ",".join(str(s) for s in read_sites(store, "lv")[:2])
    person = folder / "person.pt"
    args = ["--store", str(store), "--subject", "lv-healthy", "--sites", sites, "--out", str(person)]
    result = runner.invoke(app, ["personalize", best, *args, "--device", device])
    assert result.exit_code == 0, result.output
    pred = folder / "pred.npz"
    result = runner.invoke(app, ["predict", str(person), "--sites", "0,7", "--out", str(pred), "--device", device])
    assert result.exit_code == 0, result.output
    assert np.isfinite(np.load(pred)["v_mv"]).all()


def test_every_command_runs_on_the_cpu(tiny_store, tiny_toml, tmp_path):
    _every_command("cpu", tiny_store, tmp_path, tiny_toml(tiny_store, workers=1, train="epochs = 1"))


@CUDA
def test_every_command_runs_on_a_gpu(tiny_store, tiny_toml, tmp_path):
    _every_command("cuda", tiny_store, tmp_path, tiny_toml(tiny_store, workers=1, train="epochs = 1"))


def test_device_strings_are_checked():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ConfigError, match="device must be one of auto, cpu, cuda, cuda:N"):
        resolve_device("gpu0")


@CUDA
def test_each_local_rank_gets_its_own_gpu():
    assert resolve_device("cuda", local_rank=0, world_size=2) == torch.device("cuda", 0)
    with pytest.raises(ConfigError, match="one GPU per local rank"):
        resolve_device("cuda:0", local_rank=1, world_size=2)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message given where no GPU is present")
def test_asking_for_cuda_without_a_gpu_fails_on_one_line(tiny_store, tiny_toml, tmp_path):
    text = tiny_toml(tiny_store, workers=1, train="epochs = 1")
    result = runner.invoke(app, ["train", _train_config(tmp_path, text), "--device", "cuda"])
    assert result.exit_code == 2
    assert "torch finds no CUDA GPU" in result.output and "Traceback" not in result.output
