"""``skyfix demo``: the whole pipeline once, on bundled or generated data."""

from __future__ import annotations

import click

from .options import overwrite_option


@click.command()
@click.option("--out", type=click.Path(file_okay=False), default="skyfix-demo", show_default=True,
              help="Output folder.")
@click.option("--seed", type=int, default=4, show_default=True, help="Where the rover is hidden.")
@overwrite_option
def demo(out, seed, overwrite):
    """Build a small skyline database from a real DEM (../shared/data, else a generated one),
    simulate a rover's 360 deg frame set at a hidden position, detect its skyline, locate it,
    and print the fix and its error."""
    from ..demo import run_demo

    run_demo(out, seed=seed, overwrite=overwrite, say=click.echo)
