"""An angular profile: elevation per azimuth bin, unobserved bins empty, as JSON (``skyfix horizon
--json``, ``skyfix profile -o``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import write_json
from ..errors import SkyfixError
from .values import attitude_prior_field, camera_height_field, json_object, number_list


@dataclass
class Profile:
    """Elevation [deg] per azimuth bin; bin k is centred on ``k * 360 / n`` deg. NaN = unobserved.

    sigma_deg : per-bin 1-sigma uncertainty [deg] (NaN where unobserved)
    frame : ``"world"`` (azimuth from grid north) or ``"body"`` (from the rover's forward axis)
    meta : anything else the producer knows (x, y, crs, contributing frames, ...)
    """

    elevation_deg: np.ndarray
    sigma_deg: np.ndarray | None = None
    frame: str = "world"
    meta: dict = field(default_factory=dict)

    @property
    def n_bins(self) -> int:
        return int(self.elevation_deg.shape[-1])

    @property
    def azimuth_deg(self) -> np.ndarray:
        return np.arange(self.n_bins) * (360.0 / self.n_bins)

    @property
    def observed(self) -> np.ndarray:
        return np.isfinite(self.elevation_deg)

    def to_dict(self) -> dict:
        d = {"azimuth_deg": self.azimuth_deg, "elevation_deg": self.elevation_deg,
             "sigma_deg": self.sigma_deg if self.sigma_deg is not None
             else np.full(self.n_bins, np.nan), "frame": self.frame}
        d.update(self.meta)
        return d


def write_profile_json(path, profile: Profile) -> Path:
    """Write ``profile`` as one-line JSON to ``path`` atomically; returns the path."""
    return write_json(path, profile.to_dict(), indent=None)


def read_profile_json(path, *, frame: str | None = None) -> Profile:
    """Read and validate a profile JSON file (``conventions.md``, "An angular profile").

    frame : ``"body"`` or ``"world"`` to require that frame (a profile without ``frame`` is a
        rendered one, in the world frame)
    Raises :class:`SkyfixError` naming the field: elevations [deg] in [-90, 90] or null,
    ``sigma_deg`` [deg] > 0 or null and ``azimuth_deg`` (optional, the regular bin centres
    ``k * 360 / n``) one per bin; ``attitude_prior`` pitch/roll [deg] and ``camera_height_m``
    [m] finite and in range when present.
    """
    path = Path(path)
    d = json_object(path, "profile")
    if "elevation_deg" not in d:
        raise SkyfixError(f"{path} is not a profile JSON file: missing field 'elevation_deg'")
    el = number_list(d, "elevation_deg", path, lo=-90.0, hi=90.0, unit=" deg")
    n = el.size
    if n < 1:
        raise SkyfixError(f"{path}: 'elevation_deg' is empty: one entry per azimuth bin")
    if d.get("azimuth_deg") is not None:
        az = number_list(d, "azimuth_deg", path, n=n, null_ok=False)
        if not np.allclose(az, np.arange(n) * 360.0 / n, atol=1e-6):
            raise SkyfixError(f"{path}: 'azimuth_deg' must be the regular bin centres k * 360 / {n} "
                              "deg (bin k centred on k * 360 / n)")
    sig = None
    if d.get("sigma_deg") is not None:
        # > 0: a measured elevation always has some uncertainty; 0 would weigh a bin infinitely
        sig = number_list(d, "sigma_deg", path, n=n, lo=1e-9, hi=90.0, unit=" deg (> 0)")
    got = d.get("frame", "world")
    if got not in ("world", "body"):
        raise SkyfixError(f"{path}: 'frame' must be 'body' (azimuth from the rover's forward axis) "
                          f"or 'world' (from grid north), got {got!r}")
    if frame is not None and got != frame:
        has = (f"is in the '{got}' frame" if "frame" in d
               else "has no 'frame' field, so it is a world-frame (rendered) profile")
        made = " as 'skyfix profile' writes" if frame == "body" else ""
        raise SkyfixError(f"{path} {has}: give a '{frame}'-frame profile{made} "
                          f"(\"frame\": \"{frame}\")")
    meta = {k: v for k, v in d.items() if k not in ("azimuth_deg", "elevation_deg", "sigma_deg", "frame")}
    where = f"{path}: "
    if "attitude_prior" in meta:
        p, r = attitude_prior_field(d, where, SkyfixError)
        meta["attitude_prior"] = {"pitch_deg": p, "roll_deg": r}
    if meta.get("camera_height_m") is not None:
        meta["camera_height_m"] = camera_height_field(d, f"{where}camera_height_m", SkyfixError)
    return Profile(el, sig, got, meta)
