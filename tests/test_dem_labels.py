"""DEMs whose labels do not match their numbers, and coordinates given in the wrong unit: each
is one clear line and exit status 2 (or read right, and said), never a traceback or a message
that sends the user to an option the command lacks.

Most cases are the small shared glacier DEM (UTM 7N, 20 m) written again with another label.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_one_error_line as assert_clean_error
from conftest import cli_run, shared_dem_path
from skyfix.dem import load_dem
from skyfix.errors import DemError, SkyfixError

run = cli_run


@pytest.fixture
def glacier():
    return shared_dem_path("south_glacier_20m")


def relabel(src, dst, *, crs=None, scale=1.0, offset=0.0, transform=None, units=None):
    """A copy of the raster ``src`` at ``dst`` with another CRS label (the numbers unchanged),
    its heights times ``scale`` plus ``offset``, another ``transform`` or a band unit."""
    import rasterio

    with rasterio.open(src) as s:
        profile = s.profile.copy()
        z = s.read(1, masked=True)
    profile.update(crs=crs if crs is not None else profile["crs"])
    if transform is not None:
        profile.update(transform=transform)
    with rasterio.open(dst, "w", **profile) as d:
        d.write((z * scale + offset).filled(profile["nodata"]).astype(profile["dtype"]), 1)
        if units:
            d.units = (units,)
    return dst


# --- 1. a geographic CRS on coordinates in metres --------------------------------------------------

def test_metres_labelled_degrees_are_one_line_naming_the_coordinates(tmp_path, glacier):
    """EPSG:4326 on UTM coordinates ended in GDAL's "Too many points (441 out of 441) failed to
    transform", a traceback and exit 1."""
    mislabel = relabel(glacier, tmp_path / "mislabel.tif", crs="EPSG:4326")
    r = run("info", mislabel)
    assert_clean_error(r, "mislabel.tif: its CRS EPSG:4326 is geographic",
                       "x 599000..603960, y 6741000..6747000", "not longitudes and latitudes",
                       "gdal_edit.py -a_srs EPSG:XXXX mislabel.tif")
    with pytest.raises(DemError, match="is geographic but its coordinates"):
        load_dem(mislabel)


def test_degrees_labelled_projected_are_one_line_naming_the_coordinates(tmp_path):
    """The Alps tile (3-arcsecond cells) labelled UTM 32N was read as a DEM 1 m wide of 0.8 mm
    cells; a real projected DEM of small coordinates (a local grid) still reads."""
    alps = shared_dem_path("alps_srtm3_n46e008")
    mislabel = relabel(alps, tmp_path / "alps_utm.tif", crs="EPSG:32632")
    r = run("info", mislabel)
    assert_clean_error(r, "alps_utm.tif: its CRS EPSG:32632 is projected", "look like longitudes and "
                       "latitudes", "gdal_edit.py -a_srs EPSG:4326 alps_utm.tif")
    from rasterio.transform import from_origin

    local = relabel(glacier_path := shared_dem_path("south_glacier_20m"), tmp_path / "local.tif",
                    transform=from_origin(0.0, 6000.0, 20.0, 20.0))
    assert load_dem(local).dx == pytest.approx(20.0, rel=0.01) and glacier_path.exists()  # read


def test_a_reprojection_gdal_refuses_is_one_line_naming_both_crss(glacier):
    # an orthographic view centred on the far side of the Earth holds no point of Alaska
    far = "+proj=ortho +lat_0=-60 +lon_0=40 +datum=WGS84 +units=m"
    with pytest.raises(DemError, match=r"cannot reproject it from EPSG:32607 to .*ortho.*"
                                       r"\(GDAL: Too many points.*give a --crs that covers"):
        load_dem(glacier, crs=far)
    r = run("horizon", glacier, "--x", 601000, "--y", 6744000, "--crs", far)
    assert_clean_error(r, "cannot reproject it from EPSG:32607")


# --- 2. a projected CRS in feet -----------------------------------------------------------------------

UTM7_FT = "+proj=utm +zone=7 +datum=WGS84 +units=ft"
UTM7_US_FT = "+proj=utm +zone=7 +datum=WGS84 +units=us-ft"


def in_feet(glacier, dst, crs, foot, units=None):
    """The glacier DEM truly in feet: its coordinates and (with ``units``) heights divided by the
    foot; without ``units`` the heights stay metres, unsaid."""
    import rasterio
    from rasterio.transform import Affine

    with rasterio.open(glacier) as s:
        t = s.transform
    return relabel(glacier, dst, crs=crs, transform=Affine.scale(1 / foot) @ t,
                   scale=1 / foot if units else 1.0, units=units)


@pytest.mark.parametrize("crs, foot, unit", [(UTM7_FT, 0.3048, "ft"),
                                             (UTM7_US_FT, 1200 / 3937, "us-ft")])
def test_a_dem_in_feet_is_read_in_metres_in_the_same_projection(tmp_path, glacier, caplog, crs,
                                                                foot, unit):
    ref = load_dem(glacier)
    with caplog.at_level("WARNING", logger="skyfix.dem"):
        dem = load_dem(in_feet(glacier, tmp_path / "feet.tif", crs, foot, units=unit))
    assert dem.crs_name == "EPSG:32607"  # the metric twin has its EPSG code
    assert dem.shape == ref.shape and abs(dem.dx - 20.0) < 1e-6 and abs(dem.dy - 20.0) < 1e-6
    assert abs(dem.x0 - ref.x0) < 1e-4 and abs(dem.y0 - ref.y0) < 1e-4
    assert np.nanmax(np.abs(dem.z - ref.z)) < 1e-3  # heights back in metres, cell for cell
    # the user's coordinates change unit: said, with the CRS they are now in
    assert "read in EPSG:32607, the same projection in metres" in caplog.text
    r = run("info", tmp_path / "feet.tif")
    assert r.exit_code == 0, r.output
    assert "work crs     EPSG:32607" in r.output and "heights      1684.6 .. 3165.2 m" in r.output


def test_a_dem_in_feet_with_heights_of_no_unit_is_refused_saying_how_to_say_it(tmp_path, glacier):
    """It said "target CRS unknown is not projected in metres: pass --crs", an option info,
    build-db and locate lack: feet heights in a feet CRS are as common as metres ones, so the
    unit is asked for, not guessed."""
    feet = in_feet(glacier, tmp_path / "feet.tif", UTM7_FT, 0.3048)
    for cmd in (["info", feet], ["build-db", feet, "-o", tmp_path / "db.zarr", "--bounds", 0, 0, 1, 1,
                                 "--spacing-m", 20]):
        r = run(*cmd)
        assert_clean_error(r, "feet.tif: its CRS +proj=", "+units=ft", "is in foot",
                           "does not say the unit of its heights", "gdal_edit.py -units ft",
                           "reads it in metres, in EPSG:32607")
        assert "--crs" not in r.output and "unknown" not in r.output
    with pytest.raises(DemError, match="is in US survey foot"):
        load_dem(in_feet(glacier, tmp_path / "usft.tif", UTM7_US_FT, 1200 / 3937))


def test_a_compound_crs_says_its_heights_are_in_feet(tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    z = np.linspace(3000.0, 3300.0, 400, dtype=np.float32).reshape(20, 20)
    path = tmp_path / "ca.tif"
    # California zone 3 (US feet) with NAVD88 heights in US feet: San Francisco
    with rasterio.open(path, "w", driver="GTiff", width=20, height=20, count=1, dtype="float32",
                       crs="EPSG:2227+6360", transform=from_origin(6_000_000, 2_100_000, 60, 60)) as d:
        d.write(z, 1)
    dem = load_dem(path)
    ft = 1200 / 3937
    assert dem.crs_name == "EPSG:26943" and abs(dem.dx - 60 * ft) < 1e-6
    assert np.allclose(dem.z, z * ft, atol=1e-3)


def test_a_crs_asked_for_in_feet_is_refused_naming_it(glacier):
    r = run("horizon", glacier, "--x", 601000, "--y", 6744000, "--crs", "EPSG:2227")
    assert_clean_error(r, "the CRS asked for, EPSG:2227, is not projected in metres",
                       "US survey foot")


# --- 3. degrees typed where metres are expected ----------------------------------------------------

LONLAT_HINT = "these look like longitude/latitude: give metres in the work CRS (`skyfix info"


def test_degrees_for_bounds_are_printed_as_typed_with_a_hint(tmp_path, glacier):
    """It said "corner (-139.2, 60.8) is outside the DEM": rounded to 0.1, no hint."""
    r = run("build-db", glacier, "-o", tmp_path / "x.zarr", "--bounds", -139.15, 60.80, -139.14,
            60.81, "--spacing-m", 20)
    assert_clean_error(r, "corner (-139.15, 60.81) is outside the DEM", LONLAT_HINT)
    assert "--lon" not in r.output  # build-db has no option for degrees
    assert not (tmp_path / "x.zarr").exists()


@pytest.mark.parametrize("cmd", ["heading", "horizon", "stack"])
def test_degrees_for_a_point_name_the_commands_options_for_degrees(tmp_path, glacier, cmd):
    where = ["--x", -139.13492, "--y", 60.81938]
    if cmd == "heading":  # refused before the profile is read
        (tmp_path / "p.json").write_text("{}")
        r = run("heading", "--profile", tmp_path / "p.json", "--dem", glacier, *where)
    else:
        r = run("horizon", glacier, *where, *(["--dem", glacier] if cmd == "stack" else []))
    assert_clean_error(r, "(-139.13492, 60.81938)", LONLAT_HINT, "or give them with --lon/--lat")


def test_locate_names_its_prior_options_for_degrees(tmp_path, glacier):
    (tmp_path / "p.json").write_text("{}")
    r = run("locate", "--profile", tmp_path / "p.json", "--dem", glacier, "--prior-x", -139.13492,
            "--prior-y", 60.81938, "--prior-radius-m", 100)
    assert_clean_error(r, "prior position (-139.13492, 60.81938)", LONLAT_HINT,
                       "or give them with --prior-lon/--prior-lat")


def test_no_degree_hint_where_metres_could_be_meant():
    from skyfix.workcrs import lonlat_hint

    far = (599010.0, 6741010.0, 603950.0, 6746990.0)
    assert lonlat_hint([-139.15], [60.81], far).startswith("; these look like longitude/latitude")
    assert lonlat_hint([599000.5], [6744000.0], far) == ""  # metres, just off the edge
    assert lonlat_hint([0.0], [0.0], far) == ""  # a placeholder origin, not a place
    # a DEM in a local CRS centred near its origin: small numbers are metres there
    assert lonlat_hint([8.5], [46.5], (-5000.0, -5000.0, 5000.0, 5000.0)) == ""


def test_a_prior_in_degrees_off_a_database_gets_the_hint():
    from types import SimpleNamespace

    from skyfix.cli.locate import _check_prior_area

    db = SimpleNamespace(x_coords=np.arange(599010.0, 603950.0, 100.0),
                         y_coords=np.arange(6746990.0, 6741010.0, -100.0))
    with pytest.raises(SkyfixError, match=r"prior area \(-139.13492, 60.81938\) \+- 100 m.*"
                                          "these look like longitude/latitude.*--prior-lon"):
        _check_prior_area(db, None, (-139.13492, 60.81938), 100.0)


# --- 4. info on a path that is not there -----------------------------------------------------------

@pytest.mark.parametrize("name, says", [
    ("nonexistent.tif", "DEM file {p} does not exist"),
    ("nonexistent", "no such file or folder: {p} (give a DEM or a skyline database)"),
    ("nonexistent.zarr", "database {p} does not exist: build it with `skyfix build-db`"),
])
def test_info_on_a_missing_path_assumes_a_database_only_for_zarr(tmp_path, name, says):
    """/nonexistent.tif was 'database /nonexistent.tif does not exist: build it with build-db'."""
    p = tmp_path / name
    r = run("info", p)
    assert_clean_error(r, says.format(p=p))
    if not name.endswith(".zarr"):
        assert "database" not in r.output.replace("skyline database", "")


# --- 5. a DEM of several bands; stacks whose members disagree or lie apart ------------------------

def test_a_second_band_is_said_to_be_ignored(tmp_path, glacier):
    import rasterio

    with rasterio.open(glacier) as s:
        profile, z = s.profile.copy(), s.read(1)
    profile.update(count=2)
    with rasterio.open(tmp_path / "two.tif", "w", **profile) as d:
        d.write(np.stack([z, z * 0]))
    r = run("info", tmp_path / "two.tif")
    assert r.exit_code == 0 and "two.tif has 2 bands: its heights are taken from band 1" in r.output


def test_a_stack_whose_heights_disagree_is_refused_naming_both(tmp_path, glacier):
    """B = A / 1000 (heights in km read as metres) was stacked without a word."""
    km = relabel(glacier, tmp_path / "km.tif", scale=1e-3)
    r = run("horizon", glacier, "--dem", km, "--x", 601000, "--y", 6744000)
    assert_clean_error(r, f"{km} and {glacier} disagree on heights where they overlap",
                       "lies 2,", "m below", "another unit", "another datum")
    from skyfix.stack import load_dems

    # 80 m one way: another datum (the geoid is up to 106 m from the ellipsoid)
    with pytest.raises(DemError, match="lies 80 m above"):
        load_dems([glacier, relabel(glacier, tmp_path / "up80.tif", offset=80.0)])
    # 30 m one way may be two surveys of one place: kept
    assert len(load_dems([glacier, relabel(glacier, tmp_path / "up30.tif", offset=30.0)]).members) == 2


def test_a_coarse_average_of_rugged_terrain_stacks(tmp_path):
    """The median |difference| of the Alps tile against its own 1 km average is 84 m: the check
    takes the signed median (4 m), which resolution leaves near 0."""
    import rasterio
    from rasterio.enums import Resampling

    from skyfix.stack import load_dems

    alps = shared_dem_path("alps_srtm3_n46e008")
    with rasterio.open(alps) as s:
        profile = s.profile.copy()
        h, w = s.height // 12, s.width // 12
        z = s.read(1, out_shape=(h, w), resampling=Resampling.average)
        profile.update(height=h, width=w,
                       transform=s.transform * s.transform.scale(s.width / w, s.height / h))
    with rasterio.open(tmp_path / "alps_1km.tif", "w", **profile) as d:
        d.write(z, 1)
    assert len(load_dems([alps, tmp_path / "alps_1km.tif"]).members) == 2


def test_unrelated_dems_are_refused_without_a_stretch_warning_first(glacier):
    alps = shared_dem_path("alps_srtm3_n46e008")
    r = run("horizon", glacier, "--dem", alps, "--x", 601000, "--y", 6744000)
    assert_clean_error(r, f"{alps} does not overlap {glacier}")
    assert "stretches distances" not in r.output and "WARNING" not in r.output


# --- 6. outputs on the kernel's file systems; counts of one -----------------------------------------

def _proc_is_procfs():
    from skyfix._io import _file_system_type

    return _file_system_type("/proc") == "proc"


@pytest.mark.skipif(not _proc_is_procfs(), reason="needs Linux's /proc")
def test_an_output_under_proc_says_why_it_cannot_be(tmp_path, glacier):
    """It said "folder /proc is not writable (No such file or directory)"."""
    why = "folder /proc is on the kernel's proc file system, which holds no files of yours"
    r = run("horizon", glacier, "--x", 601000, "--y", 6744000, "--plot", "/proc/h.png")
    assert_clean_error(r, "cannot write /proc/h.png: " + why)
    (tmp_path / "p.json").write_text("{}")
    r = run("locate", "--profile", tmp_path / "p.json", "--dem", glacier, "--prior-x", 601000,
            "--prior-y", 6744000, "--prior-radius-m", 100, "--geojson", "/proc/fix.geojson")
    assert_clean_error(r, "cannot write /proc/fix.geojson: " + why)
    r = run("build-db", glacier, "-o", "/proc/x.zarr", "--bounds", 600000, 6743000, 600100, 6743100,
            "--spacing-m", 50)
    assert_clean_error(r, "cannot write /proc/x.zarr: " + why)
    assert "No such file" not in r.output


def test_counts_of_one_are_singular(tmp_path, glacier):
    from skyfix.voids import VoidReport

    assert str(VoidReport(n_void=1, n_filled=1, fraction=0.001, n_outside=1)) == (
        "1 void cell (0.1 %): 1 filled, 0 left masked; 1 cell around the data (no terrain)")
    assert str(VoidReport(n_void=2, n_filled=2, fraction=0.002)).startswith("2 void cells")
    db = tmp_path / "one.zarr"
    r = run("build-db", glacier, "-o", db, "--bounds", 600000, 6743000, 600100, 6743100,
            "--spacing-m", 50, "--workers", 0, "--azimuth-bins", 64, "--no-progress")
    assert r.exit_code == 0 and f"{db}: 1 block (1 built now" in r.output, r.output
    r = run("info", db)
    assert "completeness 1 of 1 block (complete)" in r.output, r.output
    assert "coarse index 1 of 1 block (" in r.output
