"""The traverse filter against closed forms, and the loop's gating, operator requests, resume and
input checks on scripted measurements."""

import json
import math
import re

import numpy as np
import pytest

from skyfix.errors import ParameterError, SkyfixError
from skyfix.traverse import (Measure, Measurement, Odometry, PoseFilter, TraverseConfig,
                             read_traverse, run_traverse)
from skyfix.traverse.inputs import Start, Traverse


def test_straight_path_covariance_grows_as_the_closed_form():
    """Heading 0 (north), n steps of f metres, per-step sigmas sf, sl, sh, a perfect start.
    Linearised: y_n = sum of forward steps, var n sf^2; x_n = f sum_k dh_k - sum_k l_k with dh_k
    the heading error accumulated before step k, var n sl^2 + f^2 sh^2 (n-1) n (2n-1) / 6
    (sh in rad); var(heading) = n sh^2."""
    f, sf, sl, sh, n = 50.0, 1.0, 0.3, 0.2, 40
    filt = PoseFilter(0.0, 0.0, 0.0, np.zeros((3, 3)))
    for _ in range(n):
        filt.predict(Odometry.from_sigmas(f, 0.0, 0.0, sf, sl, sh))
    shr = math.radians(sh)
    assert filt.state == pytest.approx([0.0, n * f, 0.0])
    assert filt.cov[1, 1] == pytest.approx(n * sf ** 2)
    assert filt.cov[0, 0] == pytest.approx(n * sl ** 2 + f ** 2 * shr ** 2 * (n - 1) * n * (2 * n - 1) / 6)
    assert filt.cov[2, 2] == pytest.approx(n * sh ** 2)


def test_the_filter_covariance_matches_a_monte_carlo_of_the_exact_motion():
    rng = np.random.default_rng(0)
    steps = [(30.0, 2.0, 4.0)] * 25  # a curving path: forward, left [m], heading change [deg]
    sig = (0.6, 0.2, 0.3)
    filt = PoseFilter(100.0, 200.0, 30.0, np.diag([1.0, 1.0, 0.25]))
    for s in steps:
        filt.predict(Odometry.from_sigmas(*s, *sig))
    m = 20000
    x = rng.normal(100.0, 1.0, m)
    y = rng.normal(200.0, 1.0, m)
    h = rng.normal(30.0, 0.5, m)
    for f, l_, dh in steps:
        fn, ln, dn = f + rng.normal(0, sig[0], m), l_ + rng.normal(0, sig[1], m), dh + rng.normal(0, sig[2], m)
        r = np.radians(h)
        x, y, h = x + fn * np.sin(r) - ln * np.cos(r), y + fn * np.cos(r) + ln * np.sin(r), h + dn
    mc = np.cov(np.stack([x, y, h]))
    assert filt.state[:2] == pytest.approx([x.mean(), y.mean()], abs=0.5)
    assert np.allclose(filt.cov, mc, rtol=0.1, atol=0.05 * np.sqrt(np.outer(np.diag(mc), np.diag(mc))).max())


def test_an_update_near_360_wraps_and_shrinks_the_variance():
    filt = PoseFilter(0.0, 0.0, 359.5, np.diag([1.0, 1.0, 4.0]))
    u = filt.update_heading(0.5, 2.0)  # 1 deg of innovation, not 359
    assert u.accepted and u.innovation[0] == pytest.approx(1.0)
    assert filt.state[2] == pytest.approx(0.0, abs=1e-9)
    assert filt.cov[2, 2] == pytest.approx(2.0)  # 1 / (1/4 + 1/4)


def test_headings_stay_in_0_360_and_a_crs_without_true_north_says_so():
    """A heading a hair below 0 is 0, not 360.0 (-1e-15 % 360 rounds to 360.0), in the state and
    in a stop's record; a local CRS has no true north: the record's convergence is NaN (as in
    locate's and heading's outputs) and the heading from true north is the grid one, not one
    shifted by an invented 0."""
    from skyfix.traverse.run import _record, convergence_function

    filt = PoseFilter(0.0, 0.0, 0.0, np.eye(3))
    filt.predict(Odometry(1.0, 0.0, -1e-15, np.eye(3) * 1e-4))
    assert 0.0 <= filt.state[2] < 360.0
    local = ('ENGCRS["site",EDATUM["site datum"],CS[Cartesian,2],'
             'AXIS["easting",east,LENGTHUNIT["metre",1]],'
             'AXIS["northing",north,LENGTHUNIT["metre",1]]]')
    conv = convergence_function(local)
    assert math.isnan(conv(0.0, 0.0))
    rec = _record(0, "s0", filt, conv)
    assert math.isnan(rec["meridian_convergence_deg"])
    assert rec["heading_deg"] == rec["grid_heading_deg"] and 0.0 <= rec["heading_deg"] < 360.0
    utm = convergence_function("EPSG:32611")  # west of zone 11's central meridian: negative
    assert utm(300000.0, 4146000.0) < 0.0


def test_a_confident_outlier_is_gated_out():
    filt = PoseFilter(0.0, 0.0, 90.0, np.diag([4.0, 4.0, 1.0]))
    u = filt.update_heading(100.0, 0.2)  # 10 deg off a 1-deg track: chi-square ~ 96
    assert not u.accepted and u.nis > 50
    assert filt.state[2] == 90.0 and filt.cov[2, 2] == 1.0
    u = filt.update_pose(30.0, 0.0, 90.0, 0.5, 0.2)  # 30 m off a 2 m track
    assert not u.accepted and filt.state[0] == 0.0


# --- the loop on scripted measurements -----------------------------------------------------------

def _straight(n, step=50.0, start=True):
    names = [f"s{k:03d}" for k in range(n)]
    odo = [Odometry.from_sigmas(step, 0.0, 0.0, 0.02 * step, 0.01 * step, 0.25) for _ in names[1:]]
    st = Start(0.0, 0.0, 0.0, 1.0, 0.5) if start else None
    truth = [{"x": 0.0, "y": step * k, "heading_deg": 0.0} for k in range(n)]
    return Traverse(root=None, stops=names, folders=[None] * n, odometry=odo, start=st,
                    truth=truth, leg_length_m=500.0)


def _scripted(bad=(), outlier=(), fail=()):
    """Measurements of the truth (heading 0, x 0, y 50 k) with 0.1 deg / 0.5 m sigmas; stops in
    ``bad`` low confidence, in ``outlier`` 15 deg / 60 m off at confidence 0.99, in ``fail`` no
    skyline."""
    calls = []

    def heading(k, x, y, prior, window, position_sigma_m=None):
        calls.append(("h", k, window))
        if k in fail:
            raise SkyfixError("no skyline detected in any image")
        if k in bad:
            return Measurement(40.0, 3.0, 0.05)
        return Measurement(15.0 if k in outlier else 0.0, 0.1, 0.99, skyline_distance_m=3000.0)

    def fix(k, x, y, r):
        calls.append(("p", k, r))
        if k in fail:
            raise SkyfixError("no skyline detected in any image")
        if k in bad:
            return Measurement(40.0, 3.0, 0.05, 300.0, 50 * k, 40.0)
        dx = 60.0 if k in outlier else 0.0
        return Measurement(0.0, 0.1, 0.99, dx, 50.0 * k, 0.5)

    return Measure(heading, fix), calls


def test_headings_at_every_stop_and_a_fix_at_each_legs_end(tmp_path):
    trav = _straight(23)
    m, calls = _scripted()
    rows = run_traverse(trav, m, tmp_path)
    kinds = [r["update"] for r in rows]
    assert kinds[0] == "heading"
    assert [k for k, u in enumerate(kinds) if u == "position"] == [10, 20, 22]  # every 500 m, the end
    assert all(u in ("heading", "position") for u in kinds)
    assert all(r["operator_request"] is None for r in rows)
    assert max(abs(r["x"]) for r in rows) < 3.0 and rows[-1]["heading_sigma_deg"] < 0.2
    assert rows[20]["position_sigma_m"] < 0.6  # right after a fix


def test_an_outlier_is_rejected_and_the_track_holds(tmp_path):
    m, _ = _scripted(outlier={5, 10})  # a heading stop and a leg end
    rows = run_traverse(_straight(13), m, tmp_path)
    assert rows[5]["update"] == "rejected" and "gate" in rows[5]["reason"]
    assert rows[10]["update"] == "rejected" and rows[11]["update"] == "position"  # fix owed, then taken
    assert all(abs(r["heading_deg"]) < 1.0 or abs(r["heading_deg"] - 360) < 1.0 for r in rows)
    assert all(r["operator_request"] is None for r in rows)


def test_operator_requests_where_detection_fails_and_after_n_misses(tmp_path):
    m, calls = _scripted(bad={3, 4, 5}, fail={8})
    rows = run_traverse(_straight(12), m, tmp_path, config=TraverseConfig(max_rejections=3))
    req = [k for k, r in enumerate(rows) if r["operator_request"] is not None]
    assert req == [5, 8]
    assert "3 stops in a row" in rows[5]["operator_request"]["reason"]
    assert "no usable skyline" in rows[8]["operator_request"]["reason"]
    assert [r["update"] for r in rows[3:6]] == ["rejected"] * 3 and rows[8]["update"] == "none"
    # a low-confidence heading is tried again with the window doubled
    assert ("h", 3, 10.0) in calls and ("h", 3, 20.0) in calls
    assert rows[6]["update"] == "heading"


def test_an_interrupted_traverse_resumes_at_the_first_stop_not_written(tmp_path):
    m, _ = _scripted(outlier={4})
    full = run_traverse(_straight(15), m, tmp_path / "a")

    class Stop(Exception):
        pass

    def interrupt(k, d):
        if k == 6:
            raise Stop

    with pytest.raises(Stop):
        run_traverse(_straight(15), m, tmp_path / "b", on_stop=interrupt)
    lines = (tmp_path / "b" / "stops.jsonl").read_text().splitlines()
    assert len(lines) == 7
    m2, calls = _scripted(outlier={4})
    resumed = run_traverse(_straight(15), m2, tmp_path / "b")
    assert min(c[1] for c in calls) == 7  # nothing measured again
    def timeless(rows):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]

    written = [json.loads(line) for line in (tmp_path / "b" / "stops.jsonl").read_text().splitlines()]
    assert timeless(written) == timeless(full) == timeless(resumed)


def test_no_start_takes_a_global_fix_first(tmp_path):
    m, calls = _scripted()
    rows = run_traverse(_straight(4, start=False), m, tmp_path)
    assert calls[0] == ("p", 0, None) and rows[0]["update"] == "position"
    assert rows[0]["position_sigma_m"] == pytest.approx(0.5)


# --- the traverse folder --------------------------------------------------------------------------

def _folder(tmp_path, odo_lines, n=3):
    for k in range(n):
        (tmp_path / f"stop_{k:03d}").mkdir()
        (tmp_path / f"stop_{k:03d}" / "acquisition.json").write_text("{}")
    (tmp_path / "odometry.jsonl").write_text("\n".join(odo_lines) + "\n")
    return tmp_path


GOOD = json.dumps({"forward_m": 50, "left_m": 0, "dheading_deg": 1.0, "sigma_forward_m": 1,
                   "sigma_left_m": 0.5, "sigma_heading_deg": 0.25})


def test_a_traverse_folder_is_read_in_order(tmp_path):
    cov = json.dumps({"from": "stop_001", "to": "stop_002", "forward_m": 40, "left_m": 1,
                      "dheading_deg": -2, "cov": [[1, 0, 0], [0, 0.25, 0], [0, 0, 0.0625]]})
    trav = read_traverse(_folder(tmp_path, [GOOD, cov]))
    assert trav.stops == ["stop_000", "stop_001", "stop_002"] and trav.start is None
    assert trav.odometry[1].forward_m == 40 and trav.odometry[1].cov[2, 2] == 0.0625


@pytest.mark.parametrize("bad, says", [
    ('{"forward_m": 50, "left_m": 0}', "line 2: 'dheading_deg' is missing"),
    ('{"forward_m": "x", "left_m": 0, "dheading_deg": 0}', "line 2: 'forward_m' must be a finite number"),
    ('not json', "line 2: not JSON"),
    (GOOD.replace('"sigma_left_m": 0.5', '"sigma_left_m": 0'), "line 2: 'sigma_left_m' must be > 0"),
    ('{"forward_m": 1, "left_m": 0, "dheading_deg": 0, "cov": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}',
     "line 2: 'cov' must be symmetric positive definite"),
    # one of the two was silently ignored
    (GOOD.replace('"sigma_left_m"', '"cov": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "sigma_left_m"'),
     "line 2: give 'cov' or the sigmas (sigma_forward_m, sigma_left_m, sigma_heading_deg), not both"),
])
def test_a_malformed_odometry_file_names_the_line(tmp_path, bad, says):
    with pytest.raises(ParameterError, match=re.escape(says)):
        read_traverse(_folder(tmp_path, [GOOD, bad]))


def test_odometry_steps_must_match_the_stops(tmp_path):
    with pytest.raises(ParameterError, match="1 odometry steps for 3 stops"):
        read_traverse(_folder(tmp_path, [GOOD]))
    wrong = json.dumps({**json.loads(GOOD), "from": "stop_002", "to": "stop_001"})
    (tmp_path / "x").mkdir()
    with pytest.raises(ParameterError, match="line 1: step 0 goes from 'stop_000' to 'stop_001'"):
        read_traverse(_folder(tmp_path / "x", [wrong, GOOD]))


def test_a_middling_fix_is_taken_only_where_the_track_corroborates_it(tmp_path):
    """A leg-end fix at confidence 0.4 (below 0.5, above the 0.25 floor): taken, with its sigma,
    when it lies where the odometry predicts (inside the 95 % chi-square region); rejected when
    it lies 7.5 m off, although the 99.9 % gate alone would have let that through; one at 0.1 is
    never taken. A stop whose fix is not taken still gives its heading."""
    def measure_with(dx, conf):
        def heading(k, x, y, prior, window, position_sigma_m=None):
            return Measurement(0.0, 0.1, 0.99, skyline_distance_m=3000.0)

        def fix(k, x, y, r):
            return Measurement(0.0, 0.1, conf if k == 10 else 0.99, dx if k == 10 else 0.0,
                               50.0 * k, 1.0)

        return Measure(heading, fix)

    trav = _straight(12)
    rows = run_traverse(trav, measure_with(0.0, 0.4), tmp_path / "a")
    assert rows[10]["update"] == "position" and "corroborated" in rows[10]["reason"]
    assert rows[10]["position_sigma_m"] < rows[9]["position_sigma_m"]
    # 7.5 m off: a chi-square of ~12 with 3 dof given the prediction's ~2 m sigma and the fix's
    # 1 m (inside 16.3, the 99.9 % gate; outside 7.8, the 95 % region)
    rows = run_traverse(trav, measure_with(7.5, 0.4), tmp_path / "b")
    why = rows[10]["reason"]
    assert why.startswith("position fix rejected") and "not corroborated" in why
    chi2 = float(why.split("chi-square ")[1].split(" ")[0])
    assert 7.81 < chi2 < 16.27 and "with 3 dof" in why
    # the stop still gives its heading, and the fix stays owed to the next stop
    assert rows[10]["update"] == "heading" and rows[10]["fix_owed"]
    assert rows[11]["attempted"] == "position" and rows[11]["update"] == "position"
    rows = run_traverse(trav, measure_with(0.0, 0.1), tmp_path / "c")
    assert rows[10]["reason"].startswith("position fix rejected (confidence 0.10 < 0.5)")
    assert rows[11]["update"] == "position"


def test_the_operator_is_asked_when_the_owed_fix_keeps_failing_though_headings_are_taken(tmp_path):
    def heading(k, x, y, prior, window, position_sigma_m=None):
        return Measurement(0.0, 0.1, 0.99, skyline_distance_m=3000.0)

    def fix(k, x, y, r):
        return Measurement(0.0, 0.1, 0.1 if k >= 10 else 0.99, 0.0, 50.0 * k, 1.0)

    rows = run_traverse(_straight(16), Measure(heading, fix), tmp_path)
    assert [r["update"] for r in rows[10:16]] == ["heading"] * 6  # every stop keeps its heading
    assert all(r["attempted"] == "position" for r in rows[10:16])
    asked = [k for k, r in enumerate(rows) if r["operator_request"]]
    assert asked == [12, 15]  # every third fix not taken
    assert "3 position fixes in a row not taken" in rows[12]["operator_request"]["reason"]


def test_an_output_resumes_only_the_run_that_made_it(tmp_path):
    """run.json, written before the first stop, holds what made the output; a rerun with another
    traverse, other settings or other inputs is refused naming them, the output untouched;
    overwrite starts afresh; a folder that is no traverse output is never written to."""
    from skyfix.errors import OutputExistsError

    class Stop(Exception):
        pass

    def interrupt(k, d):
        raise Stop

    m, _ = _scripted(bad={2})
    out = tmp_path / "o"
    with pytest.raises(Stop):
        run_traverse(_straight(6), m, out, inputs={"dem_sha256": "a" * 64}, on_stop=interrupt)
    rec = json.loads((out / "run.json").read_text())
    assert rec["params"]["dem_sha256"] == "a" * 64 and rec["params"]["stops"][0] == "s000"
    before = (out / "stops.jsonl").read_bytes()
    step40 = _straight(6, step=40.0)
    for kw, says in [(dict(trav=step40), "the odometry (sha256)"),
                     (dict(trav=_straight(7)), "the traverse's stops"),
                     (dict(config=TraverseConfig(min_confidence=0.9)),
                      "--min-confidence: 0.5 there, 0.9 now"),
                     (dict(inputs={"dem_sha256": "b" * 64}),
                      "the DEM (--dem, sha256): aaaaaaaaaaaa there, bbbbbbbbbbbb now"),
                     (dict(inputs={}), "the DEM")]:
        args = {"trav": _straight(6), "config": TraverseConfig(), "inputs": {"dem_sha256": "a" * 64},
                **kw}
        with pytest.raises(OutputExistsError, match="made with other inputs or options") as e:
            run_traverse(args["trav"], m, out, config=args["config"], inputs=args["inputs"])
        assert says in str(e.value)
        assert (out / "stops.jsonl").read_bytes() == before
    rows = run_traverse(_straight(6), m, out, inputs={"dem_sha256": "a" * 64})  # the same: resumed
    assert len(rows) == 6 and (out / "stops.jsonl").read_bytes().startswith(before)
    rows = run_traverse(step40, m, out, inputs={"dem_sha256": "b" * 64}, overwrite=True)
    assert rows[1]["y"] == pytest.approx(40.0, abs=1.0)  # a heading after one step of 40 m, not 50
    assert json.loads((out / "run.json").read_text())["params"]["dem_sha256"] == "b" * 64
    other = tmp_path / "acq"
    other.mkdir()
    (other / "acquisition.json").write_text("{}")
    with pytest.raises(OutputExistsError, match="is not a traverse output"):
        run_traverse(_straight(3), m, other, overwrite=True)
    assert sorted(p.name for p in other.iterdir()) == ["acquisition.json"]


def test_check_stops_names_a_broken_stop_and_check_start_a_start_off_the_dem(tmp_path):
    """Checked before the first stop: each image there and decoding whole (a truncated JPEG at
    the last stop was met only when the run reached it); what the images show is left to the
    run (a featureless image passes here)."""
    import cv2

    from skyfix.errors import AcquisitionError, OutsideDemError
    from skyfix.traverse.inputs import check_start, check_stops
    from conftest import plane_dem

    root = _folder(tmp_path, [GOOD, GOOD])
    noise = np.random.default_rng(0).integers(0, 256, (64, 256, 3), dtype=np.uint8)
    for k in range(3):
        (root / f"stop_{k:03d}" / "acquisition.json").write_text(json.dumps(
            {"panorama": {"image": "pano.jpg"}, "camera_height_m": 1.5}))
        cv2.imwrite(str(root / f"stop_{k:03d}" / "pano.jpg"), noise if k else noise * 0 + 128)
    trav = read_traverse(root)
    assert len(check_stops(trav)) == 3
    last = root / "stop_002" / "pano.jpg"
    whole = last.read_bytes()
    last.write_bytes(whole[:len(whole) // 2])
    with pytest.raises(AcquisitionError, match=r"stop 'stop_002' .*pano.jpg is damaged or truncated "
                                               r"\(the JPEG decoder: Premature end of JPEG file\)"):
        check_stops(trav)
    last.write_bytes(b"")
    with pytest.raises(AcquisitionError, match=r"stop 'stop_002' .*cannot read image .*pano.jpg: not "
                                               "an image OpenCV can decode"):
        check_stops(trav)
    last.write_bytes(whole)
    (root / "stop_001" / "pano.jpg").unlink()
    with pytest.raises(AcquisitionError, match="stop 'stop_001' .*image pano.jpg named in"):
        check_stops(trav)
    dem = plane_dem(1000.0, 20.0)
    check_start(trav, dem)  # no start: nothing to check
    trav.start = Start(500.0, 500.0, 0.0, 1.0, 1.0)
    check_start(trav, dem)
    trav.start = Start(5000.0, 500.0, 0.0, 1.0, 1.0)
    with pytest.raises(OutsideDemError, match="the traverse's start .* is outside the DEM.*check 'start'"):
        check_start(trav, dem)


def test_position_sigmas_in_and_out_are_radial_as_a_fixs():
    """A fix's position_sigma_m is radial (the root of its covariance's trace): fed to the
    filter it is half its square an axis, and the filter's own is radial again. It was read as
    each axis's, so a fix weighed half what it should, and the track's sigma was its worst
    axis's, which holds 39 % of 2-D errors where 63 % are claimed."""
    from skyfix.traverse.ekf import PoseFilter

    f = PoseFilter(0.0, 0.0, 0.0, np.diag([1e8, 1e8, 1e4]))
    f.update_pose(3.0, 4.0, 10.0, 2.0, 1.0, gate=False)
    assert f.position_sigma_m == pytest.approx(2.0, rel=1e-6)
    assert f.position_axis_sigma_m == pytest.approx(2.0 / math.sqrt(2.0), rel=1e-6)
    # two independent fixes of radial sigma 2 m: 2 / sqrt(2) radial
    f.update_pose(3.0, 4.0, 10.0, 2.0, 1.0, gate=False)
    assert f.position_sigma_m == pytest.approx(math.sqrt(2.0), rel=1e-6)
    # a circular normal of radial sigma s holds 1 - exp(-1) = 63 % of errors within s
    rng = np.random.default_rng(1)
    err = rng.multivariate_normal([0, 0], f.cov[:2, :2], 200_000)
    assert np.mean(np.hypot(*err.T) <= f.position_sigma_m) == pytest.approx(1 - math.exp(-1), abs=0.005)


def test_a_dem_search_as_wide_as_the_traverse_asks_is_not_refused():
    """The traverse searches a leg-end fix on the DEM over up to 150 m (3 sigma); at the 2 m
    first step that is 22,801 points, refused ('give a smaller --prior-radius-m', an option
    traverse lacks). The step coarsens to keep within the limit; 100 m keeps 2 m."""
    from conftest import shared_dem_path
    from skyfix.dem import load_dem
    from skyfix.pose import PoseConfig
    from skyfix.pose.config import MAX_PRIOR_GRID_POINTS
    from skyfix.pose.refine import prior_grid
    from skyfix.traverse.measure import dem_search_config

    dem = load_dem(shared_dem_path("south_glacier_20m"))
    x0, y0, x1, y1 = dem.bounds
    c = ((x0 + x1) / 2, (y0 + y1) / 2)
    cfg = PoseConfig()
    with pytest.raises(ParameterError, match="give a smaller"):
        prior_grid(dem, c, 150.0, cfg.grid_step_m)
    for r in (100.0, 150.0, TraverseConfig().max_fix_radius_m):
        step = dem_search_config(cfg, r).grid_step_m
        assert step == (cfg.grid_step_m if r <= 100.0 else pytest.approx(r / 50.0))
        assert prior_grid(dem, c, r, step)[0].size <= MAX_PRIOR_GRID_POINTS


def test_a_position_fix_that_fails_outright_still_leaves_the_stop_its_heading(tmp_path):
    """A skyline of 12 bins is too narrow for locate's search (20 at least) but gives a heading:
    the stop keeps its heading, the fix stays owed, and nobody is asked for a skyline the stop
    has (it was marked 'none' with a 'no usable skyline' request)."""
    from skyfix.errors import ParameterError

    def heading(k, x, y, prior, window, position_sigma_m=None):
        return Measurement(0.0, 0.1, 0.99, skyline_distance_m=3000.0)

    def fix(k, x, y, r):
        if k >= 2:
            raise ParameterError("the profile has 12 observed azimuth bins; at least 20 are needed")
        return Measurement(0.0, 0.1, 0.99, 0.0, 50.0 * k, 1.0)

    rows = run_traverse(_straight(4), Measure(heading, fix), tmp_path)
    last = rows[-1]  # the last stop is due a fix
    assert last["attempted"] == "position" and last["update"] == "heading"
    assert last["reason"].startswith("position fix failed (the profile has 12 observed")
    assert last["operator_request"] is None and last["fix_owed"]
