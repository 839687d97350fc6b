"""``np.percentile`` and ``np.median`` of a large array, to the bit, without partitioning it all.

Detection takes percentiles and medians of a frame's full-resolution or working-scale values for
its scales and thresholds: a partition of a megapixel array is ~7 ms, a tenth of a navcam frame's
detection on one core. Only the values near the order statistics sought matter: two bounds taken
from every 16th value, safely either side of them, select those (a few compares and a copy of a
few per cent), and the order statistics are read from that small set, then combined as NumPy
does (``percentile``'s "linear" interpolation, ``median``'s mean of the middle two). A bound that
turns out not to be safe, a NaN, or a small array take NumPy itself.
"""

from __future__ import annotations

import math

import numpy as np

#: below this many values NumPy is as fast
_MIN_SIZE = 20_000
#: the bounds come from every this many values
_STRIDE = 16


def _order_stats(a, ranks):
    """The values of ``a`` (1-D, no NaN) of the given ascending ranks (0-based), or None where
    the sampled bounds were not safe."""
    n = a.size
    sample = a[::_STRIDE]
    m = sample.size
    lo_k, hi_k = ranks[0], ranks[-1]
    p_lo, p_hi = (lo_k + 0.5) / n, (hi_k + 0.5) / n
    # the sample's order statistics some standard deviations of a binomial count either side
    j_lo = int(math.floor(p_lo * m - 4.0 * math.sqrt(m * p_lo * (1.0 - p_lo)) - 2.0))
    j_hi = int(math.ceil(p_hi * m + 4.0 * math.sqrt(m * p_hi * (1.0 - p_hi)) + 2.0))
    kth = [j for j in (j_lo, j_hi) if 0 <= j < m]
    part = np.partition(sample, kth) if kth else sample
    if j_lo >= 0:
        keep = a >= part[j_lo]
        below = n - int(np.count_nonzero(keep))  # values strictly below the lower bound
    else:
        keep, below = None, 0
    if j_hi < m:
        upper = a <= part[j_hi]
        keep = upper if keep is None else np.logical_and(keep, upper, out=keep)
    sub = a if keep is None else a[keep]
    if below > lo_k or below + sub.size <= hi_k:
        return None  # the ranks sought lie outside the bounds
    local = [k - below for k in ranks]
    sel = np.partition(sub, local)
    return [sel[k] for k in local]


def percentile(a, q: float) -> float:
    """``float(np.percentile(a, q))`` for a 1-D float array ``a`` and a percentile ``q`` in
    [0, 100] (the same value to the bit; ``a`` is not modified)."""
    a = np.asarray(a)
    n = a.size
    if a.ndim != 1 or n < _MIN_SIZE or a.dtype.kind != "f" or np.isnan(a).any():
        return float(np.percentile(a, q))  # NaN: it never passes a comparison, and is the answer
    quant = np.true_divide(q, 100)
    virtual = (n - 1) * quant
    lo_k = int(np.floor(virtual))
    hi_k = min(lo_k + 1, n - 1)
    gamma = virtual - lo_k
    got = _order_stats(a, (lo_k, hi_k))
    if got is None:
        return float(np.percentile(a, q))
    x0, x1 = got
    if type(q) in (int, float):
        gamma = float(gamma)  # NumPy's "weak" q: the interpolation in the array's own dtype
    diff = x1 - x0
    out = x0 + diff * gamma
    if gamma >= 0.5:
        out = x1 - diff * (1 - gamma)
    return float(out)


def median(a) -> float:
    """``float(np.median(a))`` for a 1-D float array ``a`` (the same value to the bit: the middle
    value, or the mean of the middle two in the array's dtype; ``a`` is not modified)."""
    a = np.asarray(a)
    n = a.size
    if a.ndim != 1 or n < _MIN_SIZE or a.dtype.kind != "f" or np.isnan(a).any():
        return float(np.median(a))
    k = n // 2
    got = _order_stats(a, (k - 1, k) if n % 2 == 0 else (k,))
    if got is None:
        return float(np.median(a))
    if n % 2:
        return float(got[0])
    total = got[0] + got[1]  # np.mean of the two: their sum in the dtype, then halved
    return float(total.dtype.type(total / 2))
