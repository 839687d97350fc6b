"""skyfix.nearest against SciPy's exact Euclidean distance transform (an independent
implementation), and on cases whose answer is known by hand."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from skyfix.nearest import nearest_valid


@pytest.mark.parametrize("spacing", [(1.0, 1.0), (1.0, 64.0), (2.5, 0.3)])
def test_distances_and_cells_match_scipy(spacing):
    rng = np.random.default_rng(int(spacing[1] * 10))
    for share in (0.01, 0.05, 0.3, 0.9):
        for _ in range(20):
            h, w = rng.integers(1, 40, 2)
            valid = rng.random((h, w)) < share
            if not valid.any():
                continue
            d2, rows, cols = nearest_valid(valid, *spacing)
            ref, (r_ref, c_ref) = ndimage.distance_transform_edt(~valid, sampling=spacing,
                                                                 return_indices=True)
            np.testing.assert_allclose(np.sqrt(d2), ref, rtol=1e-12, atol=1e-12)
            assert valid[rows, cols].all()
            rr, cc = np.mgrid[:h, :w]
            np.testing.assert_allclose(((rows - rr) * spacing[0]) ** 2
                                       + ((cols - cc) * spacing[1]) ** 2, d2)
            if spacing != (2.5, 0.3):  # whole-number spacings: ties are exact, and go SciPy's way
                np.testing.assert_array_equal(rows, r_ref)  # (so fill_invalid's output is as before)
                np.testing.assert_array_equal(cols, c_ref)


def test_known_cases():
    v = np.zeros((3, 5), bool)
    v[1, 0] = v[1, 4] = True
    d2, rows, cols = nearest_valid(v)
    np.testing.assert_array_equal(d2[1], [0, 1, 4, 1, 0])
    assert cols[1, 2] == 0  # equally near both: the lower column
    np.testing.assert_array_equal(d2[0], [1, 2, 5, 2, 1])
    d2, rows, cols = nearest_valid(np.zeros((2, 3), bool))
    assert np.isinf(d2).all() and (rows == -1).all() and (cols == -1).all()
    # columns 64 times dearer than rows: the nearest valid cell of the same column wins
    v = np.zeros((100, 3), bool)
    v[0, 1] = v[50, 0] = True
    _, rows, cols = nearest_valid(v, 1.0, 64.0)
    assert (rows[20, 1], cols[20, 1]) == (0, 1)  # 20 rows, against hypot(30, 64)
    assert (rows[90, 1], cols[90, 1]) == (50, 0)  # hypot(40, 64) = 75 < 90
    with pytest.raises(ValueError):
        nearest_valid(np.ones((2, 2, 2), bool))
