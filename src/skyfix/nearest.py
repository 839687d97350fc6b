"""The nearest valid cell of every cell of a grid: an exact Euclidean feature transform.

Filling an image's no-data from its nearest data and bounding how far a DEM's voids are filled
both need, for every cell, the nearest valid cell under a possibly anisotropic metric (rows and
columns weighted apart). This is the separable exact algorithm of Felzenszwalb & Huttenlocher
(2012, "Distance transforms of sampled functions"): the nearest valid row of each column, then the
lower envelope of parabolas along each row. O(cells), one thread.

It is ours rather than ``scipy.ndimage.distance_transform_edt`` so that the board install runs
without scipy (143 MB of disk); the tests compare the two.
"""

from __future__ import annotations

import numpy as np

from .jit import njit


def nearest_valid(valid, row_spacing: float = 1.0, col_spacing: float = 1.0):
    """For a bool grid ``valid`` (H, W): ``(dist2, rows, cols)``, the squared distance to the
    nearest valid cell [in the units of the spacings, squared] and that cell's row and column
    (int64, -1 with ``dist2`` inf where the grid holds no valid cell). A row step costs
    ``row_spacing``, a column step ``col_spacing``. Where two cells are equally near, the one
    with the lower column wins, then the lower row."""
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    if valid.ndim != 2:
        raise ValueError(f"nearest_valid takes a 2-D grid, got shape {valid.shape}")
    if not (row_spacing > 0 and col_spacing > 0):
        raise ValueError("row_spacing and col_spacing must be positive")
    h, w = valid.shape
    dist2 = np.empty((h, w), np.float64)
    rows = np.empty((h, w), np.int64)
    cols = np.empty((h, w), np.int64)
    _feature_transform(valid, float(row_spacing), float(col_spacing), dist2, rows, cols)
    return dist2, rows, cols


@njit(cache=True, nogil=True)
def _feature_transform(valid, sy, sx, dist2, rows, cols):
    h, w = valid.shape
    f = np.empty((h, w), np.float64)  # squared distance to the nearest valid cell of the column
    fr = np.empty((h, w), np.int64)
    for c in range(w):
        last = -1
        for r in range(h):
            if valid[r, c]:
                last = r
            if last >= 0:
                f[r, c] = ((r - last) * sy) ** 2
                fr[r, c] = last
            else:
                f[r, c] = np.inf
                fr[r, c] = -1
        last = -1
        for r in range(h - 1, -1, -1):
            if valid[r, c]:
                last = r
            if last >= 0:
                d = ((last - r) * sy) ** 2
                if d < f[r, c]:  # strictly: an equal distance keeps the upper (lower-index) row
                    f[r, c] = d
                    fr[r, c] = last
    v = np.empty(w, np.int64)  # the sites (columns) of the lower envelope, left to right
    z = np.empty(w + 1, np.float64)  # where each site's parabola starts to be the lowest
    w2 = sx * sx
    for r in range(h):
        k = -1
        for q in range(w):
            fq = f[r, q]
            if fq == np.inf:
                continue
            if k < 0:
                k = 0
                v[0] = q
                z[0] = -np.inf
                z[1] = np.inf
                continue
            while True:  # ends at k = 0 at the latest: z[0] is -inf
                p = v[k]
                s = ((fq + w2 * q * q) - (f[r, p] + w2 * p * p)) / (2.0 * w2 * (q - p))
                if s <= z[k]:
                    k -= 1
                    continue
                break
            k += 1
            v[k] = q
            z[k] = s
            z[k + 1] = np.inf
        if k < 0:
            for c in range(w):
                dist2[r, c] = np.inf
                rows[r, c] = -1
                cols[r, c] = -1
            continue
        j = 0
        for c in range(w):
            while z[j + 1] < c:
                j += 1
            p = v[j]
            dist2[r, c] = w2 * (c - p) * (c - p) + f[r, p]
            rows[r, c] = fr[r, p]
            cols[r, c] = p
