"""The scoring maths: a query profile against database profiles at every azimuth shift, after a
least-squares fit of the nuisance model (a constant and, optionally, the first azimuthal
harmonic), as a few circular cross-correlations per position (real FFTs), and the slow direct
reference :func:`brute_force_scores`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..jit import njit
from ..north import arc_span_deg


@dataclass
class Query:
    """A prepared query: kernels in the frequency domain for one bin count.

    n : bins; mask : observed bins; m_obs : count; full : every bin observed
    """

    n: int
    q: np.ndarray
    mask: np.ndarray
    m_obs: int
    full: bool
    sq: float
    u_q: np.ndarray  # whitened: (L^T U)^T M q with G^-1 = L L^T
    g_inv: np.ndarray
    k_p: np.ndarray  # (n_kernels, n//2+1) conj spectra correlated with p: [m q, m U_0, m U_1, ...]
    k_p2: np.ndarray | None  # conj spectrum of m, correlated with p^2 (None when full)
    kernels: np.ndarray | None = None  # float64 (n_kernels, n) the same kernels in the bin domain


def harmonic_basis(n: int, remove_tilt: bool) -> np.ndarray:
    """(n, 1) or (n, 3) columns over ``n`` azimuth bins (bin k at k * 360 / n deg): a constant
    (camera height, partial view), and with ``remove_tilt`` cos(az), sin(az), the first harmonic a
    small pitch/roll adds to an elevation profile [dimensionless]."""
    az = np.radians(np.arange(n) * 360.0 / n)
    cols = [np.ones(n)]
    if remove_tilt:
        cols += [np.cos(az), np.sin(az)]
    return np.stack(cols, axis=1)


#: largest condition number of the observed bins' Gram matrix of :func:`harmonic_basis` at which
#: the tilt harmonic is still fitted: beyond it the bins span too narrow an arc to tell a tilt
#: from a constant and a heading shift
MAX_TILT_CONDITION = 1e6


def tilt_determinable(observed) -> bool:
    """Whether the observed bins (boolean mask over the profile's azimuth bins) span enough of the
    circle to fit the tilt harmonic (small pitch/roll) beside the constant."""
    m = np.asarray(observed, bool)
    u = harmonic_basis(m.size, True)[m]
    if m.sum() < u.shape[1] + 2:
        return False
    g = u.T @ u
    return bool(np.isfinite(np.linalg.cond(g)) and np.linalg.cond(g) <= MAX_TILT_CONDITION)


def observed_span_deg(q) -> float:
    """[deg] the arc a profile's observed bins (finite ``q``) span: the circle less its largest
    run of unobserved bins."""
    obs = np.isfinite(np.asarray(q, float))
    return arc_span_deg(np.flatnonzero(obs) * 360.0 / obs.size, 360.0 / obs.size)


def prepare_query(elevation_deg, remove_tilt: bool = True, min_observed: int = 20) -> Query:
    """Kernels for :func:`score_profiles` from a body-frame profile [deg] (NaN = unobserved)."""
    q = np.asarray(elevation_deg, np.float64)
    n = q.size
    mask = np.isfinite(q)
    m_obs = int(mask.sum())
    u = harmonic_basis(n, remove_tilt)
    need = max(min_observed, u.shape[1] + 2)
    if m_obs < need:
        raise ParameterError(
            f"the profile has {m_obs} observed azimuth bins; at least {need} are needed to match "
            "(a wider view or more frames)")
    m = mask.astype(np.float64)
    qz = np.where(mask, q, 0.0)
    # Centre q over its observed bins: the constant is fitted anyway and this keeps float32 sums small.
    qz = np.where(mask, qz - qz[mask].mean(), 0.0)
    g = u.T @ (m[:, None] * u)
    try:
        g_inv = np.linalg.inv(g)
    except np.linalg.LinAlgError:
        raise ParameterError("observed bins too few or too clustered to fit the tilt harmonic "
                             "(check with tilt_determinable; match with remove_tilt=False, "
                             "as locate and heading do for such views)") from None
    if np.linalg.cond(g) > MAX_TILT_CONDITION:
        raise ParameterError("observed bins too clustered to fit the tilt harmonic "
                             "(check with tilt_determinable; match with remove_tilt=False, "
                             "as locate and heading do for such views)")
    # Whiten the nuisance kernels with G^-1 = L L^T: the quadratic form becomes a sum of squares.
    chol = np.linalg.cholesky(g_inv)
    uw = u @ chol
    kernels = [m * qz] + [m * uw[:, i] for i in range(u.shape[1])]
    full = bool(mask.all())
    k_p = np.conj(np.fft.rfft(np.stack(kernels), axis=1)).astype(np.complex64)
    k_p2 = None if full else np.conj(np.fft.rfft(m)).astype(np.complex64)
    return Query(n, np.where(mask, q, np.nan), mask, m_obs, full, float(np.sum(qz * qz)),
                 uw.T @ (m * qz), g_inv, k_p, k_p2, np.stack(kernels))


@dataclass
class DenseQuery:
    """A query as circulant matrices: every shift's correlations in one matrix product.

    k_lin : float32 (n, n_kernels * n), column ``i * n + s`` correlates kernel i at shift s
    k_sq : float32 (n, n) circulant of the mask, applied to p^2 (None when every bin is observed)
    """

    n: int
    m_obs: int
    sq: float
    u_q: np.ndarray
    k_lin: np.ndarray
    k_sq: np.ndarray | None


def dense_query(query: Query) -> DenseQuery:
    """Circulant form of a prepared query for :func:`score_dense` (cheap for small n, e.g. 90)."""
    n = query.n
    # corr(k, p)(s) = sum_l p_l k_{l-s}: column s of the circulant holds k rolled by s.
    idx = (np.arange(n)[:, None] - np.arange(n)[None, :]) % n
    kern = query.kernels
    k_lin = np.ascontiguousarray(kern[:, idx].transpose(1, 0, 2).reshape(n, -1), np.float32)
    k_sq = None if query.full else np.ascontiguousarray(query.mask.astype(np.float32)[idx])
    return DenseQuery(n, query.m_obs, query.sq, np.asarray(query.u_q, np.float32), k_lin, k_sq)


def score_dense(p: np.ndarray, dq: DenseQuery, all_shifts: bool = False):
    """As :func:`score_profiles` (same scores, same return values) by matrix products.

    For short profiles (the coarse pass, n = 90) BLAS beats small FFTs by an order of magnitude:
    ``N x n x (n_kernels + 1) n`` multiply-adds, streamed at full sgemm speed.
    p : float32 (N, n) [deg]
    """
    n = dq.n
    p = np.asarray(p, np.float32)
    if p.ndim != 2 or p.shape[1] != n:
        raise ParameterError(f"profiles have shape {p.shape}, expected (N, {n})")
    p = p - p.mean(axis=1, keepdims=True)
    corr = (p @ dq.k_lin).reshape(p.shape[0], -1, n)
    p *= p
    if dq.k_sq is None:
        s = np.sum(p, axis=1, keepdims=True) + np.zeros((1, n), np.float32)
    else:
        s = p @ dq.k_sq
    del p
    return _finish_scores(s, corr, dq.sq, dq.u_q, dq.m_obs, all_shifts)


@njit(cache=True, nogil=True)
def _sum_squares(s, corr, sq, u_q, m_obs):
    """``s`` (N, n) float32 in place: ``max(s + sq - 2 corr[:, 0] - sum_i (corr[:, i] -
    u_q[i - 1])^2, 0) / m_obs``, in float32 and in the order NumPy's whole-array passes took
    (the same floats); one pass over ``corr`` instead of a strided one per kernel, a third of
    the search's coarse pass."""
    N, K, n = corr.shape
    two = np.float32(2.0)
    zero = np.float32(0.0)
    for r in range(N):
        for j in range(n):
            v = s[r, j] + sq
            v -= two * corr[r, 0, j]
            for i in range(1, K):
                d = corr[r, i, j] - u_q[i - 1]
                v -= d * d
            if v < zero:
                v = zero
            s[r, j] = v / m_obs


def _finish_scores(s, corr, sq, u_q, m_obs, all_shifts):
    n = s.shape[1]
    _sum_squares(s, np.ascontiguousarray(corr, np.float32), np.float32(sq),
                 np.ascontiguousarray(u_q, np.float32), np.float32(m_obs))
    if all_shifts:
        return s
    k = np.argmin(s, axis=1)
    rows = np.arange(s.shape[0])
    s0 = s[rows, k]
    sm = s[rows, (k - 1) % n]
    sp = s[rows, (k + 1) % n]
    den = sm - 2 * s0 + sp
    off = np.where(den > 1e-12, 0.5 * (sm - sp) / np.where(den > 1e-12, den, 1.0), 0.0)
    off = np.clip(off, -0.5, 0.5)
    best = s0 - 0.25 * (sm - sp) * off
    return np.maximum(best, 0.0).astype(np.float32), ((k + off) % n).astype(np.float32)


def score_profiles(p: np.ndarray, query: Query, all_shifts: bool = False):
    """Best shift and score for each database profile.

    p : float32 (N, n) [deg] predicted skylines in the world frame (no NaN)
    Returns ``(score, shift)``: score float32 (N,) = mean squared residual over observed bins
    [deg^2] at the best shift; shift float32 (N,) [bins], sub-bin by a parabola through the
    three scores around the best integer shift. With ``all_shifts`` returns the (N, n) scores.
    """
    n = query.n
    p = np.asarray(p, np.float32)
    if p.ndim != 2 or p.shape[1] != n:
        raise ParameterError(f"profiles have shape {p.shape}, expected (N, {n})")
    p = p - p.mean(axis=1, keepdims=True)
    # numpy's FFT (pocketfft, float32 since numpy 2) rather than scipy's: the board install
    # leaves scipy out (143 MB of disk, 13 MB of RSS for scipy.fft); one thread, as a rover has
    spec = np.fft.rfft(p, axis=1)
    corr = np.fft.irfft(spec[:, None, :] * query.k_p[None], n=n, axis=2)
    del spec
    if query.full:
        s = np.sum(p * p, axis=1, keepdims=True) + np.zeros((1, n), np.float32)
    else:
        s = np.fft.irfft(np.fft.rfft(p * p, axis=1) * query.k_p2[None], n=n, axis=1)
    return _finish_scores(s, corr, query.sq, query.u_q, query.m_obs, all_shifts)


def brute_force_scores(p: np.ndarray, q: np.ndarray, remove_tilt: bool = True) -> np.ndarray:
    """Reference: (N, n) scores by explicit loops over shifts and a least-squares fit each time.

    Slow and obvious; tests compare :func:`score_profiles` with it.
    """
    p = np.asarray(p, np.float64)
    q = np.asarray(q, np.float64)
    n = q.size
    mask = np.isfinite(q)
    u = harmonic_basis(n, remove_tilt)[mask]
    out = np.empty((p.shape[0], n))
    for i in range(p.shape[0]):
        for s in range(n):
            shifted = np.roll(p[i], -s)  # shifted[j] = p[j + s]
            r = q[mask] - shifted[mask]
            coef, *_ = np.linalg.lstsq(u, r, rcond=None)
            out[i, s] = np.sum((r - u @ coef) ** 2) / mask.sum()
    return out


def decimate_query(q: np.ndarray, factor: int) -> np.ndarray:
    """Average groups of ``factor`` bins [deg]; a coarse bin is observed if half its bins are."""
    n = q.size
    g = q.reshape(n // factor, factor)
    fin = np.isfinite(g)
    cnt = fin.sum(axis=1)
    with np.errstate(invalid="ignore"):
        mean = np.where(fin, g, 0.0).sum(axis=1) / np.maximum(cnt, 1)
    return np.where(cnt * 2 >= factor, mean, np.nan)
