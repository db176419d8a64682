"""Compare a prediction with a simulation of the same heart: metrics per site and overall, and a figure.

Reads a prediction file (``learner predict --out``) and a simulation file
(``simgen simulate``, ``simulation.npz``), both in physical units
(docs/formats.md), pairs their sequences by paced node, brings the truth onto
the prediction's frames where they differ, and scores each pair with
:func:`learner.metrics.sequence_metrics`: MSE (on ``u``), spatial and temporal
correlation, Dice coefficient of the activated region and the activation-time
error in ms. Refused first: a file compared with itself (the same ``v_mv``),
sequences that are not in mV, and sites whose positions (``site_xyz``) differ
by more than the site tolerance (the files number different meshes).
:func:`plot_comparison` draws truth, prediction and their
activation-time difference side by side on one colour scale.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from learner.evaluate import default_dc_frame
from learner.metrics import sequence_metrics, summarize
from learner.observations import read_npz, resample_frames
from learner.plausibility import check_millivolts
from shared.errors import InputError
from shared.sites import SITE_TOLERANCE
from shared.units import MS_PER_TIME_UNIT, from_millivolts

__all__ = ["Comparison", "compare_files", "plot_comparison"]

#: The arrays each file must hold.
PREDICTION_ARRAYS = ("sites", "site_xyz", "times_ms", "v_mv", "activation_ms", "points", "cells")
SIMULATION_ARRAYS = ("sites", "times_ms", "v_mv", "activation_ms")
#: Read where a simulation file has it (``simgen simulate`` writes it): each site's position in mm.
OPTIONAL_ARRAYS = ("site_xyz",)


@dataclass
class Comparison:
    """Per-site metrics of a prediction against the truth, the overall summary, and what the figure needs."""

    sites: np.ndarray  # (S,) paced node ids
    per_site: list[dict[str, float]]
    overall: dict[str, dict[str, float]]
    points: np.ndarray  # (N, 3) mm
    predicted_ms: np.ndarray  # (S, N) activation times, NaN never
    true_ms: np.ndarray  # (S, N)

    def to_dict(self) -> dict:
        """JSON-ready: every site's metrics and the overall mean, std and count of each."""
        return {
            "sites": [int(s) for s in self.sites],
            "per_site": [{k: _finite(v) for k, v in row.items()} for row in self.per_site],
            "overall": {k: {s: _finite(v) for s, v in stats.items()} for k, stats in self.overall.items()},
        }

    def write_json(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        return path


def _finite(value: float) -> float | None:
    """JSON has no NaN: None stands for it."""
    return float(value) if np.isfinite(value) else None


def _load(path: str | Path, names: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    """The arrays ``names`` of an ``.npz`` file, refused with one line when missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file not found: {path}")
    arrays = read_npz(path, [*names, *OPTIONAL_ARRAYS], f"a {what}")
    missing = [name for name in names if name not in arrays]
    if missing:
        raise InputError(f"{path} is not a {what} file: it lacks {missing} (docs/formats.md)")
    return arrays


def _refuse_mismatch(prediction: Path, simulation: Path, pred: dict, true: dict, rows: dict[int, int]) -> None:
    """Refuse two files that cannot be scored honestly: one file twice, sequences not in mV, or sites at other
    positions (another numbering of the mesh)."""
    if prediction.resolve() == simulation.resolve() or np.array_equal(pred["v_mv"], true["v_mv"]):
        raise InputError(
            f"{prediction} and {simulation} hold the same v_mv: a file compared with itself scores perfectly; "
            "compare the prediction with a simulation of the same sites"
        )
    for path, arrays in ((prediction, pred), (simulation, true)):
        check_millivolts(arrays["v_mv"].astype(np.float64), f"{path}: v_mv", "")
    if "site_xyz" not in true:
        return
    for i, site in enumerate(pred["sites"]):
        a, b = pred["site_xyz"][i], true["site_xyz"][rows[int(site)]]
        if np.linalg.norm(a - b) > SITE_TOLERANCE:
            raise InputError(
                f"site {int(site)} is at {np.round(a, 1).tolist()} mm in {prediction} and at "
                f"{np.round(b, 1).tolist()} mm in {simulation}, {np.linalg.norm(a - b):.1f} mm apart: the files "
                "number the nodes of different meshes (renumbered or resampled); simulate the mesh file the heart "
                "was personalised on, as it is"
            )


def compare_files(prediction: str | Path, simulation: str | Path) -> Comparison:
    """Score every site of ``prediction`` against the same site of ``simulation`` (module docstring)."""
    pred = _load(prediction, PREDICTION_ARRAYS, "prediction")
    true = _load(simulation, SIMULATION_ARRAYS, "simulation")
    n_pred, n_true = pred["v_mv"].shape[-1], true["v_mv"].shape[-1]
    if n_pred != n_true:
        raise InputError(
            f"the prediction covers {n_pred} nodes and the simulation {n_true}: compare on the same mesh "
            "(simulate the mesh file the heart was personalised on, as it is)"
        )
    rows = {int(site): i for i, site in enumerate(true["sites"])}
    missing = [int(s) for s in pred["sites"] if int(s) not in rows]
    if missing:
        raise InputError(f"the simulation has no sequence paced at node(s) {missing}; it has {sorted(rows)}")
    _refuse_mismatch(Path(prediction), Path(simulation), pred, true, rows)
    times = pred["times_ms"].astype(np.float64) / MS_PER_TIME_UNIT
    truth_u = from_millivolts(true["v_mv"][[rows[int(s)] for s in pred["sites"]]].astype(np.float64))
    true_times = true["times_ms"].astype(np.float64) / MS_PER_TIME_UNIT
    if len(true_times) != len(times) or not np.allclose(true_times, times, rtol=1e-3):
        truth_u = resample_frames(truth_u, true_times, times)
    if not np.isfinite(truth_u).all():
        raise InputError(f"{simulation}: v_mv holds NaN (nodes the simulation dropped): compare on the mesh it ran on")
    pred_u = from_millivolts(pred["v_mv"].astype(np.float64))
    true_ms = true["activation_ms"][[rows[int(s)] for s in pred["sites"]]].astype(np.float64)
    dc_frame = default_dc_frame(len(times))
    per_site = [
        sequence_metrics(p, t, a / MS_PER_TIME_UNIT, times, dc_frame) for p, t, a in zip(pred_u, truth_u, true_ms)
    ]
    return Comparison(
        pred["sites"], per_site, summarize(per_site), pred["points"], pred["activation_ms"].astype(np.float64), true_ms
    )


def plot_comparison(comparison: Comparison, path: str | Path) -> Path:
    """Truth, prediction and |prediction - truth| of the activation times, one row per site, front and back;
    truth and prediction on one colour scale."""
    from learner.plot import plot_activation_panels

    rows = []
    for i, site in enumerate(comparison.sites):
        true, pred = comparison.true_ms[i], comparison.predicted_ms[i]
        cc = comparison.per_site[i]["cc_spatial"]
        cols = [("simulated", true), ("predicted", pred), ("difference", np.abs(pred - true), "error")]
        rows.append((f"site {int(site)} (spatial CC {cc:.2f})", cols))
    sites = [comparison.points[int(s)] for s in comparison.sites]
    return plot_activation_panels(comparison.points, rows, path, sites=sites)
