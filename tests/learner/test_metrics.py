"""learner.metrics against hand-computed values (the expected numbers are worked out in the comments)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from learner.metrics import (
    METRIC_NAMES,
    activation_error_ms,
    activation_times,
    dice,
    dice_coefficient,
    frame_cc,
    mse,
    otsu_threshold,
    sequence_metrics,
    spatial_cc,
    summarize,
    temporal_cc,
    wave_started,
)
from shared.errors import InputError
from shared.units import MS_PER_TIME_UNIT

# One (T=3, N=3) sequence used by the correlation tests.
#   frame 0: pred constant            -> skipped by spatial_cc
#   frame 1: pred [1,2,3], true [2,4,7]: centred [-1,0,1] and [-7/3,-1/3,8/3],
#            r = 5 / sqrt(2 * 38/3) = 5 / sqrt(76/3) = 0.993399...
#   frame 2: pred [3,2,1], true [1,2,3]: r = -1
PRED = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [3.0, 2.0, 1.0]])
TRUE = np.array([[0.0, 0.0, 1.0], [2.0, 4.0, 7.0], [1.0, 2.0, 3.0]])
R_FRAME1 = 0.9933992677987828


def test_mse_hand_value():
    # diffs [0, 2, 3, 0] -> squares sum 13 over 4 entries
    assert mse([[1.0, 2.0], [3.0, 4.0]], [[1.0, 0.0], [0.0, 4.0]]) == 3.25


def test_mse_batch_pools_sequences():
    pred = np.zeros((2, 1, 2))
    true = np.array([[[1.0, 1.0]], [[3.0, 3.0]]])  # squares 1, 1, 9, 9
    assert mse(pred, true) == 5.0


def test_spatial_cc_hand_value_skips_constant_frame():
    assert R_FRAME1 == pytest.approx(5.0 / math.sqrt(76.0 / 3.0), rel=1e-15)
    assert spatial_cc(PRED, TRUE) == pytest.approx((R_FRAME1 - 1.0) / 2.0, rel=1e-12)


def test_temporal_cc_hand_value():
    # node 0: p [0,1,3], t [0,2,1] -> num 1, sums 14/3 and 2      -> r = 1/sqrt(28/3) = 0.327327...
    # node 1: p [0,2,2], t [0,4,2] -> num 4, sums 8/3 and 8       -> r = sqrt(3)/2    = 0.866025...
    # node 2: p [0,3,1], t [1,7,3] = 2 p + 1                       -> r = 1
    expected = (0.32732683535398854 + 0.8660254037844386 + 1.0) / 3.0
    assert temporal_cc(PRED, TRUE) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(0.7311174130461424, rel=1e-15)


def test_temporal_cc_skips_constant_nodes():
    # node 1 is constant in time in pred (0.1 repeated: centring leaves rounding residue,
    # the skip must not depend on it); node 2 is constant in true. Only node 0 counts: r = -1.
    pred = np.array([[0.0, 0.1, 5.0], [1.0, 0.1, 6.0], [2.0, 0.1, 7.0]])
    true = np.array([[2.0, 0.0, 3.0], [1.0, 1.0, 3.0], [0.0, 2.0, 3.0]])
    assert temporal_cc(pred, true) == -1.0


def test_cc_all_rows_constant_is_nan():
    pred = np.ones((4, 5))
    true = np.arange(20.0).reshape(4, 5)
    assert math.isnan(temporal_cc(pred, true))
    assert math.isnan(spatial_cc(pred, true))


def test_cc_batch_pools_rows():
    batch_p = np.stack([PRED, PRED])
    batch_t = np.stack([TRUE, TRUE])
    assert spatial_cc(batch_p, batch_t) == pytest.approx((R_FRAME1 - 1.0) / 2.0, rel=1e-12)
    assert temporal_cc(batch_p, batch_t) == pytest.approx(temporal_cc(PRED, TRUE), rel=1e-12)
    # pooled over sequences: second sequence is a perfect prediction (3 frames with r = 1)
    ramp = np.arange(6.0).reshape(3, 2) * [1.0, 2.0]
    pooled = spatial_cc(np.stack([PRED[:, :2], ramp]), np.stack([TRUE[:, :2], ramp]))
    # first sequence, 2 nodes: frame 0 pred constant (skip), frame 1 r = 1, frame 2 r = -1
    assert pooled == pytest.approx((1.0 - 1.0 + 3.0) / 5.0, rel=1e-12)


def test_shape_mismatch_names_both_shapes():
    with pytest.raises(InputError, match=r"\(3, 4\).*\(3, 5\)"):
        mse(np.zeros((3, 4)), np.zeros((3, 5)))
    with pytest.raises(InputError, match=r"\(2, 3, 4\).*\(3, 4\)"):
        spatial_cc(np.zeros((2, 3, 4)), np.zeros((3, 4)))
    with pytest.raises(InputError, match=r"\(4,\)"):
        temporal_cc(np.zeros(4), np.zeros(4))
    with pytest.raises(InputError, match=r"\(2, 3, 4\)"):
        dice_coefficient(np.zeros((2, 3, 4)), np.zeros((2, 3, 4)), 0)


def test_otsu_hand_example():
    # splits of [0,0,1,1 | 9,10,10]: w0 w1 (mu0 - mu1)^2 = 12 * (0.5 - 29/3)^2 = 1008.3 beats
    # [0,0 | ...] = 10 * 6.2^2 = 384.4 and [... | 10,10] = 10 * 7.8^2 = 608.4. Bin width 10/256;
    # 1.0 lies in bin 25, so the first best split is edge 26 = 26 * 10/256 = 1.015625.
    x = np.array([0.0, 0.0, 1.0, 1.0, 9.0, 10.0, 10.0])
    assert otsu_threshold(x) == 1.015625
    assert otsu_threshold(x, bins=2) == 5.0  # the only split: [0, 5) | [5, 10]


def test_otsu_constant_input_returns_value():
    assert otsu_threshold(np.full((3, 2), 0.25)) == 0.25
    assert otsu_threshold([7.0]) == 7.0


def _between_class(x, upper):
    w0, w1 = np.sum(~upper), np.sum(upper)
    return w0 * w1 * (x[~upper].mean() - x[upper].mean()) ** 2


def test_otsu_matches_brute_force_on_bimodal_data():
    rng = np.random.default_rng(3)
    for trial in range(4):
        x = np.concatenate([rng.normal(0.1, 0.05, 300 + 50 * trial), rng.normal(0.7, 0.15, 200)])
        thr = otsu_threshold(x)
        # brute force over the 255 split points between the 256 bins
        edges = np.linspace(x.min(), x.max(), 257)[1:-1]
        scores = np.array([_between_class(x, x >= e) if 0 < np.sum(x >= e) < x.size else -1 for e in edges])
        assert thr == edges[np.argmax(scores)]
        assert _between_class(x, x >= thr) == pytest.approx(scores.max(), rel=1e-12)


def test_otsu_separates_modes_like_unbinned_brute_force():
    rng = np.random.default_rng(4)
    x = rng.permutation(np.concatenate([rng.normal(0.2, 0.03, 150), rng.normal(0.8, 0.03, 90)]))
    s = np.sort(x)
    # every split point of the sorted values (no binning)
    best = max(range(1, s.size), key=lambda i: _between_class(s, np.arange(s.size) >= i))
    assert np.array_equal(x >= otsu_threshold(x), x >= s[best])
    assert np.sum(x >= otsu_threshold(x)) == 90


def test_otsu_refuses_bad_input():
    with pytest.raises(InputError, match="finite"):
        otsu_threshold([0.0, np.nan, 1.0])
    with pytest.raises(InputError, match="at least one"):
        otsu_threshold([])
    with pytest.raises(InputError, match="bins"):
        otsu_threshold([0.0, 1.0], bins=1)


def test_dice_hand_values():
    a = np.array([1, 1, 0, 0, 1], dtype=bool)
    b = np.array([1, 0, 0, 1, 1], dtype=bool)
    assert dice(a, b) == pytest.approx(2.0 / 3.0, rel=1e-15)  # 2 * 2 / (3 + 3)
    assert dice(np.zeros(4, bool), np.zeros(4, bool)) == 1.0
    assert dice(np.zeros(4, bool), np.ones(4, bool)) == 0.0
    with pytest.raises(InputError, match="boolean"):
        dice(np.ones(3), np.ones(3))
    with pytest.raises(InputError, match=r"\(3,\).*\(4,\)"):
        dice(np.ones(3, bool), np.ones(4, bool))


def test_dice_coefficient_hand_value():
    # last frame: pred [0, .1, .9, 1, .95] -> Otsu splits {0, .1} | {.9, 1, .95} (6 * .9^2 = 4.86 beats
    # 4 * .7375^2 = 2.18 and 6 * .6417^2 = 2.47) -> mask 00111; true [0,1,1,0,1] -> mask 01101.
    # Dice = 2 * 2 / (3 + 3).
    pred = np.array([[0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.1, 0.9, 1.0, 0.95]])
    true = np.array([[0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 1.0, 0.0, 1.0]])
    assert dice_coefficient(pred, true, -1) == pytest.approx(2.0 / 3.0, rel=1e-15)
    assert dice_coefficient(pred, true, 1) == pytest.approx(2.0 / 3.0, rel=1e-15)
    assert dice_coefficient(pred, true, 0) == 1.0  # constant maps: everything is foreground in both
    with pytest.raises(InputError, match="out of range"):
        dice_coefficient(pred, true, 2)


# Activation example, threshold 0.5, non-uniform times.
TIMES = np.array([0.0, 2.0, 3.0, 7.0])
U = np.array(
    [
        # n0    n1    n2    n3    n4    n5
        [0.00, 0.60, 0.00, 0.00, 0.00, 0.00],
        [0.25, 0.20, 0.00, 0.10, 0.90, 0.00],
        [0.75, 0.90, 0.00, 0.50, 0.00, 0.20],
        [1.00, 0.90, 0.40, 0.20, 0.90, 0.80],
    ]
)
# n0: crosses in [2, 3] at (0.5-0.25)/(0.75-0.25) = 1/2 -> 2.5
# n1: above at frame 0 -> 0 (later dip ignored); n2: never -> NaN
# n3: reaches exactly 0.5 at frame 2 -> 3.0
# n4: crosses in [0, 2] at 0.5/0.9 = 5/9 -> 10/9 (the later re-crossing is ignored)
# n5: crosses in [3, 7] at (0.5-0.2)/(0.8-0.2) = 1/2 -> 5.0
EXPECTED_ACT = np.array([2.5, 0.0, np.nan, 3.0, 10.0 / 9.0, 5.0])


def test_activation_times_hand_example():
    np.testing.assert_allclose(activation_times(U, TIMES), EXPECTED_ACT, rtol=1e-15, atol=0)


def test_activation_times_refuses_bad_times():
    with pytest.raises(InputError, match="increasing"):
        activation_times(U, [0.0, 2.0, 2.0, 7.0])
    with pytest.raises(InputError, match=r"\(4,\)"):
        activation_times(U, [0.0, 1.0])


def test_activation_error_ms_hand_example():
    # true activation (time units): diffs over nodes active in both = n0 .5, n3 .5, n4 0, n5 1 -> mean .5
    # status: n1 active only in pred, n2 never in both -> 1 mismatch of 6 nodes
    true_act = np.array([2.0, np.nan, np.nan, 3.5, 10.0 / 9.0, 4.0])
    err, mismatch = activation_error_ms(U, true_act, TIMES)
    assert err == pytest.approx(0.5 * MS_PER_TIME_UNIT, rel=1e-12)
    assert err == pytest.approx(6.45, rel=1e-12)
    assert mismatch == pytest.approx(1.0 / 6.0, rel=1e-15)


def test_activation_error_nan_when_nothing_activated_in_both():
    true_act = np.array([np.nan, np.nan, 1.0, np.nan, np.nan, np.nan])
    err, mismatch = activation_error_ms(U, true_act, TIMES)
    assert math.isnan(err)
    assert mismatch == 1.0  # n2 only in truth, the other five only in pred
    with pytest.raises(InputError, match=r"\(5,\).*\(4, 6\)"):
        activation_error_ms(U, np.zeros(5), TIMES)


def test_sequence_metrics_perfect_and_consistent():
    times = np.linspace(0.0, 3.0, 7)
    x = np.linspace(0.0, 1.0, 9)
    true = np.clip(2.0 * times[:, None] - 2.0 * x[None, :], 0.0, 1.0)  # a front moving along x
    act = activation_times(true, times)
    m = sequence_metrics(true, true, act, times, dc_frame=3)
    assert tuple(m) == METRIC_NAMES
    assert m == {"mse": 0.0, "cc_spatial": 1.0, "cc_temporal": 1.0, "dc": 1.0, "act_error_ms": 0.0, "act_mismatch": 0.0}

    pred = true + 0.05 * np.random.default_rng(0).standard_normal(true.shape)
    m = sequence_metrics(pred, true, act, times, dc_frame=-2)
    assert m["mse"] == mse(pred, true)
    assert m["cc_spatial"] == spatial_cc(pred, true)
    assert m["cc_temporal"] == temporal_cc(pred, true)
    assert m["dc"] == dice_coefficient(pred, true, -2)
    assert (m["act_error_ms"], m["act_mismatch"]) == activation_error_ms(pred, act, times)


def test_summarize_hand_values_ignores_nan():
    rows = [
        {"mse": 1.0, "dc": 0.5, "act_error_ms": float("nan")},
        {"mse": 3.0, "dc": float("nan"), "act_error_ms": float("nan")},
        {"mse": 2.0, "dc": 1.0, "act_error_ms": float("nan")},
    ]
    s = summarize(rows)
    assert list(s) == ["mse", "dc", "act_error_ms"]
    assert s["mse"]["mean"] == 2.0 and s["mse"]["n"] == 3
    assert s["mse"]["std"] == pytest.approx(math.sqrt(2.0 / 3.0), rel=1e-15)  # deviations -1, 1, 0 (ddof 0)
    assert s["dc"] == {"mean": 0.75, "std": 0.25, "n": 2}
    assert s["act_error_ms"]["n"] == 0 and math.isnan(s["act_error_ms"]["mean"])
    assert summarize([]) == {}


def test_wave_started_counts_the_nodes_that_ever_reach_the_threshold():
    """3 of 4 nodes reach 0.5 in the first sequence (a wave), 1 of 4 in the second (none): by hand."""
    u = np.zeros((2, 3, 4))
    u[0, 1, :3] = [0.9, 0.5, 0.7]  # the third frame may fall again: the peak counts
    u[1, 0, 0] = 1.0  # only the stimulated node
    u[1, 2, 1] = 0.49
    assert wave_started(u).tolist() == [True, False]
    assert wave_started(u[0]) and not wave_started(u[0], share=0.75)


def test_frame_cc_is_each_frames_pearson_and_spatial_cc_their_mean():
    rng = np.random.default_rng(2)
    true, pred = rng.random((5, 30)), rng.random((5, 30))
    true[3] = 0.25  # a constant frame: NaN
    per_frame = frame_cc(pred, true)
    for f in (0, 1, 2, 4):
        assert per_frame[f] == pytest.approx(np.corrcoef(pred[f], true[f])[0, 1], abs=1e-12)
    assert np.isnan(per_frame[3])
    assert spatial_cc(pred, true) == pytest.approx(np.nanmean(per_frame), abs=1e-12)
