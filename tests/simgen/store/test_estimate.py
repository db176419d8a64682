"""The plan of a build: its disk and memory estimates against a real build, and the refusals."""

from __future__ import annotations

from dataclasses import replace

import pytest

from simgen.store import make_plan, spec_from_mapping, validate_plan
from simgen.store.estimate import ResourceError, check_resources, estimate_build, human, task_memory


@pytest.fixture(scope="module")
def estimate(tiny_spec, tmp_path_factory):
    """The calibrated estimate of :func:`tiny_spec` into a new store."""
    plan = make_plan(tiny_spec())
    return estimate_build(plan, validate_plan(plan), str(tmp_path_factory.mktemp("plan") / "s.zarr"), None, 2)


def test_the_disk_estimate_is_close_to_a_built_store(estimate, reference_store):
    built = sum(p.stat().st_size for p in reference_store.rglob("*") if p.is_file())
    assert 0.8 * built < estimate.disk < 1.5 * built


def test_the_plan_counts_subjects_and_simulations(estimate):
    assert (estimate.subjects, estimate.tasks, estimate.simulations, estimate.frames) == (2, 4, 12, 8)
    assert estimate.seconds is not None and 0 < estimate.seconds < 60
    assert estimate.memory_limit > 0 and estimate.free > 0 and estimate.store_bytes == 0
    lines = "\n".join(estimate.lines())
    assert "subjects: 2 (1 mesh(es) x 2 tissue setting(s))" in lines and "on 2 worker(s)" in lines


def test_task_memory_follows_the_measured_worker_peak():
    """deploy/README.md: one chunk of 25 sites x 55 frames on a 2,049-node LV peaked at 244 MiB (blosc)."""
    spec = {"meshes": [{"id": "lv", "nodes": 2000}], "tissue": ["healthy"], "sites": {"count": 25}}
    plan = make_plan(spec_from_mapping({**spec, "output": {"compressor": "blosc"}}))
    assert 230 * 2**20 < task_memory(plan) < 300 * 2**20


def test_a_task_larger_than_a_worker_is_refused_with_the_numbers(estimate):
    with pytest.raises(
        ResourceError, match=r"a task needs ~.* MiB but a worker may use 95\.0 MiB \(memory limit 100\.0"
    ):
        check_resources(replace(estimate, memory_limit=100 * 2**20))


def test_a_store_larger_than_the_free_space_is_refused_with_the_numbers(estimate):
    with pytest.raises(ResourceError, match=r"needs ~.* more disk space but only 1\.0 KiB is free"):
        check_resources(replace(estimate, free=1024))
    check_resources(replace(estimate, free=1024, store_bytes=estimate.disk))  # a resumed build needs the rest only
    check_resources(replace(estimate, free=None, memory_limit=None))  # unknown: not checked


def test_human_sizes():
    assert [human(n) for n in (512, 2048, 3 * 2**30)] == ["512 B", "2.0 KiB", "3.0 GiB"]
