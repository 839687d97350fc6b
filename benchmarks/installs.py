"""Which skyfix a benchmark's child process runs: this checkout's, or another install's.

A board install (``scripts/board_install.sh DIR``) is measured by running its own Python
(``--board-python DIR/bin/python``), and that Python must import its own skyfix, never the
sources a ``PYTHONPATH`` set for this run points at.
"""

from __future__ import annotations

import os
import sys


def is_other_install(python: str) -> bool:
    """Whether ``python`` is another interpreter than the one running this benchmark. Compared
    by path unresolved: every venv's python is a link to the same interpreter binary."""
    return os.path.abspath(python) != os.path.abspath(sys.executable)


def child_env(python: str, own_src: str | None = None) -> dict:
    """The environment for a child process run by ``python``: without ``PYTHONPATH`` for another
    install (it measures its own skyfix); else this one's, with ``PYTHONPATH=own_src`` where
    given."""
    if is_other_install(python):
        return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return dict(os.environ, PYTHONPATH=own_src) if own_src else dict(os.environ)


def load_average() -> str:
    """The 1, 5 and 15 minute load averages: every time a benchmark prints is read beside them
    (this machine is shared)."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())
