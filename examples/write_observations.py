"""Write observation files (the ``--observations`` of ``learner personalize``) from recorded voltages.

The recordings here are simulated: the Aliev-Panfilov potential on an LV of about 400 nodes
with the scar of ``examples/scar.toml``, paced at 3 nodes, kept at the
epicardial sock's 64 electrodes and given in mV with NaN at the nodes that were not
recorded, as measured data would come. :func:`observation_arrays` is the part
that applies to real data: it turns such voltages into the arrays of
docs/formats.md#observation-file; :func:`activation_arrays` turns them into an
activation-time map (each electrode's first crossing of -30 mV, in ms), what a
mapping system exports.

Usage::

    python examples/write_observations.py examples/observations.npz --maps examples/activation_maps.npz
    learner personalize anatomies --observations examples/observations.npz --out heart.pt
    learner personalize anatomies --observations examples/activation_maps.npz --out heart.pt
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
#: Frame times after the stimulus in ms: 55 frames, 7.74 ms apart.
TIMES_MS = 7.74 * np.arange(1, 56)
#: The voltage whose first upward crossing is a node's activation time (u = 0.5).
ACTIVATION_MV = -30.0


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
        "obs_mv": millivolts.astype(np.float32),  # NaN at the nodes not recorded: ignored
        "observed": np.isfinite(millivolts[0, 0]),
        "times_ms": TIMES_MS,
        "points": mesh.points,
        "cells": mesh.cells,
    }


def activation_arrays(mesh: Mesh, sites: Sequence[int], millivolts: np.ndarray) -> dict[str, np.ndarray]:
    """The arrays of an activation-time map: each recorded node's first upward crossing of :data:`ACTIVATION_MV`
    (linear between frames) in ms, inf where it never crosses, NaN where it was not recorded."""
    above = millivolts >= ACTIVATION_MV  # (K, T, N); NaN compares False
    first = np.argmax(above, axis=1)  # (K, N)
    k, n = np.indices(first.shape)
    before = np.maximum(first - 1, 0)
    v0, v1 = millivolts[k, before, n], millivolts[k, first, n]
    t0, t1 = TIMES_MS[before], TIMES_MS[first]
    with np.errstate(invalid="ignore", divide="ignore"):
        crossing = np.where(first > 0, t0 + (ACTIVATION_MV - v0) / (v1 - v0) * (t1 - t0), TIMES_MS[0])
    times = np.where(above.any(axis=1), crossing, np.inf)
    times[:, ~np.isfinite(millivolts[0, 0])] = np.nan
    return {
        "sites": np.asarray(sites, dtype=np.int64),
        "activation_ms": times.astype(np.float32),
        "points": mesh.points,
        "cells": mesh.cells,
    }


def main(argv: Sequence[str] | None = None) -> tuple[Path, Path | None]:
    """Write the example observation file (and, with ``--maps``, its activation-time maps)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the .npz of potentials to write")
    parser.add_argument("--maps", type=Path, help="the .npz of activation-time maps to write")
    args = parser.parse_args(argv)
    mesh = get_mesh("lv", 400)
    millivolts = recorded_millivolts(mesh, SITES)
    np.savez_compressed(args.out, **observation_arrays(mesh, SITES, millivolts))
    print(f"wrote {args.out}: {len(SITES)} recordings on {mesh.n_nodes} nodes, {len(TIMES_MS)} frames")
    if args.maps is not None:
        np.savez_compressed(args.maps, **activation_arrays(mesh, SITES, millivolts))
        print(f"wrote {args.maps}: {len(SITES)} activation-time maps of {ELECTRODES} electrodes")
    return args.out, args.maps


if __name__ == "__main__":
    main()
