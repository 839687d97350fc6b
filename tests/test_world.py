"""The map is not the world: the world DEM differs from the map by the error model's statistics,
and the DEMERR set renders from it while recording where the truth lies on the map."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skyfix.dem import fractal_dem
from skyfix.errors import ParameterError
from skyfix.simulate import MapErrors, map_offset, simulate_set, world_dem


@pytest.fixture(scope="module")
def map_dem():
    return fractal_dem(200, 20.0, relief_m=800.0, seed=3)


def _matched(world, m, errors, seed, n=20000, rng=0):
    """World minus map heights [m] at random points, the map sampled where the world's terrain
    lies on it (the misregistration undone)."""
    r = np.random.default_rng(rng)
    xmin, ymin, xmax, ymax = m.bounds
    x = r.uniform(xmin + 100, xmax - 100, n)
    y = r.uniform(ymin + 100, ymax - 100, n)
    ox, oy = map_offset(errors, seed)
    return x, y, world.height_at(x, y) - m.height_at(x + ox, y + oy)


def test_world_differs_from_the_map_by_the_model(map_dem):
    e = MapErrors(spikes_per_km2=0.0)
    w = world_dem(map_dem, e, seed=4)
    assert w.dx == pytest.approx(10.0) and w.body == map_dem.body
    ox, oy = map_offset(e, 4)
    assert math.hypot(ox, oy) == pytest.approx(3.0)
    x, y, d = _matched(w, map_dem, e, 4)
    # 2 m correlated + 1 m detail + the map's own bilinear vs the world's cubic: about 2.3 m
    rms = float(np.sqrt(np.mean(d ** 2)))
    assert 2.0 < rms < 2.8 and abs(float(np.mean(d))) < 0.3
    # the misregistration is real: undoing it explains more than not undoing it
    plain = w.height_at(x, y) - map_dem.height_at(x, y)
    assert np.sqrt(np.mean(plain ** 2)) > rms + 0.2


def _component(map_dem, seed, **only):
    """The part of the world's difference from the map that one error term makes: the world with
    that term minus the world without it (same seed, everything else off) [fine grid, m]."""
    off = dict(detail_rms_m=0.0, height_rms_m=0.0, spikes_per_km2=0.0, shift_m=0.0)
    with_it = world_dem(map_dem, MapErrors(**{**off, **only}), seed=seed).z
    without = world_dem(map_dem, MapErrors(**off), seed=seed).z
    return (with_it - without).astype(np.float64)


def test_the_height_error_is_spatially_correlated_over_its_length(map_dem):
    """Gaussian-filtered white noise: autocorrelation exp(-lag^2 / (4 L^2)), 0.78 at L = 150 m."""
    e = _component(map_dem, 1, height_rms_m=2.0, correlation_m=150.0)
    assert float(e.std()) == pytest.approx(2.0, rel=0.01)
    lag = 15  # fine cells of 10 m: 150 m
    near = np.corrcoef(e[:, :-lag].ravel(), e[:, lag:].ravel())[0, 1]
    far = np.corrcoef(e[:, :-100].ravel(), e[:, 100:].ravel())[0, 1]  # 1 km
    assert 0.7 < near < 0.85 and abs(far) < 0.1


def test_spikes_and_pits_appear_at_their_rate(map_dem):
    e = _component(map_dem, 7, spikes_per_km2=5.0, spike_m=20.0)
    hit = np.abs(e) > 1.0
    area_km2 = e.size * 10.0 * 10.0 / 1e6
    expected = 5.0 * area_km2 * 4 / e.size  # spikes of 2 x 2 fine cells
    assert 0.5 * expected < hit.mean() < 1.5 * expected
    assert np.abs(e[hit]).min() >= 10.0 - 1e-3 and np.abs(e[hit]).max() <= 40.0 + 1e-3
    assert (e[hit] > 0).any() and (e[hit] < 0).any()  # spikes and pits


def test_map_errors_are_checked():
    with pytest.raises(ParameterError, match="shift_m"):
        MapErrors(shift_m=-1.0)
    with pytest.raises(ParameterError, match="refine"):
        MapErrors(refine=0)


def test_demerr_set_renders_the_world_and_records_the_offset(tmp_path, map_dem):
    out = tmp_path / "demerr"
    folders = simulate_set(map_dem, "DEMERR", 1, 5, out, camera="wide", frames=1)
    acq = json.loads((folders[0] / "acquisition.json").read_text())
    me = acq["simulation"]["map_errors"]
    assert me["shift_m"] == 3.0 and me["map_offset_m"] == pytest.approx(list(map_offset(MapErrors(), 5)))
    listing = json.loads((out / "set.json").read_text())
    assert listing["map_errors"]["map_offset_m"] == me["map_offset_m"]
    # the frame's truth skyline comes from the world, not the map
    from skyfix.formats import read_skyline_json
    from skyfix.simulate import simulate_acquisition

    ref = simulate_acquisition(map_dem, _truth(acq), tmp_path / "ref", camera="wide", frames=1,
                               seed=acq["simulation"]["seed"])
    a = np.asarray(read_skyline_json(folders[0] / "frame_000.skyline.json").rows, float)
    b = np.asarray(read_skyline_json(ref / "frame_000.skyline.json").rows, float)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 100 and np.abs(a - b)[both].mean() > 0.05


def _truth(acq):
    from skyfix.formats import Truth

    t = acq["truth"]
    return Truth(t["x"], t["y"], t["yaw_deg"], t["pitch_deg"], t["roll_deg"])


@pytest.fixture(scope="module")
def map_and_world_files(map_dem, tmp_path_factory):
    """The map as a file, and a world DEM of its north-west quarter only (the same CRS)."""
    from skyfix.dem import Dem, write_dem

    d = tmp_path_factory.mktemp("world")
    q = Dem(map_dem.z[:100, :100], map_dem.x0, map_dem.y0, map_dem.dx, map_dem.dy,
            map_dem.crs_wkt, map_dem.crs_name)
    return write_dem(d / "map.tif", map_dem), write_dem(d / "quarter.tif", q)


def test_a_world_dem_short_of_the_map_is_named_before_any_rendering(map_and_world_files, tmp_path):
    """It was refused as 'rover position ... outside the DEM' at the first case or stop off it
    (the ones before it rendered, a traverse's folder begun), naming neither the world DEM nor
    what it had to cover."""
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    def run(*args):
        return CliRunner().invoke(cli, [str(a) for a in args])

    m, quarter = map_and_world_files
    r = run("simulate-set", m, "--set", "REF", "--cases", 3, "--frames", 1, "--camera", "wide",
            "--world-dem", quarter, "-o", tmp_path / "set")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "the world DEM (quarter.tif) covers x 500000.0..501980.0" in r.output
    assert "not all of the area where cases are drawn on the map, x" in r.output
    assert "a smaller --area" in r.output and not (tmp_path / "set").exists()
    r = run("simulate-traverse", m, "-o", tmp_path / "trav", "--length-m", 3000,
            "--stop-spacing-m", 500, "--mode", "panorama", "--pano-size", 256, 64,
            "--world-dem", quarter)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "the world DEM (quarter.tif) covers" in r.output and "the traverse's stops" in r.output
    assert not (tmp_path / "trav").exists()
    # an area inside the quarter is rendered from it
    r = run("simulate-set", m, "--set", "REF", "--cases", 1, "--frames", 1, "--camera", "wide",
            "--area", 500500, 4198500, 501500, 4199500, "--world-dem", quarter, "-o", tmp_path / "in")
    assert r.exit_code == 0, r.output
    acq = json.loads((tmp_path / "in" / "case_000" / "acquisition.json").read_text())
    assert acq["simulation"]["world"]["source"].endswith("quarter.tif")


def test_a_world_dem_with_no_data_at_a_case_is_named_before_any_rendering(map_dem, tmp_path):
    """A world whose grid covers the area but holds no data over its west half (a reprojected
    DEM's empty corners): refused before rendering, naming it and the first position without a
    height (it failed at the first such case, as off "the DEM")."""
    from click.testing import CliRunner

    from skyfix.cli.main import cli
    from skyfix.dem import Dem, write_dem

    z = map_dem.z.copy()
    z[:, :100] = np.nan
    m = write_dem(tmp_path / "map.tif", map_dem)
    east = write_dem(tmp_path / "east.tif", Dem(z, map_dem.x0, map_dem.y0, map_dem.dx, map_dem.dy,
                                                 map_dem.crs_wkt, map_dem.crs_name))
    r = CliRunner().invoke(cli, ["simulate-set", str(m), "--set", "REF", "--cases", "6",
                                 "--frames", "1", "--camera", "wide", "--world-dem", str(east),
                                 "-o", str(tmp_path / "set")])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "the world DEM (east.tif) has no height at" in r.output and "case positions" in r.output
    assert not (tmp_path / "set").exists()


def test_overwrite_never_deletes_a_world_dem_inside_out(map_and_world_files, tmp_path):
    import shutil

    from click.testing import CliRunner

    from skyfix.cli.main import cli

    m, quarter = map_and_world_files
    out = tmp_path / "out"
    out.mkdir()
    inside = shutil.copy(quarter, out / "world.tif")
    r = CliRunner().invoke(cli, ["simulate-set", str(m), "--set", "REF", "--cases", "1",
                                 "--world-dem", str(inside), "-o", str(out), "--overwrite"])
    assert r.exit_code == 2 and "lies inside --out" in r.output, r.output
    assert (out / "world.tif").is_file()


def test_out_as_the_current_folder_or_a_tiny_pan_step_is_refused_at_once(map_and_world_files,
                                                                          tmp_path, monkeypatch):
    """-o . rendered into itself and failed after the rendering; a pan step of 1e-9 deg built
    its angles until the memory ran out (killed, no message)."""
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    m, _ = map_and_world_files
    work = tmp_path / "here"
    work.mkdir()
    monkeypatch.chdir(work)
    args = ["simulate", str(m), "--x", "501000", "--y", "4198000", "--yaw-deg", "10"]
    for out in (".", str(tmp_path)):
        r = CliRunner().invoke(cli, args + ["--frames", "1", "-o", out])
        assert r.exit_code == 2 and "is the current folder or holds it" in r.output, r.output
    r = CliRunner().invoke(cli, args + ["--pan-step-deg", "1e-9", "-o", "sim"])
    assert r.exit_code == 2 and "more than 360" in r.output, r.output
    assert list(work.iterdir()) == []


def test_overwrite_through_a_symbolic_link_replaces_its_target(map_and_world_files, tmp_path):
    """The link stays and its target gets the new output (the link itself was swapped for a
    folder, the run said it failed, and a hidden link to the old target was left behind)."""
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    m, _ = map_and_world_files
    real = tmp_path / "real"
    real.mkdir()
    (real / "old.txt").write_text("x")
    link = tmp_path / "link"
    link.symlink_to(real)
    r = CliRunner().invoke(cli, ["simulate", str(m), "--x", "501000", "--y", "4198000",
                                 "--yaw-deg", "10", "--frames", "1", "--camera", "wide",
                                 "-o", str(link), "--overwrite"])
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and (real / "acquisition.json").is_file()
    assert not (real / "old.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]  # no stray hidden link


def test_the_world_beside_a_void_keeps_the_maps_heights():
    """Void cells took the whole DEM's mean before the bicubic refinement, which reaches two cells
    into them: beside a reprojected DEM's empty corners the world stood ~200 m off the map. With
    every error off, the world is the map refined: within a few metres of the map's bilinear
    surface everywhere it has a height."""
    from skyfix.dem import Dem

    y, x = np.mgrid[0:80, 0:80] * 20.0
    z = 3000.0 + 2.0 * x + 100.0 * np.sin(y / 300.0)  # high terrain: the mean of it all is far off
    z[:, :30] = np.nan
    z[:20, :] = np.nan
    m = Dem.from_array(z, 20.0)
    w = world_dem(m, MapErrors(detail_rms_m=0.0, height_rms_m=0.0, spikes_per_km2=0.0,
                               shift_m=0.0), seed=1)
    r = np.random.default_rng(0)
    xs, ys = r.uniform(*m.bounds[0::2], 20000), r.uniform(*m.bounds[1::2], 20000)
    a, b = w.height_at(xs, ys), m.height_at(xs, ys)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 5000
    assert float(np.abs(a - b)[both].max()) < 15.0
