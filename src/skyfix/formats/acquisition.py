"""The acquisition format of ``conventions.md`` (the board segment's input): a folder with
``acquisition.json`` and its images. :func:`load_acquisition` never exposes ``truth``;
evaluation tools call :func:`load_truth`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import write_json
from ..camera import Camera, Distortion
from ..errors import AcquisitionError
from .values import (attitude_prior_field, camera_height_field, in_range, known_fields, number_field,
                     warn_ignored)


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

    def files(self) -> list[Path]:
        """The acquisition's own files: its ``acquisition.json`` and every image it names."""
        names = [f.image for f in self.frames] + ([self.panorama.image] if self.panorama else [])
        return [self.root / ACQUISITION_FILE] + [self.image_path(n) for n in names]

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


#: [deg] the widest field of view a pinhole camera (this model) may have
MAX_PINHOLE_FOV_DEG = 170.0
#: [deg] largest |pan| of a frame: a mast turns within a turn or two; beyond ten the value is a
#: unit mistake (1e20 deg kept no direction at all)
MAX_PAN_DEG = 3600.0
#: the fields of an acquisition's camera (conventions.md)
CAMERA_FIELDS = ("width", "height", "fx", "fy", "cx", "cy", "distortion")
#: the fields of its distortion (OpenCV's order)
DISTORTION_FIELDS = ("k1", "k2", "p1", "p2", "k3")
#: the fields of a frame
FRAME_FIELDS = ("image", "pan_deg", "tilt_deg")
#: the top-level fields skyfix reads; others are the producer's and kept as they are
TOP_FIELDS = ("camera", "camera_height_m", "frames", "panorama", "attitude_prior", "truth")
#: OpenCV's distortion coefficients beyond its five (rational, thin prism, tilted sensor): a lens
#: calibrated with them is undistorted wrongly by the five alone
UNMODELLED_DISTORTION = ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY")


def _parse_camera(d) -> Camera:
    if not isinstance(d, dict):
        raise AcquisitionError("acquisition.json: 'camera' must be an object")
    w = "camera"
    known_fields(d, CAMERA_FIELDS, w, elsewhere={"camera.distortion": DISTORTION_FIELDS})
    width = number_field(d, "width", w, positive=True)
    height = number_field(d, "height", w, positive=True)
    if width != int(width) or height != int(height):
        raise AcquisitionError("camera.width and camera.height must be whole numbers of pixels")
    dist = d.get("distortion") or {}
    if not isinstance(dist, dict):
        raise AcquisitionError("camera.distortion must be an object with k1, k2, p1, p2, k3")
    known_fields(dist, DISTORTION_FIELDS, "camera.distortion")
    extra = {k: dist[k] for k in UNMODELLED_DISTORTION if k in dist and dist[k] not in (0, 0.0, None)}
    if extra:
        raise AcquisitionError(
            f"camera.distortion: {', '.join(f'{k} = {v!r}' for k, v in extra.items())}: skyfix "
            "models OpenCV's five coefficients (k1, k2, p1, p2, k3) and would undistort this lens "
            "wrongly without the others; recalibrate it with the five (cv2.calibrateCamera's default "
            "flags) or give zeros if they are")
    dist_v = {k: number_field(dist, k, "camera.distortion", 0.0) for k in DISTORTION_FIELDS}
    fx, fy = number_field(d, "fx", w, positive=True), number_field(d, "fy", w, positive=True)
    for name, f, size in (("fx", fx, width), ("fy", fy, height)):
        # a pinhole's field of view is 2 atan(size / 2f): 170 deg and more is no real lens of
        # this model (a fisheye needs another), but a focal length in mm or m, not pixels
        fov = 2.0 * math.degrees(math.atan(size / (2.0 * f)))
        if fov >= MAX_PINHOLE_FOV_DEG:
            raise AcquisitionError(
                f"camera.{name} = {f:g} px gives a field of view of {fov:.1f} deg over {size:g} px: "
                f"a pinhole camera sees less than {MAX_PINHOLE_FOV_DEG:g} deg; give the focal "
                "length in pixels (focal length / pixel pitch)")
    # The principal point of a real lens sits near the image centre (a few per cent off);
    # shifted sensors move it further, but half an image outside the frame means another
    # image size or a unit mix-up, not a lens (pixel centres span -0.5 .. size - 0.5).
    cx = in_range(number_field(d, "cx", w), -0.5 - width / 2, width - 0.5 + width / 2, "camera.cx",
                   "the principal point lies in or near the image")
    cy = in_range(number_field(d, "cy", w), -0.5 - height / 2, height - 0.5 + height / 2, "camera.cy",
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
    # r_max is the corner's distorted radius; the undistorted radii that reach it run farther
    # for a barrel lens (a fold beyond r_max itself was missed: k1 -0.15 on a 90 deg lens gave
    # its corner pixels directions 90 deg apart)
    r = np.linspace(0.0, 4.0 * r_max, 4001)
    r2 = r * r
    scale = 1 + d.k1 * r2 + d.k2 * r2 ** 2 + d.k3 * r2 ** 3
    reach = np.flatnonzero(r * scale >= r_max)
    # judged out to the farther of the two: the corner's undistorted radius and r_max itself
    end = max(int(reach[0]) + 1 if reach.size else r.size, int(np.searchsorted(r, r_max)) + 1)
    r, scale = r[:end], scale[:end]
    lo, hi = RADIAL_SCALE_RANGE
    # A distorted radius r * scale that stops growing before the corner folds the image over
    # itself: two directions on one pixel, and the undistortion no longer converges.
    folds = not reach.size or np.any(np.diff(r * scale) <= 0)
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
    return acquisition_from_dict(_read_json(root / ACQUISITION_FILE), root)


def acquisition_from_dict(data: dict, root) -> Acquisition:
    """:func:`load_acquisition`'s checks on ``acquisition.json``'s content ``data``, its images
    looked for in folder ``root``: a writer checks what it will write before it replaces a file
    (``skyfix acquisition-init --overwrite``). Raises :class:`AcquisitionError`."""
    root = Path(root)
    # a misspelt top-level field ('attitude_priors') would be lost and its default taken; any
    # other is the producer's own (the simulator's 'simulation'), kept as it is, unwarned
    known_fields(data, TOP_FIELDS, "acquisition.json", warn=False)
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
        ignored = []  # a tool's own field on every frame is one warning, not one per frame
        seen: dict[Path, int] = {}  # each image file, resolved, -> the first frame naming it
        for i, f in enumerate(frames_raw):
            where = f"frames[{i}]"
            if not isinstance(f, dict) or not isinstance(f.get("image"), str):
                raise AcquisitionError(f"{where} must be an object with an 'image' file name")
            ignored += known_fields(f, FRAME_FIELDS, where, warn=False)
            # required, as pan_deg is: a mast is rarely level (navcams look 10-25 deg down), and
            # a tilt read as 0 put every skyline that far off, the attitude solve taking it for
            # roll with full confidence
            if "tilt_deg" not in f:
                raise AcquisitionError(f"{where}: missing field 'tilt_deg' (the mast's tilt for this "
                                       "image [deg], up positive; 0 for a level camera)")
            # tilt beyond +-90 deg points the camera backwards over the top, upside down: no
            # mast does that, and 400 is a typing or unit mistake
            tilt = in_range(number_field(f, "tilt_deg", where), -90.0, 90.0, f"{where}.tilt_deg",
                             "mast tilt, up positive")
            pan = in_range(number_field(f, "pan_deg", where), -MAX_PAN_DEG, MAX_PAN_DEG,
                           f"{where}.pan_deg", "mast pan, clockwise from forward")
            # one picture at two pans made a 360 deg profile of copies; compared as files, so
            # that "./a.png" or a link is the same picture as "a.png"
            same = (root / f["image"]).resolve()
            first = seen.setdefault(same, i)
            if first != i:
                raise AcquisitionError(f"{where} and frames[{first}] both name {same.name} "
                                       f"({frames[first].image!r} and {f['image']!r}): each "
                                       "frame is its own image")
            frames.append(Frame(f["image"], pan, tilt))
        warn_ignored("frames[0]" if len(frames) == 1 else "frames", ignored, FRAME_FIELDS)
    else:
        if not isinstance(pano_raw, dict) or not isinstance(pano_raw.get("image"), str):
            raise AcquisitionError("acquisition.json: 'panorama' must be an object with an 'image'")
        w = "panorama"
        known_fields(pano_raw, ("image", "azimuth_left_deg", "hfov_deg", "elevation_top_deg",
                                "vfov_deg"), w)
        panorama = PanoramaSpec(
            pano_raw["image"],
            number_field(pano_raw, "azimuth_left_deg", w, -180.0),
            number_field(pano_raw, "hfov_deg", w, 360.0, positive=True),
            number_field(pano_raw, "elevation_top_deg", w, 30.0),
            number_field(pano_raw, "vfov_deg", w, 60.0, positive=True),
        )
        if panorama.hfov_deg > 360.0:
            raise AcquisitionError("panorama.hfov_deg must be at most 360")
        # elevations are angles above the horizontal: the image spans top .. top - vfov, and
        # both ends must lie between the nadir (-90) and the zenith (+90)
        in_range(panorama.elevation_top_deg, -90.0, 90.0, "panorama.elevation_top_deg",
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
    h = camera_height_field(data, "camera_height_m")
    pitch, roll = attitude_prior_field(data, "")
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
        number_field(t, "x", "truth"), number_field(t, "y", "truth"), number_field(t, "yaw_deg", "truth"),
        number_field(t, "pitch_deg", "truth", 0.0), number_field(t, "roll_deg", "truth", 0.0),
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
