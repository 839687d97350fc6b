"""Scoring a detected skyline against the truth, with the metrics of ``shared/data/README.md``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..formats import Skyline


def scored_columns(pred: Skyline, truth: Skyline) -> np.ndarray:
    """The columns a detection is scored on (bool): ``truth.valid``, else ``pred.valid``, else
    all. Raises :class:`ParameterError` when the two skylines differ in width."""
    if pred.rows.shape != truth.rows.shape or (pred.height and truth.height and
                                               pred.height != truth.height):
        # a height too: rows of a half-height image against full-height truth scored 25 px
        raise ParameterError(
            f"detected skyline is {pred.rows.size} x {pred.height} px, the truth "
            f"{truth.rows.size} x {truth.height}: score the same image at the same size")
    if truth.valid is not None:
        return np.asarray(truth.valid, bool)
    if pred.valid is not None:
        return np.asarray(pred.valid, bool)
    return np.ones(truth.rows.size, bool)


def score_skyline(pred: Skyline, truth: Skyline, *, tol_px: tuple[float, float] = (3.0, 10.0)) -> dict:
    """Score a detected skyline against the truth (``shared/data/README.md``).

    Over valid columns (``truth.valid``, else ``pred.valid``, else all): ``mean_abs_err_px``
    over columns where both have a skyline, ``within_3px`` / ``within_10px`` (shares of those
    columns), ``false_rate`` (share of valid columns where a skyline is claimed but none is
    there), ``missed_rate`` (a skyline is there but none claimed), and the column counts.
    """
    valid = scored_columns(pred, truth)
    pt = np.isfinite(pred.rows) & valid
    tt = np.isfinite(truth.rows) & valid
    both = pt & tt
    err = np.abs(pred.rows[both] - truth.rows[both])
    nv = int(valid.sum())
    nb = int(both.sum())
    lo, hi = tol_px
    return {
        "n_valid": nv,
        "n_both": nb,
        "n_truth": int(tt.sum()),
        "n_false": int((pt & ~tt).sum()),
        "n_missed": int((tt & ~pt).sum()),
        "n_within_3px": int((err <= lo).sum()),
        "n_within_10px": int((err <= hi).sum()),
        "sum_abs_err_px": float(err.sum()),
        "mean_abs_err_px": float(err.mean()) if nb else float("nan"),
        "within_3px": float((err <= lo).mean()) if nb else float("nan"),
        "within_10px": float((err <= hi).mean()) if nb else float("nan"),
        "false_rate": float((pt & ~tt).sum() / nv) if nv else 0.0,
        "missed_rate": float((tt & ~pt).sum() / nv) if nv else 0.0,
    }


def combine_scores(scores) -> dict:
    """Pool per-image :func:`score_skyline` results (column-weighted)."""
    keys = ("n_valid", "n_both", "n_truth", "n_false", "n_missed", "n_within_3px",
            "n_within_10px", "sum_abs_err_px")
    tot = {k: sum(s[k] for s in scores) for k in keys}
    nb, nv = tot["n_both"], tot["n_valid"]
    tot.update({
        "mean_abs_err_px": tot["sum_abs_err_px"] / nb if nb else float("nan"),
        "within_3px": tot["n_within_3px"] / nb if nb else float("nan"),
        "within_10px": tot["n_within_10px"] / nb if nb else float("nan"),
        "false_rate": tot["n_false"] / nv if nv else 0.0,
        "missed_rate": tot["n_missed"] / nv if nv else 0.0,
    })
    return tot
