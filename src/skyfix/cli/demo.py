"""``skyfix demo``: the whole pipeline once, on bundled or generated data."""

from __future__ import annotations

import click


@click.command()
@click.option("-o", "--out", type=click.Path(file_okay=False), default="skyfix-demo", show_default=True,
              help="Output folder: new, empty, or an earlier demo's (rebuilt).")
@click.option("--seed", type=int, default=4, show_default=True, help="Where the rover is hidden (>= 0).")
@click.option("--overwrite", is_flag=True,
              help="Replace the demo's files in a non-empty --out that is not an earlier demo's.")
def demo(out, seed, overwrite):
    """Build a small skyline database from a real DEM (../shared/data, else a generated one),
    simulate a rover's 360 deg frame set at a hidden position, detect its skyline, locate it,
    and print the fix and its error."""
    from ..demo import run_demo
    from .._io import writing_to
    from ..optional import require

    require("matplotlib", "skyfix demo (its figures)")

    from ..progress import bars_shown

    shown = bars_shown()  # -q: the fix and its error only, no stage lines or progress bar
    with writing_to(out):
        run_demo(out, seed=seed, overwrite=overwrite, say=click.echo if shown else lambda m: None,
                 tell=click.echo, progress=shown)
