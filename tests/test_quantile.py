"""skyfix.detect.quantile's percentile and median against np.percentile and np.median themselves:
the same value to the bit, for float32 and float64, odd and even sizes, ties, sorted and constant
arrays, NaN, and the percentiles detection takes."""

import numpy as np
import pytest

from skyfix.detect.quantile import median, percentile


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n", [19_999, 20_000, 100_003, 1 << 20])
def test_percentile_is_numpys_to_the_bit(dtype, n):
    rng = np.random.default_rng(n)
    arrays = [rng.normal(size=n), rng.exponential(size=n), np.round(rng.normal(size=n), 1),
              np.sort(rng.normal(size=n)), np.sort(rng.normal(size=n))[::-1], np.zeros(n),
              np.where(rng.random(n) < 0.98, 0.0, rng.normal(size=n))]
    for a in arrays:
        a = a.astype(dtype)
        before = a.copy()
        for q in (0, 0.5, 1, 5, 10, 25, 50, 75, 90, 95, 99, 99.5, 99.9, 100, np.float64(99.5),
                  np.float32(1.0)):
            got, want = percentile(a, q), float(np.percentile(a, q))
            assert got == want, (q, got, want)
        assert median(a) == float(np.median(a))
        assert np.array_equal(a, before)  # the input is left as it was


def test_nan_gives_nan_as_numpy_does():
    a = np.random.default_rng(0).normal(size=50_000)
    a[1234] = np.nan
    for q in (1, 50, 99.5):
        assert np.isnan(percentile(a, q)) and np.isnan(np.percentile(a, q))
    assert np.isnan(median(a))
