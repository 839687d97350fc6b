"""What a long command is doing, one line per stage with its time (``skyfix.stage`` log).

The CLI shows these lines at its default verbosity (details of each stage at ``-v``, third-party
debug only at ``-vvv``); as a library, skyfix only logs them, and a program that does not
configure logging sees nothing. Progress bars follow them (:func:`bars_shown`): none with ``-q``.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager

log = logging.getLogger("skyfix.stage")


class Stage:
    """A running stage: set ``result`` to say what it found, shown with its time at the end."""

    def __init__(self, what: str):
        self.what = what
        self.result = ""
        self.t0 = time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.t0


@contextmanager
def stage(what: str):
    """Log ``what: result (N.N s)`` when the block ends (``what: failed after N.N s`` when it
    raises; the error itself is reported by whoever catches it)."""
    s = Stage(what)
    try:
        yield s
    except BaseException:
        log.info("%s: stopped after %.1f s", what, s.seconds)
        raise
    log.info("%s%s (%.1f s)", what, f": {s.result}" if s.result else "", s.seconds)


def bars_shown() -> bool:
    """Whether a command draws progress bars: where its stage lines are shown (not with -q, whose
    stderr holds errors only)."""
    return log.isEnabledFor(logging.INFO)
