"""The damped Gauss-Newton (Levenberg-Marquardt) loop shared by the attitude fits, with robust
weights that are recomputed at every accepted step.
"""

from __future__ import annotations

import numpy as np


def median(a) -> float:
    """``np.median`` of a 1-D array without NaN, to the bit, at a quarter of its cost (a fit's
    robust weights take two per residual evaluation: ~30,000 per fix, 12 us each in
    ``np.median``'s generic reduction)."""
    n = a.size
    k = n >> 1
    if n & 1:
        return np.partition(a, k)[k]
    p = np.partition(a, (k - 1, k))
    return (p[k - 1] + p[k]) / 2.0


def levenberg_marquardt(th, resid, robust, normal, clamp, iterations, tol=1e-4):
    """Minimise a robust cost from ``th`` (n,).

    resid(th) -> r; robust(r) -> (weights, cost); normal(th, r, w) -> (A, g), the weighted normal
    equations (A may hold nuisance columns after the first n: only the first n of the step
    apply); clamp(th) -> th, the bounds. A rejected step keeps th, r and w, so the normal
    equations are reused with more damping (a fit's rejections are mostly near convergence).
    Stops after ``iterations``, when an accepted step is below ``tol`` on every parameter, or
    when the damping exceeds 1e4. Returns (th, r, w, cost).
    """
    n = np.size(th)
    r = resid(th)
    w, cost = robust(r)
    lam, a = 1e-3, None
    for _ in range(iterations):
        if a is None:
            a, g = normal(th, r, w)
        try:
            step = np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-9), -g)[:n]
        except np.linalg.LinAlgError:
            break
        th_new = clamp(th + step)
        r_new = resid(th_new)
        w_new, cost_new = robust(r_new)
        if cost_new < cost:
            th, r, w, cost, a = th_new, r_new, w_new, cost_new, None
            lam = max(lam / 4, 1e-6)
            if np.max(np.abs(step)) < tol:
                break
        else:
            lam *= 8
            if lam > 1e4:
                break
    return th, r, w, cost
