"""The 12-lead ECG as what a personalisation reads: a mesh's lead field and ECGs ready for the encoder.

A 12-lead pseudo-ECG is linear in the potential (:meth:`shared.ecg.PseudoECG.lead_matrix`): the leads of a
sequence ``u`` (T, N) are ``L u^T`` with ``L`` (12, N). :class:`LeadField` keeps ``L`` of one mesh and
electrode set, to give the ECG of any predicted sequence, and its density per unit volume
(:attr:`LeadField.density`), each lead scaled to a largest magnitude of 1: what the ECG encoder reads at each
node (:class:`~learner.models.ecg_encoder.EcgEncoder`), the same at any resolution.

The lead field is the healthy tissue's (no tissue is known before personalisation): scar lowers the
conductivity that weighs each element, so the ECG of a prediction leaves that out (docs/method.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from shared.ecg import LEADS, Electrodes, PseudoECG, standard_electrodes
from shared.errors import InputError
from shared.fem import lumped_mass
from shared.mesh import Mesh

__all__ = ["LeadField", "normalised_ecg", "resample_ecg"]


@dataclass(frozen=True)
class LeadField:
    """The 12 leads' weights on a mesh's nodes: ``matrix`` (12, N), mV per unit of ``u``, and ``density``
    (N, 12), the weights per unit volume, each lead scaled to a largest magnitude of 1."""

    matrix: Tensor
    density: Tensor

    @classmethod
    def of_mesh(cls, mesh: Mesh, electrodes: Electrodes | None = None, scale: NDArray | None = None) -> LeadField:
        """The lead field of ``mesh`` (tetrahedra) for ``electrodes`` (None: the standard placement by the
        heart's axes, :func:`shared.ecg.standard_electrodes`); ``scale``: the tissue's diffusivity per node."""
        electrodes = standard_electrodes(mesh) if electrodes is None else electrodes
        matrix = PseudoECG.assemble(mesh, electrodes, scale).lead_matrix()
        density = matrix.T / lumped_mass(mesh)[:, None]
        density = density / np.maximum(np.abs(density).max(axis=0), 1e-30)
        return cls(torch.as_tensor(matrix, dtype=torch.float32), torch.as_tensor(density, dtype=torch.float32))

    def ecg(self, u: Tensor) -> Tensor:
        """The 12 leads (..., 12, T) in mV of sequences ``u`` (..., T, N)."""
        return torch.matmul(u, self.matrix.T.to(u.dtype)).transpose(-1, -2)

    def to(self, device: torch.device | str) -> LeadField:
        return LeadField(self.matrix.to(device), self.density.to(device))


def normalised_ecg(ecg: Tensor) -> Tensor:
    """A context set's ECGs (K, 12, T) over their largest magnitude: the encoder reads shapes and the leads'
    and recordings' relative sizes, not the amplitude in mV, which the torso sets (docs/method.md)."""
    return ecg / ecg.abs().amax().clamp_min(1e-6)


def resample_ecg(ecg: NDArray, times_ms: NDArray, model_times_ms: NDArray, leads: list[str] | None = None) -> NDArray:
    """ECGs (K, 12, T) at ``times_ms`` linearly resampled to ``model_times_ms``, leads reordered to
    :data:`~shared.ecg.LEADS` from their names ``leads`` (None: already in that order); frames before the first
    sample hold its value (the resting baseline), and so do those at most one recording interval after the last.
    Refuses what cannot be read, naming the problem."""
    ecg, times_ms = np.asarray(ecg, np.float64), np.asarray(times_ms, np.float64).reshape(-1)
    if ecg.ndim != 3 or ecg.shape[1] != len(LEADS) or ecg.shape[2] != len(times_ms):
        raise InputError(
            f"ecg has shape {ecg.shape}: it must be (recordings, {len(LEADS)} leads, frames) with one frame per "
            f"ecg_times_ms value ({len(times_ms)})"
        )
    if leads is not None:
        names = [str(n) for n in leads]
        missing = [n for n in LEADS if n not in names]
        if missing or len(names) != len(LEADS):
            raise InputError(f"leads {names}: the ECG needs the 12 leads {list(LEADS)} once each (missing {missing})")
        ecg = ecg[:, [names.index(n) for n in LEADS]]
    if not np.isfinite(ecg).all():
        raise InputError("ecg contains NaN or inf")
    if len(times_ms) < 2 or np.any(np.diff(times_ms) <= 0):
        raise InputError("ecg_times_ms must hold at least 2 increasing times (ms)")
    end, step = float(np.max(model_times_ms)), float(np.max(np.diff(times_ms)))
    if times_ms[-1] < end - step:
        raise InputError(
            f"the ECG ends at {times_ms[-1]:.1f} ms; the model needs it up to {end:.1f} ms after the stimulus "
            f"(frames at {model_times_ms[0]:.1f}, {model_times_ms[1]:.1f}, ... {end:.1f} ms)"
        )
    flat = ecg.reshape(-1, ecg.shape[-1])
    out = np.stack([np.interp(model_times_ms, times_ms, row) for row in flat])
    return out.reshape(*ecg.shape[:2], len(model_times_ms)).astype(np.float32)
