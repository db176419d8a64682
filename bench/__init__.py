"""Benchmarks: one script per thing timed or checked, each run as ``python -m bench.NAME`` from the repository root.

:mod:`bench.common` holds what they share: the ``--out`` folder, the machine header and best-of timing.
"""
