"""Libraries the board segment does without, loaded only when a ground-segment feature asks.

A rover's install (``pip install skyfix``) holds what ``detect``, ``profile``, ``locate`` and
``heading`` need. Dask (building a database with worker processes), matplotlib (figures, reports,
``--plot``), scikit-learn (training the sky model, the ``bayes`` detector's online classifier) and
SciPy (simulating a world that differs from the map) come with ``pip install "skyfix[ground]"``. Asking for one of those features without them is a
:class:`MissingDependencyError` that names the install, never an ImportError traceback.
"""

from __future__ import annotations

import importlib

from .errors import SkyfixError

GROUND_INSTALL = 'pip install "skyfix[ground]"'
#: the names users know these by (the import names differ)
_PACKAGE = {"sklearn": "scikit-learn", "distributed": "Dask (distributed)", "dask": "Dask",
            "scipy": "SciPy"}


class MissingDependencyError(SkyfixError):
    """A feature needs a library that this install leaves out."""


def require(module: str, feature: str, alternative: str = ""):
    """Import and return ``module``; if it is not installed, a :class:`MissingDependencyError`
    saying that ``feature`` needs it, how to install it, and ``alternative`` if given."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        missing = (e.name or module).split(".")[0]
        if missing != module.split(".")[0]:
            raise  # the library is there but broken: its own error says more than ours would
        also = f", or {alternative}" if alternative else ""
        raise MissingDependencyError(
            f"{feature} needs {_PACKAGE.get(missing, missing)}, which this install of skyfix leaves out (the board "
            f"install): {GROUND_INSTALL}{also}") from None


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend, imported only when a figure is drawn
    (plotting stays out of the board segment's imports)."""
    matplotlib = require("matplotlib", "drawing figures")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
