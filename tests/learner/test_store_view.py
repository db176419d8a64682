"""StoreView's statistics of a store."""

from __future__ import annotations

import numpy as np
import zarr

from learner.store_view import StoreView
from shared.schema import subject_path


def test_frame_means_average_every_site_and_node(tiny_store):
    subjects = ["lv-healthy", "lv-b-healthy"]  # 500- and 600-node meshes: the mean is over values, not subjects
    values = [zarr.open_group(tiny_store, path=subject_path(s), mode="r")["u"][...] for s in subjects]
    per_frame = np.concatenate([v.transpose(1, 0, 2).reshape(v.shape[1], -1) for v in values], axis=1)
    np.testing.assert_allclose(StoreView(tiny_store).frame_means(subjects), per_frame.mean(axis=1), rtol=1e-6)
