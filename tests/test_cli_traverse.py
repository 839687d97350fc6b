"""``skyfix simulate-traverse`` then ``skyfix traverse`` end to end on a short traverse of small
panoramas: the outputs the conventions promise, headings against the truth, resume, refusals."""

import json
import math

import pytest

from conftest import cli_run as run, shared_dem_path


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    dem = shared_dem_path("south_glacier_20m")
    trav = tmp_path_factory.mktemp("trav") / "t"
    r = run("simulate-traverse", dem, "-o", trav, "--length-m", 150, "--stop-spacing-m", 50,
            "--mode", "panorama", "--pano-size", 1440, 360, "--leg-length-m", 90, "--seed", 3)
    assert r.exit_code == 0, r.output
    return dem, trav


def test_the_simulated_heading_drift_is_per_100_m_whatever_the_spacing(simulated):
    """--heading-drift-deg-per-100m (0.5 by default) is a random walk: at 50 m stops each step's
    sigma is 0.5 sqrt(0.5) = 0.354 deg, so that two steps make 0.5 deg over 100 m (it was
    0.5 * 50 / 100 = 0.25 a step: 0.35 deg over 100 m)."""
    _, trav = simulated
    steps = [json.loads(line) for line in (trav / "odometry.jsonl").read_text().splitlines()]
    assert steps and all(s["sigma_heading_deg"] == pytest.approx(0.5 * math.sqrt(0.5))
                         for s in steps)
    assert math.sqrt(sum(s["sigma_heading_deg"] ** 2 for s in steps[:2])) == pytest.approx(0.5)


@pytest.fixture(scope="module")
def fused(simulated, tmp_path_factory):
    """The simulated traverse fused once (the tests that rerun into it copy it first)."""
    dem, trav = simulated
    out = tmp_path_factory.mktemp("fused") / "out"
    r = run("traverse", trav, "--dem", dem, "-o", out, "--detector", "dp")
    return out, r


def test_a_simulated_traverse_is_fused_within_the_truth(simulated, fused):
    dem, trav = simulated
    out, r = fused
    assert r.exit_code == 0, r.output
    assert "stop 4/4" in r.output
    rows = [json.loads(line) for line in (out / "stops.jsonl").read_text().splitlines()]
    truth = [json.loads(line) for line in (trav / "truth.jsonl").read_text().splitlines()]
    assert [r_["stop"] for r_ in rows] == [t["stop"] for t in truth]
    for r_ in rows:
        assert {"stop", "x", "y", "heading_deg", "position_sigma_m", "heading_sigma_deg", "update",
                "confidence", "operator_request"} <= set(r_)
    assert [r_["update"] for r_ in rows] == ["heading", "heading", "position", "position"]  # leg, end
    for r_, t in zip(rows, truth):  # measured: heading errors <= 0.07 deg, positions <= 3 m
        assert abs((r_["heading_deg"] - t["heading_deg"] + 180) % 360 - 180) < 0.5
        assert math.hypot(r_["x"] - t["x"], r_["y"] - t["y"]) < 3 * max(r_["position_sigma_m"], 1.0)
    assert math.hypot(rows[2]["x"] - truth[2]["x"], rows[2]["y"] - truth[2]["y"]) < 2.0
    gj = json.loads((out / "track.geojson").read_text())
    kinds = [f["geometry"]["type"] for f in gj["features"]]
    assert kinds == ["LineString"] + ["Point"] * 4
    # each point carries its stop's record (every heading with its grid heading and convergence)
    for f, r_ in zip(gj["features"][1:], rows):
        assert f["properties"] == {k: v for k, v in r_.items() if k != "filter"}
        assert {"grid_heading_deg", "meridian_convergence_deg", "reason"} <= set(f["properties"])
    assert (out / "track.png").stat().st_size > 10_000
    # rerun: everything is written, nothing is measured again, the file is unchanged
    before = (out / "stops.jsonl").read_text()
    r = run("traverse", trav, "--dem", dem, "-o", out, "--no-plot")
    assert r.exit_code == 0, r.output
    assert "stop " not in r.output.replace("stops:", "") and (out / "stops.jsonl").read_text() == before


def test_a_malformed_traverse_is_refused_before_any_stop(simulated, tmp_path):
    dem, trav = simulated
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(trav, bad)
    lines = (bad / "odometry.jsonl").read_text().splitlines()
    lines[1] = lines[1].replace('"forward_m"', '"forwards_m"')
    (bad / "odometry.jsonl").write_text("\n".join(lines) + "\n")
    r = run("traverse", bad, "--dem", dem, "-o", tmp_path / "o")
    assert r.exit_code == 2
    assert "odometry.jsonl line 2: 'forward_m' is missing" in r.output
    assert not (tmp_path / "o" / "stops.jsonl").exists()
    r = run("simulate-traverse", dem, "-o", tmp_path / "s", "--stop-conditions", "x=clouds")
    assert r.exit_code == 2 and "STOP=CONDITIONS" in r.output
    r = run("traverse", trav, "--dem", dem, "-o", tmp_path / "o2", "--dem-sigma-m", -1)
    assert r.exit_code == 2 and "--dem-sigma-m" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o2" / "stops.jsonl").exists()


def test_evaluate_traverse_reports_fused_against_odometry(tmp_path):
    dem = shared_dem_path("south_glacier_20m")
    out = tmp_path / "ev"
    r = run("evaluate", "--dem", dem, "--scenario", "traverse", "--length-m", 100,
            "--stop-spacing-m", 50, "--seed", 5, "--stop-conditions", "1=overexposed:1", "-o", out)
    assert r.exit_code == 0, r.output
    page = (out / "report.html").read_text()
    assert "Every stop" in page and "odometry alone error [m]" in page
    assert (out / "errors.png").stat().st_size > 10_000 and (out / "track.png").is_file()
    rows = [json.loads(line) for line in (out / "result" / "stops.jsonl").read_text().splitlines()]
    truth = [json.loads(line) for line in (out / "traverse" / "truth.jsonl").read_text().splitlines()]
    # whatever the overexposed stop gave, nothing wrong was taken; the last stop ends the leg
    for r_, t in zip(rows, truth):
        if r_["update"] in ("heading", "position"):
            assert abs((r_["heading_deg"] - t["heading_deg"] + 180) % 360 - 180) < 1.0
    assert rows[2]["update"] == "position"


def test_evaluate_traverse_renders_its_stops_from_a_world_that_is_not_the_map(tmp_path):
    """`evaluate --scenario traverse --map-errors` ran with the map as the world, recording
    "map_errors": null; now the stops are rendered from the world and scored from where the
    truth's terrain lies on the map."""
    dem = shared_dem_path("south_glacier_20m")
    out = tmp_path / "ev"
    r = run("evaluate", "--dem", dem, "--scenario", "traverse", "--length-m", 50,
            "--stop-spacing-m", 50, "--seed", 5, "--map-errors", "-o", out)
    assert r.exit_code == 0, r.output
    sim = json.loads((out / "traverse" / "simulation.json").read_text())["params"]
    assert sim["map_errors"]["shift_m"] == pytest.approx(3.0)
    acq = json.loads((out / "traverse" / "stop_000" / "acquisition.json").read_text())
    assert acq["simulation"]["dem"]["source"].startswith("world of")
    assert "a world that is not the map (--map-errors" in (out / "report.html").read_text()
    # a world 2 m rms off the map in height still gives right headings wherever one is taken
    rows = [json.loads(line) for line in (out / "result" / "stops.jsonl").read_text().splitlines()]
    truth = [json.loads(line) for line in (out / "traverse" / "truth.jsonl").read_text().splitlines()]
    assert len(rows) == len(truth) == 2
    taken = [(r_, t) for r_, t in zip(rows, truth) if r_["update"] in ("heading", "position")]
    assert taken
    for r_, t in taken:
        assert abs((r_["heading_deg"] - t["heading_deg"] + 180) % 360 - 180) < 1.0
    # a rerun without it is another simulation, refused by name (not resumed as the same)
    r = run("evaluate", "--dem", dem, "--scenario", "traverse", "--length-m", 50,
            "--stop-spacing-m", 50, "--seed", 5, "-o", out)
    assert r.exit_code == 2 and "--map-errors" in r.output and "Traceback" not in r.output


def test_a_traverse_rendered_from_a_world_that_is_not_the_map(tmp_path):
    """--map-errors: the stops are rendered from a world DEM (refined, height error, a 3 m
    misregistration); positions are scored from where the truth's terrain lies on the map."""
    from skyfix.traverse import read_traverse
    from skyfix.traverse.evaluation import traverse_errors

    dem = shared_dem_path("south_glacier_20m")
    trav = tmp_path / "t"
    r = run("simulate-traverse", dem, "-o", trav, "--length-m", 50, "--stop-spacing-m", 50,
            "--mode", "panorama", "--pano-size", 720, 180, "--seed", 4, "--map-errors")
    assert r.exit_code == 0, r.output
    meta = json.loads((trav / "traverse.json").read_text())
    dx, dy = meta["simulation"]["map_errors"]["map_offset_m"]
    assert math.hypot(dx, dy) == pytest.approx(3.0)
    acq = json.loads((trav / "stop_000" / "acquisition.json").read_text())
    assert acq["simulation"]["dem"]["source"].startswith("world of")
    t = read_traverse(trav)
    # a track exactly where the truth's terrain lies on the map has no error; the truth itself is
    # off by the misregistration
    on_map = [{"x": s["x"] + dx, "y": s["y"] + dy, "heading_deg": s["heading_deg"]} for s in t.truth]
    _, pe, he, _, _ = traverse_errors(on_map, t, lambda x, y: 0.0)
    assert pe.max() < 1e-9 and he.max() < 1e-9
    _, pe, _, _, _ = traverse_errors(t.truth, t, lambda x, y: 0.0)
    assert pe == pytest.approx([3.0, 3.0])
    r = run("simulate-traverse", dem, "-o", tmp_path / "u", "--map-errors", "--world-dem", dem)
    assert r.exit_code == 2 and "not both" in r.output


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_a_rerun_with_other_inputs_or_options_is_refused_and_keeps_the_output(simulated, fused, tmp_path):
    """A rerun resumes only the run that made -o (run.json): another DEM, other options or
    another traverse are refused before any stop, naming what differs, and the output stays as
    it was (it used to be reported as this run's result, exit 0)."""
    import numpy as np
    import rasterio

    dem, trav = simulated
    out = _copy(fused[0], tmp_path / "out")
    before = _files(out)
    other_dem = tmp_path / "other.tif"  # the same place, heights 0.5 m higher
    with rasterio.open(dem) as src:
        prof, z = src.profile, src.read(1)
    with rasterio.open(other_dem, "w", **prof) as dst:
        dst.write((z + np.asarray(0.5, z.dtype)).astype(z.dtype), 1)
    other_trav = _copy(trav, tmp_path / "t2")
    meta = json.loads((other_trav / "traverse.json").read_text())
    meta["start"]["x"] += 5.0
    (other_trav / "traverse.json").write_text(json.dumps(meta))
    for args, says in [
            ((trav, "--dem", other_dem), "the DEM (--dem, sha256)"),
            ((trav, "--dem", dem, "--min-confidence", 0.9), "--min-confidence: 0.5 there, 0.9 now"),
            ((trav, "--dem", dem, "--dem-sigma-m", 0), "--dem-sigma-m: 2.0 there, 0.0 now"),
            ((trav, "--dem", dem, "--leg-length-m", 200), "leg length"),
            ((trav, "--dem", dem, "--detector", "fuse"), "--detector: 'dp' there, 'fuse' now"),
            ((other_trav, "--dem", dem), "the start (traverse.json)")]:
        r = run("traverse", *args, "-o", out, "--no-plot")
        assert r.exit_code == 2, (args, r.output)
        assert "made with other inputs or options" in r.output and says in r.output, r.output
        assert "--overwrite" in r.output and "Traceback" not in r.output
        assert "stop 1/4" not in r.output
        assert _files(out) == before
    # the same inputs, options spelt otherwise (the default detector named), still resume
    r = run("traverse", trav, "--dem", dem, "-o", out, "--no-plot", "--detector", "dp")
    assert r.exit_code == 0, r.output
    assert "stop 1/4" not in r.output and (out / "stops.jsonl").read_bytes() == before["stops.jsonl"]


def test_traverse_writes_only_into_its_own_output_folder(simulated, fused, tmp_path):
    """A non-empty folder that is no traverse output is refused, --overwrite or not (it put
    stops.jsonl into an acquisition folder), and so is an output that does not say what made it
    (written before run.json), unless --overwrite."""
    dem, trav = simulated
    acq = _copy(trav / "stop_000", tmp_path / "acq")
    before = _files(acq)
    for extra in ((), ("--overwrite",)):
        r = run("traverse", trav, "--dem", dem, "-o", acq, "--no-plot", *extra)
        assert r.exit_code == 2 and "is not empty and is not a traverse output" in r.output, r.output
        assert _files(acq) == before
    r = run("traverse", trav, "--dem", dem, "-o", trav, "--no-plot")  # its own input folder
    assert r.exit_code == 2 and "is not a traverse output" in r.output
    old = _copy(fused[0], tmp_path / "old")
    (old / "run.json").unlink()
    r = run("traverse", trav, "--dem", dem, "-o", old, "--no-plot")
    assert r.exit_code == 2 and "does not record what made it" in r.output
    assert "--overwrite" in r.output and not (old / "run.json").exists()


def _truncated_jpeg(t):
    """The last stop's panorama as a JPEG cut in half: OpenCV decodes it, the rest grey."""
    import cv2

    stop = t / "stop_003"
    acq = json.loads((stop / "acquisition.json").read_text())
    acq["panorama"]["image"] = "pano.jpg"
    (stop / "acquisition.json").write_text(json.dumps(acq))
    cv2.imwrite(str(stop / "pano.jpg"), cv2.imread(str(stop / "pano.png")))
    data = (stop / "pano.jpg").read_bytes()
    (stop / "pano.jpg").write_bytes(data[:len(data) // 2])


@pytest.mark.parametrize("spoil, says", [
    (lambda t: (t / "stop_002" / "acquisition.json").write_text("{bad"),
     "stop 'stop_002' ({t}/stop_002): {t}/stop_002/acquisition.json is not valid JSON"),
    (lambda t: (t / "stop_001" / "pano.png").unlink(),
     "stop 'stop_001' ({t}/stop_001): image pano.png named in"),
    (_truncated_jpeg, "stop 'stop_003' ({t}/stop_003): image {t}/stop_003/pano.jpg is damaged or "
                      "truncated (the JPEG decoder: Premature end of JPEG file)"),
    (lambda t: (t / "traverse.json").write_text(json.dumps(
        {**json.loads((t / "traverse.json").read_text()),
         "start": {"x": 0, "y": 0, "heading_deg": 0, "position_sigma_m": 2, "heading_sigma_deg": 1}})),
     "the traverse's start (0, 0) is outside the DEM"),
])
def test_a_broken_stop_or_a_start_off_the_dem_is_refused_before_the_first_stop(simulated, tmp_path,
                                                                              spoil, says):
    """Once found only at the stop (update none, an operator request, exit 0)."""
    dem, trav = simulated
    t = _copy(trav, tmp_path / "t")
    spoil(t)
    r = run("traverse", t, "--dem", dem, "-o", tmp_path / "o", "--no-plot")
    assert r.exit_code == 2, r.output
    assert says.format(t=t) in r.output and "Traceback" not in r.output
    assert "stop 1/4" not in r.output and not (tmp_path / "o").exists()


def _sim(dem, out, *extra):
    return run("simulate-traverse", dem, "-o", out, "--length-m", 50, "--stop-spacing-m", 50,
               "--mode", "panorama", "--pano-size", 256, 64, *extra)


def test_simulate_traverse_resumes_only_with_the_same_options(tmp_path):
    """Rerun with another seed, it kept the old stops' images beside new odometry and truth (km
    apart); now refused, naming what differs; --overwrite starts afresh, stops and truth agreeing."""
    dem = shared_dem_path("south_glacier_20m")
    out = tmp_path / "s"
    r = _sim(dem, out, "--seed", 0)
    assert r.exit_code == 0, r.output
    before = _files(out)
    r = _sim(dem, out, "--seed", 7, "--heading-drift-deg-per-100m", 5)
    assert r.exit_code == 2, r.output
    assert "--seed: 0 there, 7 now" in r.output
    assert "--heading-drift-deg-per-100m: 0.5 there, 5.0 now" in r.output
    assert _files(out) == before
    r = _sim(dem, out, "--seed", 0)  # the same options: resumed, nothing rendered again
    assert r.exit_code == 0, r.output
    assert _files(out) == before
    r = _sim(dem, out, "--seed", 7, "--overwrite")
    assert r.exit_code == 0, r.output
    truth = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    assert truth != [json.loads(line) for line in before["truth.jsonl"].decode().splitlines()]
    for k, t in enumerate(truth):
        acq = json.loads((out / f"stop_{k:03d}" / "acquisition.json").read_text())
        assert math.hypot(acq["truth"]["x"] - t["x"], acq["truth"]["y"] - t["y"]) < 1e-6
    foreign = tmp_path / "f"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    r = _sim(dem, foreign, "--overwrite")
    assert r.exit_code == 2 and "is not a simulated traverse" in r.output
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]


@pytest.mark.parametrize("cond, says", [
    ("1=nonsense:1", "unknown condition 'nonsense': choose from dust"),
    ("1=dust:2", "dust strength must be in [0, 1], got 2.0"),
    ("5=dust", "stop conditions for stops [5]: the traverse has stops 0-2"),
])
def test_a_bad_stop_condition_is_refused_before_anything_is_simulated(tmp_path, cond, says):
    """Found only at that stop, after the stops before it were written."""
    dem = shared_dem_path("south_glacier_20m")
    r = run("simulate-traverse", dem, "-o", tmp_path / "s", "--length-m", 100, "--stop-spacing-m", 50,
            "--mode", "panorama", "--pano-size", 256, 64, "--stop-conditions", cond)
    assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "s").exists()
    r = run("evaluate", "--dem", dem, "--scenario", "traverse", "--length-m", 100,
            "--stop-spacing-m", 50, "--stop-conditions", cond, "-o", tmp_path / "ev")
    assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "ev").exists()


def test_a_stop_whose_images_show_no_skyline_is_still_met_at_run_time(simulated, tmp_path):
    """Not an input error: the stop loads, the run asks the operator and goes on (exit 0)."""
    import cv2
    import numpy as np

    dem, trav = simulated
    t = tmp_path / "t"
    _copy(trav / "stop_000", t / "stop_000")
    meta = json.loads((trav / "traverse.json").read_text())
    (t / "traverse.json").write_text(json.dumps({"stops": ["stop_000"], "start": meta["start"]}))
    img = cv2.imread(str(t / "stop_000" / "pano.png"))
    cv2.imwrite(str(t / "stop_000" / "pano.png"), np.full_like(img, 128))  # no edge anywhere
    r = run("traverse", t, "--dem", dem, "-o", tmp_path / "o", "--no-plot")
    assert r.exit_code == 0, r.output
    row = json.loads((tmp_path / "o" / "stops.jsonl").read_text())
    assert row["update"] == "none" and "no usable skyline" in row["operator_request"]["reason"]


def test_evaluate_traverse_writes_only_into_an_empty_folder_or_its_own_output(tmp_path):
    """It wrote report.html, traverse/ and result/ into any folder."""
    dem = shared_dem_path("south_glacier_20m")
    theirs = tmp_path / "notes"
    theirs.mkdir()
    (theirs / "mine.txt").write_text("keep")
    r = run("evaluate", "--dem", dem, "--scenario", "traverse", "--length-m", 100,
            "--stop-spacing-m", 50, "-o", theirs)
    assert r.exit_code == 2 and "not an earlier `evaluate --scenario traverse` output" in r.output
    assert sorted(p.name for p in theirs.iterdir()) == ["mine.txt"]


def test_a_database_that_does_not_reach_the_route_leaves_the_fixes_to_the_dem(simulated, fused,
                                                                              tmp_path):
    """A --db built elsewhere gave every fix 'no database position lies inside the prior area:
    check --prior-x/...' (options traverse does not have) and an operator request at each stop.
    A prior disc the database does not reach is searched on the DEM, as without --db."""
    from skyfix.dem import load_dem

    dem, trav = simulated
    s = json.loads((trav / "traverse.json").read_text())["start"]
    x0, y0, x1, y1 = load_dem(dem).bounds
    # a 100 m square in the DEM corner farthest from the start
    cx = x0 + 200 if s["x"] - x0 > x1 - s["x"] else x1 - 300
    cy = y0 + 200 if s["y"] - y0 > y1 - s["y"] else y1 - 300
    assert math.hypot(cx - s["x"], cy - s["y"]) > 1000
    db = tmp_path / "far.zarr"
    r = run("build-db", dem, "-o", db, "--bounds", cx, cy, cx + 100, cy + 100, "--spacing-m", 50,
            "--workers", 0, "--no-progress")
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    r = run("traverse", trav, "--dem", dem, "--db", db, "-o", out, "--detector", "dp", "--no-plot")
    assert r.exit_code == 0, r.output
    rows = [json.loads(line) for line in (out / "stops.jsonl").read_text().splitlines()]
    plain = [json.loads(line) for line in (fused[0] / "stops.jsonl").read_text().splitlines()]
    assert [r_["update"] for r_ in rows] == [r_["update"] for r_ in plain]
    assert all(r_["operator_request"] is None for r_ in rows)
    for a, b in zip(rows, plain):  # the same fixes as without the database
        assert math.hypot(a["x"] - b["x"], a["y"] - b["y"]) < 1e-6


def test_an_output_written_when_sigmas_meant_the_worst_axis_is_not_resumed(simulated, fused,
                                                                           tmp_path):
    """Its lines' position_sigma_m were the worst axis's; resumed, new lines would be radial
    beside them without a word."""
    import shutil

    dem, trav = simulated
    out = tmp_path / "old"
    shutil.copytree(fused[0], out)
    rec = json.loads((out / "run.json").read_text())
    del rec["params"]["position_sigma"]
    (out / "run.json").write_text(json.dumps(rec))
    r = run("traverse", trav, "--dem", dem, "-o", out, "--detector", "dp", "--no-plot")
    assert r.exit_code == 2 and "what position_sigma_m means" in r.output, r.output
