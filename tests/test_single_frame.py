"""One photograph: roll, pitch and heading from a single navcam frame at a known position
(``skyfix attitude``), a frame seeing its skyline over a third of its width, a camera 30 m above
the DEM, and a frame with no skyline refused."""

import json
import math

import numpy as np
import pytest

from conftest import cli_run as run, shared_dem_path
from skyfix.dem import load_dem
from skyfix.formats import Truth
from skyfix.simulate import simulate_acquisition

X, Y = 601500.0, 6743500.0  # glacier DEM, a valley with ridges around


@pytest.fixture(scope="module")
def dem_path():
    return shared_dem_path("south_glacier_20m")


def _frame(dem_path, out, *, yaw, pan, height=1.5, tilt=10.0, pitch=2.0, roll=-1.5, prior=None):
    dem = load_dem(dem_path)
    return simulate_acquisition(dem, Truth(X, Y, yaw, pitch, roll), out, frames=1, pan_start_deg=pan,
                                tilt_deg=tilt, camera_height_m=height, seed=3,
                                attitude_prior=prior)


def _angle(a):
    return abs((a + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("height", [1.5, 30.0])
def test_one_frame_gives_roll_pitch_and_heading(dem_path, tmp_path, height):
    """The inclinometer off by (1.5, -1) deg and the heading prior 6 deg off; the camera 1.5 m or
    30 m above the DEM surface (taken from the acquisition)."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, height=height, prior=(3.5, -2.5))
    r = run("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0,
            "--prior-north", "grid")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert _angle(d["grid_heading_deg"] - 40.0) < 1.0
    assert abs(d["pitch_deg"] - 2.0) < 0.5 and abs(d["roll_deg"] + 1.5) < 0.5
    # solved in the image plane as well: measured 0.005-0.009 deg off on every axis
    assert _angle(d["grid_heading_deg"] - 40.0) < 0.05
    assert abs(d["pitch_deg"] - 2.0) < 0.05 and abs(d["roll_deg"] + 1.5) < 0.05
    assert set(d["determined"]) == {"heading", "pitch", "roll"} and d["determined"]["heading"]
    assert 0 < d["heading_sigma_deg"] < 1.0 and np.isfinite(d["pitch_sigma_deg"])
    assert d["confidence"] >= 0.5
    # with -o the JSON goes to the file and a closing line says what was found, as locate's does
    r = run("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0,
            "--prior-north", "grid", "-o", tmp_path / "att.json")
    assert r.exit_code == 0 and json.loads((tmp_path / "att.json").read_text()) == d
    assert f"confidence {d['confidence']:.2f} -> {tmp_path / 'att.json'}" in r.output


def test_a_frame_looking_at_the_ground_is_refused_clearly(dem_path, tmp_path):
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, tilt=-60.0)
    r = run("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0)
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and "no skyline" in r.output and "sky visible?" in r.output


def _synthetic_world(m=7200):
    az = np.arange(m) * 360.0 / m
    a = np.radians(az)
    return az, 2.0 + 1.5 * np.sin(3 * a) + 0.8 * np.cos(7 * a + 0.4) + 0.3 * np.sin(23 * a)


@pytest.mark.parametrize("share", [1.0, 1.0 / 3.0])
def test_image_plane_solve_recovers_a_known_attitude(share):
    """Rows made by the geometry module's forward path (``horizon_rows``, the one the profile's
    projection is tested against) from a known attitude; the solve starts 2 deg off on every
    axis and must land on the truth, with the skyline over the whole width or its left third."""
    from skyfix.camera import get_camera, r_world_cam
    from skyfix.pose.image_plane import FrameRows, fit_attitude_image
    from skyfix.profile import horizon_rows

    cam = get_camera("navcam")
    az, el = _synthetic_world()
    truth = (123.4, 2.1, -1.3)
    rows = horizon_rows(cam, az, el, r_world_cam(*truth, 20.0, 10.0))
    rows[int(share * cam.width):] = np.nan
    assert np.isfinite(rows).sum() >= share * cam.width - 2
    fit = fit_attitude_image([FrameRows(cam, 20.0, 10.0, rows)], el, 125.4, 0.1, 0.7)
    assert _angle(fit.yaw_deg - truth[0]) < 0.01
    assert abs(fit.pitch_deg - truth[1]) < 0.01 and abs(fit.roll_deg - truth[2]) < 0.02
    assert fit.robust_rms_px < 0.1 and fit.n_columns >= share * cam.width / 4 - 1


def test_image_plane_solve_is_not_pulled_by_a_stretch_the_map_has_wrong():
    """A stretch of 15 % of the columns up to 25 px off the rest's geometry (a near slope that the
    map's height error tilts, as DEMERR frames show): the answer follows the columns that fit.
    Under the Huber loss the solve paid for the stretch in proportion and came out 0.95 deg off
    in yaw and 1.04 in roll; the Cauchy loss redescends (0.02-0.03 deg)."""
    from skyfix.camera import get_camera, r_world_cam
    from skyfix.pose.image_plane import FrameRows, fit_attitude_image
    from skyfix.profile import horizon_rows

    cam = get_camera("navcam")
    az, el = _synthetic_world()
    truth = (123.4, 2.1, -1.3)
    rows = horizon_rows(cam, az, el, r_world_cam(*truth, 20.0, 10.0))
    u = np.arange(cam.width)
    bump = 25.0 * np.clip(1.0 - np.abs(u - 0.8 * cam.width) / (0.075 * cam.width), 0.0, None) ** 0.25
    fit = fit_attitude_image([FrameRows(cam, 20.0, 10.0, rows - bump)], el, 124.4, 1.1, -0.3)
    assert _angle(fit.yaw_deg - truth[0]) < 0.1
    assert abs(fit.pitch_deg - truth[1]) < 0.05 and abs(fit.roll_deg - truth[2]) < 0.1


def test_image_plane_solve_needs_a_skyline():
    from skyfix.camera import get_camera
    from skyfix.pose.image_plane import FrameRows, fit_attitude_image

    cam = get_camera("navcam")
    rows = np.full(cam.width, np.nan)
    rows[:20] = 300.0
    assert fit_attitude_image([FrameRows(cam, 0.0, 10.0, rows)], _synthetic_world()[1], 0, 0, 0) is None


def test_one_frame_located_on_a_prior_area_gets_its_attitude_from_the_image(dem_path, tmp_path):
    """``skyfix locate`` on one frame (prior area, no database), the inclinometer 1.5/1 deg off:
    the position is what a 50-deg view allows (4.5 m off), and the attitude reported is solved
    in the image plane at the fix (measured 0.07 / 0.03 / 0.09 deg off in pitch / roll /
    heading; the refinement's profile fit gave the same here within 0.005 deg)."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, prior=(3.5, -2.5))
    r = run("locate", acq, "--dem", dem_path, "--prior-x", X + 4.0, "--prior-y", Y - 3.0,
            "--prior-radius-m", 15)
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert np.hypot(d["x"] - X, d["y"] - Y) < 8.0
    assert abs(d["pitch_deg"] - 2.0) < 0.15 and abs(d["roll_deg"] + 1.5) < 0.15
    assert _angle(d["grid_heading_deg"] - 40.0) < 0.5


def test_view_span_goes_round_north():
    from skyfix.camera import get_camera
    from skyfix.pose.image_plane import FrameRows, view_span_deg

    cam = get_camera("navcam")
    rows = np.zeros(cam.width)
    span = lambda pans: view_span_deg([FrameRows(cam, p, 10.0, rows) for p in pans])  # noqa: E731
    assert span([0.0]) == pytest.approx(cam.hfov_deg)
    assert span([350.0, 10.0]) == pytest.approx(20.0 + cam.hfov_deg)
    assert span([0.0, 120.0, 240.0]) == pytest.approx(240.0 + cam.hfov_deg)
    assert span(np.arange(0.0, 360.0, 30.0)) == 360.0


def test_map_share_of_the_sigmas_matches_the_spread_of_fits_under_map_errors():
    """The sigmas' map share (a linearised sandwich) against an independent Monte Carlo: terrain
    heights drawn with the model's error (2 m rms, exponential correlation over 150 m, at every
    skyline point and under the camera), rows rendered from that world through the camera
    model, the nonlinear solve run on the map; the fits' spread must be what the sigmas say."""
    from skyfix.camera import get_camera, r_world_cam
    from skyfix.pose.image_plane import MAP_CORRELATION_M, FrameRows, fit_attitude_image
    from skyfix.profile import horizon_rows

    cam = get_camera("navcam")
    az, el = _synthetic_world()
    a = np.radians(az)
    dist = 300.0 + 2500.0 * (0.5 + 0.5 * np.sin(2.0 * a + 1.0))  # [m] near and far ridges
    truth = (123.4, 2.1, -1.3)
    rot = r_world_cam(*truth, 20.0, 10.0)
    seen = np.flatnonzero((az > 105.0) & (az < 182.0))  # the frame's bins and a margin
    pts = np.r_[np.c_[dist[seen] * np.sin(a[seen]), dist[seen] * np.cos(a[seen])], [[0.0, 0.0]]]
    gap = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
    chol = np.linalg.cholesky(np.exp(-gap / MAP_CORRELATION_M) + 1e-9 * np.eye(len(pts)))
    sigma_m = 2.0
    ref = fit_attitude_image([FrameRows(cam, 20.0, 10.0, horizon_rows(cam, az, el, rot))], el,
                             *truth, world_dist_m=dist, dem_sigma_m=sigma_m)
    assert ref.map_sigma_deg is not None and min(ref.map_sigma_deg) > 0.005
    rng = np.random.default_rng(7)
    fits = []
    for _ in range(60):
        e = sigma_m * chol @ rng.standard_normal(len(pts))
        world = el.copy()
        world[seen] += np.degrees((e[:-1] - e[-1]) / dist[seen])  # the terrain the camera saw
        rows = horizon_rows(cam, az, world, rot)
        f = fit_attitude_image([FrameRows(cam, 20.0, 10.0, rows)], el, *truth)
        fits.append(((f.yaw_deg - truth[0] + 180.0) % 360.0 - 180.0, f.pitch_deg - truth[1],
                     f.roll_deg - truth[2]))
    spread = np.sqrt(np.mean(np.square(fits), axis=0))
    # 60 draws: the rms itself is known to ~10 %
    np.testing.assert_allclose(spread, ref.map_sigma_deg, rtol=0.3)
    # and the reported sigmas hold the map's share
    assert ref.pitch_sigma_deg >= ref.map_sigma_deg[1] and ref.roll_sigma_deg >= ref.map_sigma_deg[2]


def test_dem_sigma_is_checked_and_widens_the_sigmas(dem_path, tmp_path):
    """``--dem-sigma-m``: refused when negative, before any image is read; 0 (the DEM taken as
    the world) gives sigmas no wider than the default 2 m, which must not be narrower."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, prior=(3.5, -2.5))
    base = ("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0,
            "--prior-north", "grid")
    r = run(*base, "--dem-sigma-m", -1)
    assert r.exit_code == 2 and "--dem-sigma-m" in r.output and "Traceback" not in r.output
    wide, exact = (json.loads(run(*base, *extra).stdout) for extra in ((), ("--dem-sigma-m", 0)))
    for k in ("heading_sigma_deg", "pitch_sigma_deg", "roll_sigma_deg"):
        assert wide[k] >= exact[k]
    assert wide["pitch_sigma_deg"] > exact["pitch_sigma_deg"]
    assert wide["provenance"]["options"]["dem_sigma_m"] == 2.0


@pytest.mark.parametrize("off_deg, capped", [(3.0, True), (0.2, False)])
def test_a_heading_whose_two_solves_disagree_says_so_in_its_notes(dem_path, monkeypatch, off_deg,
                                                                   capped):
    """The image-plane solve landing more than 1 deg from the profile fit's caps the confidence,
    as locate does; the heading result now says why in ``notes``, as locate's fix does. The
    image-plane solve is stubbed to land ``off_deg`` away (the cap is about its answer, not how
    it got there)."""
    import skyfix.pose.heading as ph
    from skyfix import pose
    from skyfix.camera import get_camera
    from skyfix.pose.image_plane import SOLVES_DISAGREE_CONFIDENCE, FrameRows, ImageAttitude

    dem = load_dem(dem_path)
    prof = pose.synthetic_profile(dem, X, Y, 80.0, noise_deg=0.05, rng=1)
    monkeypatch.setattr(ph, "image_plane_attitude", lambda frames, dem, x, y, yaw, pitch, roll, **k:
                        ImageAttitude(yaw + off_deg, pitch, roll, 0.1, 0.1, 0.1, 0.5, 500))
    cam = get_camera("navcam")
    h = pose.estimate_heading(prof, dem, X, Y, 82.0, 10.0,
                              frames=[FrameRows(cam, 0.0, 10.0, np.zeros(cam.width))])
    said = [n for n in h.notes if "image-plane heading lies more than 1 deg" in n]
    assert bool(said) == capped and h.to_dict()["notes"] == list(h.notes)
    if capped:
        assert h.confidence <= SOLVES_DISAGREE_CONFIDENCE
        # said as a bound, not as the reason for a confidence that may lie far below it
        assert said == ["the image-plane heading lies more than 1 deg from the profile fit's: "
                        f"confidence at most {SOLVES_DISAGREE_CONFIDENCE}"]


def test_a_tilt_given_wrong_is_said_where_the_attitude_leaves_the_prior(dem_path, tmp_path):
    """A mast tilted 15 deg declared level: the skyline fits that tilt as pitch or roll, with full
    confidence (the review measured roll -16 deg at 1.0); the answer must say it left the
    inclinometer's prior by more than a prior may be off. The truthful file says nothing."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=123.0, pan=90.0, tilt=15.0, prior=(2.0, -1.5))
    args = ("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 125.0,
            "--prior-north", "grid")
    r = run(*args)
    assert r.exit_code == 0, r.output
    assert not [n for n in json.loads(r.stdout)["notes"] if "inclinometer" in n]
    meta = json.loads((acq / "acquisition.json").read_text())
    meta["frames"][0]["tilt_deg"] = 0.0
    (acq / "acquisition.json").write_text(json.dumps(meta))
    r = run(*args)
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert abs(d["roll_deg"] + 1.5) > 10.0 or abs(d["pitch_deg"] - 2.0) > 10.0  # the tilt moved
    assert any("from the inclinometer's prior" in n and "check the frames' tilt_deg" in n
               for n in d["notes"]), d["notes"]


def test_attitude_cost_tells_the_truth_from_a_wrong_answer():
    """The diagnosis of single-frame misses rests on it: on rows made from a known attitude, the
    truth costs nothing and 0 px, an attitude 1 deg off in yaw costs more, by its residuals."""
    from skyfix.camera import get_camera, r_world_cam
    from skyfix.pose.image_plane import RANK_SCALE_PX, FrameRows, attitude_cost
    from skyfix.profile import horizon_rows

    cam = get_camera("navcam")
    az, el = _synthetic_world()
    truth = (123.4, 2.1, -1.3)
    frames = [FrameRows(cam, 20.0, 10.0, horizon_rows(cam, az, el, r_world_cam(*truth, 20.0, 10.0)))]
    c0, m0 = attitude_cost(frames, el, *truth)
    assert c0 < 1e-3 and m0 < 0.01
    c1, m1 = attitude_cost(frames, el, truth[0] + 1.0, truth[1], truth[2])
    # pitch 1 deg down moves every column by about the focal length's worth of a degree
    c2, m2 = attitude_cost(frames, el, truth[0], truth[1] + 1.0, truth[2])
    assert abs(m2 - cam.fy * np.radians(1.0)) < 2.0
    n = np.isfinite(frames[0].rows[::4]).sum()
    assert c2 == pytest.approx(n * 0.5 * RANK_SCALE_PX ** 2 * np.log1p((m2 / RANK_SCALE_PX) ** 2), rel=0.05)
    assert c1 > 10 * max(c0, 1.0) and m1 > 1.0


@pytest.mark.parametrize("ridge_m, near", [(40.0, True), (1500.0, False)])
def test_a_skyline_too_near_for_the_map_is_said(ridge_m, near):
    """A view of a ridge 40 m away (its near flank, where the DEM's 2 m height error is 3-4 deg)
    says so in its notes; the same ridge 1.5 km away, where that error is 0.08 deg, does not."""
    from skyfix.dem import Dem
    from skyfix.pose import estimate_heading, synthetic_profile

    cell = 10.0
    n = 401
    xs = np.arange(n) * cell
    ys = xs[::-1]
    cx, cy = xs[n // 2], ys[-1] + 200.0  # the camera 200 m from the south edge, looking north
    # a ridge running east-west ridge_m north of the camera, 30 m high, 60 m across
    z = 30.0 * np.exp(-(((ys[:, None] - (cy + ridge_m)) / 30.0) ** 2)) + np.zeros((1, n))
    dem = Dem.from_array(z, cell)
    prof = synthetic_profile(dem, cx, cy, 0.0)
    az = np.arange(prof.elevation_deg.size) * 360.0 / prof.elevation_deg.size
    q = np.where(np.abs((az + 180) % 360 - 180) <= 25.0, prof.elevation_deg, np.nan)
    prof = type(prof)(q, np.where(np.isfinite(q), prof.sigma_deg, np.nan), prof.frame, prof.meta)
    fix = estimate_heading(prof, dem, cx, cy, 0.0, 10.0)
    said = [s for s in fix.notes if "the skyline in view lies" in s]
    assert bool(said) == near, fix.notes
    if near:
        # the sight line grazes the ridge's near flank, short of its crest
        assert 20 <= float(said[0].split("lies ")[1].split(" m")[0]) <= ridge_m and "229 m" in said[0]
        # a profile's sigmas do not take --dem-sigma-m: the note does not say they allow for it
        assert "not taken from --dem-sigma-m" in said[0] and "sigmas allow for it" not in said[0]


def test_a_tilt_the_view_cannot_see_has_a_bounded_sigma(dem_path):
    """Eight bins of skyline cannot separate pitch from the rest: its sigma came out in the
    hundreds of degrees on such views (290 and 765 on a corner of slope). It stays within the
    uniform spread over the fits' +-30 deg bound."""
    from skyfix.pose import estimate_heading, synthetic_profile
    from skyfix.pose.fix import UNKNOWN_TILT_SIGMA_DEG

    dem = load_dem(dem_path)
    x0, y0, x1, y1 = dem.bounds
    x, y = (x0 + x1) / 2, (y0 + y1) / 2
    prof = synthetic_profile(dem, x, y, 40.0, noise_deg=0.05, rng=3)
    q = prof.elevation_deg.copy()
    q[8:] = np.nan
    prof = type(prof)(q, np.where(np.isfinite(q), prof.sigma_deg, np.nan), prof.frame, prof.meta)
    fix = estimate_heading(prof, dem, x, y, 40.0, 10.0)
    assert fix.pitch_sigma_deg == pytest.approx(UNKNOWN_TILT_SIGMA_DEG)  # capped, not 17.3 by chance
    assert fix.roll_sigma_deg <= UNKNOWN_TILT_SIGMA_DEG and not fix.determined["pitch"]


def test_no_angle_is_determined_at_a_heading_likely_wrong(dem_path, monkeypatch):
    """A roll with a small sigma was marked determined at a heading 8.5 deg off (confidence
    0.02): fitted in the wrong basin, it was 8.3 deg off. Below DETERMINED_MIN_CONFIDENCE nothing
    counts as determined, whatever the sigmas."""
    import skyfix.pose.heading as ph
    from skyfix.pose import estimate_heading, synthetic_profile
    from skyfix.pose.fix import DETERMINED_MIN_CONFIDENCE

    dem = load_dem(dem_path)
    x0, y0, x1, y1 = dem.bounds
    x, y = (x0 + x1) / 2, (y0 + y1) / 2
    prof = synthetic_profile(dem, x, y, 40.0, noise_deg=0.05, rng=3)
    sure = estimate_heading(prof, dem, x, y, 40.0, 10.0)
    assert sure.confidence >= DETERMINED_MIN_CONFIDENCE and all(sure.determined.values())
    monkeypatch.setattr(ph, "confidence_from_features", lambda *a, **k: 0.2)
    unsure = estimate_heading(prof, dem, x, y, 40.0, 10.0)
    assert unsure.confidence < DETERMINED_MIN_CONFIDENCE and not any(unsure.determined.values())
    # Its sigmas now say so too: with the basin's own sigmas of hundredths of a degree and the
    # answer on the priors, the 68 % half-width is where 0.2 + 0.8 r / w reaches erf(1/sqrt 2),
    # w the window (10 deg of heading; the inclinometer prior's 10 deg of tilt).
    assert max(sure.roll_sigma_deg, sure.heading_sigma_deg) < 0.5
    r = (math.erf(1 / math.sqrt(2)) - 0.2) / 0.8 * 10.0
    assert unsure.heading_sigma_deg == pytest.approx(r, abs=0.1)
    assert unsure.roll_sigma_deg == pytest.approx(r, abs=0.1)
    assert any("another basin" in n for n in unsure.notes)
    # the basin's own stays at hand for a filter that settles the basin by its track
    assert unsure.features["heading_sigma_basin_deg"] < 0.5
    assert not any("another basin" in n for n in sure.notes)


def test_wrong_basin_sigma_holds_the_error_as_often_as_a_sigma_claims():
    """Against a direct draw of the mixture it describes: right (normal, sigma) with probability
    c, else uniform over the window about the prior."""
    from skyfix.pose.basin_sigma import wrong_basin_sigma

    rng = np.random.default_rng(0)
    # windows past 90 deg: their far side lies near the other end, the short way round (the sigma
    # was 181 deg for 103 at +-170)
    for sigma, c, w, off in ((0.4, 0.9, 10.0, 2.0), (1.37, 0.55, 10.0, 5.0), (0.8, 0.3, 180.0, 0.0),
                             (0.2, 0.7, 10.0, 9.5), (0.5, 0.3, 170.0, -165.0),
                             (0.5, 0.5, 150.0, 140.0)):
        n = 400_000
        right = rng.random(n) < c
        truth_wrong = rng.uniform(-w, w, n) if w < 180 else rng.uniform(-180, 180, n)
        err = np.where(right, rng.normal(0, sigma, n), _angle(truth_wrong - off))
        s = wrong_basin_sigma(sigma, c, w, off)
        assert np.mean(np.abs(err) <= s) == pytest.approx(math.erf(1 / math.sqrt(2)), abs=0.003)
    assert wrong_basin_sigma(0.3, 1.0, 10.0, 4.0) == pytest.approx(0.3)
    assert wrong_basin_sigma(0.3, 0.0, 10.0, 0.0) == pytest.approx(10.0 * math.erf(1 / math.sqrt(2)))


def test_a_position_may_lie_in_another_basin_of_the_searched_area():
    """The radial counterpart, against a direct draw: right (round normal, radial sigma s, so
    s / sqrt(2) an axis) with probability c, else uniform over the prior disc or the
    database's rectangle; 63.2 % within the radius returned."""
    from skyfix.pose.basin_sigma import disc_share, rect_share, wrong_basin_radius

    rng = np.random.default_rng(3)
    n = 300_000
    for sigma, c, region in ((0.4, 0.5, "disc"), (3.0, 0.4, "rect"), (2.0, 0.97, "rect")):
        right = rng.random(n) < c
        if region == "disc":  # a 20 m prior disc about (0, 0), the answer at (6, -3)
            ax, ay = 6.0, -3.0
            r = 20.0 * np.sqrt(rng.random(n))
            t = rng.uniform(0, 2 * np.pi, n)
            wx, wy = r * np.cos(t), r * np.sin(t)
            share = disc_share(0.0, 0.0, 20.0, ax, ay)
        else:  # a 7 x 3 km database, the answer near a corner
            ax, ay = 500.0, 2800.0
            wx, wy = rng.uniform(0, 7000, n), rng.uniform(0, 3000, n)
            share = rect_share(0.0, 7000.0, 0.0, 3000.0, ax, ay)
        ex = np.where(right, rng.normal(0, sigma / math.sqrt(2), n), wx - ax)
        ey = np.where(right, rng.normal(0, sigma / math.sqrt(2), n), wy - ay)
        s = wrong_basin_radius(sigma, c, share)
        assert np.mean(np.hypot(ex, ey) <= s) == pytest.approx(1 - math.exp(-1), abs=0.004)
    # a confident fix keeps its sigma but for a hair
    assert wrong_basin_radius(2.0, 1.0, rect_share(0, 7000, 0, 7000, 3500, 3500)) == \
        pytest.approx(2.0, rel=1e-6)



def test_locate_heading_sigma_spreads_over_the_rival_basins_headings():
    """Against a direct draw: the answer's heading (normal, sigma) with probability c, else one of
    the rivals' (each as likely, normal about it); 68.3 % within the half-width returned. Rivals
    that keep the answer's heading leave the sigma as it was."""
    from skyfix.pose.basin_sigma import rival_heading_sigma

    rng = np.random.default_rng(5)
    n = 400_000
    for sigma, c, rivals in ((0.8, 0.03, (3.3, -103.2, -103.3)), (0.3, 0.6, (0.1, 25.0)),
                             (0.5, 0.9, (170.0, -175.0, 2.0, 0.0)), (1.0, 0.2, (-60.0,))):
        right = rng.random(n) < c
        pick = np.asarray(rivals)[rng.integers(0, len(rivals), n)]
        err = np.where(right, 0.0, pick) + rng.normal(0, sigma, n)
        s = rival_heading_sigma(sigma, c, rivals)
        assert np.mean(np.abs(_angle(err)) <= s) == pytest.approx(math.erf(1 / math.sqrt(2)),
                                                                  abs=0.003)
    assert rival_heading_sigma(0.4, 0.5, ()) == 0.4  # no rival found: the basin's own
    assert rival_heading_sigma(0.4, 0.2, (0.0, 0.05)) == pytest.approx(0.4, rel=0.01)

def test_a_saved_profile_carries_the_camera_height_and_one_without_it_is_noted(dem_path,
                                                                               tmp_path):
    """``skyfix profile -o`` dropped the acquisition's camera height, so ``locate --profile`` and
    ``heading --profile`` took 1.5 m for a camera 5 m up (3.7 m off at confidence 0.96) without
    a word."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, height=5.0)
    prof = tmp_path / "p.json"
    assert run("profile", acq, "-o", prof).exit_code == 0
    d = json.loads(prof.read_text())
    assert d["camera_height_m"] == 5.0
    r = run("heading", "--profile", prof, "--dem", dem_path, "--x", X, "--y", Y,
            "--heading-prior-deg", 44.0, "--prior-north", "grid")
    assert r.exit_code == 0, r.output
    assert not any("camera's height" in n for n in json.loads(r.stdout)["notes"])
    d.pop("camera_height_m")
    old = tmp_path / "old.json"
    old.write_text(json.dumps(d))
    for cmd in (("heading", "--profile", old, "--dem", dem_path, "--x", X, "--y", Y,
                 "--heading-prior-deg", 44.0, "--prior-north", "grid"),
                ("locate", "--profile", old, "--dem", dem_path, "--prior-x", X, "--prior-y", Y,
                 "--prior-radius-m", 5)):
        r = run(*cmd)
        assert r.exit_code == 0, r.output
        said = [n for n in json.loads(r.stdout)["notes"] if "camera's height" in n]
        assert said and "taken as 1.5 m" in said[0] and "camera_height_m" in said[0]
        assert "warning:" in r.stderr


def test_a_database_searched_inside_a_prior_disc_spreads_over_both():
    """With --db and a prior disc, the searched area is the grid inside the disc: a 5 km disc
    about a 425 m database spread a right fix's sigma over 2.9 km. Against a direct draw."""
    from skyfix.pose.basin_sigma import rect_share, wrong_basin_radius

    rng = np.random.default_rng(4)
    n = 300_000
    x0, x1, y0, y1, disc = 0.0, 425.0, 0.0, 425.0, (300.0, 100.0, 200.0)
    # uniform over rectangle and disc both: draw in the rectangle, keep those in the disc
    ux, uy = rng.uniform(x0, x1, 3 * n), rng.uniform(y0, y1, 3 * n)
    keep = np.hypot(ux - disc[0], uy - disc[1]) <= disc[2]
    ux, uy = ux[keep][:n], uy[keep][:n]
    ax, ay, sigma, c = 250.0, 150.0, 5.0, 0.6
    right = rng.random(ux.size) < c
    ex = np.where(right, rng.normal(0, sigma / math.sqrt(2), ux.size), ux - ax)
    ey = np.where(right, rng.normal(0, sigma / math.sqrt(2), ux.size), uy - ay)
    s = wrong_basin_radius(sigma, c, rect_share(x0, x1, y0, y1, ax, ay, disc=disc))
    assert np.mean(np.hypot(ex, ey) <= s) == pytest.approx(1 - math.exp(-1), abs=0.005)
    # a disc far wider than the grid changes nothing; an empty region widens nothing
    wide = wrong_basin_radius(sigma, c, rect_share(x0, x1, y0, y1, ax, ay, disc=(200, 200, 5000)))
    alone = wrong_basin_radius(sigma, c, rect_share(x0, x1, y0, y1, ax, ay))
    assert wide == pytest.approx(alone, rel=0.01) and alone < 425
    assert wrong_basin_radius(sigma, c, rect_share(x0, x1, y0, y1, ax, ay, disc=(5e4, 0, 10))) \
        == pytest.approx(sigma)


def test_a_confidence_capped_for_the_sigmas_own_width_does_not_widen_it_again(dem_path):
    """A rough position known to 200 m: the heading's own sigma spans degrees, and the
    confidence is capped at the chance such a sigma stays within 1 deg. That cap speaks of the
    sigma's width, which the sigma carries: a right heading came out +-94 deg, its pitch and
    roll +-5 deg for 0.02 of their own."""
    from skyfix.pose import estimate_heading, synthetic_profile

    dem = load_dem(dem_path)
    prof = synthetic_profile(dem, X, Y, 40.0, noise_deg=0.05, rng=5)
    hf = estimate_heading(prof, dem, X, Y, 45.0, 180.0, position_sigma_m=200.0)
    own = hf.features["heading_sigma_basin_deg"]
    assert own > 2.0 and hf.confidence == pytest.approx(math.erf(1 / (own * math.sqrt(2))))
    assert _angle(hf.grid_heading_deg - 40.0) < 1.0
    assert hf.heading_sigma_deg < 1.5 * own and hf.roll_sigma_deg < 1.0
    assert not any("another basin" in n for n in hf.notes)
