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

#: [m] highest camera above the ground skyfix accepts. A rover's mast is ~2 m and a drone or
#: balloon a few km; from 100 km up the skyline is the planet's limb, not the DEM's terrain
#: (1e9 m gave -90 deg in every bin without a word), so anything higher is a unit mistake.
MAX_CAMERA_HEIGHT_M = 100_000.0
#: [deg] largest inclinometer pitch or roll: a rover on the ground (the simulator's bound too;
#: rovers are rated to ~45 deg, tipping over well before 60).
MAX_PRIOR_TILT_DEG = 60.0


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


def _in_range(v: float, lo: float, hi: float, where: str, why: str) -> float:
    """``v`` if ``lo <= v <= hi``, else an AcquisitionError naming the field ``where``."""
    if not lo <= v <= hi:
        raise AcquisitionError(f"{where} must be within {lo:g} to {hi:g} ({why}), got {v:g}")
    return v


def _camera_height(obj: dict, where: str, err=AcquisitionError) -> float:
    v = obj["camera_height_m"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise err(f"{where} must be a finite number of metres, got {v!r}")
    if not 0 <= v <= MAX_CAMERA_HEIGHT_M:
        raise err(f"{where} must be within 0 to {MAX_CAMERA_HEIGHT_M:g} m (the camera above the "
                  f"ground), got {v:g}")
    return float(v)


def _attitude_prior(data: dict, where: str, err=AcquisitionError) -> tuple[float, float]:
    """(pitch, roll) [deg] of an optional ``attitude_prior`` object; (0, 0) when absent or null."""
    prior = data.get("attitude_prior")
    if prior is None:
        return 0.0, 0.0
    if not isinstance(prior, dict):
        raise err(f"{where}attitude_prior must be an object with pitch_deg and roll_deg [deg], "
                  f"got {prior!r}")
    out = []
    for key in ("pitch_deg", "roll_deg"):
        v = prior.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise err(f"{where}attitude_prior.{key} must be a finite number of degrees, got {v!r}")
        if abs(v) > MAX_PRIOR_TILT_DEG:
            raise err(f"{where}attitude_prior.{key} must be within +-{MAX_PRIOR_TILT_DEG:g} deg "
                      f"(a rover on the ground), got {v:g}")
        out.append(float(v))
    return out[0], out[1]


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
    fx, fy = _num(d, "fx", w, positive=True), _num(d, "fy", w, positive=True)
    # The principal point of a real lens sits near the image centre (a few per cent off);
    # shifted sensors move it further, but half an image outside the frame means another
    # image size or a unit mix-up, not a lens (pixel centres span -0.5 .. size - 0.5).
    cx = _in_range(_num(d, "cx", w), -0.5 - width / 2, width - 0.5 + width / 2, "camera.cx",
                   "the principal point lies in or near the image")
    cy = _in_range(_num(d, "cy", w), -0.5 - height / 2, height - 0.5 + height / 2, "camera.cy",
                   "the principal point lies in or near the image")
    cam = Camera(int(width), int(height), fx, fy, cx, cy, Distortion(**dist_v))
    _check_distortion(cam)
    return cam


#: Radial scale 1 + k1 r^2 + k2 r^4 + k3 r^6 allowed over the image: a strong barrel or
#: pincushion lens moves the image corner by a few tens of per cent of its radius; a factor 4
#: either way is generous (k1 = 50 on a 45 deg camera gave 18; the "wide" preset gives 0.95).
RADIAL_SCALE_RANGE = (0.25, 4.0)
#: |p1|, |p2|: decentring is ~1e-3 for a real lens; 0.1 is a hundred times that.
MAX_TANGENTIAL = 0.1


def _check_distortion(cam: Camera) -> None:
    """Refuse OpenCV coefficients that no lens has: judged by their effect over the image, not
    one by one (k3 = 100 is harmless on a narrow lens, where r**6 is tiny)."""
    d = cam.distortion
    for k in ("p1", "p2"):
        v = getattr(d, k)
        if abs(v) > MAX_TANGENTIAL:
            raise AcquisitionError(f"camera.distortion.{k} must be within +-{MAX_TANGENTIAL:g} "
                                   f"(decentring of a real lens is ~0.001), got {v:g}")
    if d.k1 == d.k2 == d.k3 == 0.0:
        return
    # normalised radius of the image corner farthest from the principal point
    xs = np.array([-0.5, cam.width - 0.5]) - cam.cx
    ys = np.array([-0.5, cam.height - 0.5]) - cam.cy
    r_max = math.sqrt(np.max(xs ** 2) / cam.fx ** 2 + np.max(ys ** 2) / cam.fy ** 2)
    r = np.linspace(0.0, r_max, 201)
    r2 = r * r
    scale = 1 + d.k1 * r2 + d.k2 * r2 ** 2 + d.k3 * r2 ** 3
    lo, hi = RADIAL_SCALE_RANGE
    # A distorted radius r * scale that stops growing folds the image over itself: two
    # directions on one pixel, and the fixed-point undistortion no longer converges.
    folds = np.any(np.diff(r * scale) <= 0)
    if scale.min() < lo or scale.max() > hi or folds:
        worst = float(scale[np.argmax(np.abs(np.log(np.clip(scale, 1e-12, None))))])
        what = "fold the image over itself" if folds else f"scale the radius by {worst:.3g}"
        raise AcquisitionError(
            f"camera.distortion k1={d.k1:g}, k2={d.k2:g}, k3={d.k3:g} {what} within the image "
            f"(allowed: a scale of {lo:g} to {hi:g}, never folding): check the coefficients, "
            "their order (OpenCV: k1, k2, p1, p2, k3) and that they are for normalised "
            "coordinates")


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
            # tilt beyond +-90 deg points the camera backwards over the top, upside down: no
            # mast does that, and 400 is a typing or unit mistake
            tilt = _in_range(_num(f, "tilt_deg", where, 0.0), -90.0, 90.0, f"{where}.tilt_deg",
                             "mast tilt, up positive")
            frames.append(Frame(f["image"], _num(f, "pan_deg", where), tilt))
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
        # elevations are angles above the horizontal: the image spans top .. top - vfov, and
        # both ends must lie between the nadir (-90) and the zenith (+90)
        _in_range(panorama.elevation_top_deg, -90.0, 90.0, "panorama.elevation_top_deg",
                  "an elevation angle")
        bottom = panorama.elevation_top_deg - panorama.vfov_deg
        if bottom < -90.0:
            raise AcquisitionError(
                f"panorama.elevation_top_deg - panorama.vfov_deg is {bottom:g} deg: the image's "
                "bottom edge must not lie below the nadir (-90 deg); check vfov_deg")
        if "camera" in data:
            camera = _parse_camera(data["camera"])
    if "camera_height_m" not in data:
        raise AcquisitionError("acquisition.json: missing field 'camera_height_m'")
    h = _camera_height(data, "camera_height_m")
    pitch, roll = _attitude_prior(data, "")
    acq = Acquisition(
        root=root, camera=camera, camera_height_m=h, frames=tuple(frames), panorama=panorama,
        prior_pitch_deg=pitch, prior_roll_deg=roll,
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


def _json_object(path: Path, what: str) -> dict:
    """The top-level JSON object of ``path``; SkyfixError naming ``what`` the file should be."""
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise SkyfixError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SkyfixError(f"{path} is not a {what} JSON file ({type(e).__name__}: {e})") from None
    if not isinstance(d, dict):
        raise SkyfixError(f"{path} is not a {what} JSON file: the top level must be an object")
    return d


def _number_list(d: dict, key: str, path: Path, *, n: int | None = None, lo=-math.inf,
                 hi=math.inf, null_ok=True, unit="") -> np.ndarray:
    """``d[key]`` as a float array (null -> NaN), every entry a finite number in [lo, hi]."""
    v = d[key]
    if not isinstance(v, list):
        raise SkyfixError(f"{path}: '{key}' must be a list of numbers, got {type(v).__name__}")
    if n is not None and len(v) != n:
        raise SkyfixError(f"{path}: '{key}' has {len(v)} entries, must have {n} (one per column/bin)")
    out = np.empty(len(v))
    for i, x in enumerate(v):
        if x is None and null_ok:
            out[i] = np.nan
            continue
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise SkyfixError(f"{path}: {key}[{i}] must be a finite number{' or null' * null_ok}, "
                              f"got {x!r}")
        if not lo <= x <= hi:
            raise SkyfixError(f"{path}: {key}[{i}] = {x:g} is outside {lo:g} .. {hi:g}{unit}")
        out[i] = x
    return out


def _whole(d: dict, key: str, path: Path) -> int:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v < 1:
        raise SkyfixError(f"{path}: '{key}' must be a whole number of pixels >= 1, got {v!r}")
    return int(v)


def read_skyline_json(path) -> Skyline:
    """Read and validate a skyline JSON file (``conventions.md``, "A skyline").

    Raises :class:`SkyfixError` naming the field when one breaks the format: ``width`` must
    equal the number of ``rows``; rows [px] lie in the image (-1 .. height: a sub-pixel edge
    may sit half a pixel past the first or last row centre); ``confidence`` in [0, 1];
    ``valid`` true/false, one per column.
    """
    path = Path(path)
    d = _json_object(path, "skyline")
    for key in ("rows", "height"):
        if key not in d:
            raise SkyfixError(f"{path} is not a skyline JSON file: missing field '{key}'")
    height = _whole(d, "height", path)
    if not isinstance(d["rows"], list) or not d["rows"]:
        raise SkyfixError(f"{path}: 'rows' must be a non-empty list, one entry per image column")
    n = len(d["rows"])
    width = _whole(d, "width", path) if "width" in d else n
    if width != n:
        raise SkyfixError(f"{path}: 'width' is {width} but 'rows' has {n} entries: one row per "
                          "image column")
    rows = _number_list(d, "rows", path, lo=-1.0, hi=float(height), unit=f" px (image height {height})")
    conf = None
    if d.get("confidence") is not None:
        conf = _number_list(d, "confidence", path, n=n, lo=0.0, hi=1.0)
    valid = None
    if d.get("valid") is not None:
        v = d["valid"]
        bad = (f"got {v!r}" if not isinstance(v, list) else
               f"it has {len(v)}" if len(v) != n else
               next((f"valid[{i}] is {x!r}" for i, x in enumerate(v) if not isinstance(x, bool)), None))
        if bad is not None:
            # "yes" or 1 would be truthy and silently change which columns are scored
            raise SkyfixError(f"{path}: 'valid' must be a list of {n} true/false values, one per "
                              f"column: {bad}")
        valid = np.array(v, dtype=bool)
    image = d.get("image", "")
    if not isinstance(image, str):
        raise SkyfixError(f"{path}: 'image' must be a file name, got {image!r}")
    return Skyline(rows=rows, width=width, height=height, image=image, confidence=conf, valid=valid)


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
    d = _json_object(path, "profile")
    if "elevation_deg" not in d:
        raise SkyfixError(f"{path} is not a profile JSON file: missing field 'elevation_deg'")
    el = _number_list(d, "elevation_deg", path, lo=-90.0, hi=90.0, unit=" deg")
    n = el.size
    if n < 1:
        raise SkyfixError(f"{path}: 'elevation_deg' is empty: one entry per azimuth bin")
    if d.get("azimuth_deg") is not None:
        az = _number_list(d, "azimuth_deg", path, n=n, null_ok=False)
        if not np.allclose(az, np.arange(n) * 360.0 / n, atol=1e-6):
            raise SkyfixError(f"{path}: 'azimuth_deg' must be the regular bin centres k * 360 / {n} "
                              "deg (bin k centred on k * 360 / n)")
    sig = None
    if d.get("sigma_deg") is not None:
        # > 0: a measured elevation always has some uncertainty; 0 would weigh a bin infinitely
        sig = _number_list(d, "sigma_deg", path, n=n, lo=1e-9, hi=90.0, unit=" deg (> 0)")
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
        p, r = _attitude_prior(d, where, SkyfixError)
        meta["attitude_prior"] = {"pitch_deg": p, "roll_deg": r}
    if meta.get("camera_height_m") is not None:
        meta["camera_height_m"] = _camera_height(d, f"{where}camera_height_m", SkyfixError)
    return Profile(el, sig, got, meta)
