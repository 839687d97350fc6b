"""``skyfix detect``: the skyline of one image, as JSON and optionally a plot."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .._io import PLOT_FORMATS, check_outputs, to_json
from ..detect.options import DEFAULT_METHOD, METHODS
from ..errors import ParameterError, SkyfixError
from ..formats.images import imread_upright, imread_whole
from .main import note



def read_image(path) -> "np.ndarray":  # noqa: F821
    """An image file as H x W x 3 RGB or H x W grey (8 or 16 bit), upright as its EXIF
    orientation says (a mask is read the same way)."""
    import cv2
    import numpy as np

    path = Path(path)
    if not path.is_file():
        raise SkyfixError(f"image {path} does not exist")
    img = imread_upright(path)
    if img is None:
        raise SkyfixError(f"cannot read {path} as an image (PNG, JPEG or TIFF expected)")
    if img.dtype.kind in "iu" and img.dtype.itemsize > 1 and img.dtype != np.uint16:
        from ..formats.images import to_8bit

        img = to_8bit(img)  # OpenCV's colour conversion takes no signed or 32-bit image
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    from ..detect import MIN_HEIGHT_PX, MIN_WIDTH_PX

    h, w = img.shape[:2]
    if w < MIN_WIDTH_PX or h < MIN_HEIGHT_PX:
        # W x H like every other size in skyfix's messages
        raise ParameterError(f"image {path} is {w} x {h} px (width x height): detection needs at "
                             f"least {MIN_WIDTH_PX} x {MIN_HEIGHT_PX} px")
    return img


def read_mask(path, shape):
    """A mask image: non-zero = valid data."""
    import cv2

    path = Path(path)
    # at its own depth: a 16-bit mask read as 8 bits lost every value below 256 (a mask of 0
    # and 1 was refused as empty, one of 1 and 1000 halved the image silently)
    m = imread_whole(path, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    if m is None:
        raise SkyfixError(f"cannot read mask {path} as an image")
    if m.shape != tuple(shape[:2]):
        raise ParameterError(
            f"mask {path} is {m.shape[1]} x {m.shape[0]} px, the image {shape[1]} x {shape[0]}: "
            "give a mask of the image's size")
    if not m.any():
        # An all-zero mask leaves nothing to search: the answer would be "no skyline" for a
        # reason that is the mask's, not the image's (an inverted mask, or one whose ones were
        # lost in a conversion).
        raise ParameterError(f"mask {path} has no non-zero pixel, so no pixel holds data: "
                             "non-zero marks valid data (check the mask is not inverted)")
    return m > 0


def plot_skyline(path, img, skyline):
    """Write the image with the detected skyline drawn over it, in the format ``path``'s suffix
    names (PNG, JPEG, PDF or SVG)."""
    from ..optional import pyplot

    plt = pyplot()
    import numpy as np

    from .._io import save_figure

    h, w = img.shape[:2]
    fig_w = min(20.0, max(6.0, w / 150))
    fig, ax = plt.subplots(figsize=(fig_w, fig_w * h / w + 0.4), dpi=150)
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None, interpolation="nearest")
    cols = np.arange(w)
    ax.plot(cols, skyline.rows, "-", color="lime", lw=0.8, label="skyline")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_axis_off()
    n = int(np.isfinite(skyline.rows).sum())
    ax.set_title(f"{skyline.image}: skyline in {n} of {w} columns", fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)


@click.command("detect")
@click.argument("image", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--mask", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Mask image of the same size: non-zero where the image holds data.")
@click.option("--method", type=click.Choice(METHODS), default=DEFAULT_METHOD, show_default=True,
              help="dp: dense-graph dynamic programming; fuse: dp with the learned sky network's "
                   "evidence (best on real photographs); net: the network alone; bayes: iterative "
                   "sky/ground likelihoods.")
@click.option("-o", "--out", "--output", "output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the skyline JSON here (default: stdout).")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Draw the image with the skyline over it (.png, .jpg, .pdf or .svg).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
def detect(image, mask, method, output, plot, overwrite):
    """Detect the skyline in IMAGE: per column the row of the first terrain pixel below the sky,
    or null where no skyline is visible."""
    from ..detect import detect_skyline
    from ..formats import write_skyline_json

    check_outputs(overwrite, ("--output", output, None), ("--plot", plot, PLOT_FORMATS),
                  inputs=(image, mask))
    img = read_image(image)
    m = read_mask(mask, img.shape) if mask is not None else None
    sky = detect_skyline(img, mask=m, method=method, name=Path(image).name)
    if output is not None:
        write_skyline_json(output, sky)
    else:
        sys.stdout.write(to_json(sky.to_dict()) + "\n")
    if plot is not None:
        plot_skyline(plot, img, sky)
    n = int(sum(1 for r in sky.rows if r == r))
    note(f"{Path(image).name}: skyline in {n} of {sky.width} columns ({method})")
