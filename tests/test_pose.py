"""Pose: known answers on a synthetic DEM (own position, rotated heading, known tilt, flat)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from skyfix.dem import Dem
from skyfix.formats import Profile
from skyfix.match import MatchConfig, MemoryStore
from skyfix.pose import (FEATURES, MODEL_PATH, SCENARIOS, PoseConfig, body_profile,
                         confidence_from_features, estimate_heading, fit_attitude, locate, relevel,
                         synthetic_profile)


def _bumpy_dem():
    y, x = np.mgrid[0:160, 0:160] * 10.0
    z = (250 * np.exp(-((x - 300) ** 2 + (y - 1100) ** 2) / 3e4)
         + 180 * np.exp(-((x - 1300) ** 2 + (y - 500) ** 2) / 6e4)
         + 60 * np.sin(x / 90.0) * np.cos(y / 130.0) + 0.03 * x)
    return Dem.from_array(z, 10.0)


@pytest.fixture(scope="module")
def world():
    dem = _bumpy_dem()
    xs = np.arange(500.0, 1100.1, 20.0)
    ys = np.arange(1100.0, 499.9, -20.0)
    return dem, MemoryStore.from_dem(dem, xs, ys, block=16)


# the synthetic DEM is the world the profiles come from: no map error for the sigmas to allow for
CFG = PoseConfig(match=MatchConfig(top_k=4), refine_candidates=2, levels=2,
                 restarts_deg=(0.0,), map_sigma_m=0.0)


def _ang(a):
    return (a + 180.0) % 360.0 - 180.0


def test_exact_grid_query_returns_its_position_and_heading(world):
    dem, st = world
    q = st.profiles_at(700.0, 900.0)[0].astype(float)
    fix = locate(Profile(q, None, "body"), db=st, config=CFG)  # no DEM: database level only
    assert (fix.x, fix.y) == (700.0, 900.0)
    assert abs(_ang(fix.heading_deg)) < 0.3
    assert fix.candidates[0]["x"] == 700.0


def test_rotating_the_profile_rotates_the_heading(world):
    _, st = world
    q = st.profiles_at(860.0, 640.0)[0].astype(float)
    for h in (37, 200):
        body = np.roll(q, -h)  # world[az] = body[az - H]
        fix = locate(Profile(body, None, "body"), db=st, config=CFG)
        assert (fix.x, fix.y) == (860.0, 640.0)
        assert abs(_ang(fix.heading_deg - h)) < 0.3


def test_off_grid_position_refined_from_the_dem(world):
    dem, st = world
    tx, ty, th = 733.3, 871.9, 123.4
    prof = synthetic_profile(dem, tx, ty, th, noise_deg=0.05, rng=3)
    fix = locate(prof, db=st, dem=dem, config=CFG)
    err = np.hypot(fix.x - tx, fix.y - ty)
    assert err < 3.0
    assert abs(_ang(fix.heading_deg - th)) < 0.5
    # the 1-sigma covers the true error and is not vacuous (measured 0.03 m; the calibrated
    # sigma, 0.5-3 m as the model is refitted, stays within scenario 1's 5 m)
    assert err <= fix.position_sigma_m < 5.0
    assert 0 < fix.heading_sigma_deg < 0.2  # measured 0.008 deg (heading scatter: own test)
    # a distinctive horizon, right fix: the calibrated model says so (measured 0.996), and the
    # value is the model's, not the flat-horizon cap's
    assert fix.confidence >= 0.9
    assert fix.confidence == pytest.approx(confidence_from_features(fix.features, key="locate"))
    d = fix.to_dict()
    assert set(d) >= {"x", "y", "crs", "lon", "lat", "heading_deg", "pitch_deg", "roll_deg",
                      "position_sigma_m", "heading_sigma_deg", "confidence", "score", "candidates"}
    # a CRS with no authority code is given as WKT: readable by another tool, not a bare name
    from pyproj import CRS

    assert CRS.from_user_input(d["crs"]) == CRS.from_wkt(dem.crs_wkt) and np.isfinite(d["lat"])


def test_prior_area_without_database(world):
    dem, _ = world
    tx, ty = 812.6, 701.2
    prof = synthetic_profile(dem, tx, ty, 300.0, noise_deg=0.05, rng=4)
    fix = locate(prof, dem=dem, prior_xy=(tx + 9.0, ty - 7.0), prior_radius_m=20.0, config=CFG)
    err = np.hypot(fix.x - tx, fix.y - ty)
    assert err < 1.5
    # measured 0.11 m; the 1-sigma, calibrated to cover held-out errors as often as it claims,
    # 0.8-1.2 m as the model is refitted (the score surface's curvature alone said 0.09 m): it
    # covers the error and stays within twice scenario 2's 1 m
    assert err <= fix.features["position_sigma_basin_m"] < 2.0
    # the reported one allows for another basin in the disc as far as the confidence does not
    # rule it out (2.9 m at the 0.8 this fix gets)
    assert fix.position_sigma_m >= fix.features["position_sigma_basin_m"]
    # rivals are other answers: candidates refined onto the fix are not listed again as rivals
    xy = [(c["x"], c["y"]) for c in fix.candidates]
    assert np.hypot(xy[0][0] - fix.x, xy[0][1] - fix.y) < 1e-6
    assert all(np.hypot(a[0] - b[0], a[1] - b[1]) > 1.0 for i, a in enumerate(xy) for b in xy[:i])


def test_tilted_query_in_a_prior_area_lands_within_decimetres(world):
    """Scenario 2 with 10 deg class tilt: the final search on the attitude-refitted cost. The
    grid's shift-search score alone stopped 0.56 m off here (and 1.3-9 m off in the example
    report's simulated cases)."""
    dem, _ = world
    tx, ty, th, p, r = 812.6, 701.2, 300.0, 9.0, -8.0
    prof = synthetic_profile(dem, tx, ty, th, p, r, noise_deg=0.05, rng=4)
    fix = locate(prof, dem=dem, prior_xy=(tx + 9.0, ty - 7.0), prior_radius_m=20.0, config=CFG)
    assert np.hypot(fix.x - tx, fix.y - ty) < 0.3  # measured 0.14
    assert abs(fix.pitch_deg - p) < 0.1 and abs(fix.roll_deg - r) < 0.1


def test_forward_model_and_relevel_are_inverse():
    a = np.radians(np.arange(720) * 0.5)
    w = 5 + 3 * np.sin(3 * a + 1) + 2 * np.cos(7 * a) + np.sin(11 * a + 0.3)  # smooth: re-binning exact
    tilted = body_profile(w, 40.0, 6.0, -4.0, n_bins=360)
    level = body_profile(w, 40.0, 0.0, 0.0, n_bins=360)
    back = relevel(tilted, 6.0, -4.0)
    assert np.nanmax(np.abs(back - level)) < 0.05
    # Small-angle check of the sign conventions: nose up lowers what is ahead.
    flat = np.full(720, 0.0)
    up = body_profile(flat, 0.0, 5.0, 0.0, n_bins=360)
    assert up[0] == pytest.approx(-5.0, abs=0.05) and up[180] == pytest.approx(5.0, abs=0.05)
    rr = body_profile(flat, 0.0, 0.0, 5.0, n_bins=360)
    assert rr[90] == pytest.approx(5.0, abs=0.05)  # right side down: the right horizon rises


def test_tilt_recovered_by_gauss_newton(world):
    dem, _ = world
    from skyfix.horizon import render_horizons

    x, y, h, p, r = 760.0, 820.0, 75.0, 7.0, -8.0
    # The query comes from a 3600-bin render averaged to 1 deg bins (synthetic_profile); the fit
    # uses its own 1440-bin render: two different discretisations.
    prof = synthetic_profile(dem, x, y, h, p, r, noise_deg=0.05, rng=5)
    w = render_horizons(dem, [x], [y], azimuth_bins=1440).elevation_deg[0]
    att = fit_attitude(prof.elevation_deg, w, h + 2.0, 0.0, 0.0)
    assert abs(att.pitch_deg - p) < 0.3 and abs(att.roll_deg - r) < 0.3
    assert abs(_ang(att.yaw_deg - h)) < 0.3


def test_rock_silhouettes_do_not_tilt_the_attitude(world):
    """A quarter of the view raised by 1-5 deg in three humps (rocks in front of the skyline, as
    in the OCCL set): the fit must ignore them, not pull the tilt towards them."""
    dem, _ = world
    from skyfix.horizon import render_horizons

    x, y, h = 760.0, 820.0, 75.0
    prof = synthetic_profile(dem, x, y, h, 0.0, 0.0, noise_deg=0.05, rng=5)
    q = np.array(prof.elevation_deg, float)
    for c, half, top in ((20, 12, 5.0), (110, 18, 3.5), (250, 15, 2.0)):
        k = np.arange(c - half, c + half + 1)
        q[k % 360] += top * np.sin(np.pi * (k - c + half) / (2 * half)) + 1.0
    w = render_horizons(dem, [x], [y], azimuth_bins=1440).elevation_deg[0]
    att = fit_attitude(q, w, h, 0.0, 0.0, restarts_deg=(0.0,))
    # measured 0.00001 / 0.0009 deg (Huber weights)
    assert abs(att.pitch_deg) < 0.05 and abs(att.roll_deg) < 0.05
    assert abs(_ang(att.yaw_deg - h)) < 0.05


def test_heading_only_mode(world):
    dem, _ = world
    prof = synthetic_profile(dem, 650.0, 950.0, 222.0, 2.0, -1.0, noise_deg=0.1, rng=6)
    hf = estimate_heading(prof, dem, 653.0, 946.0, 226.0, window_deg=10.0)
    assert abs(_ang(hf.heading_deg - 222.0)) < 1.0
    assert 0 < hf.heading_sigma_deg < 0.5  # measured 0.027 (heading scatter: own test)
    assert hf.confidence >= 0.9  # measured 0.999
    # the model's, or less: at most the chance that a normal error of the basin's own sigma
    # stays within the 1 deg tolerance
    cap = math.erf(1.0 / (hf.features["heading_sigma_basin_deg"] * math.sqrt(2.0)))
    assert hf.confidence == pytest.approx(min(confidence_from_features(hf.features, key="heading"),
                                              cap))
    # Wrong answers, through the model (relief 7.6 deg, far above the flat-horizon cap's 2x noise):
    # the rough position 150 m off (fix 14 deg off, measured confidence 0.02), and the truth
    # outside the window (prior 40 deg off: fix at the window's edge, 20 deg off, measured 0.08).
    for x, y, h0 in ((800.0, 950.0, 226.0), (653.0, 946.0, 262.0)):
        wrong = estimate_heading(prof, dem, x, y, h0, window_deg=10.0)
        assert abs(_ang(wrong.heading_deg - 222.0)) > 5.0
        assert wrong.confidence < 0.2


def test_an_unsure_fix_sigma_allows_for_another_basin_of_the_prior_disc(world, monkeypatch):
    """The same fix at a confidence of 0.2: its basin's sigma (about a metre) would say it is
    right to a metre while the confidence says it is likely wrong. The reported sigma
    is the radius holding 63 % of errors when the rover is, four times in five, anywhere in the
    20 m prior disc: metres, and a note says why."""
    import importlib

    from skyfix.pose.basin_sigma import disc_share, wrong_basin_radius

    pl = importlib.import_module("skyfix.pose.locate")  # the module, not the function it exports

    dem, _ = world
    tx, ty = 812.6, 701.2
    prof = synthetic_profile(dem, tx, ty, 300.0, noise_deg=0.05, rng=4)
    prior = (tx + 9.0, ty - 7.0)
    sure = locate(prof, dem=dem, prior_xy=prior, prior_radius_m=20.0, config=CFG)
    monkeypatch.setattr(pl, "confidence_from_features", lambda *a, **k: 0.2)
    fix = locate(prof, dem=dem, prior_xy=prior, prior_radius_m=20.0, config=CFG)
    assert (fix.x, fix.y) == (sure.x, sure.y) and fix.confidence == pytest.approx(0.2)
    basin = fix.features["position_sigma_basin_m"]
    assert basin < 2.0 and sure.position_sigma_m < fix.position_sigma_m
    want = wrong_basin_radius(basin, 0.2, disc_share(*prior, 20.0, fix.x, fix.y))
    assert fix.position_sigma_m == pytest.approx(want) and 5.0 < want < 20.0
    assert any("another basin of the searched area" in n for n in fix.notes), fix.notes


def test_heading_sigma_matches_the_scatter_over_noise_draws(world):
    """20 noise draws on one exact skyline at the true position: the reported 1-sigma heading is
    the spread of the estimates (ratio measured 1.0-1.35), and their mean is the truth. The query
    is a centred average of a 0.1 deg render over each 1 deg bin, built here (not with
    synthetic_profile). This is the fit's own sigma (``model={}``: no calibration); the
    calibrated one skyfix reports is wider, for the systematic errors white noise lacks. The
    position is exact here (``position_sigma_m=0``: no position error to weigh bins by or to add
    to the sigma)."""
    from skyfix.horizon import render_horizons

    dem, _ = world
    rng = np.random.default_rng(0)
    for x, y, h, p, r, noise in ((650.0, 950.0, 222.0, 2.0, -1.0, 0.1),
                                 (733.3, 871.9, 123.4, 0.0, 0.0, 0.3)):
        w = render_horizons(dem, [x], [y], azimuth_bins=3600).elevation_deg[0]
        sub = body_profile(w, h, p, r, n_bins=3600)
        q0 = sub[(np.arange(360)[:, None] * 10 + np.arange(-4, 5)) % 3600].mean(axis=1)
        err, sig = [], []
        for _ in range(20):
            q = q0 + rng.normal(0.0, noise, 360)
            prof = Profile(q, np.full(360, noise), "body")
            hf = estimate_heading(prof, dem, x, y, h + 3.0, 10.0, model={}, position_sigma_m=0.0)
            err.append(_ang(hf.heading_deg - h))
            # the basin's own sigma: without a model the confidence is a fallback of at most 0.5,
            # which the reported sigma widens for
            sig.append(hf.features["heading_sigma_basin_deg"])
        assert estimate_heading(prof, dem, x, y, h + 3.0, 10.0,
                                position_sigma_m=0.0).heading_sigma_deg >= sig[-1]
        err, sig = np.array(err), float(np.median(sig))
        assert 0.6 < np.std(err, ddof=1) / sig < 1.7
        assert abs(err.mean()) < 3 * sig / np.sqrt(20) + 0.005  # measured 0.004 and 0.005 deg


def test_featureless_horizon_gives_low_confidence():
    y, x = np.mgrid[0:80, 0:80] * 10.0
    dem = Dem.from_array(0.0 * x, 10.0)
    st = MemoryStore.from_dem(dem, np.arange(300.0, 500.1, 20.0), np.arange(500.0, 299.9, -20.0))
    q = np.full(360, 0.0) + np.random.default_rng(0).normal(0, 0.1, 360)
    fix = locate(Profile(q, np.full(360, 0.1), "body"), db=st, dem=dem, config=CFG)
    assert fix.confidence < 0.3


def _logistic(model, feat):
    """The confidence model written out: a logistic on standardised features, shifted by the
    logit offset."""
    z = model["intercept"] - model["logit_offset"]
    for name, c, mu, sd in zip(model["features"], model["coef"], model["mean"], model["scale"]):
        z += c * (feat[name] - mu) / sd
    return 1.0 / (1.0 + np.exp(-z))


def test_confidence_model_is_the_shipped_logistic_model():
    import json
    import math

    shipped = json.loads(MODEL_PATH.read_text())
    assert set(SCENARIOS) <= set(shipped)
    # Hand-made feature vectors: a clear fix (values of a measured one), a wrong one (a measured
    # 20 deg heading error), and per model points where the logit is 0 and 1 exactly.
    good = dict(log_ratio=7.2, log_rms_over_noise=0.0, log_relief=1.9, observed_fraction=1.0,
                log_sigma=-0.7, tilt_deg=0.0)
    bad = dict(log_ratio=0.0, log_rms_over_noise=4.0, log_relief=2.0, observed_fraction=1.0,
               log_sigma=-0.25, tilt_deg=1.0)
    for key in SCENARIOS:
        m = shipped[key]
        assert tuple(m["features"]) == FEATURES
        assert len(m["coef"]) == len(m["mean"]) == len(m["scale"]) == len(FEATURES)
        assert all(sd > 0 for sd in m["scale"]) and "isotonic" not in m
        at_mean = dict(zip(FEATURES, m["mean"]))  # z = intercept - offset exactly
        assert confidence_from_features(at_mean, key=key) == pytest.approx(
            1 / (1 + math.exp(-(m["intercept"] - m["logit_offset"]))), abs=1e-12)
        # log_ratio where z = 0 (p = 1/2), then log_rms_over_noise moved to add exactly 1 to z
        c, mu, sd = m["coef"], m["mean"], m["scale"]
        half = dict(at_mean, log_ratio=mu[0] - (m["intercept"] - m["logit_offset"]) * sd[0] / c[0])
        z_one = dict(half, log_rms_over_noise=mu[1] + sd[1] / c[1])
        assert confidence_from_features(half, key=key) == pytest.approx(0.5, abs=1e-12)
        assert confidence_from_features(z_one, key=key) == pytest.approx(1 / (1 + math.exp(-1)),
                                                                          abs=1e-12)
        for feat in (good, bad, z_one):
            assert confidence_from_features(feat, key=key) == pytest.approx(
                _logistic(m, feat), abs=1e-12)
            # the model passed explicitly gives the same as the one loaded from the package
            assert confidence_from_features(feat, shipped, key) == confidence_from_features(feat, key=key)
        # a rival basin as good as the fix, or a residual far above the noise, lowers it
        assert m["coef"][0] > 0 and m["coef"][1] < 0
        # (0.79 for scenario 2 since its cases include map errors, where a residual at the noise
        # level is no longer the best one sees)
        assert confidence_from_features(good, key=key) > 0.75 > 0.2 > confidence_from_features(bad, key=key)
    # Closed forms on a one-feature model: z = 1 + 0.5 (ln 3 - 1) / 0.5 = ln 3, minus the offset.
    tiny = {"locate": {"features": ["log_ratio"], "coef": [0.5], "mean": [1.0], "scale": [0.5],
                       "intercept": 1.0, "logit_offset": 0.0}}
    feat = dict(good, log_ratio=math.log(3.0))
    assert confidence_from_features(feat, tiny) == pytest.approx(0.75, abs=1e-12)
    tiny["locate"]["logit_offset"] = math.log(3.0)
    assert confidence_from_features(feat, tiny) == pytest.approx(0.5, abs=1e-12)
    # Without a model: the uncalibrated fallback 0.5 (1 - 1/ratio), at most 0.5.
    assert confidence_from_features(feat, {}) == pytest.approx(1 / 3, abs=1e-12)


def test_cli_locate_and_heading_from_a_profile(world, tmp_path):
    import json

    from click.testing import CliRunner

    from skyfix.cli.main import cli
    from skyfix.dem import write_dem
    from skyfix.formats import write_profile_json

    dem, _ = world
    dem_path = write_dem(tmp_path / "dem.tif", dem)
    prof = synthetic_profile(dem, 812.6, 701.2, 300.0, noise_deg=0.05, rng=4)
    write_profile_json(tmp_path / "p.json", prof)
    r = CliRunner().invoke(cli, ["locate", "--profile", str(tmp_path / "p.json"), "--dem",
                                 str(dem_path), "--prior-x", "820", "--prior-y", "695",
                                 "--prior-radius-m", "20", "-o", str(tmp_path / "fix.json"),
                                 "--geojson", str(tmp_path / "fix.geojson")])
    assert r.exit_code == 0, r.output
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert np.hypot(fix["x"] - 812.6, fix["y"] - 701.2) < 1.5
    gj = json.loads((tmp_path / "fix.geojson").read_text())
    assert gj["features"][0]["geometry"]["type"] == "Point"
    # the 1-sigma ring runs anticlockwise (RFC 7946 3.1.6): a positive signed area
    ring = gj["features"][1]["geometry"]["coordinates"][0]
    assert sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(ring, ring[1:])) > 0
    assert "body" not in gj and "GIS tools read GeoJSON" not in r.output  # on Earth
    again = CliRunner().invoke(cli, ["locate", "--profile", str(tmp_path / "p.json"), "--dem",
                                     str(dem_path), "--prior-x", "820", "--prior-y", "695",
                                     "--prior-radius-m", "20", "-o", str(tmp_path / "fix.json")])
    assert again.exit_code == 2 and "--overwrite" in again.output
    no_prior = CliRunner().invoke(cli, ["locate", "--profile", str(tmp_path / "p.json"), "--dem",
                                        str(dem_path)])
    assert no_prior.exit_code == 2 and "prior" in no_prior.output
    r = CliRunner().invoke(cli, ["heading", "--profile", str(tmp_path / "p.json"), "--dem",
                                 str(dem_path), "--x", "815", "--y", "700",
                                 "--heading-prior-deg", "305"])
    assert r.exit_code == 0, r.output
    assert abs(_ang(json.loads(r.stdout)["heading_deg"] - 300.0)) < 1.0


def test_the_position_sigma_allows_for_the_maps_height_error(world):
    """By default (``map_sigma_m`` 2 m) the position and heading sigmas hold what a 2 m map error
    does to the fix, added in quadrature to the fit's own; 0 (the DEM is the world) leaves the
    fit's. The fix itself does not change."""
    dem, st = world
    prof = synthetic_profile(dem, 733.3, 871.9, 123.4, noise_deg=0.05, rng=3)
    exact = locate(prof, db=st, dem=dem, config=CFG)
    real = locate(prof, db=st, dem=dem, config=replace(CFG, map_sigma_m=PoseConfig().map_sigma_m))
    assert (real.x, real.y, real.heading_deg) == (exact.x, exact.y, exact.heading_deg)
    share = real.features["position_sigma_map_m"]
    assert "position_sigma_map_m" not in exact.features
    assert 1.0 < share < 50.0  # metres, on a 10 m DEM with hills 300-1000 m away
    basin = "position_sigma_basin_m"  # before a wrong basin's chance widens the reported one
    assert real.features[basin] == pytest.approx(math.hypot(exact.features[basin], share))
    assert real.position_sigma_m >= real.features[basin]
    yaw = real.features["heading_sigma_map_deg"]
    assert 0.01 < yaw < 2.0
    hb = "heading_sigma_basin_deg"  # before the rival basins' headings widen the reported one
    assert real.features[hb] == pytest.approx(math.hypot(exact.features[hb], yaw))
    assert real.heading_sigma_deg >= real.features[hb]


def test_tilted_query_with_zero_prior_is_located(world):
    # 10 deg class pitch/roll with a level prior: the source study's failure case (hundreds of m).
    dem, st = world
    tx, ty, th, p, r = 847.3, 766.1, 41.0, 8.0, -9.0
    prof = synthetic_profile(dem, tx, ty, th, p, r, noise_deg=0.1, rng=8)
    fix = locate(prof, db=st, dem=dem, config=CFG)
    err = np.hypot(fix.x - tx, fix.y - ty)
    assert err < 3.0
    assert abs(_ang(fix.heading_deg - th)) < 0.5
    assert abs(fix.pitch_deg - p) < 0.5 and abs(fix.roll_deg - r) < 0.5
    # measured 0.27 m; the calibrated sigma (2.4 m: the model widens it with the tilt found, as
    # tilted views erred more in its held-out cases) within scenario 1's 5 m
    assert err <= fix.position_sigma_m < 5.0
    assert fix.confidence >= 0.9  # measured 0.984


def test_residual_level_matches_the_simulated_noise_despite_outliers(world):
    dem, _ = world
    from skyfix.horizon import render_horizons

    x, y, h = 700.0, 880.0, 150.0
    prof = synthetic_profile(dem, x, y, h, noise_deg=0.2, outlier_fraction=0.03, rng=9)
    w = render_horizons(dem, [x], [y], azimuth_bins=1440).elevation_deg[0]
    att = fit_attitude(prof.elevation_deg, w, h, 0.0, 0.0, restarts_deg=(0.0,))
    # Gaussian noise 0.2 deg: the robust level estimates it; the plain rms is inflated by outliers.
    assert 0.16 < att.robust_rms_deg < 0.25
    assert att.rms_deg > att.robust_rms_deg


def _with_near_rock(prof, centre_deg, width_deg=8.0, lift_deg=6.0, spikes=(40, 41, 200, 300)):
    """The profile with a near rock (a block of bins lifted by ``lift_deg``) and a few spikes."""
    q = np.array(prof.elevation_deg, float)
    n = q.size
    az = np.arange(n) * 360.0 / n
    rock = np.abs((az - centre_deg + 180.0) % 360.0 - 180.0) <= width_deg / 2
    q[rock] += lift_deg
    q[list(spikes)] -= 4.0
    return Profile(q, prof.sigma_deg, "body", prof.meta)


def test_gross_outlier_bins_do_not_move_the_fix(world):
    # A near rock covering 8 deg of the view (+6 deg) and four -4 deg spikes: in a plain sum of
    # squares they outweigh all the 0.1 deg noise; the robust search must still land on the truth.
    dem, st = world
    tx, ty, th = 812.6, 701.2, 300.0
    prof = _with_near_rock(synthetic_profile(dem, tx, ty, th, noise_deg=0.1, rng=4), 75.0)
    fix = locate(prof, dem=dem, prior_xy=(tx + 9.0, ty - 7.0), prior_radius_m=20.0, config=CFG)
    assert np.hypot(fix.x - tx, fix.y - ty) < 1.0
    assert abs(_ang(fix.heading_deg - th)) < 0.3
    tx, ty, th = 733.3, 871.9, 123.4
    prof = _with_near_rock(synthetic_profile(dem, tx, ty, th, noise_deg=0.1, rng=3), 250.0)
    fix = locate(prof, db=st, dem=dem, config=CFG)
    assert np.hypot(fix.x - tx, fix.y - ty) < 3.0
    assert abs(_ang(fix.heading_deg - th)) < 0.3


def test_false_fragment_that_misleads_the_database_search_is_left_out_on_retry(world):
    # A false skyline fragment 20 deg wide, 15 deg above the truth: the database's sum of squares
    # picks a basin 235 m away (fit residual 17x the noise). Searching again with each quarter of
    # the view left out in turn brings the true basin into the refined candidates, where the
    # whole profile's clipped cost prefers it (0.024 vs 0.18).
    dem, st = world
    tx, ty, th = 733.3, 871.9, 123.4
    prof = _with_near_rock(synthetic_profile(dem, tx, ty, th, noise_deg=0.1, rng=4), 250.0,
                           width_deg=20.0, lift_deg=15.0, spikes=())
    once = locate(prof, db=st, dem=dem, config=replace(CFG, retry_below=0.0,
                                                       retry_rms_ratio=np.inf))
    assert np.hypot(once.x - tx, once.y - ty) > 100.0  # the failure the retry is for
    assert once.confidence < 0.7  # 235 m off: measured 0.55 (no rival basin left, rms 17x noise)
    fix = locate(prof, db=st, dem=dem, config=CFG)
    assert np.hypot(fix.x - tx, fix.y - ty) < 1.0
    assert abs(_ang(fix.heading_deg - th)) < 0.3
    assert fix.score < 0.5 * once.score
    # right, and far surer than the misled fix; not >= 0.9 since the confidence model learnt from
    # map-error cases that a residual well above the noise (the fragment is still in the view)
    # is often a wrong fix (measured 0.82; 0.95 before that refit)
    assert fix.confidence >= 0.75 and fix.confidence > once.confidence + 0.2


def test_residual_correlation_length_of_white_and_ar1_noise():
    """Integrated autocorrelation length against closed forms: 1 for white noise and
    (1 + rho) / (1 - rho) for an AR(1) sequence."""
    from skyfix.pose import residual_correlation_bins

    rng = np.random.default_rng(0)
    white = rng.normal(0, 0.1, 3600)
    assert residual_correlation_bins(white) == pytest.approx(1.0, abs=0.15)
    rho = 0.8
    e = rng.normal(0, 1, 20000)
    ar = np.empty_like(e)
    ar[0] = e[0]
    for i in range(1, e.size):
        ar[i] = rho * ar[i - 1] + e[i]
    # truncated where rho^k < 0.05: sum_{k<=13} 2 rho^k = 7.9, the infinite sum 8
    assert residual_correlation_bins(ar, max_lag=200) == pytest.approx(1 + 2 * sum(
        rho ** k for k in range(1, 14)), rel=0.1)
    gaps = white.copy()
    gaps[100:400] = np.nan
    assert residual_correlation_bins(gaps) == pytest.approx(1.0, abs=0.15)


def test_clipped_cost_counts_outliers_at_the_clip():
    """A query equal to a profile plus an offset, with 30 of 360 bins 10 deg off (a rock):
    residuals are 0 on the inliers, so the cost is exactly 30/360 clip^2 at the right shift."""
    from skyfix.pose import clipped_costs

    rng = np.random.default_rng(1)
    az = np.arange(360)
    p = np.stack([5 + 3 * np.sin(np.radians(az) * k) + rng.normal(0, 0.5) for k in (1, 2, 3)])
    q = np.roll(p[1], -17) + 1.5  # q[j] = p[1][j + 17]
    q[40:70] += 10.0
    cost = clipped_costs(p, q, np.array([17.0, 17.0, 17.0]), remove_tilt=True, clip_deg=0.5)
    assert cost[1] == pytest.approx(30 / 360 * 0.25, abs=1e-9)
    assert cost[0] > 5 * cost[1] and cost[2] > 5 * cost[1]


@pytest.mark.parametrize("arc", [8, 12])
def test_a_narrow_arc_gives_a_heading_rather_than_a_refusal(world, arc):
    """A frame whose skyline spans 8-12 deg (a partial detection in one photo) used to be refused
    ("observed bins too clustered to fit the tilt harmonic"): the tilt harmonic is dropped there
    and the heading still comes out (map = world here, so within a few tenths of a degree)."""
    from skyfix.match import tilt_determinable

    dem, _ = world
    prof = synthetic_profile(dem, 650.0, 950.0, 222.0, 0.0, 0.0, noise_deg=0.05, rng=7)
    q = np.full(prof.elevation_deg.size, np.nan)
    q[40:40 + arc] = prof.elevation_deg[40:40 + arc]
    assert not tilt_determinable(np.isfinite(q))
    hf = estimate_heading(Profile(q, np.where(np.isfinite(q), 0.05, np.nan), "body"),
                          dem, 650.0, 950.0, 226.0, window_deg=10.0)
    assert abs(_ang(hf.heading_deg - 222.0)) < 1.0


def test_the_tilt_harmonic_needs_a_wide_arc():
    """Closed form: over a full turn the Gram matrix of (1, cos, sin) is diag(n, n/2, n/2)
    (condition 2); a 50 deg frame still determines a tilt, a few degrees do not."""
    from skyfix.match import tilt_determinable

    assert tilt_determinable(np.ones(360, bool))
    for width, ok in ((50, True), (20, True), (5, False), (2, False)):
        m = np.zeros(360, bool)
        m[100:100 + width] = True
        assert tilt_determinable(m) is ok, width


def test_locate_takes_a_narrow_arc_on_the_attitude_prior(world):
    """30 observed bins of a 1440-bin profile span 7.5 deg: enough bins for the search, too narrow
    an arc for the tilt harmonic. locate searches without it (and says so) instead of refusing.
    So narrow a view of a bumpy world is ambiguous: the answer faces 103 deg away from the truth,
    and says so by its confidence and its sigmas (the heading's was 0.81 deg), which reach the
    rival basins facing the truth's way."""
    dem, _ = world
    full = synthetic_profile(dem, 700.0, 900.0, 40.0, 0.0, 0.0, noise_deg=0.02, rng=8, n_bins=1440)
    q = np.full(1440, np.nan)
    q[200:230] = full.elevation_deg[200:230]
    fix = locate(Profile(q, np.where(np.isfinite(q), 0.02, np.nan), "body"), dem=dem,
                 prior_xy=(700.0, 900.0), prior_radius_m=15.0, config=CFG)
    assert any("too narrow an arc" in n for n in fix.notes)
    assert fix.confidence < 0.3
    assert math.hypot(fix.x - 700.0, fix.y - 900.0) <= 2.0 * fix.position_sigma_m
    err = abs(_ang(fix.heading_deg - 40.0))
    assert err <= 2.0 * fix.heading_sigma_deg
    # the rivals that face the truth's way are what widens it, and the notes say so
    assert any(abs(_ang(c["heading_deg"] - 40.0)) < 1.0 for c in fix.candidates)
    assert any("rival basins face other ways" in n for n in fix.notes)


def test_the_calibrated_sigma_widens_with_the_residual_and_never_shrinks():
    """scripts/calibrate_confidence.py fits log s on the confidence features so that the 1-sigma
    covers held-out errors as often as it claims; skyfix never reports less than the fit's own
    curvature sigma, and more where the residuals exceed the expected noise."""
    from skyfix.pose.confidence import calibrated_sigma, load_confidence_model

    model = load_confidence_model()
    m = model["locate_prior"]["sigma"]
    assert m["radial"] and m["features"][:2] == ["log_sigma", "log_rms_over_noise"]
    feat = {"log_ratio": 3.0, "log_rms_over_noise": -1.0, "log_relief": 1.5, "observed_fraction": 1.0,
            "log_sigma": math.log(0.1), "tilt_deg": 0.0}
    z = m["intercept"] + sum(c * feat[f] for c, f in zip(m["coef"], m["features"]))
    assert calibrated_sigma(0.1, feat, model, "locate_prior") == pytest.approx(math.sqrt(2) * math.exp(z))
    worse = dict(feat, log_rms_over_noise=1.0)  # residuals e times the noise
    assert calibrated_sigma(0.1, worse, model, "locate_prior") > calibrated_sigma(0.1, feat, model, "locate_prior")
    assert calibrated_sigma(50.0, feat, model, "locate_prior") == 50.0
    assert calibrated_sigma(0.1, feat, {}, "locate_prior") == 0.1  # no model: the raw sigma
    # the fit's held-out coverage is recorded beside it, against the claim (held out by site:
    # 60 % within 1 sigma, 80 % within 2, against 63 % and 98 % claimed; the 2-sigma misses are
    # DEMERR fixes the map pulled 4-8 m at a good fit, which the map's share added to it covers:
    # 94 % and 99 % with it)
    assert m["cv_within_1_sigma"] >= m["claimed"][0] - 0.05 and m["cv_within_2_sigma"] >= 0.75
    assert m["cv_with_map_share"][0] >= m["claimed"][0] and m["cv_with_map_share"][1] >= 0.95


def test_kept_renders_equal_fresh_ones_and_are_not_redone(monkeypatch):
    """The refinement's kept skylines: the same numbers as a fresh render of each point alone,
    and a point asked for again is not rendered again."""
    import skyfix.horizon as horizon
    from skyfix.pose.scoring import Renders

    dem = _bumpy_dem()
    xs, ys = np.array([400.0, 410.0, 400.0, 620.5]), np.array([500.0, 500.0, 500.0, 610.25])
    rendered = []
    real = horizon.render_horizons

    def counting(dem_, x, y, **kw):
        rendered.extend(zip(np.ravel(x), np.ravel(y)))
        return real(dem_, x, y, **kw)

    monkeypatch.setattr(horizon, "render_horizons", counting)
    r = Renders(dem, camera_height_m=1.5, planet="earth")
    el, dist = r.horizons(xs, ys, 720)
    el2, _ = r.horizons(xs[::-1], ys[::-1], 720)
    assert len(rendered) == 3  # (400, 500) once, and nothing on the second call
    for i in range(xs.size):
        one = real(dem, [xs[i]], [ys[i]], camera_height_m=1.5, planet="earth", azimuth_bins=720)
        assert np.array_equal(el[i], one.elevation_deg[0], equal_nan=True)
        assert np.array_equal(dist[i], one.skyline_distance_m[0], equal_nan=True)
    assert np.array_equal(el2, el[::-1], equal_nan=True)


def test_grid_levels_are_five_by_five(world):
    """The grid refinement's levels span +/- 2 of their steps (the level before placed the best
    point within half its step, two of these), re-centred where the best point is on the edge:
    from 17 m off, on a clean profile, they land on the same point as 9 x 9 levels do, and the
    finest grid ends centred on its best point, the 5 x 5 around it there for the position
    sigma."""
    from skyfix.pose.refine import refine_grid
    from skyfix.pose.scoring import Renders

    dem, _ = world
    tx, ty = 733.3, 871.9
    q = synthetic_profile(dem, tx, ty, 123.4, noise_deg=0.02, rng=5).elevation_deg
    kw = dict(camera_height_m=1.5, planet=None, remove_tilt=True)
    counts = {}
    for half in (2, 4):
        renders = Renders(dem, camera_height_m=1.5, planet=None)
        counts[half] = renders
        res = refine_grid(dem, q, 745.0, 860.0, 5.0, 3, half=half, renders=renders, **kw)
        if half == 2:
            new = res
        else:
            old = res
    assert new[:2] == old[:2]
    assert math.hypot(new[0] - tx, new[1] - ty) < 0.5  # the finest step is 0.31 m (0.32 m here)
    gx, gy, sc, step = new[4]
    assert step == 5.0 / 16
    assert gx.size == 25 and (gx.min() + gx.max()) / 2 == new[0] and (gy.min() + gy.max()) / 2 == new[1]
    assert sc.min() == new[2]
    # what it saves: the points rendered (9 x 9 at each of three levels before)
    assert len(counts[2]._kept) < 0.5 * len(counts[4]._kept)


def test_polish_stops_in_a_known_basin(world, monkeypatch):
    """A candidate's polish that walks into the basin of one polished before it (within
    ``join_m``, that one's cost no higher) stops there: it would only find that answer again.
    Without the basin it walks on to the floor."""
    from skyfix.pose import refine
    from skyfix.pose.attitude import fit_attitude

    dem, _ = world
    tx, ty, th = 733.3, 871.9, 123.4
    prof = synthetic_profile(dem, tx, ty, th, noise_deg=0.02, rng=6)
    q = prof.elevation_deg
    start = (tx + 9.0, ty - 6.0)
    att0 = fit_attitude(q, refine.Renders(dem, camera_height_m=1.5, planet=None).horizons(
        [start[0]], [start[1]], 1440)[0][0], th, restarts_deg=(0.0,))
    fits = []
    monkeypatch.setattr(refine, "fit_attitude", lambda *a, **k: fits.append(1) or fit_attitude(*a, **k))
    kw = dict(camera_height_m=1.5, planet=None, render_bins=1440, prior_pitch_deg=0.0,
              prior_roll_deg=0.0, noise=0.02)
    free = refine.polish_position(dem, q, *start, att0, **kw)
    n_free = len(fits)
    fits.clear()
    joined = refine.polish_position(dem, q, *start, att0, basins=[(tx, ty, 0.0)], join_m=5.0, **kw)
    assert math.hypot(free[0] - tx, free[1] - ty) < 0.3  # walked 11 m to the floor
    assert math.hypot(joined[0] - tx, joined[1] - ty) <= 5.0  # stopped on entering the basin
    # measured: 124 fits to 0.06 m off, against 12 fits to 2.1 m off
    assert joined[3] > free[3] and len(fits) < n_free / 2


def test_a_view_narrower_than_the_calibration_is_not_confident(world):
    """One navcam frame's 45 deg: the confidence model saw views of 120-360 deg only, and gave
    0.80 on single frames 18-37 m off. Capped, and said, whatever the fix."""
    from skyfix.pose.locate import CALIBRATED_MIN_SPAN_DEG, DEGENERATE_CAP

    dem, st = world
    prof = synthetic_profile(dem, 733.3, 871.9, 123.4, noise_deg=0.05, rng=3)
    az = np.arange(prof.elevation_deg.size) * 360.0 / prof.elevation_deg.size
    keep = np.abs(_ang(az - 40.0)) <= 22.5
    q = np.where(keep, prof.elevation_deg, np.nan)
    narrow = type(prof)(q, np.where(keep, prof.sigma_deg, np.nan), prof.frame, prof.meta)
    fix = locate(narrow, db=st, dem=dem, config=CFG)
    assert fix.confidence <= DEGENERATE_CAP
    assert any(f"narrower than the {CALIBRATED_MIN_SPAN_DEG:g} deg" in n for n in fix.notes)
    full = locate(prof, db=st, dem=dem, config=CFG)  # the whole turn is not capped
    assert not any("narrower than" in n for n in full.notes) and full.confidence > DEGENERATE_CAP
