"""DEM stacks: a fine DEM inside a coarse one is one terrain, the finest at every point, and a
ridge only the coarse DEM holds is still in the skyline."""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.dem import Dem, fractal_dem, write_dem
from skyfix.errors import DemError
from skyfix.horizon import render_horizons
from skyfix.stack import DemStack, load_dems

X0, Y0 = 500_000.0, 4_210_000.0  # north-west corner of the coarse DEM (pixel centre)


def _coarse():
    d = fractal_dem(161, 100.0, relief_m=300.0, seed=11, x0=X0, y0=Y0)
    z = d.z.copy()
    # a ridge 5.5 km east of the centre, north-south, 900 m above its surroundings
    xs = X0 + np.arange(161) * 100.0
    z += (900.0 * np.exp(-((xs - (X0 + 8000 + 5500)) / 250.0) ** 2))[None, :].astype(np.float32)
    return Dem(z, d.x0, d.y0, 100.0, 100.0, d.crs_wkt, d.crs_name, body=d.body)


def _fine(coarse):
    """2 x 2 km at 10 m in the middle: the coarse surface (bilinear) plus metre-scale detail."""
    n = 201
    fx0, fy0 = X0 + 7000.0, Y0 - 7000.0
    xs = fx0 + np.arange(n) * 10.0
    ys = fy0 - np.arange(n) * 10.0
    gx, gy = np.meshgrid(xs, ys)
    rng = np.random.default_rng(2)
    from scipy import ndimage

    detail = ndimage.gaussian_filter(rng.normal(0, 1, (n, n)), 3.0)
    z = coarse.height_at(gx, gy) + 8.0 * detail / detail.std()
    return Dem(z.astype(np.float32), fx0, fy0, 10.0, 10.0, coarse.crs_wkt, coarse.crs_name,
               body=coarse.body)


def _merged_by_hand(coarse, fine):
    """One DEM at 10 m: the coarse surface sampled at 10 m everywhere, the fine DEM pasted in."""
    n = 1601
    xs = X0 + np.arange(n) * 10.0
    ys = Y0 - np.arange(n) * 10.0
    gx, gy = np.meshgrid(xs, ys)
    z = coarse.height_at(gx, gy)
    inside = np.asarray(fine.contains(gx, gy), bool)
    z[inside] = fine.height_at(gx[inside], gy[inside])
    return Dem(z.astype(np.float32), X0, Y0, 10.0, 10.0, coarse.crs_wkt, coarse.crs_name,
               body=coarse.body)


@pytest.fixture(scope="module")
def stack_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("stack")
    coarse = _coarse()
    fine = _fine(coarse)
    return write_dem(d / "fine.tif", fine), write_dem(d / "coarse.tif", coarse), coarse, fine


def test_stack_horizon_matches_one_dem_merged_by_hand(stack_files):
    fine_p, coarse_p, coarse, fine = stack_files
    stack = load_dems([coarse_p, fine_p])  # any order: the finest comes first
    assert isinstance(stack, DemStack) and stack.members[0].cell_m == 10.0
    merged = _merged_by_hand(coarse, fine)
    rng = np.random.default_rng(5)
    xs = rng.uniform(X0 + 7300, X0 + 8700, 25)
    ys = rng.uniform(Y0 - 8700, Y0 - 7300, 25)
    a = render_horizons(stack, xs, ys, azimuth_bins=360).elevation_deg
    b = render_horizons(merged, xs, ys, azimuth_bins=360).elevation_deg
    d = np.abs(a - b)[np.isfinite(a) & np.isfinite(b)]
    assert d.size > 8000 and np.percentile(d, 99) <= 0.01, np.percentile(d, [50, 99, 100])


def test_a_ridge_only_the_coarse_dem_holds_is_in_the_skyline(stack_files):
    fine_p, coarse_p, coarse, fine = stack_files
    stack = load_dems([fine_p, coarse_p])
    # from the fine DEM's summit (its own terrain below the camera), looking east
    r, c = np.unravel_index(np.argmax(fine.z[40:-40, 40:-40]), fine.z[40:-40, 40:-40].shape)
    x, y = fine.x0 + (c + 40) * 10.0, fine.y0 - (r + 40) * 10.0
    hs = render_horizons(stack, [x], [y], azimuth_bins=360)
    ha = render_horizons(load_dems([fine_p]), [x], [y], azimuth_bins=360)
    east = slice(85, 96)  # azimuths 85-95 deg: towards the ridge ~5 km east
    ridge_x = X0 + 13500.0
    assert np.all(np.abs(hs.skyline_distance_m[0, east] - (ridge_x - x)) < 600)  # the ridge
    assert np.all(ha.skyline_distance_m[0, east] < 1500)  # alone: the fine DEM's own terrain
    assert np.nanmin(hs.elevation_deg[0, east]) > np.nanmax(ha.elevation_deg[0, east])


def test_stacks_of_two_bodies_or_two_places_are_refused(tmp_path, stack_files):
    fine_p, coarse_p, coarse, fine = stack_files
    far = Dem(fine.z, fine.x0 + 500_000.0, fine.y0, 10.0, 10.0, fine.crs_wkt, fine.crs_name)
    with pytest.raises(DemError, match="does not overlap"):
        load_dems([fine_p, write_dem(tmp_path / "far.tif", far)])
    import rasterio
    from rasterio.transform import from_origin

    mars = tmp_path / "mars.tif"
    with rasterio.open(mars, "w", driver="GTiff", width=50, height=50, count=1, dtype="float32",
                       crs="IAU_2015:49900", transform=from_origin(77.0, 18.5, 0.001, 0.001)) as dst:
        dst.write(np.zeros((50, 50), np.float32), 1)
    with pytest.raises(DemError, match="different bodies"):
        load_dems([fine_p, mars])


def test_build_and_locate_on_a_stack(tmp_path, stack_files):
    """build-db and locate over a stack: the database records every source, the fix from an
    exact skyline of the stack lands on the truth, and a DEM list other than the database's is
    refused."""
    import json

    from click.testing import CliRunner

    from skyfix.cli.main import cli
    from skyfix.database import open_database
    from skyfix.formats import write_profile_json
    from skyfix.pose import synthetic_profile

    fine_p, coarse_p, coarse, fine = stack_files
    db = tmp_path / "db.zarr"
    bounds = [str(v) for v in (X0 + 7600, Y0 - 8400, X0 + 8400, Y0 - 7600)]
    r = CliRunner().invoke(cli, ["build-db", str(fine_p), "--dem", str(coarse_p), "-o", str(db),
                                 "--bounds", *bounds, "--spacing-m", "40", "--workers", "0",
                                 "--no-progress"])
    assert r.exit_code == 0, r.output
    rec = open_database(db).attrs["dem"]
    assert [s["cell_m"] for s in rec["sources"]] == [10.0, 100.0]
    stack = load_dems([fine_p, coarse_p])
    tx, ty, th = X0 + 8013.0, Y0 - 7987.0, 63.0
    prof = synthetic_profile(stack, tx, ty, th, noise_deg=0.02, rng=3)
    write_profile_json(tmp_path / "p.json", prof)
    r = CliRunner().invoke(cli, ["locate", "--profile", str(tmp_path / "p.json"), "--db", str(db),
                                 "--dem", str(fine_p), "--dem", str(coarse_p), "-o",
                                 str(tmp_path / "fix.json")])
    assert r.exit_code == 0, r.output
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert np.hypot(fix["x"] - tx, fix["y"] - ty) < 1.0
    assert abs((fix["grid_heading_deg"] - th + 180) % 360 - 180) < 0.05
    only_fine = CliRunner().invoke(cli, ["locate", "--profile", str(tmp_path / "p.json"), "--db",
                                         str(db), "--dem", str(fine_p)])
    assert only_fine.exit_code == 2 and "is not the DEM the database" in only_fine.output


def test_a_simulated_panorama_of_the_stack_is_that_of_the_dem_merged_by_hand(stack_files, tmp_path):
    """The simulator renders a stack as one terrain: the panorama's exact skyline is the one
    rendered from the hand-merged DEM (whose 10 m samples of the coarse surface, on the coarse
    grid's lines, reproduce it exactly: measured identical to the 0.001 px written), and the
    ridge only the coarse DEM holds is in it, 15 px above the fine DEM's own skyline."""
    import json

    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    fine_p, coarse_p, coarse, fine = stack_files
    stack = load_dems([fine_p, coarse_p])
    merged = _merged_by_hand(coarse, fine)
    truth = Truth(X0 + 8100.0, Y0 - 7900.0, 30.0)
    skylines = []
    for name, dem in (("stack", stack), ("merged", merged), ("fine", fine)):
        out = simulate_acquisition(dem, truth, tmp_path / name, mode="panorama", pano_size=(1440, 360),
                                   planet="earth")
        skylines.append(np.array(json.loads((out / "pano.skyline.json").read_text())["rows"],
                                 dtype=float))
        meta = json.loads((out / "acquisition.json").read_text())["simulation"]["dem"]
        assert ("sources" in meta) == (name == "stack")
    assert isinstance(stack, DemStack)
    a, b, fine_only = skylines
    ok = np.isfinite(a) & np.isfinite(b)
    assert ok.sum() == 1440
    d = np.abs(a - b)[ok]  # 4 px per degree
    assert np.percentile(d, 99) <= 0.01 and d.max() <= 0.05, np.percentile(d, [50, 99, 100])
    # the ridge 5.5 km east (grid azimuth 90: body azimuth 60, column (60 + 180) * 4) stands above
    # what the fine DEM alone shows there
    for col in (950, 960, 970):
        assert a[col] < fine_only[col] - 10.0, (a[col], fine_only[col])


def test_horizon_of_a_stack_prints_its_summary(stack_files, tmp_path):
    """`skyfix horizon FINE --dem COARSE` printed a traceback ('DemStack' has no describe)
    unless --json was given; the summary names every member, finest first, and the plot is
    written."""
    from conftest import cli_run

    fine_path, coarse_path, _, _ = stack_files
    png = tmp_path / "h.png"
    r = cli_run("horizon", fine_path, "--dem", coarse_path, "--x", X0 + 8000.0, "--y", Y0 - 8000.0,
                "--plot", png)
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output and "2 DEMs, the finest wins" in r.output
    lines = r.output.splitlines()
    i = next(k for k, s in enumerate(lines) if "2 DEMs" in s)
    assert "fine.tif" in lines[i + 1] and "coarse.tif" in lines[i + 2]
    assert png.stat().st_size > 10_000


def test_a_void_in_the_fine_dem_shows_the_coarse_heights(tmp_path):
    """The fine DEM's void over a hilltop (120 m across) was filled by interpolation from its
    edges before stacking, so the stack stood 27 m below the hill the coarse DEM holds. The
    coarse heights show through it now."""
    coarse = _coarse()
    x, y = X0 + 8000.0, Y0 - 8000.0
    z = coarse.z.copy().astype(np.float64)
    xs, ys = X0 + np.arange(161) * 100.0, Y0 - np.arange(161) * 100.0
    hill = 60.0 * np.exp(-((xs[None, :] - x) ** 2 + (ys[:, None] - y) ** 2) / (2 * 150.0 ** 2))
    coarse = Dem((z + hill).astype(np.float32), coarse.x0, coarse.y0, 100.0, 100.0,
                 coarse.crs_wkt, coarse.crs_name, body=coarse.body)
    fine = _fine(coarse)
    fz = fine.z.copy()
    fxs, fys = fine.x0 + np.arange(201) * 10.0, fine.y0 - np.arange(201) * 10.0
    fz[(np.abs(fys[:, None] - y) <= 60) & (np.abs(fxs[None, :] - x) <= 60)] = np.nan
    fine = Dem(fz, fine.x0, fine.y0, 10.0, 10.0, fine.crs_wkt, fine.crs_name, body=fine.body)
    st = load_dems([write_dem(tmp_path / "fine.tif", fine), write_dem(tmp_path / "c.tif", coarse)])
    assert float(st.height_at(x, y)) == pytest.approx(float(coarse.height_at(x, y)), abs=0.5)
    # outside the void the fine DEM's own heights still win
    assert float(st.height_at(x + 300, y)) == pytest.approx(float(fine.height_at(x + 300, y)),
                                                            abs=1e-3)


def test_a_stack_is_read_in_a_projection_true_over_all_of_it(tmp_path):
    """A 1 km HiRISE-like DTM in its own equirectangular (true at its latitude, 18.4 N) inside a
    200 km MOLA-like geographic DEM: the stack was read in the DTM's projection, chosen over the
    DTM alone, which stretches the coarse DEM by 1 % and turns a ridge 100 km away by 0.3 deg.
    Now the stack's CRS holds the whole within 0.1 %, and the bearing of a far point agrees with
    the sphere's (pyproj.Geod) within 0.01 deg."""
    import math

    import rasterio
    from pyproj import CRS, Geod, Transformer
    from rasterio.transform import from_origin

    from skyfix.workcrs import scale_error

    R, lon0, lat0 = 3396190.0, 77.5, 18.4

    def write(path, z, crs, transform):
        with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0],
                           count=1, dtype="float32", crs=crs, transform=transform) as d:
            d.write(z.astype("float32"), 1)
        return path

    def terrain(lon, lat):
        return -2500 + 30 * np.sin(40 * (lon - lon0)) * np.cos(50 * (lat - lat0))

    n, step = 220, math.degrees(920.0 / R)  # 200 km at about 920 m
    west, north = lon0 - step * n / 2, lat0 + step * n / 2
    lon = west + (np.arange(n) + 0.5) * step
    lat = north - (np.arange(n) + 0.5) * step
    coarse = write(tmp_path / "mola.tif", terrain(*np.meshgrid(lon, lat)), "IAU_2015:49900",
                   from_origin(west, north, step, step))
    eqc = CRS.from_proj4(f"+proj=eqc +lat_ts={lat0} +lon_0={lon0} +R={R} +units=m +no_defs")
    m, cell = 200, 5.0
    fx0, fy0 = -m * cell / 2, m * cell / 2 + R * math.radians(lat0)
    gx, gy = np.meshgrid(fx0 + (np.arange(m) + 0.5) * cell, fy0 - (np.arange(m) + 0.5) * cell)
    flon, flat = Transformer.from_crs(eqc, eqc.geodetic_crs, always_xy=True).transform(gx, gy)
    fine = write(tmp_path / "hirise.tif", terrain(flon, flat), eqc.to_wkt(),
                 from_origin(fx0, fy0, cell, cell))
    st = load_dems([coarse, fine])
    work = CRS.from_wkt(st.crs_wkt)
    assert all(mb.crs_wkt == st.crs_wkt for mb in st.members)
    co = st.members[-1]
    assert scale_error(work, co.bounds) <= 0.001
    # the bearing from the DTM's centre to a point 90 km north-east, in the stack's grid plus its
    # meridian convergence, against the sphere's
    to = Transformer.from_crs(work.geodetic_crs, work, always_xy=True)
    (x0, y0), (x1, y1) = to.transform(lon0, lat0), to.transform(lon0 + 0.6, lat0 + 0.6)
    from skyfix.north import meridian_convergence_deg

    grid = math.degrees(math.atan2(x1 - x0, y1 - y0))
    true = grid + meridian_convergence_deg(st.crs_wkt, x0, y0)
    fwd, _, _ = Geod(a=R, b=R).inv(lon0, lat0, lon0 + 0.6, lat0 + 0.6)
    assert abs((true - fwd + 180) % 360 - 180) < 0.01
