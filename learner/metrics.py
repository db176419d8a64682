"""Accuracy metrics of a surrogate against simulated truth (defined in docs/surrogate.md).

All functions are pure NumPy and compute in float64. A *sequence* is an array
``(T, N)`` of frames x nodes; :func:`mse`, :func:`spatial_cc` and
:func:`temporal_cc` also take a batch ``(S, T, N)`` of sequences and pool it.
The map metrics (:func:`dice_coefficient`, :func:`activation_times`,
:func:`activation_error_ms`, :func:`sequence_metrics`) take one sequence.

Metrics
-------
- MSE over frames and nodes.
- CC, reported two ways because the paper does not say which one it uses:
  spatial (Pearson over nodes per frame, mean over frames) and temporal
  (Pearson over time per node, mean over nodes). Rows where either signal is
  constant have no defined correlation and are skipped, as the reference does.
- DC: Dice of the Otsu-thresholded predicted and true maps at one (late) frame.
- Activation-time error in ms over nodes activated in both, plus the fraction
  of nodes whose activated / never-activated status disagrees.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InputError
from shared.units import MS_PER_TIME_UNIT

__all__ = [
    "mse",
    "spatial_cc",
    "frame_cc",
    "temporal_cc",
    "otsu_threshold",
    "dice",
    "dice_coefficient",
    "activation_times",
    "wave_started",
    "activation_error_ms",
    "sequence_metrics",
    "summarize",
    "METRIC_NAMES",
]

#: Keys of the dictionary returned by :func:`sequence_metrics`, in report order.
METRIC_NAMES: tuple[str, ...] = ("mse", "cc_spatial", "cc_temporal", "dc", "act_error_ms", "act_mismatch")


def _pair(pred: ArrayLike, true: ArrayLike, ndims: tuple[int, ...] = (2, 3)) -> tuple[NDArray, NDArray]:
    """Both arrays as float64, refusing different shapes or a wrong rank."""
    p = np.asarray(pred, dtype=np.float64)
    t = np.asarray(true, dtype=np.float64)
    if p.shape != t.shape:
        raise InputError(f"pred and true must have the same shape, got pred {p.shape} and true {t.shape}")
    if p.ndim not in ndims:
        want = " or ".join(("(T, N)", "(S, T, N)")[d - 2] for d in ndims)
        raise InputError(f"pred and true must be {want} arrays, got shape {p.shape}")
    if p.size == 0:
        raise InputError(f"pred and true are empty (shape {p.shape})")
    return p, t


def _rowwise_pearson(a: NDArray, b: NDArray) -> NDArray:
    """Pearson correlation of each row pair of ``a``, ``b`` (R, L); NaN where a row is constant.

    .. math:: r = \\frac{\\sum (a - \\bar a)(b - \\bar b)}{\\sqrt{\\sum (a - \\bar a)^2 \\sum (b - \\bar b)^2}}
    """
    ac = a - a.mean(axis=1, keepdims=True)
    bc = b - b.mean(axis=1, keepdims=True)
    num = np.einsum("rl,rl->r", ac, bc)
    den = np.sqrt(np.einsum("rl,rl->r", ac, ac) * np.einsum("rl,rl->r", bc, bc))
    # Constancy is tested exactly on the raw values (max == min): centring a
    # constant row can leave rounding residue that would fake a correlation.
    ok = (np.ptp(a, axis=1) > 0) & (np.ptp(b, axis=1) > 0) & (den > 0)
    r = np.full(a.shape[0], np.nan)
    r[ok] = np.clip(num[ok] / den[ok], -1.0, 1.0)
    return r


def _mean_skipping_nan(r: NDArray) -> float:
    """Mean of the finite entries; NaN when there are none (no RuntimeWarning)."""
    r = r[np.isfinite(r)]
    return float(r.mean()) if r.size else float("nan")


def mse(pred: ArrayLike, true: ArrayLike) -> float:
    """Mean squared error over all frames and nodes (and sequences for ``(S, T, N)``)."""
    p, t = _pair(pred, true)
    return float(np.mean((p - t) ** 2))


def spatial_cc(pred: ArrayLike, true: ArrayLike) -> float:
    """Spatial correlation: Pearson over nodes for each frame, averaged over frames.

    Frames where the predicted or the true map is constant (e.g. the resting
    heart before the stimulus spreads) are skipped. A batch ``(S, T, N)`` pools
    the frames of all sequences. NaN when every frame is constant.
    """
    p, t = _pair(pred, true)
    n = p.shape[-1]
    return _mean_skipping_nan(_rowwise_pearson(p.reshape(-1, n), t.reshape(-1, n)))


def frame_cc(pred: ArrayLike, true: ArrayLike) -> NDArray[np.float64]:
    """Spatial correlation of each frame of a sequence ``(T, N)``: ``(T,)``, NaN where a map is constant.

    :func:`spatial_cc` is their mean over the frames that are not NaN.
    """
    p, t = _pair(pred, true, ndims=(2,))
    return _rowwise_pearson(p, t)


def temporal_cc(pred: ArrayLike, true: ArrayLike) -> float:
    """Temporal correlation: Pearson over frames for each node, averaged over nodes.

    Nodes whose predicted or true signal is constant in time are skipped. A
    batch ``(S, T, N)`` pools the nodes of all sequences. NaN when every node's
    signal is constant.
    """
    p, t = _pair(pred, true)
    steps = p.shape[-2]
    rows_p = np.swapaxes(p, -1, -2).reshape(-1, steps)
    rows_t = np.swapaxes(t, -1, -2).reshape(-1, steps)
    return _mean_skipping_nan(_rowwise_pearson(rows_p, rows_t))


def otsu_threshold(values: ArrayLike, bins: int = 256) -> float:
    """Otsu's threshold of ``values``: the split maximising the between-class variance.

    The values are binned into ``bins`` equal bins over ``[min, max]``; each
    split between bin ``k`` and ``k + 1`` scores
    :math:`w_0 w_1 (\\mu_0 - \\mu_1)^2`, with class counts ``w`` and class
    means ``mu`` taken from the exact values in the bins (not bin centres). The
    result is the edge between the two classes, so ``values >= threshold`` is
    exactly the upper class. The first best split wins ties. Constant input
    returns its value (everything is the upper class).

    Parameters
    ----------
    values : array of any shape, finite.
    bins : number of histogram bins, >= 2.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 2:
        raise InputError(f"bins must be an integer >= 2, got {bins!r}")
    if x.size == 0:
        raise InputError("otsu_threshold needs at least one value")
    if not np.all(np.isfinite(x)):
        raise InputError("otsu_threshold needs finite values (found NaN or inf)")
    lo, hi = float(x.min()), float(x.max())
    if lo == hi:
        return lo
    # np.histogram puts x in bin i iff edges[i] <= x < edges[i+1] (last bin
    # closed), so returning an edge makes ">=" agree with the binning exactly.
    counts, edges = np.histogram(x, bins=int(bins), range=(lo, hi))
    sums, _ = np.histogram(x, bins=edges, weights=x)
    w0 = np.cumsum(counts)[:-1].astype(np.float64)  # split after bin k, k = 0..bins-2
    s0 = np.cumsum(sums)[:-1]
    w1 = x.size - w0
    s1 = sums.sum() - s0
    score = np.full(w0.shape, -np.inf)
    ok = (w0 > 0) & (w1 > 0)
    score[ok] = w0[ok] * w1[ok] * (s0[ok] / w0[ok] - s1[ok] / w1[ok]) ** 2
    return float(edges[int(np.argmax(score)) + 1])


def dice(a_mask: ArrayLike, b_mask: ArrayLike) -> float:
    """Dice coefficient :math:`2|A \\cap B| / (|A| + |B|)` of two boolean masks; 1.0 when both are empty."""
    a = np.asarray(a_mask)
    b = np.asarray(b_mask)
    if a.shape != b.shape:
        raise InputError(f"masks must have the same shape, got a_mask {a.shape} and b_mask {b.shape}")
    if a.dtype != np.bool_ or b.dtype != np.bool_:
        raise InputError(f"masks must be boolean arrays, got a_mask {a.dtype} and b_mask {b.dtype}")
    total = int(a.sum()) + int(b.sum())
    if total == 0:
        return 1.0
    return 2.0 * int(np.logical_and(a, b).sum()) / total


def _frame_index(frame: int, n_frames: int) -> int:
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)):
        raise InputError(f"frame must be an integer, got {frame!r}")
    if not -n_frames <= frame < n_frames:
        raise InputError(f"frame {frame} is out of range for {n_frames} frames")
    return int(frame) % n_frames


def dice_coefficient(pred: ArrayLike, true: ArrayLike, frame: int) -> float:
    """Dice of the Otsu-thresholded predicted and true maps at one frame.

    Each map is thresholded at its own Otsu threshold (``u >= otsu(u)``). The
    paper evaluates a late frame; negative ``frame`` counts from the end.

    Parameters
    ----------
    pred, true : (T, N) one sequence.
    frame : frame index.
    """
    p, t = _pair(pred, true, ndims=(2,))
    k = _frame_index(frame, p.shape[0])
    return dice(p[k] >= otsu_threshold(p[k]), t[k] >= otsu_threshold(t[k]))


def _check_times(times: ArrayLike, n_frames: int) -> NDArray:
    tt = np.asarray(times, dtype=np.float64)
    if tt.shape != (n_frames,):
        raise InputError(f"times must have shape ({n_frames},) to match the frames, got {tt.shape}")
    if not np.all(np.isfinite(tt)) or np.any(np.diff(tt) <= 0):
        raise InputError("times must be finite and strictly increasing")
    return tt


def wave_started(u: ArrayLike, threshold: float = 0.5, share: float = 0.5) -> NDArray[np.bool_]:
    """Whether each simulation's stimulus started a wave: more than ``share`` of its nodes ever reach ``threshold``.

    ``u`` is ``(S, T, N)`` (or one ``(T, N)`` sequence). A stimulus in a
    scar core that starts no wave excites a few nodes around the site only.
    """
    u = np.asarray(u)
    return (u.max(axis=-2) >= threshold).mean(axis=-1) > share


def activation_times(u: ArrayLike, times: ArrayLike, threshold: float = 0.5) -> NDArray[np.float64]:
    """First upward crossing of ``threshold`` per node, linearly interpolated between frames.

    If frame ``k`` is the first with ``u[k] >= threshold`` then
    :math:`t = t_{k-1} + (\\theta - u_{k-1}) / (u_k - u_{k-1}) (t_k - t_{k-1})`;
    a node already at or above threshold in frame 0 gets ``times[0]``.
    Resolution is limited by the frame spacing (the simulator records its
    activation times at step resolution).

    Parameters
    ----------
    u : (T, N) one sequence, finite.
    times : (T,) strictly increasing frame times (model time units).
    threshold : activation threshold on ``u``.

    Returns
    -------
    (N,) float64 activation times in the units of ``times``; NaN = never.
    """
    x = np.asarray(u, dtype=np.float64)
    if x.ndim != 2 or x.size == 0:
        raise InputError(f"u must be a non-empty (T, N) array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError("u must be finite to find activation times (found NaN or inf)")
    tt = _check_times(times, x.shape[0])
    above = x >= threshold
    ever = above.any(axis=0)
    first = np.argmax(above, axis=0)  # first True per node (0 when never: masked below)
    prev = np.maximum(first - 1, 0)
    nodes = np.arange(x.shape[1])
    u0, u1 = x[prev, nodes], x[first, nodes]
    t0, t1 = tt[prev], tt[first]
    out = np.full(x.shape[1], np.nan)
    at_start = ever & (first == 0)
    out[at_start] = tt[0]
    cross = ever & (first > 0)  # here u0 < threshold <= u1, so u1 - u0 > 0
    frac = (threshold - u0[cross]) / (u1[cross] - u0[cross])
    out[cross] = t0[cross] + frac * (t1[cross] - t0[cross])
    return out


def activation_error_ms(
    pred_u: ArrayLike, true_activation: ArrayLike, times: ArrayLike, threshold: float = 0.5
) -> tuple[float, float]:
    """Activation-time error of a predicted sequence against true activation times.

    Parameters
    ----------
    pred_u : (T, N) predicted sequence.
    true_activation : (N,) true activation times in model time units (NaN = never).
    times : (T,) frame times in model time units.
    threshold : activation threshold on ``u``.

    Returns
    -------
    error_ms : mean ``|t_pred - t_true|`` in ms (``MS_PER_TIME_UNIT``) over nodes
        activated in both; NaN when no node is.
    mismatch : fraction of nodes activated in exactly one of the two.
    """
    t_true = np.asarray(true_activation, dtype=np.float64)
    p = np.asarray(pred_u)
    if p.ndim != 2 or t_true.shape != (p.shape[1],):
        raise InputError(
            f"true_activation must have shape (N,) matching pred_u (T, N), got true_activation {t_true.shape} "
            f"and pred_u {p.shape}"
        )
    t_pred = activation_times(p, times, threshold)
    on_pred, on_true = np.isfinite(t_pred), np.isfinite(t_true)
    both = on_pred & on_true
    error = float(np.mean(np.abs(t_pred[both] - t_true[both]))) * MS_PER_TIME_UNIT if both.any() else float("nan")
    return error, float(np.mean(on_pred != on_true))


def sequence_metrics(
    pred: ArrayLike,
    true: ArrayLike,
    true_activation: ArrayLike,
    times: ArrayLike,
    dc_frame: int,
    threshold: float = 0.5,
) -> dict[str, float]:
    """All metrics of one predicted sequence (T, N) against the truth.

    Returns a dict with keys :data:`METRIC_NAMES`: ``mse``, ``cc_spatial``,
    ``cc_temporal``, ``dc`` (at ``dc_frame``), ``act_error_ms``, ``act_mismatch``.
    """
    p, t = _pair(pred, true, ndims=(2,))
    act_error, act_mismatch = activation_error_ms(p, true_activation, times, threshold)
    return {
        "mse": mse(p, t),
        "cc_spatial": spatial_cc(p, t),
        "cc_temporal": temporal_cc(p, t),
        "dc": dice_coefficient(p, t, dc_frame),
        "act_error_ms": act_error,
        "act_mismatch": act_mismatch,
    }


def summarize(results: Iterable[Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """Mean, standard deviation (ddof = 0) and count of each metric, ignoring NaNs.

    Parameters
    ----------
    results : per-sequence dicts such as :func:`sequence_metrics` returns.

    Returns
    -------
    ``{metric: {"mean": m, "std": s, "n": n}}`` for every key seen, in order of
    first appearance; ``n`` counts the non-NaN values (mean and std are NaN
    when ``n == 0``).
    """
    columns: dict[str, list[float]] = {}
    for row in results:
        for key, value in row.items():
            columns.setdefault(key, []).append(float(value))
    summary: dict[str, dict[str, float]] = {}
    for key, column in columns.items():
        v = np.asarray(column, dtype=np.float64)
        v = v[~np.isnan(v)]
        if v.size:
            summary[key] = {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}
        else:
            summary[key] = {"mean": float("nan"), "std": float("nan"), "n": 0}
    return summary
