"""``skyfix verify``: check a skyline database block by block and re-render a sample."""

from __future__ import annotations

import click


@click.command("verify")
@click.argument("db", type=click.Path())
@click.option("--dem", type=click.Path(dir_okay=False), default=None,
              help="DEM to re-render samples from (default: the path recorded at build time).")
@click.option("--samples", type=int, default=20, show_default=True,
              help="Positions re-rendered and compared (0: checksums only).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sample draw.")
def verify(db, dem, samples, seed):
    """Check that every block of DB is present and intact, and that a sample matches the DEM.

    Exit status 0 when all is well, 2 (with the problems listed) otherwise.
    """
    from ..database import verify_database
    from ..errors import DatabaseError

    r = verify_database(db, dem=dem, samples=samples, seed=seed)
    intact = r.n_blocks - len(r.missing) - len(r.corrupt)
    click.echo(f"blocks   {intact} of {r.n_blocks} present and intact")
    for b in r.missing:
        click.echo(f"  missing block {b}")
    for b, why in r.corrupt:
        click.echo(f"  corrupt block {b}: {why}")
    if r.samples:
        click.echo(f"samples  {r.samples} positions re-rendered, max difference "
                   f"{r.sample_max_error_deg:.4f} deg")
    for f in r.sample_failures:
        click.echo(f"  {f}")
    for n in r.notes:
        click.echo(f"note     {n}")
    if not r.ok:
        raise DatabaseError(f"{db} failed verification: {len(r.missing)} missing and {len(r.corrupt)} "
                            f"corrupt blocks, {len(r.sample_failures)} sample failures (rebuild missing "
                            "blocks by rerunning build-db; delete a corrupt block's marker to rebuild it)")
    click.echo("OK")
