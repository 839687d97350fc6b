"""``np.percentile`` of a large array at a high or low percentile, to the bit, without partitioning
the whole array.

Detection takes a 99.5th, 99th, 90th or 5th percentile of a frame's full-resolution or working-scale
values for its scales and thresholds: a partition of a megapixel array is ~7 ms, a tenth of a
navcam frame's detection on one core. Only the values beyond the percentile matter: a bound taken
from every 16th value, safely on the near side, selects them (a compare and a copy of a few per
cent), and the order statistics are read from that small set. The interpolation is NumPy's own
(method "linear", ``numpy.lib._function_base_impl._lerp``); a bound that turns out not to be safe,
a NaN, or a small array take ``np.percentile`` itself.
"""

from __future__ import annotations

import math

import numpy as np

#: below this many values np.percentile is as fast
_MIN_SIZE = 20_000
#: the bound comes from every this many values
_STRIDE = 16


def percentile(a, q: float) -> float:
    """``float(np.percentile(a, q))`` for a 1-D float array ``a`` and a percentile ``q`` in
    [0, 100] (the same value to the bit; ``a`` is not modified)."""
    a = np.asarray(a)
    n = a.size
    if a.ndim != 1 or n < _MIN_SIZE or a.dtype.kind != "f" or 5.0 < q < 95.0 or np.isnan(a).any():
        return float(np.percentile(a, q))  # NaN: it never passes a comparison, and is the answer
    quant = np.true_divide(q, 100)
    virtual = (n - 1) * quant
    lo_k = int(np.floor(virtual))
    hi_k = min(lo_k + 1, n - 1)
    gamma = virtual - lo_k
    high = q >= 50.0
    sample = a[::_STRIDE]
    m = sample.size
    # the sample's order statistic some standard deviations of a binomial count to the near side
    # of the one sought: beyond it lie (almost surely) all the values of rank >= lo_k (q high)
    p = (lo_k + 0.5) / n
    margin = 4.0 * math.sqrt(m * p * (1.0 - p)) + 2.0
    if high:
        j = max(0, int(math.floor(p * m - margin)))
        bound = np.partition(sample, j)[j]
        sub = a[a >= bound]
        below = n - sub.size  # values strictly below the bound: ranks 0 .. below - 1
        if below > lo_k:  # the bound was not safe: rank lo_k lies below it
            return float(np.percentile(a, q))
        lo_s, hi_s = lo_k - below, hi_k - below
    else:
        j = min(m - 1, int(math.ceil(p * m + margin)))
        bound = np.partition(sample, j)[j]
        sub = a[a <= bound]
        if sub.size <= hi_k:
            return float(np.percentile(a, q))
        lo_s, hi_s = lo_k, hi_k
    part = np.partition(sub, (lo_s, hi_s))
    x0, x1 = part[lo_s], part[hi_s]
    if type(q) in (int, float):
        gamma = float(gamma)  # NumPy's "weak" q: the interpolation in the array's own dtype
    diff = x1 - x0
    out = x0 + diff * gamma
    if gamma >= 0.5:
        out = x1 - diff * (1 - gamma)
    return float(out)
