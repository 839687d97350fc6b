"""DEM ingest: CRS handling, voids, bilinear heights, the max pyramid, clear errors."""

from __future__ import annotations

import math
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from conftest import plane_dem, shared_dem_path
from skyfix.dem import Dem, build_max_pyramid, load_dem
from skyfix.errors import DemError, OutsideDemError


def test_bilinear_height_is_exact_on_a_plane():
    dem = plane_dem(1_000, 10, z0=50, slope_x=0.3, slope_y=-0.1)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 1_000, 100), rng.uniform(0, 1_000, 100)
    np.testing.assert_allclose(dem.height_at(x, y), 50 + 0.3 * x - 0.1 * y, atol=1e-3)
    assert np.isnan(dem.height_at(-1.0, 5.0))


@settings(max_examples=30, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(2, 40), st.integers(2, 40)),
              elements=st.floats(-500, 5000, width=32)))
def test_pyramid_blocks_bound_every_height_inside(z):
    levels = build_max_pyramid(z)
    ny, nx = z.shape
    assert levels[-1].shape == (1, 1) and levels[-1][0, 0] == z.max()
    for lv, arr in enumerate(levels):
        size = 1 << lv
        for bi in range(arr.shape[0]):
            for bj in range(arr.shape[1]):
                block = z[bi * size: min((bi + 1) * size + 1, ny), bj * size: min((bj + 1) * size + 1, nx)]
                assert arr[bi, bj] == block.max()


def test_geographic_dem_is_reprojected_to_its_utm_zone_and_voids_filled():
    dem = load_dem(shared_dem_path("alps_srtm3_n46e008"))
    assert dem.crs_name == "EPSG:32632"  # 8-9 deg E, northern hemisphere
    assert 60 < dem.dx < 100 and dem.dx == dem.dy
    assert dem.voids.n_void > 0 and dem.voids.n_remaining == 0
    # the UTM grid's corners beyond the tile hold no terrain; every cell inside it has a height
    # (the tile's own voids on its edges, up to 386 cells, are holes, filled: they run along
    # the edge for 12 cells at most)
    assert dem.voids.n_outside > 0
    lon, lat = _cells_lonlat(dem)
    assert np.isfinite(dem.z[(lon > 8.02) & (lon < 8.98) & (lat > 46.02) & (lat < 46.98)]).all()
    assert 150 < np.nanmin(dem.z) and np.nanmax(dem.z) < 4_300


def test_projected_dem_keeps_its_crs_and_grid():
    dem = load_dem(shared_dem_path("south_glacier_20m"))
    assert dem.crs_name == "EPSG:32607"
    assert dem.z.shape == (300, 248) and dem.dx == 20.0
    assert len(dem.checksum) == 64


def test_explicit_target_crs(tmp_dem_file):
    path = tmp_dem_file(plane_dem(2_000, 20, z0=10))
    dem = load_dem(path, crs="EPSG:32612")
    assert dem.crs_name == "EPSG:32612"
    assert np.nanmax(dem.z) == pytest.approx(10, abs=1e-3)


def test_dem_without_crs_is_refused(tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    path = tmp_path / "nocrs.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       transform=from_origin(0, 40, 10, 10)) as dst:
        dst.write(np.ones((4, 4), np.float32), 1)
    with pytest.raises(DemError, match="no CRS"):
        load_dem(path)


def test_unreadable_and_missing_files(tmp_path):
    bad = tmp_path / "notes.tif"
    bad.write_text("not a raster")
    with pytest.raises(DemError, match="cannot read"):
        load_dem(bad)
    with pytest.raises(DemError, match="does not exist"):
        load_dem(tmp_path / "missing.tif")


def test_large_voids_stay_masked_and_points_in_them_are_refused():
    z = np.full((50, 50), 100.0)
    z[10:40, 10:40] = np.nan
    from skyfix.voids import fill_voids

    rep = fill_voids(z, max_cells=5)
    assert rep.n_void == 900 and 0 < rep.n_filled < 900 and rep.n_remaining == 900 - rep.n_filled
    dem = Dem.from_array(z, 10.0)
    with pytest.raises(OutsideDemError, match="void"):
        dem.require_inside(250.0, 250.0)


def test_fractal_dem_is_reproducible_and_has_the_requested_relief():
    from skyfix.dem import fractal_dem

    a = fractal_dem(128, 30.0, relief_m=800.0, seed=5)
    b = fractal_dem(128, 30.0, relief_m=800.0, seed=5)
    c = fractal_dem(128, 30.0, relief_m=800.0, seed=6)
    np.testing.assert_array_equal(a.z, b.z)
    assert not np.array_equal(a.z, c.z)
    assert float(a.z.max() - a.z.min()) == pytest.approx(800.0, rel=1e-4)
    assert a.crs_name == "EPSG:32611" and a.dx == 30.0


# --- reprojection: crop to the source's footprint, never to its voids ------------------------------

def _write_tif(path, z, transform, crs, nodata):
    import rasterio

    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype=z.dtype.name, crs=crs, transform=transform, nodata=nodata) as dst:
        dst.write(z, 1)
    return path


def _lonlat_plane(lon, lat, lon0, lat0):
    """A smooth tilted surface [m] over lon/lat [deg]: bilinear resampling reproduces it to a few cm."""
    return 1000.0 + 3000.0 * (lon - lon0) + 2000.0 * (lat - lat0)


def _geographic_tile(tmp_path, lon0, lat0, size_deg, step_deg, voids=None, name="geo.tif"):
    """A north-up EPSG:4326 GeoTIFF of :func:`_lonlat_plane`, SRTM-like (int16 would round: float32),
    with NaN nodata where ``voids(rows, cols)`` is true. Returns (path, source transform)."""
    from rasterio.transform import from_origin

    n = int(round(size_deg / step_deg))
    transform = from_origin(lon0, lat0 + size_deg, step_deg, step_deg)
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    lon = lon0 + (cols + 0.5) * step_deg
    lat = lat0 + size_deg - (rows + 0.5) * step_deg
    z = _lonlat_plane(lon, lat, lon0, lat0).astype(np.float32)
    if voids is not None:
        z[voids(rows, cols)] = np.nan
    return _write_tif(tmp_path / name, z, transform, "EPSG:4326", np.nan), transform


def _footprint_area_m2(crs_wkt, west, south, east, north, n=200):
    """Area [m2] of a lon/lat box drawn in a projected CRS (densified edges, shoelace): the
    reference for how much of the source a reprojected DEM may keep."""
    from pyproj import CRS, Transformer

    t = Transformer.from_crs("EPSG:4326", CRS.from_wkt(crs_wkt), always_xy=True)
    s = np.linspace(0.0, 1.0, n)
    lon = np.concatenate([west + (east - west) * s, np.full(n, east),
                          east - (east - west) * s, np.full(n, west)])
    lat = np.concatenate([np.full(n, south), south + (north - south) * s,
                          np.full(n, north), north - (north - south) * s])
    x, y = t.transform(lon, lat)
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _dem_area_m2(dem):
    """Area [m2] of the cells that hold a height."""
    return float(np.isfinite(dem.z).sum()) * dem.dx * dem.dy


def _cells_lonlat(dem):
    """lon, lat [deg] of every cell centre (pyproj), shaped as the grid."""
    from pyproj import CRS, Transformer

    rows, cols = np.mgrid[0:dem.z.shape[0], 0:dem.z.shape[1]]
    to_ll = Transformer.from_crs(CRS.from_wkt(dem.crs_wkt), "EPSG:4326", always_xy=True)
    return to_ll.transform(*dem.colrow_to_xy(cols, rows))


def _heights_only_on(dem, west, south, east, north, inset, tol=0.0):
    """Every cell with a height lies on the lon/lat box (no height invented beyond the source; to
    ``tol`` [deg], GDAL's warper placing its samples to 1/8 of a source cell), and every cell
    ``inset`` [deg] inside it has one (none of the source lost)."""
    lon, lat = _cells_lonlat(dem)
    has = np.isfinite(dem.z)
    on = (lon >= west - tol) & (lon <= east + tol) & (lat >= south - tol) & (lat <= north + tol)
    deep = (lon > west + inset) & (lon < east - inset) & (lat > south + inset) & (lat < north - inset)
    assert on[has].all() and has[deep].all()
    # cropped to the footprint's rectangle: every edge row and column holds terrain
    assert has[0].any() and has[-1].any() and has[:, 0].any() and has[:, -1].any()


def test_voids_of_a_geographic_dem_never_shrink_it_when_reprojected(tmp_path):
    """A band of voids along the west edge and 8 % scattered voids used to be cut as 'border'
    until every edge line was 99 % valid; they must be filled and the extent kept."""
    from pyproj import CRS, Transformer

    lon0, lat0, size, step = 8.0, 46.0, 0.2, 1 / 1200  # 3 arc-second cells, 240 x 240
    rng = np.random.default_rng(3)
    scattered = rng.random((240, 240)) < 0.08

    def voids(rows, cols):
        return ((cols >= 1) & (cols <= 6)) | scattered[rows, cols]

    path, _ = _geographic_tile(tmp_path, lon0, lat0, size, step, voids)
    dem = load_dem(path)
    assert dem.crs_name == "EPSG:32632"
    assert dem.voids.n_void > 0.07 * dem.z.size and dem.voids.n_remaining == 0
    _heights_only_on(dem, lon0, lat0, lon0 + size, lat0 + size, 1.5 * step, step / 8)
    # Nothing of the tile is lost: only the thin wedges of the grid's rotation are no terrain.
    area = _footprint_area_m2(dem.crs_wkt, lon0, lat0, lon0 + size, lat0 + size)
    assert 0.99 * area < _dem_area_m2(dem) < 1.01 * area
    to_xy = Transformer.from_crs("EPSG:4326", CRS.from_wkt(dem.crs_wkt), always_xy=True)
    # In the void band, 4.5 source cells (290 m) from the west edge, beyond the 140 m wedge the
    # meridian's tilt costs there: still on the DEM.
    x, y = to_xy.transform(lon0 + 4.5 * step, lat0 + size / 2)
    dem.require_inside(x, y)
    # Heights agree with the source surface evaluated at the same lon/lat (pyproj, not skyfix):
    # where no source cell nearby is void, to within GDAL's warp (it places samples to about 1/8
    # cell: 0.3 m on this 4 m-a-cell slope); on filled cells to within the rise over one cell.
    # Filled heights in the band are plausible, not exact (inverse-distance filling is not
    # linear): within the 25 m the surface rises over ten cells.
    lon = rng.uniform(lon0 + 0.01, lon0 + size - 0.01, 2000)
    lat = rng.uniform(lat0 + 0.01, lat0 + size - 0.01, 2000)
    err = np.abs(dem.height_at(*to_xy.transform(lon, lat)) - _lonlat_plane(lon, lat, lon0, lat0))
    col = np.floor((lon - lon0) / step - 0.5).astype(int)
    row = np.floor((lat0 + size - lat) / step - 0.5).astype(int)
    void = voids(*np.meshgrid(np.arange(240), np.arange(240), indexing="ij"))
    near_void = np.array([void[r - 1:r + 3, c - 1:c + 3].any() for r, c in zip(row, col)])
    assert 300 < near_void.sum() < 1700
    assert err[~near_void].max() < 0.5 and err.max() < 4.0
    lon_band = lon0 + rng.uniform(4.5, 6.5, 50) * step
    err_band = (dem.height_at(*to_xy.transform(lon_band, lat[:50]))
                - _lonlat_plane(lon_band, lat[:50], lon0, lat0))
    assert np.isfinite(err_band).all() and np.abs(err_band).max() < 25.0


def test_reprojection_wedges_are_no_terrain_and_no_heights_invented(tmp_path):
    """Far from the UTM central meridian the tile is rotated in the grid (2.6 deg at 12 E, 60 N).
    The empty wedges around it are no terrain (NaN), never filled; all of the tile is kept (the
    largest rectangle inside it kept 91 % here and 70 % of the Sierra DEM, whose skylines then
    ended kilometres short of its far ridges)."""
    from pyproj import CRS, Transformer
    from rasterio.warp import calculate_default_transform

    lon0, lat0, size, step = 11.8, 60.0, 0.3, 1 / 600
    path, src_transform = _geographic_tile(tmp_path, lon0, lat0, size, step)
    dem = load_dem(path)
    assert dem.crs_name == "EPSG:32632"
    assert dem.voids.n_void == 0 and dem.voids.n_outside > 0.05 * dem.z.size
    assert "around the data (no terrain)" in str(dem.voids)
    # no larger than the reprojection's full grid ...
    _, w, h = calculate_default_transform("EPSG:4326", dem.crs_wkt, 180, 180, lon0, lat0,
                                          lon0 + size, lat0 + size, resolution=dem.dx)
    assert dem.z.shape[0] <= h and dem.z.shape[1] <= w
    # ... heights on the source only (checked by pyproj) and all of it
    _heights_only_on(dem, lon0, lat0, lon0 + size, lat0 + size, 0.75 * step, step / 8)
    area = _footprint_area_m2(dem.crs_wkt, lon0, lat0, lon0 + size, lat0 + size)
    assert 0.99 * area < _dem_area_m2(dem) < 1.01 * area
    to_ll = Transformer.from_crs(CRS.from_wkt(dem.crs_wkt), "EPSG:4326", always_xy=True)
    ny, nx = dem.z.shape
    lon_c, lat_c = to_ll.transform(*dem.colrow_to_xy(nx // 2, ny // 2))
    assert dem.z[ny // 2, nx // 2] == pytest.approx(_lonlat_plane(lon_c, lat_c, lon0, lat0), abs=0.5)
    # a position in a wedge has no height, and says so
    with pytest.raises(OutsideDemError, match="no height"):
        dem.require_inside(*dem.colrow_to_xy(0, 0))
    # the max pyramid ignores the wedges: its top is the tile's highest height
    assert dem.pyramid[-1].max() == pytest.approx(np.nanmax(dem.z))


def test_a_target_crs_rotated_against_the_dem_keeps_all_of_it(tmp_path, caplog):
    """An oblique Mercator whose grid is turned 45 deg: the 15.4 x 22.2 km tile fills only
    2 a b / (a + b)**2 = 48 % of its north-up rectangle; the rest is no terrain, and all of the
    tile is kept (the largest rectangle inside it was 35 %)."""
    path, _ = _geographic_tile(tmp_path, 8.0, 46.0, 0.2, 1 / 1200)
    rotated = ("+proj=omerc +lat_0=46.1 +lonc=8.1 +alpha=45 +gamma=0 +k=1 +x_0=0 +y_0=0 "
               "+ellps=WGS84 +units=m")
    with caplog.at_level("INFO", logger="skyfix.dem"):
        dem = load_dem(path, crs=rotated)
    share = float(caplog.text.split("cells, ")[1].split(" %")[0])
    assert 50 < share < 54
    assert dem.voids.n_void == 0 and dem.voids.n_outside == pytest.approx(share / 100 * dem.z.size, rel=0.01)
    area = _footprint_area_m2(dem.crs_wkt, 8.0, 46.0, 8.2, 46.2)
    assert 0.99 * area < _dem_area_m2(dem) < 1.01 * area


def test_shared_alps_tile_keeps_its_whole_degree():
    from skyfix.workcrs import geographic_bounds, lonlat_to_xy

    dem = load_dem(shared_dem_path("alps_srtm3_n46e008"))
    w, s, e, n = geographic_bounds(dem.crs_wkt, dem.bounds)
    assert w < 8.01 and e > 8.99 and s < 46.01 and n > 46.99  # it was lon 8.198..9.000
    dem.require_inside(*lonlat_to_xy(dem.crs_wkt, 8.1, 46.5))
    swiss = load_dem(shared_dem_path("alps_srtm3_n46e008"), crs="EPSG:2056")
    xmin, ymin, xmax, ymax = swiss.bounds
    assert xmax - xmin > 74_000 and ymax - ymin > 109_000  # it was 80 m wide


# --- distorted projected Earth DEMs ----------------------------------------------------------------

def _web_mercator_tile(tmp_path):
    """The lon/lat surface on a Web Mercator grid around 8.5 E, 46.5 N (distances stretched 45 %)."""
    from pyproj import Transformer
    from rasterio.transform import from_origin

    to_ll = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True)
    x0, y0 = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(8.45, 46.55)
    step, n = 100.0, 100
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    lon, lat = to_ll.transform(x0 + (cols + 0.5) * step, y0 - (rows + 0.5) * step)
    z = _lonlat_plane(lon, lat, 8.45, 46.45).astype(np.float32)
    return _write_tif(tmp_path / "merc.tif", z, from_origin(x0, y0, step, step), "EPSG:3857", np.nan)


def test_earth_dem_in_web_mercator_is_read_into_its_utm_zone(tmp_path, caplog):
    from pyproj import CRS, Transformer

    path = _web_mercator_tile(tmp_path)
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        dem = load_dem(path)
    assert dem.crs_name == "EPSG:32632" and dem.scale_error < 1e-3
    assert "EPSG:3857 stretches distances by up to 45" in caplog.text and "reprojected to EPSG:32632" in caplog.text
    # True distances: 100 Mercator metres are 100 cos(46.5 deg) = 69 m on the ground.
    assert dem.dx == pytest.approx(100 * np.cos(np.radians(46.5)), rel=0.01)
    rng = np.random.default_rng(0)
    lon, lat = rng.uniform(8.46, 8.50, 100), rng.uniform(46.51, 46.54, 100)
    x, y = Transformer.from_crs("EPSG:4326", CRS.from_wkt(dem.crs_wkt), always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(dem.height_at(x, y), _lonlat_plane(lon, lat, 8.45, 46.45), atol=0.5)
    # Asked for by name, Web Mercator is kept, with the distortion said.
    caplog.clear()
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        merc = load_dem(path, crs="EPSG:3857")
    assert merc.crs_name == "EPSG:3857" and merc.scale_error > 0.4
    assert "requested CRS EPSG:3857 stretches distances" in caplog.text


def test_a_distorted_earth_dem_is_read_into_its_utm_zone(caplog):
    """The Sierra DEM's USA Albers stretches distances by 0.98 % and, not being conformal, turns
    directions by up to 0.56 deg: kept, it put a full turn's true-north heading 0.3-0.4 deg off.
    It is read into its UTM zone (conventions.md: the DEM's own CRS only within 0.1 %), and each
    cell holds the source's height at that place (independent reference: the source raster
    interpolated bilinearly by SciPy at the cell centre carried back into Albers by pyproj; GDAL's
    bilinear widens a little where it shrinks the grid, 30 to 30.14 m, which smooths the crests)."""
    import rasterio
    from pyproj import Transformer
    from scipy.ndimage import map_coordinates

    path = shared_dem_path("sierra_nevada_30m")
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        dem = load_dem(path)
    assert dem.crs_name == "EPSG:32611" and dem.scale_error < 1e-3
    assert "stretches distances by up to 0.98 %" in caplog.text
    assert "turns directions by up to 0.56 deg" in caplog.text
    assert "reprojected to EPSG:32611" in caplog.text and "gdalwarp -t_srs EPSG:32611 -te" in caplog.text
    rng = np.random.default_rng(3)
    i, j = np.nonzero(np.isfinite(dem.z))  # the grid's corners beyond the Albers square: no terrain
    k = rng.integers(0, i.size, 3000)
    i, j = i[k], j[k]
    x, y = dem.x0 + j * dem.dx, dem.y0 - i * dem.dy
    with rasterio.open(path) as src:
        z, t = src.read(1).astype(float), src.transform
        ax, ay = Transformer.from_crs("EPSG:32611", src.crs.to_wkt(), always_xy=True).transform(x, y)
    col, row = ~t * (ax, ay)
    r, c = np.asarray(row) - 0.5, np.asarray(col) - 0.5
    ref = map_coordinates(z, [r, c], order=1)
    # on the source's outer half-cell the reference has no second sample to interpolate with
    inner = (r >= 0) & (r <= z.shape[0] - 1) & (c >= 0) & (c <= z.shape[1] - 1)
    assert inner.mean() > 0.99
    err = np.abs(dem.z[i, j] - ref)[inner]
    i, j, ref = i[inner], j[inner], ref[inner]
    assert np.median(err) < 0.15 and np.percentile(err, 99) < 1.5 and err.max() < 5.0
    assert abs(np.mean(dem.z[i, j] - ref)) < 0.05  # no shift, no bias: only the crests smoothed


def _utm_tif(path, data, crs="EPSG:32611", **kw):
    import rasterio
    from rasterio.transform import from_origin

    data = np.asarray(data)
    if data.ndim == 2:
        data = data[None]
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[2], height=data.shape[1],
                       count=data.shape[0], dtype=data.dtype, crs=crs,
                       transform=from_origin(500_000, 4_000_000, 30, 30), **kw) as dst:
        dst.write(data)
    return path


def test_heights_no_terrain_has_are_refused(tmp_path):
    """A fill value of 1e30 not marked as nodata was read as a 1e30 m mountain."""
    z = np.full((8, 8), 1500.0, np.float32)
    z[3, 3] = 1e30
    with pytest.raises(DemError, match=r"height of 1e\+30 m.*nodata"):
        load_dem(_utm_tif(tmp_path / "fill.tif", z))
    z[3, 3] = -8_000.0  # the floor of Hellas on Mars is about this far below its datum
    assert load_dem(_utm_tif(tmp_path / "deep.tif", z)).z[3, 3] == -8_000.0


def test_complex_or_multiband_rasters_are_refused_or_said(tmp_path, caplog):
    with pytest.raises(DemError, match="complex numbers"):
        load_dem(_utm_tif(tmp_path / "c.tif", np.full((8, 8), 1 + 2j, np.complex64)))
    two = np.stack([np.full((8, 8), 100.0, np.float32), np.full((8, 8), 900.0, np.float32)])
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        dem = load_dem(_utm_tif(tmp_path / "two.tif", two))
    assert np.all(dem.z == 100.0) and "2 bands: its heights are taken from band 1" in caplog.text


def test_an_image_without_georeferencing_is_refused_without_rasterio_s_warning(tmp_path):
    import warnings

    import cv2

    png = tmp_path / "frame.png"
    cv2.imwrite(str(png), np.full((8, 8), 7, np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning escaping would fail here
        with pytest.raises(DemError, match="has no CRS"):
            load_dem(png)


def test_direction_error_is_how_far_grid_azimuths_miss_the_geodesic_ones():
    """Independent reference: the geodesic azimuth (pyproj.Geod) of a 100 m step at each grid
    azimuth, against that azimuth plus the meridian convergence, at one Sierra point in USA
    Albers (equal-area, so directions turn where its two scales differ); a UTM zone turns none."""
    import math

    from pyproj import CRS, Geod, Transformer

    from skyfix.north import meridian_convergence_deg
    from skyfix.workcrs import direction_error_deg

    c = CRS.from_user_input("ESRI:102003")
    x0, y0 = -2016950.0, 241757.0
    to_geo = Transformer.from_crs(c, c.geodetic_crs, always_xy=True)
    conv = meridian_convergence_deg(c.to_wkt(), x0, y0)
    lon0, lat0 = to_geo.transform(x0, y0)
    worst = 0.0
    for a in np.arange(0.0, 360.0, 1.0):
        lon1, lat1 = to_geo.transform(x0 + 100 * math.sin(math.radians(a)),
                                      y0 + 100 * math.cos(math.radians(a)))
        az = Geod(ellps="GRS80").inv(lon0, lat0, lon1, lat1)[0]
        worst = max(worst, abs((az - a - conv + 180.0) % 360.0 - 180.0))
    assert worst == pytest.approx(0.556, abs=0.002)
    assert direction_error_deg(c, (x0 - 1, y0 - 1, x0 + 1, y0 + 1), n=2) == pytest.approx(worst, abs=1e-3)
    assert direction_error_deg("EPSG:32611", (300_000, 4_000_000, 400_000, 4_100_000)) < 1e-6


def test_a_dem_too_wide_for_one_metric_crs_is_refused(tmp_path):
    """A whole-world lon/lat raster went into one UTM zone: 657 % scale error, every horizon
    stretched, a heading sigma of 9285 deg, exit 0."""
    import rasterio
    from rasterio.transform import from_origin

    path = tmp_path / "world.tif"
    with rasterio.open(path, "w", driver="GTiff", width=360, height=170, count=1, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(-180, 85, 1, 1)) as dst:
        dst.write(np.full((1, 170, 360), 500.0, np.float32))
    with pytest.raises(DemError, match="spans too much of its body for one metric CRS"):
        load_dem(path)


def test_the_advised_gdalwarp_writes_the_grid_read(tmp_path, caplog):
    """The warning's gdalwarp command (-te, -tr, bilinear, no-data wedges: done here with rasterio,
    GDAL's warper) writes the grid skyfix reads, which then loads with no reprojection, its wedges
    no terrain again (a raster's no-data collar): a plain `gdalwarp -t_srs` fills them with 0, and
    the void filling had made up terrain in 344,000 of their cells."""
    import re

    import rasterio
    from rasterio.transform import from_origin
    from rasterio.warp import Resampling, reproject

    path = shared_dem_path("sierra_nevada_30m")
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        dem = load_dem(path)
    m = re.search(r"gdalwarp -t_srs (\S+) -te (\S+) (\S+) (\S+) (\S+) -tr (\S+) (\S+) -r bilinear "
                  r"-ot Float32 -dstnodata (\S+) ", caplog.text)
    crs, (x0, y0, x1, y1, rx, ry, nodata) = m.group(1), map(float, m.groups()[1:])
    w, h = round((x1 - x0) / rx), round((y1 - y0) / ry)
    out = np.full((h, w), nodata, np.float32)
    with rasterio.open(path) as src:
        reproject(rasterio.band(src, 1), out, dst_transform=from_origin(x0, y1, rx, ry),
                  dst_crs=crs, resampling=Resampling.bilinear, dst_nodata=nodata)
        profile = dict(driver="GTiff", width=w, height=h, count=1, dtype="float32", crs=crs,
                       transform=from_origin(x0, y1, rx, ry), nodata=nodata)
    with rasterio.open(tmp_path / "utm.tif", "w", **profile) as dst:
        dst.write(out, 1)
    caplog.clear()
    with caplog.at_level("INFO", logger="skyfix.dem"):
        again = load_dem(tmp_path / "utm.tif")
    assert "reprojected" not in caplog.text
    assert again.z.shape == dem.z.shape and again.bounds == pytest.approx(dem.bounds, abs=1e-3)
    # the same cells hold terrain: the wedges (29 % of the grid) none; the voids filled are the
    # staircase of the footprint's rasterised edge inside the hull of the heights, a cell deep
    import cv2

    assert again.voids.n_outside > 0.25 * dem.z.size and again.voids.n_void < 0.002 * dem.z.size
    has, had = np.isfinite(again.z), np.isfinite(dem.z)
    next_to = cv2.dilate(had.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert next_to[has].all() and (had & ~has).sum() < 0.001 * dem.z.size
    both = has & had
    # ... with heights as GDAL's warper gives them, which widens its bilinear kernel by each
    # window's scale (measured: median 0.25 m, p99 1.9 m apart, on crests up to 13 m)
    d = np.abs(again.z - dem.z)[both]
    assert np.median(d) < 0.5 and np.percentile(d, 99) < 3.0 and abs(np.mean((again.z - dem.z)[both])) < 0.1


def _strip_with_collar(n=200):
    """A 30-deg rotated strip of heights inside a no-data collar (as a map-projected HiRISE DTM
    is), with a 6 x 6 hole inside the strip: (z, in_strip mask)."""
    rows, cols = np.mgrid[0:n, 0:n].astype(float)
    u = (cols - n / 2) * np.cos(np.radians(30)) + (rows - n / 2) * np.sin(np.radians(30))
    v = -(cols - n / 2) * np.sin(np.radians(30)) + (rows - n / 2) * np.cos(np.radians(30))
    strip = (np.abs(u) < 0.45 * n) & (np.abs(v) < 0.2 * n)
    z = np.where(strip, 1000.0 + 2.0 * cols + 1.0 * rows, np.nan).astype(np.float32)
    z[97:103, 97:103] = np.nan
    return z, strip


def test_a_rasters_no_data_collar_is_no_terrain_and_its_holes_are_filled(tmp_path):
    """The no-data around a rotated strip used to be filled out to 100 cells from the strip: a ramp
    of made-up terrain on every side. Outside the hull of the heights it stays no terrain; the
    hole inside is filled, with the plane's heights."""
    from rasterio.transform import from_origin

    z, strip = _strip_with_collar()
    path = _write_tif(tmp_path / "strip.tif", z, from_origin(500_000, 4_000_000, 1, 1), "EPSG:32611",
                      -3.4028234663852886e38)
    raw = z.copy()
    raw[~np.isfinite(raw)] = -3.4028234663852886e38
    with __import__("rasterio").open(path, "r+") as dst:
        dst.write(raw, 1)
    dem = load_dem(path)
    assert dem.z.shape == z.shape  # not reprojected: the same grid
    import cv2

    has = np.isfinite(dem.z)
    # all of the strip, and beyond it only the staircase of its rasterised edge inside the hull
    # of the heights, a cell deep (not 100)
    next_to = cv2.dilate(strip.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert has[strip].all() and next_to[has].all()
    assert dem.voids.n_remaining == 0 and dem.voids.n_outside > 0.95 * (~strip).sum()
    rows, cols = np.mgrid[97:103, 97:103]
    np.testing.assert_allclose(dem.z[97:103, 97:103], 1000.0 + 2.0 * cols + rows, atol=6.0)


def test_a_source_collar_stays_outside_once_reprojected(tmp_path):
    """The same strip on a lon/lat grid, reprojected: its collar and the reprojection's wedges are
    both no terrain, and the grid is cropped to the strip's rectangle, not the raster's."""
    from rasterio.transform import from_origin

    z, strip = _strip_with_collar()
    step = 1 / 1200
    path = _write_tif(tmp_path / "strip_ll.tif", z, from_origin(8.0, 46.2, step, step), "EPSG:4326",
                      np.nan)
    dem = load_dem(path)
    # the voids are the 6 x 6 hole alone (its area in the work CRS's cells), not cells of the
    # collar beside the strip's slanted edges too (200 more, once filled by extrapolation)
    hole_m2 = 36 * (step * 111_320 * math.cos(math.radians(46.1))) * (step * 111_130)
    assert abs(dem.voids.n_void - hole_m2 / dem.cell_m ** 2) < 3 and dem.voids.n_remaining == 0
    lon, lat = _cells_lonlat(dem)
    col = (lon - 8.0) / step - 0.5
    row = (46.2 - lat) / step - 0.5
    has = np.isfinite(dem.z)
    # every height lies on the strip (to a cell: the strip's rasterised edge), the strip is covered
    ri, ci = np.clip(np.round(row).astype(int), 0, 199), np.clip(np.round(col).astype(int), 0, 199)
    import cv2

    near_strip = cv2.dilate(strip.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert near_strip[ri[has], ci[has]].all()
    core = cv2.erode(strip.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    inside = (row > 0) & (row < 199) & (col > 0) & (col < 199)
    assert has[inside & core[ri, ci]].all()
    # cropped to the strip, which spans 80 % of the raster's 200 rows (18.5 km north to south)
    assert 0.78 * 18_530 < dem.z.shape[0] * dem.dy < 0.85 * 18_530


@pytest.mark.parametrize("crs, step", [("EPSG:4326", 0.001), ("EPSG:32611", 30.0)])
def test_a_raster_of_no_data_alone_is_refused(tmp_path, crs, step):
    """Reprojected, it had died in OpenCV's convex hull (a traceback) before the refusal."""
    from rasterio.transform import from_origin

    origin = (8.0, 46.2) if crs == "EPSG:4326" else (500_000.0, 4_000_000.0)
    path = _write_tif(tmp_path / "none.tif", np.full((20, 20), np.nan, np.float32),
                      from_origin(*origin, step, step), crs, np.nan)
    with pytest.raises(DemError, match="no valid heights"):
        load_dem(path)


def test_info_json_gives_the_voids_as_numbers_too():
    """`skyfix info --json` gave the voids as a sentence alone; a program reads the counts."""
    import json

    from click.testing import CliRunner

    from skyfix.cli.main import cli

    path = shared_dem_path("alps_srtm3_n46e008")
    r = CliRunner().invoke(cli, ["info", str(path), "--json"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout[r.stdout.index("{"):])
    dem = load_dem(path)
    assert d["void_cells"] == {"void": dem.voids.n_void, "filled": dem.voids.n_filled,
                               "left_masked": dem.voids.n_remaining,
                               "outside_data": dem.voids.n_outside}
    assert d["void_cells"]["void"] > 0 and f"{d['void_cells']['void']} void cells" in d["voids"]


def test_info_names_a_crs_without_a_code_in_one_line(tmp_path):
    """A Mars equirectangular DEM (no EPSG code) had its WKT, dozens of lines, printed twice."""
    from click.testing import CliRunner
    from pyproj import CRS
    from rasterio.transform import from_origin

    from skyfix.cli.main import cli

    crs = CRS.from_proj4("+proj=eqc +lat_ts=0 +lon_0=137 +R=3396190 +units=m +no_defs")
    z = np.random.default_rng(0).uniform(0, 100, (60, 60)).astype(np.float32)
    path = _write_tif(tmp_path / "mars.tif", z, from_origin(0.0, 0.0, 20.0, 20.0), crs.to_wkt(), -9999.0)
    r = CliRunner().invoke(cli, ["info", str(path)])
    assert r.exit_code == 0, r.output
    lines = {ln.split(None, 2)[0] + " " + ln.split(None, 2)[1]: ln for ln in r.stdout.splitlines()
             if ln.startswith(("native crs", "work crs"))}
    assert set(lines) == {"native crs", "work crs"}
    for ln in lines.values():
        assert "+proj=eqc" in ln and "+R=3396190" in ln and "PROJCRS" not in ln and "[" not in ln
    assert load_dem(path).crs_name.startswith("+proj=eqc")


# --- files that are not what they seem --------------------------------------------------------------

def _small(tmp_path, name, z, *, crs="EPSG:32611", nodata=None, transform=None):
    from rasterio.transform import from_origin

    return _write_tif(tmp_path / name, z, transform or from_origin(300000, 4150000, 30, 30), crs,
                      nodata)


def test_an_undeclared_fill_value_is_refused_not_read_as_terrain(tmp_path):
    """A block of -32768 with no nodata declared was read as terrain 32 km deep, silently."""
    z = (1000 + np.arange(400, dtype=np.int16).reshape(20, 20)).astype(np.int16)
    z[:5, :5] = -32768
    with pytest.raises(DemError, match=r"25 cells hold exactly -32768.*gdal_edit.py -a_nodata"):
        load_dem(_small(tmp_path, "fill.tif", z))
    z[:5, :5] = 900  # the same DEM without the fill reads
    assert load_dem(_small(tmp_path, "ok.tif", z)).z.min() == pytest.approx(900)


def test_a_radius_product_says_it_holds_the_radius(tmp_path):
    z = (3396190.0 + np.linspace(0, 500, 400).reshape(20, 20)).astype(np.float32)
    from rasterio.transform import from_origin

    path = _small(tmp_path, "radius.tif", z, crs="IAU_2015:49900",
                  transform=from_origin(77.0, 18.5, 0.001, 0.001))
    with pytest.raises(DemError, match=r"about mars's radius.*subtract the reference radius"):
        load_dem(path)


def test_a_raster_running_east_to_west_is_read(tmp_path):
    """A negative x pixel size gave left > right bounds and a traceback."""
    from rasterio.transform import Affine

    z = (np.arange(20, dtype=np.float32)[None, :] * 3 + np.zeros((20, 1), np.float32) + 100)
    t = Affine(-30.0, 0.0, 300600.0, 0.0, -30.0, 4150000.0)  # column k at x = 300585 - 30 k
    d = load_dem(_small(tmp_path, "ew.tif", z, transform=t))
    # the column at x = 300585 - 30 k holds 100 + 3 k
    assert float(d.height_at(300585.0 - 30 * 7, 4149985.0 - 300)) == pytest.approx(121.0, abs=1e-3)


def test_a_truncated_dem_names_the_file(tmp_path):
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    z = np.random.default_rng(0).normal(1000, 50, (400, 400)).astype(np.float32)
    path = _small(tmp_path, "cut.tif", z)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    r = CliRunner().invoke(cli, ["info", str(path)])
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert "cut.tif" in r.output and "truncated or damaged" in r.output, r.output


def test_a_dem_across_the_180th_meridian_is_read_into_the_zone_there(tmp_path):
    """The middle of west 179.97 and east -179.97 was taken as 0: the DEM was read into the UTM
    zone at 3 deg E, a projection through the pole, 180 deg away. (Its reprojection into the
    right zone still keeps only the half west of 180: reported, not fixed.)"""
    from pyproj import CRS, Transformer
    from rasterio.transform import from_origin

    from skyfix.workcrs import mid_longitude

    assert mid_longitude(179.97, -179.97) == pytest.approx(180.0)
    assert mid_longitude(170.0, -170.0) == pytest.approx(180.0)
    assert mid_longitude(175.0, -165.0) == pytest.approx(-175.0)
    assert mid_longitude(-10.0, 20.0) == pytest.approx(5.0)
    to = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    x0, y0 = to.transform(179.97, 65.0)
    x1 = 2 * 20037508.342789244 - x0  # as far past 180 (EPSG:3857 runs on in x)
    n = 60
    cell = (x1 - x0) / n
    z = np.full((n, n), 500.0, np.float32)
    d = load_dem(_small(tmp_path, "dateline.tif", z, crs="EPSG:3857",
                        transform=from_origin(x0, y0, cell, cell)))
    assert CRS.from_wkt(d.crs_wkt).to_epsg() in (32601, 32660)


def test_an_earth_datum_named_like_another_body_is_earth():
    """EPSG:4732 (Marshall Islands 1960) contains 'mars': it was taken for another body (no
    refraction, and --planet earth refused as contradicting it)."""
    from skyfix.planets import EARTH, planet_from_crs

    assert planet_from_crs("EPSG:4732") is EARTH


def test_scale_error_counts_the_shear_of_a_sinusoidal_projection():
    """A sinusoidal projection (a common Mars DEM CRS) keeps its meridional and parallel scales
    near 1 off its central meridian while stretching other directions: the stretch is the
    largest singular value of the projection's Jacobian in metres per metre, here taken by
    finite differences on the sphere (independent of PROJ's factors)."""
    from pyproj import CRS, Transformer

    from skyfix.workcrs import scale_error

    r = 3396190.0
    crs = CRS.from_proj4(f"+proj=sinu +lon_0=77.5 +R={r} +units=m +no_defs")
    fwd = Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    corners = [fwd.transform(lon, lat) for lon in (77.5, 79.0) for lat in (17.5, 19.0)]
    xs, ys = zip(*corners)
    bounds = (min(xs), min(ys), max(xs), max(ys))
    inv = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    worst, h = 0.0, 1e-5  # [deg]
    for x in np.linspace(bounds[0], bounds[2], 5):
        for y in np.linspace(bounds[1], bounds[3], 5):
            lon, lat = inv.transform(x, y)
            east = np.radians(h) * r * math.cos(math.radians(lat))  # [m] on the sphere
            north = np.radians(h) * r
            jac = np.array([[(a - b) / (2 * d)
                             for a, b in zip(fwd.transform(*p1), fwd.transform(*p0))]
                            for p1, p0, d in (((lon + h, lat), (lon - h, lat), east),
                                              ((lon, lat + h), (lon, lat - h), north))]).T
            worst = max(worst, *np.abs(np.linalg.svd(jac, compute_uv=False) - 1.0))
    assert worst > 0.004  # a stretch the conventions' 0.1 % does not allow
    assert scale_error(crs, bounds) == pytest.approx(worst, rel=0.02)


def test_the_collar_is_every_void_cell_outside_the_hull_of_the_data():
    """collar_cells against an independent hull (scipy's Qhull half-planes on the cell centres):
    rotated rectangles of data with holes. The raster fill it starts from also took cells up to
    half a cell outside a slanted edge, which fill_voids then extrapolated (20 of a square turned
    20 deg)."""
    from scipy.spatial import ConvexHull

    from skyfix.voids import collar_cells

    rng = np.random.default_rng(0)
    for _ in range(60):
        h, w = rng.integers(20, 60, 2)
        ii, jj = np.mgrid[0:h, 0:w]
        a = rng.uniform(0, np.pi)
        cx, cy = rng.uniform(0.3, 0.7, 2) * (w, h)
        u = (jj - cx) * np.cos(a) + (ii - cy) * np.sin(a)
        v = -(jj - cx) * np.sin(a) + (ii - cy) * np.cos(a)
        valid = (np.abs(u) < rng.uniform(3, w / 3)) & (np.abs(v) < rng.uniform(3, h / 3))
        valid &= rng.random(valid.shape) > 0.1  # holes inside the data
        eq = ConvexHull(np.argwhere(valid)[:, ::-1].astype(float)).equations
        cells = np.argwhere(~valid)[:, ::-1].astype(float)
        outside = (cells @ eq[:, :2].T + eq[:, 2]).max(axis=1) > 1e-9
        assert np.array_equal(collar_cells(~valid)[~valid], outside)
