"""``skyfix verify``: check a skyline database block by block and re-render a sample."""

from __future__ import annotations

import click

#: exit status when every block is intact but the sample re-render asked for could not run
EXIT_SAMPLES_SKIPPED = 3


@click.command("verify")
@click.argument("db", type=click.Path())
@click.option("--dem", type=click.Path(dir_okay=False), default=None,
              help="DEM to re-render samples from (default: the path recorded at build time).")
@click.option("--samples", type=int, default=20, show_default=True,
              help="Positions re-rendered and compared (0: checksums only; at most every position).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sample draw.")
@click.pass_context
def verify(ctx, db, dem, samples, seed):
    """Check that every block of DB is present and intact, and that a sample matches the DEM.

    Exit status 0 when all is well; 3 when every block is intact but the sample re-render could
    not run (the DEM recorded at build time is gone: pass --dem, or --samples 0 to check the
    checksums only); 2 (with the problems listed) when something is wrong.
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
    elif r.samples_skipped:
        click.echo(f"samples  SKIPPED: {r.samples_skipped}")
    for f in r.sample_failures:
        click.echo(f"  {f}")
    for n in r.notes:
        click.echo(f"note     {n}")
    if not r.ok:
        # advice for what was found, not for every kind of failure
        todo = []
        if r.missing or r.corrupt:
            todo.append("rerun the build-db command to rebuild missing blocks and blocks whose "
                        "data files are gone; delete a corrupt block's marker folder, "
                        "_skyfix/blocks/rRRRR_cCCCC, to rebuild it")
        if r.dem_mismatch:
            todo.append("pass --dem the DEM the database was built from (`skyfix info DB` names it)"
                        " to re-render samples")
        elif r.sample_failures:
            todo.append("the stored skylines differ from a re-render on this DEM: rebuild the "
                        "store (build-db --overwrite) if the DEM is the right one")
        raise DatabaseError(f"{db} failed verification: {len(r.missing)} missing and {len(r.corrupt)} "
                            f"corrupt blocks, {len(r.sample_failures)} sample failures ("
                            + "; ".join(todo) + ")")
    if r.samples_skipped:
        click.echo("PARTIAL: every block intact, samples not re-rendered")
        ctx.exit(EXIT_SAMPLES_SKIPPED)
    click.echo("OK" if r.samples else "OK (checksums only)")
