"""Mars DEMs in the formats missions ship them: a HiRISE-style PDS3 DTM (detached label, 32-bit
float, MISSING_CONSTANT voids, equirectangular), a MOLA-MEGDR-style PDS3 product (16-bit integers
with SCALING_FACTOR and OFFSET, simple cylindrical at the equator) and an ISIS3 cube: each read
through GDAL, on the right body, with the right heights and voids, and reprojected where its
projection distorts the area.

The labels are written here by hand as HiRISE and MEGDR products lay them out (no real product
ships in ../shared/data). The georeference is checked against the label by hand: GDAL reads
SAMPLE_PROJECTION_OFFSET and LINE_PROJECTION_OFFSET as the (0-based) pixel centre of the map
origin, x = (sample - SAMPLE_PROJECTION_OFFSET) * MAP_SCALE, y = (LINE_PROJECTION_OFFSET - line)
* MAP_SCALE, and an equirectangular x on a sphere of radius R with standard parallel lat_ts is
R cos(lat_ts) (lon - CENTER_LONGITUDE), y = R lat.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from skyfix.dem import load_dem
from skyfix.errors import DemError
from skyfix.planets import MARS, MOON, planet_from_crs

R = 3_396_190.0
LAT_TOP, LON0 = 18.41, 77.5
NY, NX = 240, 320
HIRISE_MISSING = struct.unpack("<f", struct.pack("<I", 0xFF7FFFFB))[0]


def _terrain():
    """Heights [m] (row 0 north): gentle slopes (0.1 m/m east, 0.3 m/m south) and a bump, so a
    pixel misplaced by the reader moves the height by metres while half a pixel stays < 0.2 m."""
    yy, xx = np.mgrid[0:NY, 0:NX].astype(np.float64)
    return -2500.0 + 0.1 * xx + 0.3 * yy + 20.0 * np.exp(-((xx - 200) ** 2 + (yy - 90) ** 2) / 800.0)


def _label(image, *, sample_type, bits, lat_ts, projection="EQUIRECTANGULAR", scale=1.0,
           extra_image="", target="MARS"):
    line_off = math.radians(LAT_TOP) * R / scale  # the image's top row lies at LAT_TOP
    samp_off = NX / 2
    target_line = f"TARGET_NAME = {target}\n" if target else ""
    return f"""PDS_VERSION_ID = PDS3
{target_line}RECORD_TYPE = FIXED_LENGTH
RECORD_BYTES = {NX * bits // 8}
FILE_RECORDS = {NY}
^IMAGE = "{image}"
OBJECT = IMAGE
  LINES = {NY}
  LINE_SAMPLES = {NX}
  BANDS = 1
  SAMPLE_TYPE = {sample_type}
  SAMPLE_BITS = {bits}
  UNIT = METER
{extra_image}END_OBJECT = IMAGE
OBJECT = IMAGE_MAP_PROJECTION
  MAP_PROJECTION_TYPE = "{projection}"
  A_AXIS_RADIUS = {R / 1000:.5f} <KM>
  B_AXIS_RADIUS = {R / 1000:.5f} <KM>
  C_AXIS_RADIUS = {R / 1000:.5f} <KM>
  COORDINATE_SYSTEM_NAME = PLANETOCENTRIC
  POSITIVE_LONGITUDE_DIRECTION = EAST
  CENTER_LATITUDE = {lat_ts} <DEG>
  CENTER_LONGITUDE = {LON0} <DEG>
  MAP_SCALE = {scale} <METERS/PIXEL>
  LINE_PROJECTION_OFFSET = {line_off:.4f} <PIXEL>
  SAMPLE_PROJECTION_OFFSET = {samp_off:.4f} <PIXEL>
END_OBJECT = IMAGE_MAP_PROJECTION
END
"""


def _lonlat_of_pixel(row, col, lat_ts, scale=1.0):
    """The label's own georeference, by hand: (lon, lat) [deg] of a pixel centre."""
    x = (col - NX / 2) * scale
    y = (math.radians(LAT_TOP) * R / scale - row) * scale
    return LON0 + math.degrees(x / (R * math.cos(math.radians(lat_ts)))), math.degrees(y / R)


def _hirise(tmp_path, lat_ts, target="MARS"):
    z = _terrain().astype("<f4")
    z[20:30, 40:50] = HIRISE_MISSING
    z.tofile(tmp_path / "DTEEC_TEST.IMG")
    lbl = tmp_path / f"DTEEC_TEST_{lat_ts:g}.LBL"
    lbl.write_text(_label("DTEEC_TEST.IMG", sample_type="PC_REAL", bits=32, lat_ts=lat_ts,
                          extra_image="  MISSING_CONSTANT = 16#FF7FFFFB#\n", target=target))
    return lbl


def _height_at_lonlat(dem, lon, lat):
    from pyproj import CRS, Transformer

    geo = CRS.from_wkt(dem.crs_wkt).geodetic_crs
    x, y = Transformer.from_crs(geo, CRS.from_wkt(dem.crs_wkt), always_xy=True).transform(lon, lat)
    return float(dem.height_at(x, y))


def test_a_hirise_pds3_dtm_is_mars_with_its_voids_and_heights(tmp_path):
    dem = load_dem(_hirise(tmp_path, LAT_TOP))
    assert dem.body is MARS
    # standard parallel through the DTM: kept in its own projection, the area undistorted
    assert dem.scale_error < 1e-3 and dem.z.shape == (NY, NX)
    truth = _terrain()
    for row, col in ((120, 160), (90, 200), (200, 300)):
        lon, lat = _lonlat_of_pixel(row, col, LAT_TOP)
        assert _height_at_lonlat(dem, lon, lat) == pytest.approx(truth[row, col], abs=0.2)
    assert dem.voids.n_void == 100  # the MISSING_CONSTANT block, filled from its surroundings
    assert np.all(np.isfinite(dem.z)) and np.nanmin(dem.z) > -2600


def test_a_pds3_dtm_stretched_by_its_projection_is_reprojected_true_to_the_ground(tmp_path):
    """Standard parallel at the equator, the DTM at 18.4 N: 5.4 % east-west stretch. skyfix
    reprojects to a local transverse Mercator; every point keeps its height by longitude and
    latitude, and distances become true (the 320 px row, 320 m on the label's stretched x, is
    320 cos(18.4) m on the ground)."""
    dem = load_dem(_hirise(tmp_path, 0.0))
    assert dem.body is MARS and "transverse Mercator" in dem.crs_name
    truth = _terrain()
    for row, col in ((120, 160), (90, 200), (60, 60), (200, 300)):
        lon, lat = _lonlat_of_pixel(row, col, 0.0)
        assert _height_at_lonlat(dem, lon, lat) == pytest.approx(truth[row, col], abs=0.3)
    (x0, _, x1, _) = dem.bounds
    ground = (NX - 1) * math.cos(math.radians(LAT_TOP - 0.004))
    assert x1 - x0 == pytest.approx(ground, rel=0.01)


def test_a_label_without_target_name_is_mars_by_its_radius(tmp_path):
    dem = load_dem(_hirise(tmp_path, LAT_TOP, target=None))
    assert dem.body is MARS


def test_a_megdr_style_integer_product_has_its_scale_and_offset_applied(tmp_path):
    """MOLA MEGDR-style: 16-bit integers, heights = OFFSET + SCALING_FACTOR * DN [m]."""
    dn = np.round((_terrain() + 3000.0) / 0.5).astype("<i2")
    dn.tofile(tmp_path / "MEGT_TEST.IMG")
    lbl = tmp_path / "MEGT_TEST.LBL"
    lbl.write_text(_label("MEGT_TEST.IMG", sample_type="LSB_INTEGER", bits=16, lat_ts=0.0,
                          projection="SIMPLE CYLINDRICAL", scale=1.0,
                          extra_image="  SCALING_FACTOR = 0.5\n  OFFSET = -3000.0\n"))
    dem = load_dem(lbl)
    assert dem.body is MARS
    truth = _terrain()
    for row, col in ((120, 160), (90, 200)):
        lon, lat = _lonlat_of_pixel(row, col, 0.0)
        assert _height_at_lonlat(dem, lon, lat) == pytest.approx(truth[row, col], abs=0.5)


def test_an_isis3_cube_reads_as_the_same_terrain(tmp_path):
    """An ISIS3 cube (GDAL writes its Mapping group from the CRS) of the PDS3 DTM: same body,
    same heights at the same longitudes and latitudes."""
    import rasterio

    src = _hirise(tmp_path, 0.0)
    cube = tmp_path / "dtm.cub"
    with rasterio.open(src) as s:
        prof, a = s.profile, s.read(1)
    prof.update(driver="ISIS3")
    with rasterio.open(cube, "w", **prof) as d:
        d.write(a, 1)
    dem, ref = load_dem(cube), load_dem(src)
    assert dem.body is MARS
    truth = _terrain()
    for row, col in ((120, 160), (90, 200), (60, 60), (200, 300)):
        lon, lat = _lonlat_of_pixel(row, col, 0.0)
        assert _height_at_lonlat(dem, lon, lat) == pytest.approx(truth[row, col], abs=0.3)
        assert _height_at_lonlat(dem, lon, lat) == pytest.approx(_height_at_lonlat(ref, lon, lat), abs=1e-3)


def test_an_anonymous_datum_is_named_by_its_radius_only_when_it_is_unambiguous():
    sphere = "+proj=longlat +a={a} +b={a} +no_defs +type=crs"
    assert planet_from_crs(sphere.format(a=3396190)) is MARS
    assert planet_from_crs(sphere.format(a=1737400)) is MOON
    io = planet_from_crs(sphere.format(a=1821600))  # Io: no body we know by that radius
    assert io.name.startswith("unnamed body") and io.radius_m == pytest.approx(1821600)


def test_a_pds3_label_in_kilometres_is_refused_not_read_as_metres(tmp_path):
    """GDAL's PDS driver does not pass the label's UNIT on: a DTM in KILOMETER was read as metres
    (heights a thousandth of the terrain's), silently. The label's unit is read now."""
    lbl = _hirise(tmp_path, LAT_TOP)
    km = tmp_path / "DTEEC_KM.LBL"
    km.write_text(lbl.read_text().replace("UNIT = METER", "UNIT = KILOMETER"))
    with pytest.raises(DemError, match=r"heights are in 'KILOMETER', not metres"):
        load_dem(km)
    import rasterio

    from skyfix.heights import pds3_unit

    with rasterio.open(lbl) as src:  # the label's own unit, as GDAL exposes its label
        assert pds3_unit(src) == "METER"
