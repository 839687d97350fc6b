"""Camera model and attitude conventions (``conventions.md``, exactly).

A pixel's direction in the world (ENU at the camera) is
``R_world_body(yaw, pitch, roll) @ R_body_mast(pan, tilt) @ C @ d_cam`` with
``d_cam = ((u - cx)/fx, (v - cy)/fy, 1)`` for an undistorted pixel (u column, v row, 0-based).

All public angles are in degrees; azimuth is clockwise from grid north (+y), elevation is
positive up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from .errors import ParameterError

#: camera axes (x right, y down, z forward) -> body axes (x right, y forward, z up)
C_CAM_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def rot_x(angle_deg: float) -> np.ndarray:
    """``Rx(a)`` of ``conventions.md``; angle in degrees."""
    a = np.radians(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_deg: float) -> np.ndarray:
    """``Ry(a)`` of ``conventions.md``; angle in degrees."""
    a = np.radians(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_deg: float) -> np.ndarray:
    """``Rz(a)`` of ``conventions.md``; angle in degrees."""
    a = np.radians(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def r_body_mast(pan_deg: float, tilt_deg: float) -> np.ndarray:
    """Mast head to body: ``Rz(-pan) @ Rx(tilt)``; pan clockwise positive, tilt up positive [deg]."""
    return rot_z(-pan_deg) @ rot_x(tilt_deg)


def r_world_body(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Body to world (ENU): ``Rz(-yaw) @ Rx(pitch) @ Ry(roll)`` [deg].

    yaw: heading clockwise from grid north; pitch: nose up positive; roll: right side down positive.
    """
    return rot_z(-yaw_deg) @ rot_x(pitch_deg) @ rot_y(roll_deg)


def r_world_cam(yaw_deg, pitch_deg, roll_deg, pan_deg, tilt_deg) -> np.ndarray:
    """Camera axes to world (ENU) for a rover attitude and a mast pointing [deg]."""
    return r_world_body(yaw_deg, pitch_deg, roll_deg) @ r_body_mast(pan_deg, tilt_deg) @ C_CAM_TO_BODY


def direction_to_az_el(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth [deg, 0..360, clockwise from +y] and elevation [deg] of direction vectors ``(..., 3)``."""
    d = np.asarray(d, dtype=float)
    az = np.degrees(np.arctan2(d[..., 0], d[..., 1])) % 360.0
    el = np.degrees(np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1])))
    return az, el


def az_el_to_direction(az_deg, el_deg) -> np.ndarray:
    """Unit direction vectors ``(..., 3)`` (ENU) for azimuth/elevation [deg]."""
    az = np.radians(np.asarray(az_deg, dtype=float))
    el = np.radians(np.asarray(el_deg, dtype=float))
    ce = np.cos(el)
    return np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)], axis=-1)


@dataclass(frozen=True)
class Distortion:
    """OpenCV's radial/tangential model (k1, k2, p1, p2, k3), dimensionless."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @property
    def is_zero(self) -> bool:
        return not any((self.k1, self.k2, self.p1, self.p2, self.k3))

    def as_array(self) -> np.ndarray:
        """OpenCV's coefficient order ``(k1, k2, p1, p2, k3)``."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels, with OpenCV distortion.

    width, height : int  [px]
    fx, fy : float  [px]  focal lengths
    cx, cy : float  [px]  principal point, 0-based (centre of a 1024-px image: 511.5)
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Distortion = field(default_factory=Distortion)

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0:
            raise ParameterError(f"camera size must be positive, got {self.width} x {self.height}")
        if not (self.fx > 0 and self.fy > 0 and np.isfinite(self.fx) and np.isfinite(self.fy)):
            raise ParameterError(f"camera focal lengths must be finite and > 0 px, got fx={self.fx}, "
                                 f"fy={self.fy}")
        if not (np.isfinite(self.cx) and np.isfinite(self.cy)):  # NaN rays for every pixel
            raise ParameterError(f"camera principal point must be finite [px], got cx={self.cx}, "
                                 f"cy={self.cy}")
        d = self.distortion
        if not all(np.isfinite(v) for v in (d.k1, d.k2, d.p1, d.p2, d.k3)):
            raise ParameterError(f"camera distortion coefficients must be finite, got {d}")

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view [deg] (undistorted pinhole)."""
        return float(np.degrees(2 * np.arctan2(self.width / 2.0, self.fx)))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view [deg] (undistorted pinhole)."""
        return float(np.degrees(2 * np.arctan2(self.height / 2.0, self.fy)))

    def matrix(self) -> np.ndarray:
        """3x3 intrinsic matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def with_size(self, width: int, height: int) -> "Camera":
        return replace(self, width=width, height=height)

    # --- projection -------------------------------------------------------------------------
    def distort_normalized(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply OpenCV distortion to normalised image coordinates."""
        d = self.distortion
        if d.is_zero:
            return x, y
        r2 = x * x + y * y
        radial = 1 + d.k1 * r2 + d.k2 * r2 * r2 + d.k3 * r2 * r2 * r2
        xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)
        yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
        return xd, yd

    def undistort_normalized(self, xd: np.ndarray, yd: np.ndarray, iterations: int = 20):
        """Invert :meth:`distort_normalized`: fixed-point iteration (as OpenCV does), then Newton
        steps on the 2-D map until it is inverted to 1e-12. The fixed point alone does not
        converge for a strong wide-angle lens (k1 -0.3, k2 0.05 at 90 deg: 2.6 deg off at the
        corners); a point that no direction distorts to (beyond a fold) is NaN."""
        d = self.distortion
        if d.is_zero:
            return xd, yd
        xd, yd = np.asarray(xd, dtype=float), np.asarray(yd, dtype=float)
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + d.k1 * r2 + d.k2 * r2 * r2 + d.k3 * r2 * r2 * r2
            dx = 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)
            dy = d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for _ in range(30):
                ex, ey = self.distort_normalized(x, y)
                ex, ey = ex - xd, ey - yd
                if not np.any(np.hypot(ex, ey) > 1e-12):
                    break
                r2 = x * x + y * y
                radial = 1 + d.k1 * r2 + d.k2 * r2 * r2 + d.k3 * r2 * r2 * r2
                dr = d.k1 + 2 * d.k2 * r2 + 3 * d.k3 * r2 * r2  # d radial / d r2
                # the Jacobian [[a, b], [b, e]]: both off-diagonal terms are the same
                a = radial + 2 * x * x * dr + 2 * d.p1 * y + 6 * d.p2 * x
                b = 2 * x * y * dr + 2 * d.p1 * x + 2 * d.p2 * y
                e = radial + 2 * y * y * dr + 6 * d.p1 * y + 2 * d.p2 * x
                det = a * e - b * b
                x = x - (e * ex - b * ey) / det
                y = y - (a * ey - b * ex) / det
            ex, ey = self.distort_normalized(x, y)
            bad = ~(np.hypot(ex - xd, ey - yd) <= 1e-9)
        if np.any(bad):
            x, y = np.where(bad, np.nan, x), np.where(bad, np.nan, y)
        return x, y

    def pixel_to_ray(self, u, v) -> np.ndarray:
        """Camera-frame direction ``(..., 3)`` (not normalised, z = 1) of pixel (u, v) [px]."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        x, y = self.undistort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy)
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    @cached_property
    def fold_radius(self) -> float:
        """Undistorted normalised radius [tan of the angle off the axis] beyond which the radial
        distortion turns over (the distorted radius stops growing: directions beyond it land
        back inside the image); inf where it never does (no distortion, pincushion). Sampled
        out to 87 deg off the axis, the tangential terms left out."""
        d = self.distortion
        if d.k1 == d.k2 == d.k3 == 0.0:
            return math.inf
        r = np.linspace(0.0, 20.0, 20001)
        r2 = r * r
        grow = 1 + 3 * d.k1 * r2 + 5 * d.k2 * r2 * r2 + 7 * d.k3 * r2 * r2 * r2  # d(r s(r))/dr
        turn = np.flatnonzero(grow <= 0)
        return float(r[turn[0]]) if turn.size else math.inf

    def ray_to_pixel(self, d_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel (u, v) [px] of camera-frame directions ``(..., 3)``, and a mask of those that
        can be projected: in front, and short of the lens's fold (:attr:`fold_radius`: with
        k1 -0.05 directions 70-85 deg off the axis were distorted back inside the image)."""
        d_cam = np.asarray(d_cam, dtype=float)
        z = d_cam[..., 2]
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        xn, yn = d_cam[..., 0] / zs, d_cam[..., 1] / zs
        fold = self.fold_radius
        if math.isfinite(fold):
            front = front & (xn * xn + yn * yn < fold * fold)
        x, y = self.distort_normalized(xn, yn)
        return self.fx * x + self.cx, self.fy * y + self.cy, front

    def to_dict(self) -> dict:
        d = self.distortion
        return {
            "width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
            "cx": self.cx, "cy": self.cy,
            "distortion": {"k1": d.k1, "k2": d.k2, "p1": d.p1, "p2": d.p2, "k3": d.k3},
        }


def camera_from_fov(width: int, height: int, hfov_deg: float, distortion: Distortion | None = None) -> Camera:
    """Square-pixel camera with the principal point at the image centre and a horizontal FoV [deg]."""
    fx = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return Camera(width, height, float(fx), float(fx), (width - 1) / 2.0, (height - 1) / 2.0,
                  distortion or Distortion())


#: Named camera presets. ``navcam``: 1024 x 1024, 45 deg, like the ExoMars / Mars 2020 navigation
#: cameras. ``wide``: 1280 x 960, 90 deg, with mild barrel distortion.
CAMERA_PRESETS = {
    "navcam": camera_from_fov(1024, 1024, 45.0),
    "wide": camera_from_fov(1280, 960, 90.0, Distortion(k1=-0.05, k2=0.01)),
}


def get_camera(name: str) -> Camera:
    try:
        return CAMERA_PRESETS[name]
    except KeyError:
        raise ParameterError(
            f"unknown camera preset {name!r}: choose one of {', '.join(CAMERA_PRESETS)}"
        ) from None
