"""bench.convergence's summary: every site, and the sites paced outside scars, each with its converged resolution."""

from __future__ import annotations

import math

from bench.convergence import figures, summary, verdict


def _row(target: int, cc: list[float], error: list[float], flip: list[bool], share: list[float]) -> dict:
    return {"target": target, "site_cc": cc, "site_error_ms": error, "site_flip": flip, "site_scar_share": share}


def test_the_sites_paced_in_a_scar_are_summarised_apart() -> None:
    nan = float("nan")
    rows = [
        # at 1k a site paced in a scar flips and a healthy one is 6 ms off; at 2k the scar site is 12 ms late
        _row(1000, [0.97, nan, 0.96], [6.0, nan, 4.6], [False, True, False], [0.0, 0.8, 0.2]),
        _row(2000, [0.99, 0.90, 0.98], [2.0, 12.0, 3.0], [False, False, False], [0.0, 0.8, 0.2]),
        _row(5000, [0.99, 0.99, 0.99], [1.0, 2.0, 1.0], [False, False, False], [0.0, 0.8, 0.2]),
    ]
    every = figures(rows[1])
    assert every["flips"] == 0 and every["cc_min"] == 0.90 and every["error_worst_ms"] == 12.0
    assert math.isclose(every["error_mean_ms"], 17.0 / 3)
    lines, converged = summary(rows, [1000, 2000, 5000, 20000])
    assert converged == {"every site": 5000, "paced outside scars": 2000}
    assert "| 1000 | every site | 1 | 0.960 | 5.3 | 6.0 |" in lines
    assert "| 2000 | paced outside scars | 0 | 0.980 | 2.5 | 3.0 |" in lines
    assert verdict(converged).endswith("every site from 5000 nodes; paced outside scars from 2000 nodes.")
