"""The ``skyfix`` command group.

Subcommands are imported only when invoked, so ``skyfix --help`` stays instant and heavy
modules (numba, cv2, dask, matplotlib) load only for the command that needs them. A
:class:`~skyfix.errors.SkyfixError` (or an OS error: a disk or permission problem) is printed
as one line and exits with status 2.
"""

from __future__ import annotations

import importlib
import logging
import sys

import click

from .. import __version__
from ..errors import ParameterError, SkyfixError

#: command name -> (module under skyfix.cli, function name, one-line help)
COMMANDS = {
    "horizon": ("horizon", "horizon", "Render the skyline a DEM predicts from one point."),
    "build-db": ("build_db", "build_db", "Build a skyline database over a search area."),
    "info": ("info", "info", "Describe a skyline database or a DEM."),
    "verify": ("verify", "verify", "Check a skyline database block by block."),
    "simulate": ("simulate", "simulate", "Simulate a rover acquisition from a DEM."),
    "simulate-set": ("simulate", "simulate_set", "Simulate a named robustness set."),
    "detect": ("detect", "detect", "Detect the skyline in an image."),
    "profile": ("profile", "profile", "Turn an acquisition into an angular skyline profile."),
    "locate": ("locate", "locate", "Find position, heading and attitude from an acquisition."),
    "heading": ("heading", "heading", "Find the heading only, from a rough position."),
    "attitude": ("heading", "attitude", "Find roll, pitch and heading from one frame at a known position."),
    "demo": ("demo", "demo", "Run the whole pipeline on bundled or generated data."),
    "evaluate": ("evaluate", "evaluate", "Evaluate a scenario on simulated cases."),
    "evaluate-detect": ("evaluate", "evaluate_detect", "Score skyline detection on labelled images."),
    "traverse": ("traverse", "traverse",
                 "Fuse a traverse's odometry with skyline headings and position fixes."),
    "simulate-traverse": ("traverse", "simulate_traverse",
                          "Simulate a traverse: stops, odometry with drift, truth."),
    "acquisition-init": ("acquisition", "acquisition_init",
                         "Write a checked acquisition.json for a folder of your camera's images."),
}


#: commands whose output a rerun continues rather than redoes
RESUMABLE = {"build-db", "traverse", "simulate-traverse"}

#: the board segment's commands: they run on a rover in 256 MB (skyfix.cli.heap)
BOARD = {"detect", "profile", "locate", "heading", "attitude"}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return list(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module, attr, _ = COMMANDS[name]
        if name in BOARD:
            from .heap import board_heap

            board_heap()
        try:
            mod = importlib.import_module(f"skyfix.cli.{module}")
        except ModuleNotFoundError as e:
            if e.name == f"skyfix.cli.{module}":
                return None
            raise
        return with_verbosity_options(getattr(mod, attr))

    def format_commands(self, ctx, formatter):
        # Help text from the table, without importing every subcommand module.
        rows = [(name, help_) for name, (_, _, help_) in COMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            # One line, not the tracebacks of every frame (and worker) that was interrupted.
            name = ctx.invoked_subcommand or ""
            hint = ("; run the same command again to resume where it stopped"
                    if name in RESUMABLE else "")
            click.echo(f"interrupted{hint}", err=True)
            ctx.exit(130)
        except SkyfixError as e:
            raise UserError(str(e)) from None
        except BrokenPipeError:
            raise  # stdout piped into `head`: click handles it
        except OSError as e:
            # Writers turn their own OS errors into SkyfixError ("cannot write PATH: ..."); one
            # that still escapes is the environment's (a file vanished, a disk failed, a folder
            # turned read-only) and gets a line, not a traceback. -vv logs the traceback.
            logging.getLogger("skyfix").debug("OS error", exc_info=True)
            where = f": {e.filename}" if e.filename else ""
            raise UserError(f"{e.strerror or e}{where} "
                            "(check the path, its permissions and free disk space)") from None


#: ctx.meta key: the -v count and -q given so far, the group's first, then the subcommand's
VERBOSITY = "skyfix.verbosity"

VERBOSE_HELP = "More log output: -v skyfix's details, -vv its debug, -vvv everyone's debug."
QUIET_HELP = "Only errors on stderr (no stage lines, warnings, progress bars or summaries)."


def _verbosity_after(ctx, param, value):
    """Callback of a subcommand's -v/-q: added to the group's (``skyfix -v locate ... -v`` is
    -vv; -q anywhere is quiet) and logging configured again, before the command runs."""
    given = ctx.meta.setdefault(VERBOSITY, {"verbose": 0, "quiet": False})
    if param.name == "verbose" and value:
        given["verbose"] += value
    elif param.name == "quiet" and value:
        given["quiet"] = True
    else:
        return  # not given here: the group's configuration stands
    check_verbosity(given["verbose"], given["quiet"])
    configure_logging(given["verbose"], given["quiet"])


def check_verbosity(verbose: int, quiet: bool) -> None:
    """Refuse -v with -q, wherever each was given: they do not count against each other (-q
    silenced everything -v asked for, without a word)."""
    if verbose and quiet:
        raise ParameterError("give -v or -q, not both (-v: more log output, -q: errors only)")


def with_verbosity_options(cmd):
    """``cmd`` with -v/--verbose and -q/--quiet of its own, meaning what the group's mean: users
    put them after the subcommand as often as before it, and click knew them only before. Added
    once (``attitude`` shares ``heading``'s parameter list)."""
    if cmd is not None and not any(p.name == "verbose" for p in cmd.params):
        cmd.params.extend([
            click.Option(["-v", "--verbose"], count=True, expose_value=False,
                         callback=_verbosity_after, help=VERBOSE_HELP),
            click.Option(["-q", "--quiet"], is_flag=True, expose_value=False,
                         callback=_verbosity_after, help=QUIET_HELP)])
    return cmd


class UserError(click.ClickException):
    """A SkyfixError as the CLI reports it: ``Error: <message>``, exit status 2."""

    exit_code = 2


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="skyfix")
@click.option("-v", "--verbose", count=True, help=VERBOSE_HELP)
@click.option("-q", "--quiet", is_flag=True, help=QUIET_HELP)
@click.pass_context
def cli(ctx, verbose: int, quiet: bool):
    """skyfix: where a rover is and which way it faces, from the skyline."""
    # a subcommand's own -v/-q add to these (with_verbosity_options)
    ctx.meta[VERBOSITY] = {"verbose": verbose, "quiet": quiet}
    check_verbosity(verbose, quiet)
    configure_logging(verbose, quiet)


def configure_logging(verbose: int, quiet: bool) -> None:
    """Warnings and one line per stage by default (``skyfix.stage``); skyfix's info at -v, its
    debug at -vv; third-party libraries stay at warnings until -vvv."""
    root = logging.getLogger()
    for h in list(root.handlers):  # ours from an earlier call in this process (tests), no other
        if getattr(h, "_skyfix", False):
            root.removeHandler(h)
    handler = logging.StreamHandler(sys.stderr)
    handler._skyfix = True
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    root.setLevel(logging.ERROR if quiet else (logging.DEBUG if verbose >= 3 else logging.WARNING))
    sky = logging.getLogger("skyfix")
    sky.setLevel(logging.ERROR if quiet else
                 (logging.WARNING, logging.INFO, logging.DEBUG, logging.DEBUG)[min(verbose, 3)])
    stages = logging.getLogger("skyfix.stage")
    stages.setLevel(logging.ERROR if quiet else logging.INFO)
    stages.propagate = False
    for h in list(stages.handlers):
        stages.removeHandler(h)
    plain = logging.StreamHandler(sys.stderr)
    plain.setFormatter(logging.Formatter("%(message)s"))
    stages.addHandler(plain)
    if quiet:
        quiet_opencv()


def note(message: str) -> None:
    """A line for the user on stderr, a summary or a warning: none with -q (errors only)."""
    if logging.getLogger("skyfix").isEnabledFor(logging.WARNING):
        click.echo(message, err=True)


def quiet_opencv() -> None:
    """OpenCV's warnings to errors: it logs on its own, to file descriptor 2, past Python's
    logging ("[ WARN:0@0.0] ... TIFF_Warning ..." for every GeoTIFF tag, with -q too)."""
    import os

    os.environ["OPENCV_LOG_LEVEL"] = "ERROR"  # read when cv2 is loaded: most commands load it later
    cv2 = sys.modules.get("cv2")
    if cv2 is not None:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def main():  # console-script entry point
    cli()


if __name__ == "__main__":
    main()
