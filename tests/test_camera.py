"""Camera model: OpenCV's distortion, checked against OpenCV itself (``cv2.projectPoints``)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from skyfix.camera import Camera, Distortion, camera_from_fov, direction_to_az_el, r_world_cam

#: A 90 deg wide camera with all five terms non-zero at the magnitudes of a calibrated wide-angle
#: lens (barrel k1, tangential terms of a slightly decentred lens), fx != fy and an off-centre
#: principal point, so that no term can hide behind another or behind a symmetry.
DIST = Distortion(k1=-0.12, k2=0.03, p1=1.2e-3, p2=-8e-4, k3=-4e-3)
CAM = Camera(1280, 960, fx=640.3, fy=641.1, cx=645.2, cy=478.6, distortion=DIST)

#: (yaw [deg], the camera's axes (x right, y down, z forward) as rows in ENU world axes), written
#: out by hand from conventions.md for a level camera: facing north, and facing east (right = south)
POSES = [(0.0, [[1, 0, 0], [0, 0, -1], [0, 1, 0]]),
         (90.0, [[0, -1, 0], [0, 0, -1], [1, 0, 0]])]
CENTRE = np.array([612345.0, 4123456.0, 2100.0])  # [m] camera centre, ENU world


def opencv_pixels(points_world, r_cam_world, centre=CENTRE):
    """OpenCV's projection of world points by a camera at ``centre`` with rotation world -> cam."""
    r = np.asarray(r_cam_world, float)
    rvec, _ = cv2.Rodrigues(r)
    tvec = -r @ centre
    uv, _ = cv2.projectPoints(points_world.reshape(-1, 1, 3), rvec, tvec, CAM.matrix(), DIST.as_array())
    return uv.reshape(-1, 2)


def test_distortion_coefficients_are_all_in_play():
    """The set-up: each term moves the frame's corner by pixels, not by rounding errors."""
    corner = np.array([[1.1, 0.8, 1.0]])  # normalised undistorted coordinates, near a corner
    _, dist = cv2.projectPoints(corner, np.zeros(3), np.zeros(3), CAM.matrix(), DIST.as_array())
    for name in ("k1", "k2", "p1", "p2", "k3"):
        d = DIST.as_array().copy()
        d[["k1", "k2", "p1", "p2", "k3"].index(name)] = 0.0
        _, without = cv2.projectPoints(corner, np.zeros(3), np.zeros(3), CAM.matrix(), d)
        assert np.abs(dist - without).max() > 0.5, name


@pytest.mark.parametrize("yaw, r_cam_world", POSES)
def test_projection_of_3d_points_matches_opencv(yaw, r_cam_world):
    rng = np.random.default_rng(3)
    # Directions filling the frame and beyond its corners, at 2 m to 5 km.
    x = np.r_[rng.uniform(-1.2, 1.2, 3000), -1.2, 1.2, -1.2, 1.2]
    y = np.r_[rng.uniform(-0.9, 0.9, 3000), -0.9, -0.9, 0.9, 0.9]
    z = np.r_[rng.uniform(2.0, 5000.0, 3000), 10.0, 100.0, 1000.0, 3.0]
    p_cam = np.stack([x * z, y * z, z], axis=-1)
    points = CENTRE + p_cam @ np.asarray(r_cam_world, float)  # world = R^T cam, explicitly
    ref = opencv_pixels(points, r_cam_world)
    # skyfix: world -> camera axes through its own conventions, then the lens.
    d_cam = (points - CENTRE) @ r_world_cam(yaw, 0.0, 0.0, 0.0, 0.0)
    u, v, front = CAM.ray_to_pixel(d_cam)
    assert front.all()
    inside = (ref[:, 0] >= 0) & (ref[:, 0] <= CAM.width - 1) & (ref[:, 1] >= 0) & (ref[:, 1] <= CAM.height - 1)
    assert inside.mean() > 0.5 and (~inside).sum() > 100  # the frame and its surroundings
    np.testing.assert_allclose(u, ref[:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(v, ref[:, 1], rtol=0, atol=1e-6)


def test_pixel_to_ray_inverts_opencv_over_the_whole_frame():
    """Every pixel, corners and outer pixel edges included: the ray skyfix gives for it projects
    back (by OpenCV) onto that pixel, and is the ray that OpenCV projects there."""
    us = np.r_[-0.5, np.linspace(0, CAM.width - 1, 65), CAM.width - 0.5]
    vs = np.r_[-0.5, np.linspace(0, CAM.height - 1, 49), CAM.height - 0.5]
    uu, vv = (a.ravel() for a in np.meshgrid(us, vs))
    rays = CAM.pixel_to_ray(uu, vv)
    assert np.allclose(rays[:, 2], 1.0)
    back, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), CAM.matrix(),
                                DIST.as_array())
    back = back.reshape(-1, 2)
    err = np.hypot(back[:, 0] - uu, back[:, 1] - vv)
    assert err.max() < 1e-6, (uu[err.argmax()], vv[err.argmax()], err.max())
    # and the forward model round-trips: ray -> pixel -> the same ray (angle < 1e-9 rad)
    u, v, front = CAM.ray_to_pixel(rays)
    again = CAM.pixel_to_ray(u, v)
    sin = np.linalg.norm(np.cross(again, rays), axis=1) / (np.linalg.norm(again, axis=1)
                                                           * np.linalg.norm(rays, axis=1))
    assert front.all() and sin.max() < 1e-9
    # The corners really are distorted: their rays differ from the pinhole ones by many pixels.
    pinhole = np.stack([(uu - CAM.cx) / CAM.fx, (vv - CAM.cy) / CAM.fy], axis=1)
    assert np.abs(rays[:, :2] - pinhole).max() * CAM.fx > 50


def test_undistortion_of_a_strong_wide_lens_against_a_root_finder():
    """k1 -0.3, k2 0.05 on a 90 deg lens (a real wide-angle calibration): OpenCV's fixed point
    alone stops 2.6 deg off near the corners. The radius is the root of r (1 + k1 r^2 + k2 r^4)
    = r_d, found by bisection (scipy's brentq), independent of the camera's code."""
    from scipy.optimize import brentq

    cam = camera_from_fov(1280, 960, 90.0, Distortion(k1=-0.3, k2=0.05))
    u, v = np.array([0.0, 1.0, 100.0, 640.0]), np.array([2.0, 2.0, 2.0, 479.5])
    xd, yd = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    x, y = cam.undistort_normalized(xd, yd)
    for i in range(u.size):
        rd = math.hypot(xd[i], yd[i])
        want = brentq(lambda r: r * (1 - 0.3 * r * r + 0.05 * r ** 4) - rd, 0.0, 3.0 * rd + 1e-9)
        assert math.hypot(x[i], y[i]) == pytest.approx(want, abs=1e-9)


def test_directions_beyond_the_lens_fold_are_not_projected_into_the_image():
    """A barrel lens's polynomial turns over past its field of view: directions 70-85 deg off the
    axis were distorted back inside the image, and a horizon projected through it mixed them
    with the true one (9.7 deg off; the single-frame attitude fit then froze at its start)."""
    from skyfix.profile import horizon_rows

    cam = Camera(1024, 768, 886.8, 886.8, 511.5, 383.5, Distortion(k1=-0.05))
    _, _, seen = cam.ray_to_pixel(np.array([[math.tan(math.radians(80)), 0.0, 1.0],
                                            [0.3, 0.2, 1.0]]))
    assert list(seen) == [False, True]
    az = np.arange(7200) * 0.05
    el = 6 + 3 * np.sin(np.radians(3 * az)) + 1.5 * np.cos(np.radians(7 * az + 20))
    rot = r_world_cam(123, 3, -2, 0, 10)
    rows = horizon_rows(cam, az, el, rot)
    a, e = direction_to_az_el(cam.pixel_to_ray(np.arange(1024.0), rows) @ rot.T)
    ok = np.isfinite(e)
    assert ok.sum() > 900
    assert np.max(np.abs(e[ok] - np.interp(a[ok], az, el, period=360))) < 0.01


@pytest.mark.parametrize("kw", [dict(cx=float("nan")), dict(cy=float("inf")), dict(fx=float("inf")),
                                dict(distortion=Distortion(k1=float("nan")))])
def test_a_camera_of_non_finite_numbers_is_refused(kw):
    """NaN or infinite intrinsics were accepted and gave NaN rays for every pixel."""
    from skyfix.errors import ParameterError

    base = dict(width=640, height=480, fx=500.0, fy=500.0, cx=319.5, cy=239.5)
    with pytest.raises(ParameterError, match="finite"):
        Camera(**{**base, **kw})
