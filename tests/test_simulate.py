"""Simulator: geometry against the horizon renderer, attitude conventions, truth files, sets, CLI."""

from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.camera import (Camera, az_el_to_direction, camera_from_fov, direction_to_az_el, get_camera,
                           r_world_cam)
from skyfix.cli.main import cli
from skyfix.dem import Dem, write_dem
from skyfix.errors import OutputExistsError, OutsideDemError, ParameterError
from skyfix.formats import Truth, load_acquisition, load_truth, read_skyline_json
from skyfix.horizon import render_horizons
from skyfix.raycast import Projection, camera_centre, cast_image, column_skyline
from skyfix.simulate import (SETS, Conditions, frame_pans, plan_set, simulate_acquisition,
                             simulate_set)


def hills_dem(n=160, spacing=30.0, seed=1) -> Dem:
    """Rolling hills with a few sharp ridges: skylines at many distances and slopes."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0:n] * spacing
    z = np.zeros((n, n))
    ext = n * spacing
    for _ in range(18):
        cx, cy = rng.uniform(0, ext, 2)
        s = rng.uniform(0.03, 0.12) * ext
        z += rng.uniform(60, 500) * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    z += 40 * np.abs(np.sin(xx / 700.0 + yy / 1300.0))  # creases: kinks on cell edges
    return Dem.from_array(z, spacing)


@pytest.fixture(scope="module")
def hills():
    return hills_dem()


def peak_dem(peak_xy=(800.0, 500.0), height=80.0):
    """A flat plain, 1 km square at 10 m, with one narrow peak; the rover sits at (500, 500)."""
    n = 101
    yy, xx = np.mgrid[0:n, 0:n] * 10.0
    yy = (n - 1) * 10.0 - yy  # row 0 is north
    z = height * np.exp(-((xx - peak_xy[0]) ** 2 + (yy - peak_xy[1]) ** 2) / (2 * 25.0**2))
    return Dem.from_array(z, 10.0)


def horizon_rows(dem, x, y, cam: Camera, yaw, pan=0.0, bins=36000):
    """Independent prediction: the horizon renderer's profile projected through a level camera."""
    hb = render_horizons(dem, x, y, azimuth_bins=bins)
    xn = (np.arange(cam.width) - cam.cx) / cam.fx
    az = (yaw + pan + np.degrees(np.arctan(xn))) % 360
    el = np.interp(az, hb.azimuth_deg, hb.elevation_deg[0], period=360)
    # A level pinhole column is a vertical plane: d_cam = (xn, yn, 1) has tan(el) = -yn / hypot(xn, 1).
    return cam.cy - cam.fy * np.tan(np.radians(el)) * np.hypot(xn, 1.0)


def render_rows(dem, truth: Truth, cam: Camera, pan=0.0, tilt=0.0, rocks=None):
    origin = camera_centre(dem, truth.x, truth.y, 1.5)
    proj = Projection.frame(cam, truth.yaw_deg, truth.pitch_deg, truth.roll_deg, pan, tilt)
    cast = cast_image(dem, origin, proj, rocks=rocks)
    return column_skyline(dem, origin, proj, ~np.isfinite(cast.terrain_t)), cast


# --- geometry ------------------------------------------------------------------------------------

@pytest.mark.parametrize("yaw", [0.0, 137.0, 251.5])
def test_nominal_frame_matches_projected_horizon(hills, yaw):
    cam = get_camera("navcam")
    x, y = 2400.3, 2210.7
    rows, _ = render_rows(hills, Truth(x, y, yaw), cam)
    pred = horizon_rows(hills, x, y, cam, yaw)
    in_frame = (pred >= 0) & (pred <= cam.height - 1)
    assert in_frame.sum() > 0.6 * cam.width
    assert np.mean(np.abs(rows[in_frame] - pred[in_frame]) <= 1.0) >= 0.99  # NaN rows count as misses
    # Where the predicted skyline lies above the frame, the column has no skyline.
    assert np.all(np.isnan(rows[pred < -1.0]))


def test_written_truth_file_matches_horizon_renderer(hills, tmp_path):
    cam = get_camera("navcam")
    t = Truth(1800.0, 3000.0, 40.0)
    out = simulate_acquisition(hills, t, tmp_path / "acq", frames=1, pan_start_deg=10.0, seed=2)
    sky = read_skyline_json(out / "frame_000.skyline.json")
    assert (sky.width, sky.height, sky.image) == (cam.width, cam.height, "frame_000.png")
    pred = horizon_rows(hills, t.x, t.y, cam, t.yaw_deg, pan=10.0)
    ok = np.isfinite(sky.rows) & np.isfinite(pred)
    assert ok.mean() > 0.95
    assert np.mean(np.abs(sky.rows[ok] - pred[ok]) <= 1.0) >= 0.99


@pytest.mark.parametrize("attitude", [(5.0, -7.0, 10.0, 4.0), (-8.0, 9.0, -25.0, -3.0)])
def test_tilted_distorted_skyline_rays_lie_on_the_rendered_horizon(hills, attitude):
    """Any attitude and a distorted lens: each skyline point's ray has the horizon's elevation."""
    pitch, roll, pan, tilt = attitude
    cam = camera_from_fov(320, 240, 90.0, get_camera("wide").distortion)
    t = Truth(2500.0, 2500.0, 75.0, pitch, roll)
    rows, _ = render_rows(hills, t, cam, pan=pan, tilt=tilt)
    cols = np.flatnonzero(np.isfinite(rows))
    assert cols.size > 0.9 * cam.width
    d_cam = cam.pixel_to_ray(cols.astype(float), rows[cols])
    d = d_cam @ r_world_cam(t.yaw_deg, pitch, roll, pan, tilt).T
    az, el = direction_to_az_el(d)
    hb = render_horizons(hills, t.x, t.y, azimuth_bins=36000)
    el_h = np.interp(az, hb.azimuth_deg, hb.elevation_deg[0], period=360)
    px_per_deg = cam.fy * np.pi / 180
    assert np.mean(np.abs(el - el_h) * px_per_deg <= 1.0) >= 0.99


def test_panorama_rows_match_horizon_and_spec(hills, tmp_path):
    t = Truth(2000.0, 2600.0, 30.0)
    out = simulate_acquisition(hills, t, tmp_path / "pano", mode="panorama", pano_size=(720, 180),
                               seed=1)
    acq = load_acquisition(out)
    spec = acq.panorama
    assert acq.frames == () and spec.image == "pano.png" and spec.hfov_deg == 360.0
    sky = read_skyline_json(out / "pano.skyline.json")
    W, H = 720, 180
    # Pixel centres at (j + 0.5, i + 0.5) of the angular grid, azimuth from the rover's forward axis.
    az_body = spec.azimuth_left_deg + (np.arange(W) + 0.5) * spec.hfov_deg / W
    hb = render_horizons(hills, t.x, t.y, azimuth_bins=36000)
    el = np.interp((az_body + t.yaw_deg) % 360, hb.azimuth_deg, hb.elevation_deg[0], period=360)
    pred = (spec.elevation_top_deg - el) / (spec.vfov_deg / H) - 0.5
    assert np.isfinite(sky.rows).all()
    assert np.max(np.abs(sky.rows - pred)) < 0.3


def test_panorama_is_levelled_in_the_body_frame(hills):
    """With roll, a body-frame panorama shows the world horizon as a sine across azimuth."""
    from skyfix.formats import PanoramaSpec

    t = Truth(2000.0, 2600.0, 0.0, 0.0, 8.0)
    spec = PanoramaSpec("p.png", -180.0, 360.0, 45.0, 90.0)
    W, H = 720, 360
    origin = camera_centre(hills, t.x, t.y, 1.5)
    proj = Projection.panorama(spec, W, H, t.yaw_deg, t.pitch_deg, t.roll_deg)
    cast = cast_image(hills, origin, proj)
    rows = column_skyline(hills, origin, proj, ~np.isfinite(cast.terrain_t))
    flat = Projection.panorama(spec, W, H, 0.0, 0.0, 0.0)
    cast0 = cast_image(hills, origin, flat)
    rows0 = column_skyline(hills, origin, flat, ~np.isfinite(cast0.terrain_t))
    d = (rows - rows0) * (90.0 / H)  # [deg] how much lower the skyline sits when rolled
    az = -180.0 + (np.arange(W) + 0.5) * 360.0 / W
    # Right side down: to the right (az 90) the world's horizon rises in the body frame.
    k90, km90 = np.argmin(np.abs(az - 90)), np.argmin(np.abs(az + 90))
    assert d[k90] < -6 and d[km90] > 6
    assert abs(d[np.argmin(np.abs(az))]) < 1.5


# --- conventions ---------------------------------------------------------------------------------

def peak_column(rows):
    return int(np.nanargmin(rows))


@pytest.fixture(scope="module")
def east_peak():
    return peak_dem((800.0, 500.0))


CAM = camera_from_fov(401, 301, 60.0)


def test_peak_due_east_seen_with_yaw_and_pan(east_peak):
    fx, cx = CAM.fx, CAM.cx
    rows, _ = render_rows(east_peak, Truth(500.0, 500.0, 0.0), CAM, pan=90.0)
    assert abs(peak_column(rows) - cx) <= 2
    rows, _ = render_rows(east_peak, Truth(500.0, 500.0, 90.0), CAM)
    assert abs(peak_column(rows) - cx) <= 2
    # Facing 70 deg, the peak (az 90) is 20 deg to the right.
    rows, _ = render_rows(east_peak, Truth(500.0, 500.0, 70.0), CAM)
    assert abs(peak_column(rows) - (cx + fx * np.tan(np.radians(20)))) <= 2
    # Pan clockwise by 40 from heading 70: the peak is now 20 deg to the left.
    rows, _ = render_rows(east_peak, Truth(500.0, 500.0, 70.0), CAM, pan=40.0)
    assert abs(peak_column(rows) - (cx - fx * np.tan(np.radians(20)))) <= 2


def test_tilt_and_pitch_up_move_the_skyline_down(east_peak):
    t = Truth(500.0, 500.0, 90.0)
    base, _ = render_rows(east_peak, t, CAM)
    up, _ = render_rows(east_peak, t, CAM, tilt=10.0)
    nose_up, _ = render_rows(east_peak, Truth(500.0, 500.0, 90.0, 10.0, 0.0), CAM)
    c = int(CAM.cx)
    assert base[c] < CAM.cy - 30  # the peak, well above the level line
    # Raising the optical axis by 10 deg moves a point at elevation e from fy tan(e) to
    # fy tan(e - 10) above the centre row.
    e = np.arctan((CAM.cy - base[c]) / CAM.fy)
    shift = CAM.fy * (np.tan(e) - np.tan(e - np.radians(10)))
    assert up[c] - base[c] == pytest.approx(shift, abs=1.0)
    assert nose_up[c] - base[c] == pytest.approx(shift, abs=1.0)


def _slope(rows):
    cols = np.arange(rows.size)
    ok = np.isfinite(rows)
    # Fit away from the peak (due east, near the centre column at yaw 90).
    ok &= np.abs(cols - rows.size / 2) > rows.size * 0.2
    return np.polyfit(cols[ok], rows[ok], 1)[0]


def test_roll_right_side_down_raises_the_right_of_the_skyline(east_peak):
    t0 = _slope(render_rows(east_peak, Truth(500.0, 500.0, 90.0), CAM)[0])
    rolled = _slope(render_rows(east_peak, Truth(500.0, 500.0, 90.0, 0.0, 6.0), CAM)[0])
    assert abs(t0) < 0.01
    # Right side down: the image turns clockwise, the world's horizon rises on the right
    # (smaller rows), with slope about -tan(roll).
    assert rolled == pytest.approx(-np.tan(np.radians(6)), rel=0.15)
    # Pitch nose-up looking right (pan 90): forward is on the image's left and goes up.
    side = _slope(render_rows(east_peak, Truth(500.0, 500.0, 0.0, 6.0, 0.0), CAM, pan=90.0)[0])
    assert side == pytest.approx(-np.tan(np.radians(6)), rel=0.15)


def test_curvature_lowers_distant_terrain():
    """A 1000 m wall 30 km away: its elevation drops by coeff * d on Mars versus a huge planet."""
    n = 70
    z = np.zeros((n, n))
    z[:, -3:] = 1000.0
    dem = Dem.from_array(z, 500.0)
    cam = camera_from_fov(201, 201, 20.0)
    x, y = 1000.0, (n - 1) * 250.0
    rows = {}
    for planet in ("mars", 1e12):
        origin = camera_centre(dem, x, y, 1.5)
        proj = Projection.frame(cam, 90.0, 0, 0, 0, 0)
        cast = cast_image(dem, origin, proj, planet=planet)
        rows[planet] = column_skyline(dem, origin, proj, ~np.isfinite(cast.terrain_t), planet=planet)
    d = (n - 3) * 500.0 - x
    from skyfix.planets import MARS
    drop_deg = np.degrees(MARS.curvature_coeff * d)
    c = 100
    shift = rows["mars"][c] - rows[1e12][c]
    assert shift == pytest.approx(cam.fy * np.tan(np.radians(drop_deg)), rel=0.05)


# --- acquisitions --------------------------------------------------------------------------------

def test_frame_pans():
    nav = get_camera("navcam")
    assert frame_pans(nav) == [30.0 * k for k in range(12)]
    assert frame_pans(nav, 3) == [-30.0, 0.0, 30.0]
    assert frame_pans(get_camera("wide")) == [60.0 * k for k in range(6)]
    with pytest.raises(ParameterError):
        frame_pans(nav, 14)


def test_acquisition_files_and_truth(hills, tmp_path):
    cam = camera_from_fov(160, 120, 45.0)
    t = Truth(2100.5, 2300.25, 12.0, 2.0, -1.0)
    out = simulate_acquisition(hills, t, tmp_path / "a", camera=cam, frames=3, pan_step_deg=30,
                               attitude_prior=(0.0, 0.0), seed=4)
    acq = load_acquisition(out)
    assert [f.pan_deg for f in acq.frames] == [-30.0, 0.0, 30.0]
    assert acq.camera == cam and (acq.prior_pitch_deg, acq.prior_roll_deg) == (0.0, 0.0)
    assert load_truth(out) == t
    import cv2

    for f in acq.frames:
        img = cv2.imread(str(out / f.image), cv2.IMREAD_UNCHANGED)
        assert img.shape == (120, 160, 3) and img.dtype == np.uint8
        raw = json.loads((out / f.image.replace(".png", ".skyline.json")).read_text())
        assert len(raw["rows"]) == 160 and raw["height"] == 120
    with pytest.raises(OutputExistsError):
        simulate_acquisition(hills, t, out, camera=cam, frames=1)
    simulate_acquisition(hills, t, out, camera=cam, frames=1, overwrite=True)
    assert sorted(p.name for p in out.glob("*.png")) == ["frame_000.png"]


def test_rocks_cut_the_skyline_and_are_written_apart(hills, tmp_path):
    cam = camera_from_fov(256, 192, 60.0)
    out = simulate_acquisition(hills, Truth(2500.0, 2500.0, 0.0), tmp_path / "r", camera=cam,
                               frames=3, conditions="rocks", seed=3)
    cut = 0
    for k in range(3):
        terr = read_skyline_json(out / f"frame_{k:03d}.skyline.json").rows
        vis = read_skyline_json(out / f"frame_{k:03d}.visible.skyline.json").rows
        both = np.isfinite(terr) & np.isfinite(vis)
        # Rocks only hide terrain: the visible skyline is never below the terrain one.
        assert np.all(vis[both] <= terr[both] + 1e-3)
        cut += int(np.sum(vis[both] < terr[both] - 2))
    assert cut > 20
    meta = json.loads((out / "acquisition.json").read_text())["simulation"]
    assert len(meta["rocks"]) >= 4


def test_rock_silhouette_matches_ellipsoid():
    """On a flat plain, a sphere's visible outline is where its tangent cone meets the column."""
    dem = Dem.from_array(np.zeros((41, 41)), 10.0)
    cam = camera_from_fov(201, 201, 40.0)
    t = Truth(200.0, 200.0, 0.0)
    rock = np.array([[200.0, 210.0, 1.5, 1.0, 1.0]])  # centre at camera height, 10 m north
    rows, cast = render_rows(dem, t, cam, rocks=rock)
    vis = column_skyline(dem, camera_centre(dem, 200, 200, 1.5), Projection.frame(cam, 0, 0, 0, 0, 0),
                         cast.kind == 0, rocks=rock)
    c = 100  # the centre column looks straight at the rock: top tangent at asin(r / d) above level
    expected = cam.cy - cam.fy * np.tan(np.arcsin(1.0 / 10.0))
    assert vis[c] == pytest.approx(expected, abs=0.05)
    assert rows[c] > cam.cy  # the plain's own skyline is just below the level line


def test_looks_sky_colours_and_exposure(hills, tmp_path):
    import cv2

    cam = camera_from_fov(160, 120, 45.0)
    t = Truth(2400.0, 2400.0, 200.0)
    means = {}
    for name, planet, cond in (("e", "earth", None), ("m", "mars", None), ("dark", "earth", "dark"),
                               ("over", "earth", "overexposed:0.7")):
        out = simulate_acquisition(hills, t, tmp_path / name, camera=cam, frames=1, planet=planet,
                                   conditions=cond, seed=1, tilt_deg=10)
        rgb = cv2.imread(str(out / "frame_000.png"))[..., ::-1].astype(float)
        rows = read_skyline_json(out / "frame_000.skyline.json").rows
        vv = np.arange(cam.height)[:, None]
        sky = vv < np.nan_to_num(rows, nan=0)[None, :] - 3
        means[name] = (rgb[sky].mean(axis=0), rgb.mean())
    assert means["e"][0][2] > means["e"][0][0] + 20  # Earth sky is blue
    assert means["m"][0][0] > means["m"][0][2] + 20  # Mars sky is butterscotch
    assert means["dark"][1] < 0.6 * means["e"][1] < means["over"][1]


def test_ground_is_rougher_than_the_sky(hills, tmp_path):
    """Real mosaics (the Curiosity dev set) have 10-20x more local gradient in terrain than in
    the sky; a DEM's smooth bilinear facets alone give ~2x, which no real image shows."""
    import cv2

    cam = camera_from_fov(400, 300, 45.0)
    out = simulate_acquisition(hills, Truth(2400.0, 2400.0, 200.0), tmp_path / "r", camera=cam,
                               frames=1, seed=2, tilt_deg=10)
    g = cv2.imread(str(out / "frame_000.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    g = cv2.GaussianBlur(g, (0, 0), 1.0)  # the measure of the dev-set figures: sensor noise damped
    mag = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))
    rows = read_skyline_json(out / "frame_000.skyline.json").rows
    vv = np.arange(cam.height)[:, None]
    sky = vv < np.nan_to_num(rows, nan=0)[None, :] - 3
    ground = vv > np.nan_to_num(rows, nan=cam.height)[None, :] + 3
    assert sky.sum() > 5000 and ground.sum() > 5000
    # measured: 5.9x with the sub-DEM roughness, 2.2x without
    assert np.median(mag[ground]) > 4 * np.median(mag[sky])


def test_slope_in_its_own_shadow_keeps_its_texture(tmp_path):
    """A 35 deg slope facing the camera, the sun 20 deg up behind it: only sky light reaches it.
    Real shaded slopes still show stones and soil (albedo is multiplicative, so its relative
    contrast is the same in shadow); a smooth one read as sky to the detector -- the scenario-1
    misses of the example report were such slopes filling whole frames."""
    import cv2

    yy, xx = np.mgrid[0:200, 0:200] * 10.0
    dem = Dem.from_array(np.clip(1000.0 - yy, 0, None) * math.tan(math.radians(35)), 10.0)
    cam = camera_from_fov(400, 300, 45.0)
    rel = {}
    for name, sun_az in (("shadow", 0.0), ("sunlit", 180.0)):
        out = simulate_acquisition(dem, Truth(1000.0, 880.0, 0.0), tmp_path / name, camera=cam,
                                   frames=1, seed=2, sun_el_deg=20.0, sun_az_deg=sun_az)
        g = cv2.imread(str(out / "frame_000.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        g = cv2.GaussianBlur(g, (0, 0), 1.0)[20:120, 50:350]  # all slope
        mag = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))
        rel[name] = (np.median(mag) / np.median(g), np.median(g))
    assert rel["shadow"][1] < 0.7 * rel["sunlit"][1]  # the set-up: it is in shadow
    # relative texture [1/px]; measured 0.137 in shadow (0.134 sunlit); 0.062 with +-6 % albedo
    assert rel["shadow"][0] > 0.1
    assert rel["shadow"][0] > 0.6 * rel["sunlit"][0]


@pytest.mark.parametrize("yaw, conditions", [(0.0, None), (200.0, "lake:0.5")])
def test_overlapping_frames_agree(hills, tmp_path, yaw, conditions):
    """World-fixed texture: the same direction looks the same in two overlapping frames (with a
    lake too: a fifth of this view is water, its level and ripples fixed in the world)."""
    import cv2

    cam = camera_from_fov(300, 200, 45.0)
    out = simulate_acquisition(hills, Truth(2400.0, 2400.0, yaw), tmp_path / "o", camera=cam,
                               frames=2, pan_start_deg=0, pan_step_deg=20, seed=5, tilt_deg=-10,
                               conditions=conditions)
    a, b = (cv2.imread(str(out / f"frame_00{k}.png"), cv2.IMREAD_GRAYSCALE).astype(float) for k in range(2))
    # High-pass: vignetting differs between the frames (smooth), texture must not.
    a, b = (im - cv2.GaussianBlur(im, (0, 0), 6) for im in (a, b))
    vv, uu = np.mgrid[20:180:3, 20:280:3]
    r0 = r_world_cam(0, 0, 0, 0, -10)
    r1 = r_world_cam(0, 0, 0, 20, -10)
    d = cam.pixel_to_ray(uu, vv) @ r1.T @ r0  # frame-1 rays in frame-0 camera axes
    u0, v0, front = cam.ray_to_pixel(d)
    inside = front & (u0 > 20) & (u0 < cam.width - 20) & (v0 > 20) & (v0 < cam.height - 20)
    assert inside.sum() > 300
    same = b[vv[inside], uu[inside]]
    there = a[np.round(v0[inside]).astype(int), np.round(u0[inside]).astype(int)]
    agree, control = np.corrcoef(same, there)[0, 1], np.corrcoef(same, np.roll(there, 37))[0, 1]
    assert agree > 0.6
    # out of register nothing agrees but the large shapes: the shoreline's edge keeps 0.28
    assert abs(control) < (0.2 if conditions is None else 0.35) and agree > control + 0.4


# --- conditions and sets -------------------------------------------------------------------------

def test_conditions_parse():
    c = Conditions.parse("dust:0.5, rocks")
    assert (c.dust, c.rocks, c.glare) == (0.5, 1.0, 0.0)
    assert str(c) == "dust:0.5,rocks:1"
    with pytest.raises(ParameterError, match="unknown condition"):
        Conditions.parse("smoke")
    with pytest.raises(ParameterError, match=r"\[0, 1\]"):
        Conditions.parse("dust:2")
    with pytest.raises(ParameterError, match="Earth"):
        simulate_acquisition(hills_dem(20), Truth(300, 300, 0), "/nonexistent/x", planet="mars",
                             conditions="clouds")


def test_every_condition_renders(hills, tmp_path):
    cam = camera_from_fov(96, 64, 45.0)
    for name in Conditions.names():
        planet = "earth"
        out = simulate_acquisition(hills, Truth(2400.0, 2400.0, 0.0), tmp_path / name, camera=cam,
                                   frames=1, conditions=name, planet=planet, seed=1)
        assert (out / "frame_000.png").is_file()


# Each condition against the same frame without it (same seed, pose and sun: the sensor noise
# draws are the same too, so unchanged pixels come out identical).

COND_CAM = camera_from_fov(200, 150, 60.0)


def render_frame(dem, truth, out, conditions=None, cam=COND_CAM, **kw):
    """One frame: (RGB as float, terrain skyline truth rows, acquisition folder)."""
    import cv2

    out = simulate_acquisition(dem, truth, out, camera=cam, frames=1, conditions=conditions,
                               seed=1, **kw)
    rgb = cv2.imread(str(out / "frame_000.png"))[..., ::-1].astype(float)
    return rgb, read_skyline_json(out / "frame_000.skyline.json").rows, out


def band(rows, lo, hi, height=COND_CAM.height):
    """Pixels lo..hi rows below each column's skyline (negative: above it)."""
    v = np.arange(height)[:, None]
    r = np.nan_to_num(rows, nan=-1e6)[None, :]
    return (v >= r + lo) & (v <= r + hi)


def test_dust_hazes_distant_terrain_towards_the_sky(hills, tmp_path):
    """Dust shortens the haze distance (distant terrain takes the horizon sky's colour, near
    terrain keeps its own) and flattens the sky towards the dust colour (a less blue sky)."""
    t = Truth(2400.0, 2400.0, 200.0)
    m = {}
    for c in (None, "dust:0.5", "dust:1"):
        rgb, rows, _ = render_frame(hills, t, tmp_path / str(c), c, tilt_deg=10)
        g = rgb.mean(axis=2)
        sky, far = g[band(rows, -12, -4)].mean(), g[band(rows, 4, 12)].mean()
        assert np.nanmin(rows) > 40 and np.nanmax(rows) < 110  # the set-up: near terrain below
        near = g[-10:].mean()  # the frame's bottom rows: ground tens of metres away
        blue = (rgb[..., 2] - rgb[..., 0])[band(rows, -1000, -4)].mean()
        m[c] = dict(sky=sky, far=far, near=near, contrast=(sky - far) / (sky + far), blue=blue)
    n, d5, d1 = m[None], m["dust:0.5"], m["dust:1"]
    # Contrast across the skyline falls with strength (measured 0.29, 0.25, 0.15).
    assert n["contrast"] > d5["contrast"] + 0.02 and d5["contrast"] > d1["contrast"] + 0.05
    # The terrain just below the skyline, kilometres away, brightens towards the sky
    # (measured 110 -> 123 -> 151 of 255) ...
    assert d5["far"] > n["far"] + 6 and d1["far"] > d5["far"] + 15
    assert d1["far"] < d1["sky"]
    # ... the near ground hardly at all: the haze grows with distance, it is no global brightening.
    assert abs(d1["near"] - n["near"]) < 2
    # The sky whitens towards the dust colour (blue minus red measured 53, 34, 12).
    assert n["blue"] > d5["blue"] + 10 and d5["blue"] > d1["blue"] + 10


def test_clouds_texture_the_sky_and_leave_the_terrain(hills, tmp_path):
    import cv2

    t = Truth(2400.0, 2400.0, 200.0)
    res = {}
    for c in (None, "clouds:0.5", "clouds:1"):
        rgb, rows, _ = render_frame(hills, t, tmp_path / str(c), c, tilt_deg=10)
        res[c] = rgb.mean(axis=2), rows
    g0, rows = res[None]
    sky, ground = band(rows, -1000, -4), band(rows, 4, 1000)
    assert sky.sum() > 5000 and ground.sum() > 5000
    changed = {}
    for c in ("clouds:0.5", "clouds:1"):
        g = res[c][0]
        # Terrain below the skyline: the very same pixels (the noise draws are the same too).
        np.testing.assert_array_equal(g[ground], g0[ground])
        # Local texture in the sky: high-passed std measured 1.4 clear, 2.9 and 2.6 cloudy.
        hp0, hp = (im - cv2.blur(im, (7, 7)) for im in (g0, g))
        assert hp[sky].std() > 1.5 * hp0[sky].std()
        changed[c] = np.mean(np.abs(g - g0)[sky] > 8)
    # A stronger condition covers more of the sky (measured 68 % and 91 % of sky pixels).
    assert 0.3 < changed["clouds:0.5"] < changed["clouds:1"] - 0.1


def test_snow_whitens_the_summits_first_and_leaves_the_sky(hills, tmp_path):
    """Snow lies above a snow line that falls with strength: at 0.5 the terrain just below the
    skyline (summits, hundreds of metres above the camera) whitens towards the sky while the
    ground at the camera's feet keeps its very pixels; at 1 that ground whitens too. The sky is
    untouched."""
    t = Truth(2400.0, 2400.0, 200.0)
    res = {c: render_frame(hills, t, tmp_path / str(c), c, tilt_deg=10)[:2]
           for c in (None, "snow:0.5", "snow:1")}
    g0, rows = res[None][0].mean(axis=2), res[None][1]
    sky, summit = band(rows, -1000, -4), band(rows, 3, 10)
    assert sky.sum() > 5000 and summit.sum() > 1000
    g5, g1 = (res[c][0].mean(axis=2) for c in ("snow:0.5", "snow:1"))
    for g in (g5, g1):
        np.testing.assert_array_equal(g[sky], g0[sky])
    # Below the skyline: measured 109 bare, 126 at 0.5, 162 at 1, against a sky of 198.
    assert g5[summit].mean() > g0[summit].mean() + 8 and g1[summit].mean() > g5[summit].mean() + 20
    assert g1[summit].mean() < g0[band(rows, -12, -4)].mean()
    # The bottom rows, ground by the camera: unchanged at 0.5, measured 112 -> 175 at 1.
    np.testing.assert_array_equal(g5[-10:], g0[-10:])
    assert g1[-10:].mean() > g0[-10:].mean() + 30


def test_a_lake_mirrors_the_sky_below_the_skyline_and_leaves_the_truth(hills, tmp_path):
    """The lake fills the ground under its level with water that mirrors the sky: smooth, bluish
    and bright where the terrain was rough and brown. The sky's pixels and the skyline truth are
    untouched; the level lies under the rover's feet."""
    import cv2

    from skyfix.simulate.scene import lake_level

    t = Truth(2400.0, 2400.0, 200.0)
    (g0, rows0, out0), (g1, rows1, out1) = (
        render_frame(hills, t, tmp_path / str(c), c, tilt_deg=5) for c in (None, "lake:0.5"))
    np.testing.assert_array_equal(rows1, rows0)
    sky = band(rows0, -1000, -4)
    np.testing.assert_array_equal(g1[sky], g0[sky])
    level = lake_level(hills, t.x, t.y, 0.5)
    assert level <= float(hills.height_at(t.x, t.y)) - 0.3
    changed = np.any(g1 != g0, axis=2) & band(rows0, 4, 1000)
    assert changed.mean() > 0.1  # this view looks down on a valley floor (measured 16 %)
    blue = g1[..., 2] - g1[..., 0]  # blue minus red: measured 27 over the water, -15 bare
    assert blue[changed].mean() > (g0[..., 2] - g0[..., 0])[changed].mean() + 20
    # smooth: high-passed grey std over the water against the same pixels bare (1.8 and 5.6)
    hp0, hp1 = (im.mean(axis=2) - cv2.blur(im.mean(axis=2), (7, 7)) for im in (g0, g1))
    inner = cv2.erode(changed.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert inner.sum() > 500 and hp1[inner].std() < 0.5 * hp0[inner].std()


def test_earth_only_conditions_are_refused_on_mars(hills, tmp_path):
    for c in ("clouds", "snow:0.4", "lake"):
        with pytest.raises(ParameterError, match=f"{c.split(':')[0]} condition is for Earth only"):
            simulate_acquisition(hills, Truth(2400.0, 2400.0, 0.0), tmp_path / c, frames=1,
                                 conditions=c, planet="mars", seed=1)
    assert not any(tmp_path.iterdir())  # refused before anything was written


def test_glare_brightens_towards_the_sun(hills, tmp_path):
    """Veiling glare falls off with the angle from the sun. The sun sits 8 deg behind a ridge
    (skyline at 20 deg elevation at azimuth 156) so that the pixels around it are unsaturated
    terrain; the brightening is measured in linear units against the same frame without glare."""
    t, sun, tilt = Truth(2400.0, 2400.0, 156.0), (156.0, 12.0), 10.0
    lin = {}
    for c in (None, "glare:0.3", "glare:0.6"):
        rgb, rows, _ = render_frame(hills, t, tmp_path / str(c), c, tilt_deg=tilt,
                                    sun_az_deg=sun[0], sun_el_deg=sun[1])
        lin[c] = (rgb.mean(axis=2) / 255.0) ** 2.2
    vv, uu = np.mgrid[0:COND_CAM.height, 0:COND_CAM.width].astype(float)
    d = COND_CAM.pixel_to_ray(uu, vv) @ r_world_cam(t.yaw_deg, 0, 0, 0, tilt).T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(d @ az_el_to_direction(*sun), -1, 1)))
    ground = band(rows, 4, 1000)
    rings = [(0, 3), (3, 6), (6, 10), (10, 20), (20, 40)]
    rise = {}
    for c in ("glare:0.3", "glare:0.6"):
        diff = lin[c] - lin[None]
        rise[c] = np.array([diff[ground & (ang >= lo) & (ang < hi)].mean() for lo, hi in rings])
        # Brighter everywhere, most near the sun and less with every ring outwards
        # (measured 0.26, 0.12, 0.075, 0.036, 0.015 at strength 0.3).
        assert np.all(rise[c] > 0) and np.all(np.diff(rise[c]) < 0)
        assert rise[c][0] > 8 * rise[c][-1]
    # Strength scales the veil: twice the strength, about twice the added light (unsaturated).
    np.testing.assert_allclose(rise["glare:0.6"][1:] / rise["glare:0.3"][1:], 2.0, rtol=0.15)


def test_glare_puts_the_sun_in_view(hills, tmp_path):
    cam = camera_from_fov(64, 48, 60.0)
    t = Truth(2400.0, 2400.0, 40.0)
    for c in (None, "glare:0.5"):
        out = simulate_acquisition(hills, t, tmp_path / str(c), camera=cam, frames=1, conditions=c,
                                   seed=3)
        sun = json.loads((out / "acquisition.json").read_text())["simulation"]["sun"]
        d_cam = r_world_cam(t.yaw_deg, 0, 0, 0, 0).T @ az_el_to_direction(sun["azimuth_deg"],
                                                                          sun["elevation_deg"])
        u, v, front = cam.ray_to_pixel(d_cam)
        in_view = bool(front and 0 <= u < cam.width and 0 <= v < cam.height)
        assert in_view == (c is not None), (c, sun)


def test_blur_softens_the_skyline_but_not_its_truth(hills, tmp_path):
    t = Truth(2400.0, 2400.0, 200.0)
    steepest, truth = {}, {}
    for c in (None, "blur:0.5", "blur:1"):
        rgb, rows, _ = render_frame(hills, t, tmp_path / str(c), c, tilt_deg=10)
        # The largest vertical step per column (the skyline edge), median over columns.
        steepest[c] = np.median(np.abs(np.diff(rgb.mean(axis=2), axis=0)).max(axis=0))
        truth[c] = rows
    # measured 46, 15, 10 grey levels per pixel
    assert steepest["blur:0.5"] < 0.5 * steepest[None]
    assert steepest["blur:1"] < 0.8 * steepest["blur:0.5"]
    for c in ("blur:0.5", "blur:1"):
        np.testing.assert_array_equal(truth[c], truth[None])


def test_blur_streak_is_horizontal(tmp_path):
    """Motion blur is a horizontal streak on top of (isotropic) defocus: it widens a slanted
    edge more than a level one. A flat plain's horizon, level and then rolled 40 deg, measured
    as the edge's width across it (step over steepest slope of the mean profile)."""
    dem = Dem.from_array(np.zeros((201, 201)), 20.0)
    cam = COND_CAM

    def edge_width(rgb, rows):
        g = (rgb.mean(axis=2) / 255.0) ** 2.2
        c = np.arange(cam.width)
        s, r0 = np.polyfit(c[np.isfinite(rows)], rows[np.isfinite(rows)], 1)
        vv, uu = np.mgrid[0:cam.height, 0:cam.width]
        n = (vv - (s * uu + r0)) / np.hypot(1.0, s)  # signed distance below the horizon [px]
        inner = (uu > 10) & (uu < cam.width - 10) & (vv > 10) & (vv < cam.height - 10) & (np.abs(n) < 16)
        k = np.round(n[inner]).astype(int) + 16
        prof = np.bincount(k, g[inner]) / np.bincount(k)
        return s, (prof[0] - prof[-1]) / np.max(-np.diff(prof))

    w = {}
    for c in (None, "blur:0.5", "blur:1"):
        for roll in (0.0, 40.0):
            rgb, rows, _ = render_frame(dem, Truth(2000.0, 2000.0, 0.0, 0.0, roll),
                                        tmp_path / f"{c}_{roll}", c, cam=cam)
            s, w[c, roll] = edge_width(rgb, rows)
            assert abs(np.degrees(np.arctan(s)) + roll) < 1.0  # the set-up: horizon tilted by roll
    # Blur widens the level edge (measured 1.4, 5.0, 9.0 px) ...
    assert w["blur:0.5", 0.0] > 2.5 * w[None, 0.0] and w["blur:1", 0.0] > 1.5 * w["blur:0.5", 0.0]
    # ... and the slanted one further: a horizontal streak of sigma s adds s sin(40 deg) across
    # it, in quadrature (measured 6.4 vs 5.0 and 11.4 vs 9.0 px; defocus alone gives 1.02x).
    for c in ("blur:0.5", "blur:1"):
        assert w[c, 40.0] > 1.15 * w[c, 0.0]
        assert w[c, 40.0] ** 2 - w[c, 0.0] ** 2 > 5 * abs(w[None, 40.0] ** 2 - w[None, 0.0] ** 2)


def test_sets_are_deterministic_and_do_what_they_say(hills):
    for name in SETS:
        a = plan_set(hills, name, 4, seed=7)
        b = plan_set(hills, name, 4, seed=7)
        assert [(p["truth"], p["kwargs"]) for p in a] == [(p["truth"], p["kwargs"]) for p in b]
    c = plan_set(hills, "REF", 4, seed=8)
    assert [p["truth"] for p in c] != [p["truth"] for p in plan_set(hills, "REF", 4, seed=7)]
    xs = np.array([[p["truth"].x, p["truth"].y] for p in plan_set(hills, "REF", 30, seed=1)])
    assert np.all(np.abs(xs / 30.0 - np.round(xs / 30.0)) > 1e-6)  # off-grid
    lrel = plan_set(hills, "LREL", 10, seed=1)
    att = np.array([[p["truth"].pitch_deg, p["truth"].roll_deg] for p in lrel])
    assert np.all(np.abs(att) <= 10) and np.abs(att).max() > 3
    assert lrel[0]["kwargs"]["attitude_prior"] == (0.0, 0.0)
    # HREL picks flatter horizons than random positions.
    def relief(plans):
        pts = np.array([[p["truth"].x, p["truth"].y] for p in plans])
        e = render_horizons(hills, pts[:, 0], pts[:, 1]).elevation_deg
        return np.mean(e.max(axis=1) - e.min(axis=1))
    assert relief(plan_set(hills, "HREL", 5, seed=1)) < 0.7 * relief(plan_set(hills, "REF", 20, seed=1))
    area = (1000.0, 1000.0, 1500.0, 1200.0)
    pts = np.array([[p["truth"].x, p["truth"].y] for p in plan_set(hills, "OCCL", 10, 1, area=area)])
    assert np.all((pts >= [1000, 1000]) & (pts <= [1500, 1200]))
    with pytest.raises(ParameterError, match="unknown set"):
        plan_set(hills, "NOPE", 2, 0)


def test_simulate_set_writes_identical_cases_for_a_seed(hills, tmp_path):
    cam = camera_from_fov(64, 48, 45.0)
    a = simulate_set(hills, "COND", 2, 3, tmp_path / "a", camera=cam, frames=1)
    b = simulate_set(hills, "COND", 2, 3, tmp_path / "b", camera=cam, frames=1)
    assert [p.name for p in a] == ["case_000", "case_001"]
    for pa, pb in zip(a, b):
        for f in sorted(pa.iterdir()):
            assert f.read_bytes() == (pb / f.name).read_bytes(), f.name
    listing = json.loads((tmp_path / "a" / "set.json").read_text())
    assert listing["set"] == "COND" and len(listing["cases"]) == 2


def test_scom_skyline_leaves_the_frame(hills, tmp_path):
    cam = camera_from_fov(96, 96, 45.0)
    folders = simulate_set(hills, "SCOM", 2, 5, tmp_path / "s", camera=cam, frames=4)
    missing = []
    for f in folders:
        for sj in f.glob("*.skyline.json"):
            rows = read_skyline_json(sj).rows
            missing.append(np.mean(~np.isfinite(rows)))
    assert max(missing) > 0.2 and min(missing) < 1.0


def test_columns_without_a_skyline_are_recorded_as_all_ground_or_all_sky(hills, tmp_path):
    """A frame tilted down until the skyline leaves its top: the columns without a row are the
    ones recorded as all ground, and where the horizon renderer puts the skyline above the frame's
    top edge (an independent prediction); none is all sky. Every column is one of the three."""
    cam = camera_from_fov(160, 90, 60.0)
    t = Truth(2400.0, 2400.0, 200.0)
    out = simulate_acquisition(hills, t, tmp_path / "down", camera=cam, frames=1, tilt_deg=-10,
                               seed=1)
    info = json.loads((out / "acquisition.json").read_text())["simulation"]["images"][0]
    rows = read_skyline_json(out / "frame_000.skyline.json").rows
    ground = np.zeros(cam.width, bool)
    for a, b in info["ground_only_columns"]:
        ground[a:b] = True
    assert info["sky_only_columns"] == []
    assert 0.1 < ground.mean() < 0.9  # the set-up: the skyline leaves the top over part of it
    np.testing.assert_array_equal(ground, ~np.isfinite(rows))
    # the top row's ray against the rendered horizon at its azimuth
    d = cam.pixel_to_ray(np.arange(cam.width) + 0.0, np.zeros(cam.width)) @ r_world_cam(
        t.yaw_deg, 0, 0, 0, -10).T
    az, el = direction_to_az_el(d)
    hb = render_horizons(hills, t.x, t.y, azimuth_bins=3600)
    sky_el = np.interp(az % 360, hb.azimuth_deg, hb.elevation_deg[0], period=360)
    clear = np.abs(sky_el - el) > 0.2  # away from the edge case of a skyline on the top row
    np.testing.assert_array_equal(ground[clear], (sky_el > el)[clear])


# --- CLI -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def dem_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("dem") / "hills.tif"
    write_dem(p, hills_dem(60))
    return p


def test_cli_simulate(dem_file, tmp_path):
    out = tmp_path / "acq"
    r = CliRunner().invoke(cli, ["simulate", str(dem_file), "--x", "900", "--y", "800", "--yaw-deg", "30",
                                 "--frames", "1", "--camera", "navcam", "--conditions", "dust:0.3",
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert load_truth(out) == Truth(900.0, 800.0, 30.0)
    rows = np.array(json.loads((out / "frame_000.skyline.json").read_text())["rows"], float)
    # the summary counts the truth skyline's columns, and says what it wrote
    assert (f"{out}: 1 frame, 1024 x 1024 px, seen from (900.0, 800.0) at yaw 30.0 deg"
            in r.output), r.output
    assert f"the terrain skyline in {np.isfinite(rows).sum():,} of 1,024 columns" in r.output
    r = CliRunner().invoke(cli, ["simulate", str(dem_file), "--x", "900", "--y", "800", "--yaw-deg", "30",
                                 "--out", str(out)])
    assert r.exit_code == 2 and "--overwrite" in r.output


@pytest.mark.parametrize("args, msg", [
    (["--x", "900", "--y", "800", "--conditions", "smoke"], "unknown condition"),
    (["--x", "90000", "--y", "800"], "outside the DEM"),
    (["--x", "900", "--y", "800", "--frames", "0"], "at least one frame"),
    (["--x", "900", "--y", "800", "--tilt-deg", "120"], "mast tilt must be within +-90 deg"),
])
def test_cli_simulate_errors(dem_file, tmp_path, args, msg):
    r = CliRunner().invoke(cli, ["simulate", str(dem_file), "--yaw-deg", "0", *args, "--out",
                                 str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert msg in r.output and "Traceback" not in r.output


def test_cli_simulate_set(dem_file, tmp_path):
    out = tmp_path / "set"
    r = CliRunner().invoke(cli, ["simulate-set", str(dem_file), "--set", "ref", "--cases", "1",
                                 "--mode", "panorama", "--pano-size", "360", "90", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert load_acquisition(out / "case_000").panorama is not None
    r = CliRunner().invoke(cli, ["simulate-set", str(dem_file), "--set", "XYZ", "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "unknown set" in r.output


def test_outside_dem_raises(hills, tmp_path):
    with pytest.raises(OutsideDemError):
        simulate_acquisition(hills, Truth(-50.0, 100.0, 0.0), tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_antialiased_edge_carries_the_subpixel_row():
    """Ground coverage per column equals the ground extent below the truth row, (H - 0.5) - r."""
    from skyfix.simulate.shading import antialias_edge as _antialias_edge

    H, W = 40, 64
    r = np.linspace(3.0, 30.0, W) + 0.37 * np.sin(np.arange(W))
    v = np.arange(H)[:, None]
    img = np.where(v >= r[None, :], 0.0, 1.0)[..., None].repeat(3, axis=2)  # sky 1, ground 0
    before = np.sum(1 - img[..., 0], axis=0)
    _antialias_edge(img, r)
    after = np.sum(1 - img[..., 0], axis=0)
    np.testing.assert_allclose(after, H - 0.5 - r, atol=1e-9)
    assert np.max(np.abs(before - (H - 0.5 - r))) > 0.4  # point sampling alone misses it


def test_default_cases_keep_their_margin_from_the_dems_data_not_only_its_grid():
    """A reprojected DEM's corners hold no terrain: the default area's margin (10 cells or 5 % of
    the extent) is kept from where the heights end, as on a DEM without corners (the example
    report's cases had stood 68 m from the end of the Sierra's terrain)."""
    from skyfix.dem import fractal_dem
    from skyfix.nearest import nearest_valid
    from skyfix.simulate import plan_set
    from skyfix.simulate.sets import default_margin

    full = fractal_dem(200, 30.0, seed=4)
    rows, cols = np.mgrid[0:200, 0:200]
    z = np.where(rows + cols < 120, np.nan, full.z)  # a wedge 2.5 km deep in the north-west corner
    dem = Dem(z, full.x0, full.y0, full.dx, full.dy, full.crs_wkt, full.crs_name)
    margin = default_margin(dem)
    assert margin == pytest.approx(300.0)  # 5 % of 6 km
    dist2, _, _ = nearest_valid(~np.isfinite(dem.z))  # to the nearest cell without a height
    for name in ("REF", "HREL"):
        for c in plan_set(dem, name, 60, 3):
            col, row = dem.xy_to_colrow(c["truth"].x, c["truth"].y)
            d = math.sqrt(dist2[int(round(row)), int(round(col))]) * dem.dx
            assert d > 0.95 * margin, (name, d)


def test_an_area_given_near_the_end_of_the_data_is_drawn_as_given_with_a_warning(caplog):
    """A user's --area is honoured, but cases within the default margin of where the heights end
    (their skylines see the terrain stop) are counted in a warning; an area well inside is not."""
    from skyfix.dem import fractal_dem
    from skyfix.simulate import plan_set
    from skyfix.simulate.sets import default_margin

    dem = fractal_dem(200, 30.0, seed=4)
    xmin, ymin, xmax, ymax = dem.bounds
    margin = default_margin(dem)
    edge = (xmin + 1.0, ymin + 1.0, xmin + 100.0, ymax - 1.0)  # a strip along the west edge
    with caplog.at_level(logging.WARNING, logger="skyfix.simulate"):
        cases = plan_set(dem, "REF", 5, 1, area=edge)
    assert all(edge[0] <= c["truth"].x <= edge[2] for c in cases)  # drawn where asked
    assert any(f"5 of 5 REF cases lie within {margin:.0f} m" in r.getMessage() for r in caplog.records)
    caplog.clear()
    inside = (xmin + 2 * margin, ymin + 2 * margin, xmax - 2 * margin, ymax - 2 * margin)
    with caplog.at_level(logging.WARNING, logger="skyfix.simulate"):
        plan_set(dem, "REF", 5, 1, area=inside)
    assert not [r for r in caplog.records if "lie within" in r.getMessage()]


@pytest.mark.parametrize("tilt_deg", [-60.0, -85.0, -89.9])
def test_a_ray_steeply_down_meets_the_ground_below_the_camera(tilt_deg):
    """Closed form on flat ground: a ray ``a`` below the horizontal from 1.5 m up meets it at
    1.5 / sin(a). One steeper than 86 deg was already under the ground where the search began
    (0.1 m out) and got a hit 57 m along it, below the ground."""
    dem = Dem.from_array(np.zeros((50, 50), np.float32), 10.0)
    o = camera_centre(dem, 245.0, 245.0, 1.5)
    r = cast_image(dem, o, Projection.frame(Camera(5, 5, 3.0, 3.0, 2.0, 2.0), 0, 0, 0, 0, tilt_deg))
    assert r.distance[2, 2] == pytest.approx(1.5 / math.sin(math.radians(-tilt_deg)), rel=1e-4)
