"""Which refined answers are rivals: one basin of the cost against two, on a closed-form cost and
on a detected profile whose valley floor is wider than scenario 2's 1 m."""

import importlib
import math
from pathlib import Path

import numpy as np
import pytest

from skyfix.formats import read_profile_json
from skyfix.pose import locate

from conftest import shared_dem_path

refine = importlib.import_module("skyfix.pose.refine")


@pytest.fixture
def double_well(monkeypatch):
    """refit_costs replaced by a closed-form cost [deg^2]: two wells along x, at 0 and 4 m, with a
    ridge between them at x = 2 (cost 4.01 there against 0.01 at each floor)."""
    calls = []

    def cost(x, y):
        return min(x * x, (x - 4.0) ** 2) + 0.25 * y * y + 0.01

    def fake(renders, q, xs, ys, att, **kw):
        calls.append(len(np.atleast_1d(xs)))
        return [(cost(x, y), att, None) for x, y in zip(np.atleast_1d(xs), np.atleast_1d(ys))]

    monkeypatch.setattr(refine, "refit_costs", fake)
    return cost, calls


def test_two_wells_are_two_basins_and_one_floor_is_one(double_well):
    cost, calls = double_well
    end = lambda x, y: (x, y, cost(x, y))  # noqa: E731
    kw = dict(spacing_m=0.5)
    # across the ridge: a rival, though both ends cost the same
    assert not refine.same_basin(None, None, end(0.0, 0.0), end(4.0, 0.0), None, **kw)
    # down one well's side: the cheaper end is the floor, nothing between rises above the dearer
    assert refine.same_basin(None, None, end(0.1, 0.0), end(1.2, 0.9), None, **kw)
    # within one spacing: nothing to sample between them
    n = len(calls)
    assert refine.same_basin(None, None, end(0.0, 0.0), end(0.3, 0.0), None, **kw)
    assert len(calls) == n
    # farther than max_points samples reach: not examined, counted as a rival
    assert not refine.same_basin(None, None, end(0.0, 0.0), end(0.0, 10.0), None, spacing_m=0.5,
                                 max_points=8)
    assert len(calls) == n


def test_a_small_bump_on_one_floor_is_within_the_rise(monkeypatch):
    # a 0.5 % bump between two points of one floor (below the 1 % rise): one basin; 5 %: two
    for bump, same in ((0.005, True), (0.05, False)):
        def fake(renders, q, xs, ys, att, bump=bump, **kw):
            return [(1.0 + bump, att, None) for _ in np.atleast_1d(xs)]
        monkeypatch.setattr(refine, "refit_costs", fake)
        assert refine.same_basin(None, None, (0.0, 0.0, 1.0), (2.0, 0.0, 1.0), None,
                                 spacing_m=0.5) is same


def test_the_confidence_does_not_turn_on_the_priors_last_decimals():
    """A profile detected in simulated frames on the Sierra DEM (the README demo's acquisition,
    truth at x 301555.98, y 4146614.15): its cost has a floor about 3 m long. Refined starts stop
    on it 0.6-1.2 m from the best, and before the basin check a prior 1 cm away turned one of them
    into a rival: log_ratio 1.75 -> 0.10, confidence 0.80 -> 0.49."""
    dem_path = shared_dem_path("sierra_nevada_30m")
    from skyfix.dem import load_dem

    prof = read_profile_json(Path(__file__).parent / "data" / "sierra_demo_profile.json")
    dem = load_dem(dem_path)
    tx, ty = 301555.979404365, 4146614.15060849
    fixes = [locate(prof, dem=dem, prior_xy=(px, 4146614.2), prior_radius_m=20.0)
             for px in (301556.0, 301556.01)]
    ratios = [f.features["log_ratio"] for f in fixes]
    assert ratios[0] == pytest.approx(ratios[1], abs=0.1)  # measured 1.746 and 1.746
    assert min(ratios) > 1.0
    for f in fixes:
        # starts that stopped on the fix's floor are not listed as other candidates (one was, at
        # 1.16 m)
        assert all(math.hypot(c["x"] - f.x, c["y"] - f.y) > 3.0 for c in f.candidates[1:])
        err = math.hypot(f.x - tx, f.y - ty)
        assert err < 1.5  # measured 0.47 and 1.02 m: the floor is real, the fix moves along it
        # the confidence follows the error, not the decimals (0.80 at 0.47 m, 0.60 at 1.02 m)
        assert (f.confidence > 0.5) and (f.confidence < 0.95)
