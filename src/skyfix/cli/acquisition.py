"""``skyfix acquisition-init``: write a checked ``acquisition.json`` for a folder of a camera's
images, from what a rover engineer knows about the camera (``conventions.md``, "An
acquisition")."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..errors import ParameterError
from ..formats.images import imread_upright
from .main import note


def _floats(text, name):
    try:
        return [float(v) for v in str(text).replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise ParameterError(f"{name} must be comma-separated numbers, got {text!r}") from None


def _view_warnings(hfov_deg: float, pans: list) -> list[str]:
    """What looks like a unit or typing mistake in a camera's field of view and its pans [deg]
    (written anyway: a user may mean it): a view of under 2 deg (radians given as degrees), and
    neighbouring images far apart or nearly on top of each other for that view."""
    out = []
    if hfov_deg < 2.0:
        out.append(f"a horizontal field of view of {hfov_deg:.3g} deg: was it given in radians "
                   f"({math.degrees(hfov_deg):.1f} deg)?")
    steps = sorted(abs(b - a) for a, b in zip(pans, pans[1:]))
    if steps:
        step = steps[len(steps) // 2]
        if step > 1.5 * hfov_deg:
            out.append(f"images {step:g} deg apart with a {hfov_deg:.1f} deg view leave gaps between "
                       "them: check the pans and the field of view")
        elif step < hfov_deg / 20:
            out.append(f"images only {step:.3g} deg apart with a {hfov_deg:.1f} deg view nearly "
                       "overlap: were the pans given in radians?")
    return out


@click.command("acquisition-init")
@click.argument("folder", type=click.Path(file_okay=False, exists=True))
@click.option("--images", default="*.png", show_default=True,
              help="Glob of the images in FOLDER, in pan order (sorted by name).")
@click.option("--hfov-deg", type=float, help="Horizontal field of view [deg] (or --focal-px).")
@click.option("--focal-px", type=float, help="Focal length [px] (fx = fy; or --hfov-deg).")
@click.option("--pan-deg", help="Pan of each image [deg], comma-separated, clockwise from the "
                                "rover's forward axis (or --pan-step-deg).")
@click.option("--pan-step-deg", type=float, help="Pan step between consecutive images [deg].")
@click.option("--pan-start-deg", type=float, default=0.0, show_default=True,
              help="Pan of the first image with --pan-step-deg [deg].")
@click.option("--tilt-deg", type=float, required=True,
              help="Mast tilt of every image, up positive [deg]; 0 for a level camera.")
@click.option("--camera-height-m", type=float, required=True,
              help="Camera centre above the ground [m].")
@click.option("--distortion", default=None,
              help="OpenCV distortion k1,k2,p1,p2,k3 (default none).")
@click.option("--prior-pitch-deg", type=float, default=0.0, show_default=True,
              help="Inclinometer pitch, nose up positive [deg].")
@click.option("--prior-roll-deg", type=float, default=0.0, show_default=True,
              help="Inclinometer roll, right side down positive [deg].")
@click.option("--overwrite", is_flag=True, help="Replace an existing acquisition.json.")
def acquisition_init(folder, images, hfov_deg, focal_px, pan_deg, pan_step_deg, pan_start_deg,
                     tilt_deg, camera_height_m, distortion, prior_pitch_deg, prior_roll_deg,
                     overwrite):
    """Describe FOLDER's images as an acquisition: camera intrinsics (from the first image's size
    and the field of view or focal length, principal point at the centre), each image's pan and
    tilt, the camera height and the attitude prior. It is checked as ``skyfix locate`` will read
    it before it is written. Images are taken upright as their EXIF orientation says."""
    from .._io import check_can_write
    from ..camera import Camera, Distortion
    from ..formats import ACQUISITION_FILE, Acquisition, Frame, acquisition_from_dict, save_acquisition

    root = Path(folder)
    names = sorted(p.name for p in root.glob(images) if p.is_file())
    if not names:
        raise ParameterError(f"no image matches {images!r} in {root}: give --images")
    if (hfov_deg is None) == (focal_px is None):
        raise ParameterError("give the camera's --hfov-deg or its --focal-px (one of them)")
    if (pan_deg is None) == (pan_step_deg is None):
        raise ParameterError("give every image's --pan-deg, or --pan-step-deg (one of them)")
    if pan_step_deg is not None:
        if not (math.isfinite(pan_start_deg) and math.isfinite(pan_step_deg) and pan_step_deg != 0):
            raise ParameterError(f"--pan-start-deg must be finite and --pan-step-deg finite and not 0 "
                                 f"(negative pans the other way), got {pan_start_deg:g} and "
                                 f"{pan_step_deg:g}")
        # a turn's images a step apart never wrap past a full circle onto each other
        if (len(names) - 1) * abs(pan_step_deg) >= 360.0:
            raise ParameterError(f"{len(names)} images every {pan_step_deg:g} deg span more than "
                                 "360 deg: check --pan-step-deg, or give each --pan-deg")
    check_can_write(root / ACQUISITION_FILE, overwrite)
    first = imread_upright(root / names[0])
    if first is None:
        raise ParameterError(f"cannot read {root / names[0]} as an image")
    h, w = first.shape[:2]
    if hfov_deg is not None:
        if not (math.isfinite(hfov_deg) and 0 < hfov_deg < 180):
            raise ParameterError(f"--hfov-deg must be in (0, 180), got {hfov_deg}")
        focal_px = (w / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise ParameterError(f"--focal-px must be > 0, got {focal_px}")
    pans = (_floats(pan_deg, "--pan-deg") if pan_deg is not None else
            [pan_start_deg + k * pan_step_deg for k in range(len(names))])
    if len(pans) != len(names):
        raise ParameterError(f"{len(pans)} pans for {len(names)} images ({', '.join(names[:4])}"
                             f"{' ...' if len(names) > 4 else ''}): give one pan per image")
    hfov = math.degrees(2 * math.atan(w / 2 / focal_px))
    for warning in _view_warnings(hfov, pans):
        note(f"warning: {warning}")
    dist = Distortion()
    if distortion:
        d = _floats(distortion, "--distortion")
        if len(d) != 5:
            raise ParameterError(f"--distortion takes k1,k2,p1,p2,k3 (5 numbers), got {len(d)}")
        dist = Distortion(*d)
    cam = Camera(width=w, height=h, fx=focal_px, fy=focal_px, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0,
                 distortion=dist)
    acq = Acquisition(root=root, camera=cam, camera_height_m=camera_height_m,
                      frames=tuple(Frame(n, p, tilt_deg) for n, p in zip(names, pans)),
                      prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    # checked before it is written: a refused --overwrite leaves the file that was there
    back = acquisition_from_dict(acq.to_dict(), root)  # the localiser's own checks, every field
    for f in back.frames:
        im = imread_upright(root / f.image)
        if im is None or im.shape[:2] != (h, w):
            raise ParameterError(f"{f.image} is not a {w} x {h} image like {names[0]}: one camera, "
                                 "one image size")
    path = save_acquisition(root, acq)
    click.echo(f"wrote {path}: {len(names)} images of {w} x {h} px, focal {focal_px:.1f} px "
               f"(horizontal field of view {hfov:.1f} deg), "
               f"pans {pans[0]:g} .. {pans[-1]:g} deg, tilt {tilt_deg:g} deg, camera "
               f"{camera_height_m:g} m above the ground")
