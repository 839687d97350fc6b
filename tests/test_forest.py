"""The sky model's forest scored by leaf elimination (skyfix.detect.forest) against two independent
references: scikit-learn's own prediction of the fitted model, and the walk of each tree to its
leaf; the same to the bit as the walk, including values on a threshold, NaN and infinities."""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.detect.forest import MAX_LEAVES, elimination_tables, forest_scores
from skyfix.detect.skymodel import N_FEATURES, from_sklearn, load_sky_model


def _awkward(X, tables, rng):
    """X with values placed exactly on thresholds, just either side, NaN and +-inf."""
    X = X.copy()
    th, off = tables.thresholds, tables.offsets
    for f in range(N_FEATURES):
        T = th[off[f]:off[f + 1]]
        if T.size:
            rows = rng.integers(0, X.shape[0], X.shape[0] // 4)
            v = T[rng.integers(0, T.size, rows.size)]
            side = rng.integers(-1, 2, rows.size)
            X[rows, f] = np.where(side == 0, v, np.nextafter(v, np.where(side > 0, np.inf, -np.inf)
                                                            .astype(np.float32)))
    X[rng.integers(0, X.shape[0], 40), rng.integers(0, N_FEATURES, 40)] = np.nan
    X[rng.integers(0, X.shape[0], 40), rng.integers(0, N_FEATURES, 40)] = np.inf
    X[rng.integers(0, X.shape[0], 40), rng.integers(0, N_FEATURES, 40)] = -np.inf
    return X


def test_the_shipped_model_scores_as_its_walk_to_the_bit():
    rng = np.random.default_rng(5)
    for grey in (False, True):
        m = load_sky_model(grey=grey)
        tables = elimination_tables(m.feat, m.thr, m.left, m.right, m.leaf, m.value, m.roots,
                                    N_FEATURES)
        assert tables is not None
        X = _awkward(rng.normal(0, 1.5, (20000, N_FEATURES)).astype(np.float32), tables, rng)
        a = forest_scores(X, tables, m.baseline)
        assert np.array_equal(a, m.walk_log_odds_sky(X))
        assert np.array_equal(forest_scores(X, tables, m.baseline, parallel=True), a)
        assert np.array_equal(m.log_odds_sky(X), a)


@pytest.mark.parametrize("leaves", [7, 31])
def test_leaf_elimination_matches_scikit_learn(leaves):
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(leaves)
    X = rng.normal(size=(6000, N_FEATURES)).astype(np.float32)
    y = (np.sin(2 * X[:, 0]) + X[:, 3] * X[:, 5] - X[:, 7] ** 2 + 0.3 * rng.normal(size=6000)) > -0.5
    clf = HistGradientBoostingClassifier(max_iter=25, max_leaf_nodes=leaves, max_depth=None,
                                         random_state=0).fit(X, y)
    m = from_sklearn(clf)
    tables = elimination_tables(m.feat, m.thr, m.left, m.right, m.leaf, m.value, m.roots, N_FEATURES)
    assert tables is not None and m.leaf.sum() > 25 * (leaves - 2)  # the trees did grow
    Xt = _awkward(rng.normal(size=(4000, N_FEATURES)).astype(np.float32), tables, rng)
    finite = np.isfinite(Xt).all(axis=1)  # scikit-learn learns where NaN goes; the walk sends it right
    np.testing.assert_allclose(forest_scores(Xt, tables, m.baseline)[finite],
                               clf.decision_function(Xt[finite]), rtol=0, atol=1e-9)


def test_a_tree_of_more_leaves_than_a_mask_holds_is_walked():
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(1)
    X = rng.normal(size=(20000, N_FEATURES)).astype(np.float32)
    y = (np.sin(3 * X[:, 0]) * np.cos(3 * X[:, 1]) + 0.2 * rng.normal(size=20000)) > 0
    clf = HistGradientBoostingClassifier(max_iter=3, max_leaf_nodes=64, max_depth=None,
                                         min_samples_leaf=5, random_state=0).fit(X, y)
    m = from_sklearn(clf)
    assert m.leaf.sum() > 3 * MAX_LEAVES  # some tree holds more than 32 leaves
    assert elimination_tables(m.feat, m.thr, m.left, m.right, m.leaf, m.value, m.roots,
                              N_FEATURES) is None
    Xt = rng.normal(size=(2000, N_FEATURES)).astype(np.float32)
    np.testing.assert_allclose(m.log_odds_sky(Xt), clf.decision_function(Xt), rtol=0, atol=1e-9)
