"""Reading an acquisition's images and detecting their skylines (the detector is any callable with
:func:`skyfix.detect.detect_skyline`'s signature, or a method name).
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from ..errors import AcquisitionError, DetectionError
from ..formats import Acquisition, Skyline
from ..formats.images import imread_upright, to_8bit


#: A detector: RGB uint8 image (H, W, 3) and a validity mask (or None) -> Skyline.
Detector = Callable[..., Skyline]

log = logging.getLogger(__package__)  # messages name the stage, as before the split



def read_rgb(path) -> np.ndarray:
    """An image as RGB uint8 (H, W, 3), upright as its EXIF orientation says; 16-bit images are
    scaled down from their effective bit depth (:func:`~skyfix.formats.images.to_8bit`)."""
    import cv2

    img = imread_upright(path)
    if img is None:
        raise AcquisitionError(f"cannot read image {path}: not an image OpenCV can decode")
    img = to_8bit(img)  # at its own bit depth: >> 8 made a 12-bit camera's frames nearly black
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(img)


def get_detector(detector: str | Detector | None = None) -> Detector:
    """A detector callable ``(rgb, mask=None) -> Skyline`` from a method name (None: the
    default method of :mod:`skyfix.detect`) or a callable."""
    if callable(detector):
        return detector
    from ..detect import DEFAULT_METHOD, detect_skyline  # the sibling stage; only when detecting

    method = detector or DEFAULT_METHOD

    def run(image, mask=None, name=""):
        return detect_skyline(image, mask=mask, method=method, name=name)

    return run


def detect_frames(acq: Acquisition, detector: str | Detector | None = None) -> list[Skyline | None]:
    """Detect the skyline in every frame; a frame whose detection raises DetectionError is None."""
    det = get_detector(detector)
    # a method's detector takes the frame's name (its -v line names the frame); a caller's own
    # callable is called as the Detector protocol says
    named = not callable(detector)
    out: list[Skyline | None] = []
    for f in acq.frames:
        img = read_rgb(acq.image_path(f.image))
        h, w = img.shape[:2]
        if (w, h) != (acq.camera.width, acq.camera.height):
            raise AcquisitionError(
                f"image {f.image} is {w} x {h} px but camera is {acq.camera.width} x {acq.camera.height}")
        try:
            s = det(img, mask=None, name=f.image) if named else det(img, mask=None)
            s.image = s.image or f.image
            out.append(s)
        except DetectionError as e:
            log.warning("frame %s: %s", f.image, e)
            out.append(None)
    return out
