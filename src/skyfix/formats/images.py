"""Image files read whole, or refused.

OpenCV decodes a truncated or damaged JPEG without an error: libjpeg only warns on the process's
standard error ("Premature end of JPEG file") and fills what it could not read with grey, on which
a detector then finds a skyline (``fuse`` found one in all 1388 columns of a JPEG cut to an eighth,
exit 0). The decoder's own warnings are caught around the read and turn into a refusal naming the
file; anything else the decoder says is passed on.

A camera that was held on its side writes its pixels as the sensor read them and an EXIF
orientation tag that says how to turn them upright; every viewer turns them. Read as stored
(``cv2.IMREAD_UNCHANGED`` ignores the tag), such a photo had its sky at the side: no skyline in
any column, and a message about exposure. :func:`imread_upright` reads images as they are meant
to be seen.
"""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import AcquisitionError, ParameterError

#: libjpeg's warnings for data it could not decode (jerror.h: JWRN_JPEG_EOF, JWRN_HIT_MARKER,
#: JWRN_EXTRANEOUS_DATA and the corrupt-data family)
JPEG_DAMAGE = (b"Premature end of JPEG file", b"Corrupt JPEG data")


@contextmanager
def _stderr_to(f):
    """File descriptor 2 (where C libraries write) redirected to the file ``f`` meanwhile."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        os.dup2(f.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def imread_upright(path):
    """An image as its camera meant it to be seen (the EXIF orientation applied; a JPEG without
    the tag, a PNG or a TIFF as stored), at its own bit depth, grey or colour (BGR), any alpha
    channel dropped; refused or None as :func:`imread_whole`."""
    import cv2

    return imread_whole(path, cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)


def full_scale(img) -> int:
    """The value white has in an integer image: 2**bits - 1 for the fewest bits, from 8 to its
    type's, that hold its largest value (a 12-bit camera's 16-bit PNG is 0-4095, not 0-65535)."""
    top = int(img.max()) if img.size else 0
    return (1 << min(8 * img.dtype.itemsize, max(8, top.bit_length()))) - 1


def to_8bit(img):
    """A 16-bit image (or one of another integer type) as uint8 at its effective bit depth (the
    fewest bits, from 8, that hold its largest value: a 12-bit camera's PNG is 0-4095, not
    0-65535), 8-bit and float images unchanged; negative values are refused. A
    pixel above zero stays above zero: black is no data to the detectors. Taken as full 16-bit,
    12-bit data came out a sixteenth as bright, and the network found its skyline in 212 of
    1388 columns (1388 at 8 bits)."""
    import cv2
    import numpy as np

    dtype = getattr(img, "dtype", None)
    if dtype is None or dtype == np.uint8 or dtype.kind not in "iu":
        return img
    if dtype.kind == "i" and img.size and int(img.min()) < 0:
        raise ParameterError(f"the image holds negative values ({dtype}, down to {int(img.min())}): "
                             "a camera image has none; convert it to unsigned 8 or 16 bits")
    if dtype == np.uint16:
        out = cv2.convertScaleAbs(img, alpha=255.0 / full_scale(img))
    else:
        # other integer types (signed 16-bit, 32-bit) at their effective depth as well: cast
        # to 8 bits (clipped at 255) a 0-10000 int16 image read as all sky, an RGB one failed
        # in OpenCV's colour conversion
        out = np.clip(np.rint(np.asarray(img, np.float64) * (255.0 / full_scale(img))), 0, 255)
        out = out.astype(np.uint8)
    out[(out == 0) & (img > 0)] = 1
    return out


def imread_whole(path, flags):
    """``cv2.imread(path, flags)``, refused with an :class:`AcquisitionError` naming the file when
    the decoder reports data it could not read (a truncated or corrupt JPEG); None where OpenCV
    cannot decode the file at all, as ``cv2.imread``."""
    import cv2

    with tempfile.TemporaryFile() as f:
        with _stderr_to(f):
            img = cv2.imread(str(path), flags)
        f.seek(0)
        said = f.read()
    damage = [m for m in JPEG_DAMAGE if m in said]
    if damage:
        raise AcquisitionError(f"image {Path(path)} is damaged or truncated (the JPEG decoder: "
                               f"{damage[0].decode()}): replace it with a whole copy")
    if said:
        os.write(2, said)
    return img
