"""Write an observation file (the ``--observations`` of ``learner personalize``) from recorded voltages.

The recordings here are simulated: the Aliev-Panfilov potential on an LV of about 400 nodes
with the scar of ``examples/scar.toml``, paced at 3 nodes, kept at the
epicardial sock's 64 electrodes and given in mV with NaN at the nodes that were not
recorded, as measured data would come. :func:`observation_arrays` is the part
that applies to real data: it turns such voltages into the arrays of
docs/formats.md#observation-file.

Usage::

    python examples/write_observations.py examples/observations.npz
    learner personalize anatomies --observations examples/observations.npz --out heart.pt
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from shared.config import load_toml
from shared.mesh import Mesh
from simgen.meshes import get_mesh
from simgen.observe import Sock
from simgen.solver import Simulator
from simgen.tissue import tissue_fields, tissue_spec_from_mapping

HERE = Path(__file__).resolve().parent
#: The paced node of each recording.
SITES = (0, 150, 310)
#: Electrodes of the epicardial sock (247 on meshes of 1,000 nodes and more).
ELECTRODES = 64
#: Frame times after the stimulus, in model time units (1 unit = 12.9 ms): 55 frames, 0.6 apart.
TIMES = 0.6 * np.arange(1, 56)


def recorded_millivolts(mesh: Mesh, sites: Sequence[int], seed: int = 0) -> np.ndarray:
    """(K, 55, N) voltages in mV at the sock's electrodes (noise 2 mV), NaN at the other nodes."""
    spec = tissue_spec_from_mapping(load_toml(HERE / "scar.toml"))
    u = Simulator(mesh, tissue_fields(mesh, spec)).run(np.asarray(sites), threads=2).u
    volts = 100.0 * u - 80.0 + np.random.default_rng(seed).normal(0.0, 2.0, u.shape)
    recorded = np.zeros(mesh.n_nodes, dtype=bool)
    recorded[Sock(n_electrodes=ELECTRODES).indices(mesh)] = True
    return np.where(recorded, volts, np.nan)


def observation_arrays(mesh: Mesh, sites: Sequence[int], millivolts: np.ndarray) -> dict[str, np.ndarray]:
    """The arrays of an observation file from (K, 55, N) voltages in mV, NaN where a node was not recorded."""
    return {
        "sites": np.asarray(sites, dtype=np.int64),
        "obs": np.nan_to_num((millivolts + 80.0) / 100.0).astype(np.float32),  # u = (V + 80) / 100
        "observed": np.isfinite(millivolts[0, 0]),
        "times": TIMES,
        "points": mesh.points,
        "cells": mesh.cells,
    }


def main(argv: Sequence[str] | None = None) -> Path:
    """Write the example observation file to the path given on the command line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the .npz to write")
    out = parser.parse_args(argv).out
    mesh = get_mesh("lv", 400)
    np.savez_compressed(out, **observation_arrays(mesh, SITES, recorded_millivolts(mesh, SITES)))
    print(f"wrote {out}: {len(SITES)} recordings on {mesh.n_nodes} nodes, {len(TIMES)} frames")
    return out


if __name__ == "__main__":
    main()
