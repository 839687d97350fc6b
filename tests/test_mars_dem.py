"""Mars DEMs as missions publish them: the body from the CRS, geographic and equirectangular maps
brought to a local transverse Mercator on Mars, heights in metres, contradictions refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.dem import Dem, fractal_dem, load_dem
from skyfix.errors import DemError, ParameterError
from skyfix.horizon import render_horizons
from skyfix.planets import EARTH, MARS, planet_from_crs, resolve_planet

R_MARS = 3_396_190.0  # the IAU 2015 Mars sphere of IAU_2015:49900 / 49910
LAT0, LON0 = 18.4, 77.5  # Jezero
CELL = 20.0


@pytest.fixture(scope="module")
def terrain():
    """Relief on a 20 m grid (a generated DEM: its heights, not its Earth CRS, are used)."""
    return fractal_dem(200, CELL, relief_m=600.0, seed=5)


def _write(path, z, crs, transform):
    import rasterio

    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype="float32", crs=crs, transform=transform) as d:
        d.write(z.astype("float32"), 1)
    return path


def _mars_files(tmp_path, z):
    """The same 20 m terrain as a Mars geographic map and as a Mars equirectangular map (standard
    parallel at the equator: east-west metres stretched by 1 / cos(18.4 deg) = 5.4 %)."""
    from rasterio.transform import from_origin

    ny, nx = z.shape
    dlat = math.degrees(CELL / R_MARS)
    dlon = math.degrees(CELL / (R_MARS * math.cos(math.radians(LAT0))))
    north, west = LAT0 + dlat * ny / 2, LON0 - dlon * nx / 2
    geo = _write(tmp_path / "mars_geo.tif", z, "IAU_2015:49900", from_origin(west, north, dlon, dlat))
    eqc = _write(tmp_path / "mars_eqc.tif", z, "IAU_2015:49910",
                 from_origin(math.radians(west) * R_MARS, math.radians(north) * R_MARS,
                             math.radians(dlon) * R_MARS, math.radians(dlat) * R_MARS))
    return geo, eqc


def test_the_body_comes_from_the_crs():
    assert planet_from_crs("EPSG:32607") is EARTH and planet_from_crs("ESRI:102003") is EARTH
    assert planet_from_crs("IAU_2015:49900") is MARS and planet_from_crs("IAU_2015:49910") is MARS
    moon = planet_from_crs("IAU_2015:30100")
    assert moon.name == "moon" and moon.refraction_k == 0.0
    venus = planet_from_crs("IAU_2015:29900")  # any body pyproj knows
    assert venus.name == "venus" and abs(venus.radius_m - 6_051_800) < 1e3 and venus.refraction_k == 0


@pytest.mark.parametrize("kind", ["geo", "eqc"])
def test_mars_maps_become_true_distances_on_mars(tmp_path, terrain, kind):
    """Both maps load as 20 m cells of a transverse Mercator on Mars, and their horizons match the
    terrain's own (the same heights on a true 20 m grid, rendered with Mars's radius) to
    resampling noise (heights within 0.1 m on average; measured median 0.02 deg, p95 0.26 deg,
    most of it in the near field of a camera 1.5 m above rough ground); read as they come, the equirectangular one would be 5.4 % too wide, which
    moves the horizon by degrees."""
    geo, eqc = _mars_files(tmp_path, terrain.z)
    dem = load_dem(geo if kind == "geo" else eqc)
    assert dem.body is MARS
    assert "transverse Mercator" in dem.crs_name and "Mars" in dem.crs_name
    assert dem.scale_error < 1e-3
    assert abs(dem.dx - CELL) < 0.01 and abs(dem.dy - CELL) < 0.01
    ny, nx = terrain.z.shape
    truth = Dem(terrain.z, -(nx - 1) * CELL / 2, (ny - 1) * CELL / 2, CELL, CELL, body=MARS)
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1200, 1200, (30, 2))
    a = render_horizons(truth, pts[:, 0], pts[:, 1]).elevation_deg
    b = render_horizons(dem, pts[:, 0], pts[:, 1]).elevation_deg
    d = np.abs(a - b)[np.isfinite(a) & np.isfinite(b)]
    assert np.median(d) < 0.05 and np.percentile(d, 95) < 0.5
    wide = Dem(terrain.z, truth.x0 * 1.054, truth.y0, CELL * 1.054, CELL, body=MARS)
    w = render_horizons(wide, pts[:, 0] * 1.054, pts[:, 1]).elevation_deg
    assert np.percentile(np.abs(a - w)[np.isfinite(a) & np.isfinite(w)], 95) > 3 * np.percentile(d, 95)


def test_mars_curvature_without_being_told(tmp_path, terrain):
    """A flat plane on a Mars CRS: every bin dips as Mars's curvature says, closed form, at the
    distance its skyline lies (the edge, 2-2.8 km: nearer than where the dip is deepest, sqrt(h/c)
    = 3.2 km), which Earth's curvature or a flat planet would not give."""
    from skyfix.planets import EARTH

    geo, _ = _mars_files(tmp_path, np.zeros_like(terrain.z))
    hb = render_horizons(load_dem(geo), [0.0], [0.0])
    assert hb.planet is MARS
    e, d, h = hb.elevation_deg[0], hb.skyline_distance_m[0], hb.camera_height_m
    assert np.isfinite(e).all() and 1500.0 < d.min() and d.max() < 3000.0
    dip = np.degrees(np.arctan(-h / d - MARS.curvature_coeff * d))
    assert np.abs(e - dip).max() < 1e-4
    assert np.abs(e - np.degrees(np.arctan(-h / d - EARTH.curvature_coeff * d))).min() > 0.005


def test_a_planet_contradicting_a_mars_crs_is_refused(tmp_path, terrain):
    geo, _ = _mars_files(tmp_path, terrain.z)
    dem = load_dem(geo)
    with pytest.raises(ParameterError, match="contradicts the DEM's CRS, which is on mars"):
        render_horizons(dem, [0.0], [0.0], planet="earth")
    with pytest.raises(ParameterError, match="contradicts"):
        resolve_planet(6_371_000.0, MARS)
    assert resolve_planet(3_390_000.0, MARS).radius_m == 3_390_000.0  # an override, not a contradiction
    # an Earth CRS is what stand-in terrain carries: it may be rendered as Mars
    assert resolve_planet("mars", EARTH) is MARS


def test_heights_in_feet_are_read_in_metres_others_refused_and_a_scale_is_applied(tmp_path, terrain):
    import rasterio
    from rasterio.transform import from_origin

    t = from_origin(500_000, 4_200_000, CELL, CELL)
    feet = _write(tmp_path / "feet.tif", terrain.z / 0.3048, "EPSG:32611", t)
    with rasterio.open(feet, "r+") as d:
        d.units = ("ft",)
    assert np.nanmax(np.abs(load_dem(feet).z - terrain.z)) < 1e-2  # the unit says feet: exact
    with rasterio.open(feet, "r+") as d:
        d.units = ("km",)
    with pytest.raises(DemError, match="in 'km', not metres or feet"):
        load_dem(feet)
    scaled = _write(tmp_path / "scaled.tif", (terrain.z - 100.0) / 0.5, "EPSG:32611", t)
    with rasterio.open(scaled, "r+") as d:
        d.scales, d.offsets = (0.5,), (100.0,)
    got = load_dem(scaled).z
    assert np.nanmax(np.abs(got - terrain.z)) < 1e-2


def test_points_by_longitude_and_latitude_on_the_dems_body(tmp_path, terrain):
    """--lon/--lat on Mars name the same point as its work-CRS metres, and the JSON gives both."""
    import json

    from click.testing import CliRunner

    from skyfix.cli.main import cli
    from skyfix.workcrs import lonlat_to_xy

    geo, _ = _mars_files(tmp_path, terrain.z)
    dem = load_dem(geo)
    x, y = lonlat_to_xy(dem.crs_wkt, LON0 + 0.005, LAT0 - 0.004)
    assert abs(x - 0.005 * math.pi / 180 * R_MARS * math.cos(math.radians(LAT0))) < 5
    by_ll = CliRunner().invoke(cli, ["horizon", str(geo), "--lon", str(LON0 + 0.005), "--lat",
                                     str(LAT0 - 0.004), "--json"])
    by_xy = CliRunner().invoke(cli, ["horizon", str(geo), "--x", str(x), "--y", str(y), "--json"])
    assert by_ll.exit_code == 0 and by_xy.exit_code == 0, by_ll.output
    a, b = json.loads(by_ll.stdout), json.loads(by_xy.stdout)
    assert a["elevation_deg"] == b["elevation_deg"]
    assert abs(b["lon"] - (LON0 + 0.005)) < 1e-9 and abs(b["lat"] - (LAT0 - 0.004)) < 1e-9
    assert a["planet"]["name"] == "mars"
    both = CliRunner().invoke(cli, ["horizon", str(geo), "--x", "0", "--y", "0", "--lon", "77.5",
                                    "--lat", "18.4"])
    assert both.exit_code == 2 and "not both" in both.output


def test_a_mars_fix_geojson_says_whose_longitudes_it_holds(tmp_path, terrain):
    """GeoJSON means Earth's WGS 84: a Mars fix's lon/lat, written plain, put it in India in a
    GIS. The collection names the body and its geodetic CRS, and the command warns."""
    from pyproj import CRS

    from skyfix.cli.provenance import fix_geojson, off_earth_warning
    from skyfix.pose.fix import Fix, crs_and_lonlat

    geo, _ = _mars_files(tmp_path, terrain.z)
    dem = load_dem(geo)
    crs, lon, lat = crs_and_lonlat(dem.crs_wkt, 100.0, -50.0)
    fix = Fix(100.0, -50.0, crs, lon, lat, 10.0, 10.0, 0.0, 0.0, 0.0, 3.0, 0.5, 0.9, 0.01)
    gj = fix_geojson(fix)
    assert gj["type"] == "FeatureCollection" and gj["body"] == "mars"
    assert CRS.from_wkt(gj["geodetic_crs"]).is_geographic
    assert "Mars" in CRS.from_wkt(gj["geodetic_crs"]).ellipsoid.name or \
        CRS.from_wkt(gj["geodetic_crs"]).ellipsoid.semi_major_metre < 3.5e6
    w = off_earth_warning("f.geojson", fix.crs)
    assert w and "mars longitudes and latitudes" in w and "on Earth" in w
    assert off_earth_warning("f.geojson", "EPSG:32611") is None
