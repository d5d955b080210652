"""Dataset statistics with the keys and shapes of ``lerobot.datasets.compute_stats``, computed exactly.

Where they differ from LeRobot's on purpose (and ``info.json``'s ``hub_envs.stats`` says so): quantiles are
exact (``np.quantile``'s linear method; LeRobot interpolates 5000-bin histograms), and image std is computed
in float64 (LeRobot squares uint8 pixels, which overflows, so its image std is often 0). Image stats use
LeRobot's frame sampling (``count`` = sampled frames) and downsampling; global stats aggregate episode
stats with LeRobot's formula.

    >>> import numpy as np
    >>> s = vector_stats(np.arange(10, dtype=np.float32))
    >>> float(s["mean"][0]), float(s["q50"][0]), s["count"].tolist()
    (4.5, 4.5, [10])
"""

from __future__ import annotations

import functools

import numpy as np

from hub_envs._compat import stats_extremes_as_float

try:  # LeRobot depends on opencv; used only for fast image histograms
    import cv2 as _cv2
except ImportError:  # pragma: no cover
    _cv2 = None

__all__ = ["QUANTILES", "QUANTILE_KEYS", "STATS_NOTE", "vector_stats", "vector_stats_many", "image_stats", "aggregate_stats"]

STATS_EXTREMES_AS_FLOAT = stats_extremes_as_float()
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{int(q * 100):02d}" for q in QUANTILES)
#: Recorded in ``info.json`` (``hub_envs.stats``): how these stats differ from LeRobot's own.
STATS_NOTE = (
    "exact quantiles (numpy linear interpolation; LeRobot interpolates 5000-bin histograms); "
    "image std computed in float64 (LeRobot's uint8 arithmetic can overflow to 0)"
)

# --- stats (same keys/shapes as lerobot.datasets.compute_stats) --------------------------------


@functools.lru_cache(maxsize=64)
def _sample_indices(n: int) -> np.ndarray:
    """LeRobot's image frame sampling (compute_stats.sample_indices / estimate_num_samples); made once per episode
    length (read-only)."""
    min_num, max_num, power = 100, 10_000, 0.75
    if n < min_num:
        min_num = n
    num = max(min_num, min(int(n**power), max_num))
    indices = np.round(np.linspace(0, n - 1, num)).astype(int)
    indices.flags.writeable = False
    return indices


def _downsample(images: np.ndarray) -> np.ndarray:
    """LeRobot's auto_downsample_height_width, on (N, H, W, C) arrays."""
    _, h, w, _ = images.shape
    if max(w, h) < 300:
        return images
    factor = int(w / 150) if w > h else int(h / 150)
    return images[:, ::factor, ::factor]


def _quantiles(values: np.ndarray) -> np.ndarray:
    """``np.quantile(values, QUANTILES, axis=0)`` (method "linear", same arithmetic), without its overhead."""
    n = values.shape[0]
    ordered = np.sort(values, axis=0)
    pos = (n - 1) * np.asarray(QUANTILES)
    lo = np.floor(pos).astype(np.intp)
    hi = np.minimum(lo + 1, n - 1)
    t = (pos - lo).reshape(-1, *([1] * (values.ndim - 1)))
    a, b = ordered[lo], ordered[hi]
    diff = b - a
    return np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)  # numpy's _lerp


def vector_stats(arr: np.ndarray) -> dict[str, np.ndarray]:
    """Stats over axis 0 of (T, *shape); results have ``shape`` (shape (1,) for scalar columns)."""
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1)
    as_float = arr.astype(np.float64, copy=False)
    mean = as_float.mean(axis=0)
    extremes = as_float if STATS_EXTREMES_AS_FLOAT else arr  # as the installed LeRobot writes them
    stats = {
        "min": extremes.min(axis=0),
        "max": extremes.max(axis=0),
        "mean": mean,
        "std": np.sqrt(np.maximum(0.0, ((as_float - mean) ** 2).mean(axis=0))),
        "count": np.array([arr.shape[0]], dtype=np.int64),
    }
    for key, q in zip(QUANTILE_KEYS, _quantiles(as_float), strict=True):
        stats[key] = q
    return stats


def vector_stats_many(columns: list[np.ndarray]) -> list[dict[str, np.ndarray]]:
    """:func:`vector_stats` of each column, the same values bit for bit, with the scalar columns ((T,) or (T, 1)) of one
    length done together: one row each of a (K, T) float64 array, so a few numpy calls serve them all (an episode's
    ``next.*``, ``timestamp`` and index columns would otherwise cost a dozen calls each)."""
    out: list[dict[str, np.ndarray] | None] = [None] * len(columns)
    scalar = [i for i, c in enumerate(columns) if c.ndim == 1 or (c.ndim == 2 and c.shape[1] == 1)]
    by_length: dict[int, list[int]] = {}
    for i in scalar:
        by_length.setdefault(columns[i].shape[0], []).append(i)
    for n, idx in by_length.items():
        if len(idx) < 2 or n == 0:
            continue
        rows = np.empty((len(idx), n), dtype=np.float64)
        for r, i in enumerate(idx):
            rows[r] = columns[i].reshape(n)
        mean = rows.mean(axis=1)  # each row contiguous: numpy's pairwise sum, as for a lone (T, 1) column
        std = np.sqrt(np.maximum(0.0, ((rows - mean[:, None]) ** 2).mean(axis=1)))
        quantiles = _quantiles(rows.T)  # (Q, K)
        if STATS_EXTREMES_AS_FLOAT:
            mins, maxs = rows.min(axis=1), rows.max(axis=1)
        for r, i in enumerate(idx):
            col = columns[i].reshape(n, 1)
            stats = {
                "min": mins[r : r + 1] if STATS_EXTREMES_AS_FLOAT else col.min(axis=0),
                "max": maxs[r : r + 1] if STATS_EXTREMES_AS_FLOAT else col.max(axis=0),
                "mean": mean[r : r + 1],
                "std": std[r : r + 1],
                "count": np.array([n], dtype=np.int64),
            }
            for q, key in enumerate(QUANTILE_KEYS):
                stats[key] = quantiles[q, r : r + 1]
            out[i] = stats
    return [stats if stats is not None else vector_stats(col) for stats, col in zip(out, columns, strict=True)]


def _channel_histograms(images: np.ndarray) -> np.ndarray:
    """(C, 256) int64 pixel counts per channel of (N, H, W, C) uint8 images."""
    n, h, w, c = images.shape
    if _cv2 is not None and n * h * w < 2**24 and c <= 4:  # float32 counts stay exact; releases the GIL
        flat = np.ascontiguousarray(images).reshape(n * h, w, c)
        return np.stack([_cv2.calcHist([flat], [i], None, [256], [0, 256]).reshape(256) for i in range(c)]).astype(np.int64)
    return np.stack([np.bincount(images[..., i].reshape(-1), minlength=256) for i in range(c)]).astype(np.int64)


def image_stats(frames: np.ndarray) -> dict[str, np.ndarray]:
    """Per-channel stats of (T, H, W, C) uint8 frames, in [0, 1], shaped (C, 1, 1) like LeRobot's."""
    sampled = _downsample(frames[_sample_indices(frames.shape[0])])
    n_img, c = sampled.shape[0], sampled.shape[-1]
    counts = _channel_histograms(sampled)
    values = np.arange(256, dtype=np.float64)
    total = counts.sum(axis=1)
    mean = counts @ values / total
    var = (counts * (values[None, :] - mean[:, None]) ** 2).sum(axis=1) / total
    cum = np.cumsum(counts, axis=1)
    nonzero = counts > 0
    stats = {
        "min": nonzero.argmax(axis=1).astype(np.float64),
        "max": (255 - nonzero[:, ::-1].argmax(axis=1)).astype(np.float64),
        "mean": mean,
        "std": np.sqrt(var),
    }
    # np.quantile's "linear" method from the histogram: the values at sorted positions floor(pos) and ceil(pos)
    pos = (total[:, None] - 1) * np.asarray(QUANTILES)[None, :]  # (C, Q)
    lo, hi = np.floor(pos).astype(np.int64), np.ceil(pos).astype(np.int64)
    v_lo = (cum[:, None, :] <= lo[:, :, None]).sum(axis=2).astype(np.float64)  # searchsorted(cum[c], lo, "right")
    v_hi = (cum[:, None, :] <= hi[:, :, None]).sum(axis=2).astype(np.float64)
    quantiles = (v_lo + (pos - lo) * (v_hi - v_lo)).T  # (Q, C)
    out = {k: (v / 255.0).reshape(c, 1, 1) for k, v in stats.items()}
    out["count"] = np.array([n_img], dtype=np.int64)
    for key, qv in zip(QUANTILE_KEYS, quantiles, strict=True):
        out[key] = (qv / 255.0).reshape(c, 1, 1)
    return out


def aggregate_stats(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """lerobot.datasets.compute_stats.aggregate_feature_stats: combine stats of disjoint data."""
    means = np.stack([s["mean"] for s in parts])
    variances = np.stack([s["std"] ** 2 for s in parts])
    counts = np.stack([s["count"] for s in parts])
    total_count = counts.sum(axis=0)
    while counts.ndim < means.ndim:
        counts = np.expand_dims(counts, axis=-1)
    total_mean = (means * counts).sum(axis=0) / total_count
    delta = means - total_mean
    total_var = ((variances + delta**2) * counts).sum(axis=0) / total_count
    out = {
        "min": np.min(np.stack([s["min"] for s in parts]), axis=0),
        "max": np.max(np.stack([s["max"] for s in parts]), axis=0),
        "mean": total_mean,
        "std": np.sqrt(total_var),
        "count": total_count,
    }
    for key in QUANTILE_KEYS:
        out[key] = (np.stack([s[key] for s in parts]) * counts).sum(axis=0) / total_count
    return out
