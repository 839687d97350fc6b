"""``skyfix simulate-traverse`` then ``skyfix traverse`` end to end on a short traverse of small
panoramas: the outputs the conventions promise, headings against the truth, resume, refusals."""

import json
import math

import pytest
from click.testing import CliRunner

from conftest import shared_dem_path
from skyfix.cli.main import cli


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    dem = shared_dem_path("south_glacier_20m")
    trav = tmp_path_factory.mktemp("trav") / "t"
    r = run("simulate-traverse", dem, "-o", trav, "--length-m", 150, "--stop-spacing-m", 50,
            "--mode", "panorama", "--pano-size", 1440, 360, "--leg-length-m", 90, "--seed", 3)
    assert r.exit_code == 0, r.output
    return dem, trav


def test_a_simulated_traverse_is_fused_within_the_truth(simulated, tmp_path):
    dem, trav = simulated
    out = tmp_path / "out"
    r = run("traverse", trav, "--dem", dem, "-o", out, "--detector", "dp")
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
