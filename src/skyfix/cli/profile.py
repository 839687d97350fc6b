"""``skyfix profile``: an acquisition folder -> body-frame angular skyline profile (JSON)."""

from __future__ import annotations

from pathlib import Path

import click

from .main import note
from .options import detector_option


@click.command("profile")
@click.argument("acq_dir", type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(["project", "stitch"]), default="project", show_default=True,
              help="project: per-frame projection through the known pointing; stitch: OpenCV panorama "
                   "(pointing unknown or poor). A panorama acquisition is read directly.")
@click.option("--azimuth-bins", type=int, default=360, show_default=True,
              help="Bins over 360 deg; bin k is centred on k*360/n deg.")
@detector_option
@click.option("--no-refine", is_flag=True, help="Keep the nominal pan angles (project).")
@click.option("-o", "--out", "--output", "output", type=click.Path(path_type=Path),
              help="Profile JSON (default: stdout).")
@click.option("--plot", type=click.Path(path_type=Path),
              help="Also draw the profile to this file (.png, .jpg, .pdf or .svg).")
@click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
def profile(acq_dir, method, azimuth_bins, detector, no_refine, output, plot, overwrite):
    """Turn the acquisition in ACQ_DIR into an angular skyline profile in the rover's body frame."""
    from .._io import PLOT_FORMATS, check_not_inputs, check_outputs, to_json
    from ..formats import load_acquisition, write_profile_json
    from ..profile import PanRefinement, acquisition_profile

    outputs = (("--output", output, None), ("--plot", plot, PLOT_FORMATS))
    check_outputs(overwrite, *outputs)
    acq = load_acquisition(acq_dir)
    check_not_inputs(outputs, acq.files())
    prof = acquisition_profile(acq, method=method, azimuth_bins=azimuth_bins, detector=detector,
                               refine=PanRefinement(enabled=not no_refine))
    if output is not None:
        write_profile_json(output, prof)
        m = prof.meta
        note(f"{output}: {m.get('coverage_deg', 0):.0f} deg observed, method {m.get('method')}, "
             f"{m.get('frames_used', 1)} frame(s) used, {m.get('frames_dropped', 0)} dropped")
    else:
        click.echo(to_json(prof.to_dict()))
    if plot is not None:
        plot_profile(prof, plot, title=f"{acq_dir} ({prof.meta.get('method')})")


def plot_profile(prof, path, title: str = "") -> None:
    """Elevation [deg] vs body azimuth [deg] with a 2-sigma band, written atomically to ``path``
    in the format its suffix names (PNG, JPEG, PDF or SVG)."""
    from ..optional import pyplot

    plt = pyplot()
    import numpy as np

    from .._io import save_figure

    az = prof.azimuth_deg
    el = prof.elevation_deg
    fig, ax = plt.subplots(figsize=(10, 3.2))
    ax.plot(az, el, lw=1.0, color="k", label="skyline")
    if prof.sigma_deg is not None:
        s = np.nan_to_num(prof.sigma_deg)
        ax.fill_between(az, el - 2 * s, el + 2 * s, color="tab:blue", alpha=0.3, label="2 sigma")
    ax.set_xlim(0, 360)
    ax.set_xlabel("azimuth from the rover's forward axis [deg]")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(title)
    ax.legend(loc="upper right")
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)
