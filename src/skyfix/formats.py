"""The interface formats of ``conventions.md``: acquisitions, skylines and angular profiles.

Outside tools read and write these, so parsing is strict and every error names the field.
The localiser reads an acquisition with :func:`load_acquisition`, which never exposes ``truth``;
evaluation tools call :func:`load_truth`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._io import write_json
from .camera import Camera, Distortion
from .errors import AcquisitionError, SkyfixError

ACQUISITION_FILE = "acquisition.json"


@dataclass(frozen=True)
class Frame:
    """One image of a frame set: file name (relative to the acquisition folder), mast pan/tilt [deg]."""

    image: str
    pan_deg: float
    tilt_deg: float = 0.0


@dataclass(frozen=True)
class PanoramaSpec:
    """An equirectangular panorama levelled in the body frame.

    azimuth_left_deg : [deg] azimuth of the left image edge, clockwise from the rover's forward axis
    hfov_deg, vfov_deg : [deg] angular extent of the image
    elevation_top_deg : [deg] elevation of the top image edge
    Pixel (i, j) centre is at azimuth ``azimuth_left + (j + 0.5) * hfov / W`` and elevation
    ``elevation_top - (i + 0.5) * vfov / H``.
    """

    image: str
    azimuth_left_deg: float = -180.0
    hfov_deg: float = 360.0
    elevation_top_deg: float = 30.0
    vfov_deg: float = 60.0


@dataclass(frozen=True)
class Truth:
    """Ground truth of a simulated or surveyed acquisition: position [m], attitude [deg]."""

    x: float
    y: float
    yaw_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0


@dataclass(frozen=True)
class Acquisition:
    """What the board segment receives: camera, frames or a panorama, attitude prior.

    root : folder holding the images
    camera_height_m : [m] camera centre above the ground at the rover's position
    prior_pitch_deg, prior_roll_deg : [deg] inclinometer reading (may be wrong by up to 10 deg)
    """

    root: Path
    camera: Camera | None
    camera_height_m: float
    frames: tuple[Frame, ...] = ()
    panorama: PanoramaSpec | None = None
    prior_pitch_deg: float = 0.0
    prior_roll_deg: float = 0.0
    extra: dict = field(default_factory=dict)

    def image_path(self, name: str) -> Path:
        return self.root / name

    def to_dict(self) -> dict:
        d: dict = {}
        if self.camera is not None:
            d["camera"] = self.camera.to_dict()
        d["camera_height_m"] = self.camera_height_m
        if self.frames:
            d["frames"] = [
                {"image": f.image, "pan_deg": f.pan_deg, "tilt_deg": f.tilt_deg} for f in self.frames
            ]
        if self.panorama is not None:
            p = self.panorama
            d["panorama"] = {
                "image": p.image, "azimuth_left_deg": p.azimuth_left_deg, "hfov_deg": p.hfov_deg,
                "elevation_top_deg": p.elevation_top_deg, "vfov_deg": p.vfov_deg,
            }
        d["attitude_prior"] = {"pitch_deg": self.prior_pitch_deg, "roll_deg": self.prior_roll_deg}
        d.update(self.extra)
        return d


def _num(obj: dict, key: str, where: str, default=None, *, positive=False, required=True) -> float:
    if key not in obj:
        if default is not None or not required:
            return default
        raise AcquisitionError(f"{where}: missing field '{key}'")
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise AcquisitionError(f"{where}.{key} must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise AcquisitionError(f"{where}.{key} must be > 0, got {v!r}")
    return float(v)


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise AcquisitionError(
            f"no {path.name} in {path.parent}: an acquisition is a folder with {ACQUISITION_FILE} "
            "and its images (see docs/conventions.md)"
        )
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise AcquisitionError(f"{path} is not valid JSON: {e}") from None
    if not isinstance(data, dict):
        raise AcquisitionError(f"{path}: the top level must be a JSON object")
    return data


def _parse_camera(d) -> Camera:
    if not isinstance(d, dict):
        raise AcquisitionError("acquisition.json: 'camera' must be an object")
    w = "camera"
    width = _num(d, "width", w, positive=True)
    height = _num(d, "height", w, positive=True)
    if width != int(width) or height != int(height):
        raise AcquisitionError("camera.width and camera.height must be whole numbers of pixels")
    dist = d.get("distortion") or {}
    if not isinstance(dist, dict):
        raise AcquisitionError("camera.distortion must be an object with k1, k2, p1, p2, k3")
    dist_v = {k: _num(dist, k, "camera.distortion", 0.0) for k in ("k1", "k2", "p1", "p2", "k3")}
    return Camera(
        int(width), int(height), _num(d, "fx", w, positive=True), _num(d, "fy", w, positive=True),
        _num(d, "cx", w), _num(d, "cy", w), Distortion(**dist_v),
    )


def load_acquisition(folder) -> Acquisition:
    """Read and validate an acquisition folder; checks that every named image exists.

    Raises :class:`AcquisitionError` naming the offending field or file.
    """
    root = Path(folder)
    if not root.is_dir():
        raise AcquisitionError(f"acquisition folder {root} does not exist or is not a folder")
    data = _read_json(root / ACQUISITION_FILE)
    frames_raw = data.get("frames")
    pano_raw = data.get("panorama")
    if frames_raw is None and pano_raw is None:
        raise AcquisitionError("acquisition.json: needs either 'frames' (a list) or 'panorama'")
    if frames_raw is not None and pano_raw is not None:
        raise AcquisitionError("acquisition.json: give 'frames' or 'panorama', not both")
    camera = None
    frames: list[Frame] = []
    panorama = None
    if frames_raw is not None:
        if "camera" not in data:
            raise AcquisitionError("acquisition.json: 'frames' need a 'camera' with intrinsics")
        camera = _parse_camera(data["camera"])
        if not isinstance(frames_raw, list) or not frames_raw:
            raise AcquisitionError("acquisition.json: 'frames' must be a non-empty list")
        for i, f in enumerate(frames_raw):
            where = f"frames[{i}]"
            if not isinstance(f, dict) or not isinstance(f.get("image"), str):
                raise AcquisitionError(f"{where} must be an object with an 'image' file name")
            frames.append(Frame(f["image"], _num(f, "pan_deg", where), _num(f, "tilt_deg", where, 0.0)))
    else:
        if not isinstance(pano_raw, dict) or not isinstance(pano_raw.get("image"), str):
            raise AcquisitionError("acquisition.json: 'panorama' must be an object with an 'image'")
        w = "panorama"
        panorama = PanoramaSpec(
            pano_raw["image"],
            _num(pano_raw, "azimuth_left_deg", w, -180.0),
            _num(pano_raw, "hfov_deg", w, 360.0, positive=True),
            _num(pano_raw, "elevation_top_deg", w, 30.0),
            _num(pano_raw, "vfov_deg", w, 60.0, positive=True),
        )
        if panorama.hfov_deg > 360.0:
            raise AcquisitionError("panorama.hfov_deg must be at most 360")
        if "camera" in data:
            camera = _parse_camera(data["camera"])
    h = _num(data, "camera_height_m", "acquisition.json")
    if h < 0:
        raise AcquisitionError(f"camera_height_m must be >= 0 m, got {h}")
    prior = data.get("attitude_prior") or {}
    if not isinstance(prior, dict):
        raise AcquisitionError("attitude_prior must be an object with pitch_deg and roll_deg")
    acq = Acquisition(
        root=root, camera=camera, camera_height_m=h, frames=tuple(frames), panorama=panorama,
        prior_pitch_deg=_num(prior, "pitch_deg", "attitude_prior", 0.0),
        prior_roll_deg=_num(prior, "roll_deg", "attitude_prior", 0.0),
    )
    names = [f.image for f in acq.frames] if acq.frames else [acq.panorama.image]
    for name in names:
        if not (root / name).is_file():
            raise AcquisitionError(f"image {name} named in {root / ACQUISITION_FILE} is missing")
    return acq


def load_truth(folder) -> Truth | None:
    """The ``truth`` of an acquisition, or None. For evaluation tools only, never the localiser."""
    data = _read_json(Path(folder) / ACQUISITION_FILE)
    t = data.get("truth")
    if t is None:
        return None
    if not isinstance(t, dict):
        raise AcquisitionError("acquisition.json: 'truth' must be an object")
    return Truth(
        _num(t, "x", "truth"), _num(t, "y", "truth"), _num(t, "yaw_deg", "truth"),
        _num(t, "pitch_deg", "truth", 0.0), _num(t, "roll_deg", "truth", 0.0),
    )


def save_acquisition(folder, acq: Acquisition, truth: Truth | None = None, extra: dict | None = None) -> Path:
    """Write ``acquisition.json`` atomically (images are written by the caller)."""
    d = acq.to_dict()
    if truth is not None:
        d["truth"] = {
            "x": truth.x, "y": truth.y, "yaw_deg": truth.yaw_deg,
            "pitch_deg": truth.pitch_deg, "roll_deg": truth.roll_deg,
        }
    if extra:
        d.update(extra)
    return write_json(Path(folder) / ACQUISITION_FILE, d)


# --- skylines ------------------------------------------------------------------------------------

@dataclass
class Skyline:
    """Per image column: skyline row [px, sub-pixel, 0-based] or NaN where none is visible.

    confidence : per-column confidence in [0, 1] (NaN when unknown)
    valid : per-column flag, False where the column holds no image data
    """

    rows: np.ndarray
    width: int
    height: int
    image: str = ""
    confidence: np.ndarray | None = None
    valid: np.ndarray | None = None

    @property
    def has_skyline(self) -> np.ndarray:
        return np.isfinite(self.rows)

    def to_dict(self) -> dict:
        d = {"image": self.image, "width": int(self.width), "height": int(self.height),
             "rows": [None if not np.isfinite(r) else round(float(r), 3) for r in self.rows]}
        if self.confidence is not None:
            d["confidence"] = [None if not np.isfinite(c) else round(float(c), 4) for c in self.confidence]
        if self.valid is not None:
            d["valid"] = [bool(v) for v in self.valid]
        return d


def write_skyline_json(path, skyline: Skyline) -> Path:
    return write_json(path, skyline.to_dict(), indent=None)


def read_skyline_json(path) -> Skyline:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
        rows = np.array([np.nan if r is None else float(r) for r in d["rows"]])
        conf = d.get("confidence")
        valid = d.get("valid")
        return Skyline(
            rows=rows, width=int(d.get("width", len(rows))), height=int(d["height"]),
            image=d.get("image", ""),
            confidence=None if conf is None else np.array([np.nan if c is None else float(c) for c in conf]),
            valid=None if valid is None else np.array(valid, dtype=bool),
        )
    except FileNotFoundError:
        raise SkyfixError(f"skyline file {path} does not exist") from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SkyfixError(f"{path} is not a skyline JSON file ({type(e).__name__}: {e})") from None


# --- angular profiles ----------------------------------------------------------------------------

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
    return write_json(path, profile.to_dict(), indent=None)


def read_profile_json(path) -> Profile:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
        el = np.array([np.nan if v is None else float(v) for v in d["elevation_deg"]])
        az = np.array(d.get("azimuth_deg", []), dtype=float)
        if az.size and not np.allclose(az, np.arange(el.size) * 360.0 / el.size):
            raise ValueError("azimuth_deg must be the regular bin centres k * 360 / n")
        sig = d.get("sigma_deg")
        sig = None if sig is None else np.array([np.nan if v is None else float(v) for v in sig])
        meta = {k: v for k, v in d.items() if k not in ("azimuth_deg", "elevation_deg", "sigma_deg", "frame")}
        return Profile(el, sig, d.get("frame", "world"), meta)
    except FileNotFoundError:
        raise SkyfixError(f"profile file {path} does not exist") from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SkyfixError(f"{path} is not a profile JSON file ({type(e).__name__}: {e})") from None
