"""A skyline: per image column, the row of the first terrain pixel below the sky or none, as JSON
(``skyfix detect -o`` and the ``*.skyline.json`` truth files).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import write_json
from ..errors import SkyfixError
from .values import json_object, number_list, whole_number


@dataclass
class Skyline:
    """Per image column: skyline row [px, sub-pixel, 0-based] or NaN where none is visible.

    confidence : per-column confidence in [0, 1] (NaN when unknown)
    valid : per-column flag, False where the column holds no image data
    """

    rows: np.ndarray
    width: int
    height: int
    image: str = ""
    confidence: np.ndarray | None = None
    valid: np.ndarray | None = None

    @property
    def has_skyline(self) -> np.ndarray:
        return np.isfinite(self.rows)

    def to_dict(self) -> dict:
        d = {"image": self.image, "width": int(self.width), "height": int(self.height),
             "rows": [None if not np.isfinite(r) else round(float(r), 3) for r in self.rows]}
        if self.confidence is not None:
            d["confidence"] = [None if not np.isfinite(c) else round(float(c), 4) for c in self.confidence]
        if self.valid is not None:
            d["valid"] = [bool(v) for v in self.valid]
        return d


def write_skyline_json(path, skyline: Skyline) -> Path:
    """Write ``skyline`` as one-line JSON to ``path`` atomically; returns the path."""
    return write_json(path, skyline.to_dict(), indent=None)


def read_skyline_json(path) -> Skyline:
    """Read and validate a skyline JSON file (``conventions.md``, "A skyline").

    Raises :class:`SkyfixError` naming the field when one breaks the format: ``width`` must
    equal the number of ``rows``; rows [px] lie in the image (-1 .. height: a sub-pixel edge
    may sit half a pixel past the first or last row centre); ``confidence`` in [0, 1];
    ``valid`` true/false, one per column.
    """
    path = Path(path)
    d = json_object(path, "skyline")
    for key in ("rows", "height"):
        if key not in d:
            raise SkyfixError(f"{path} is not a skyline JSON file: missing field '{key}'")
    height = whole_number(d, "height", path)
    if not isinstance(d["rows"], list) or not d["rows"]:
        raise SkyfixError(f"{path}: 'rows' must be a non-empty list, one entry per image column")
    n = len(d["rows"])
    width = whole_number(d, "width", path) if "width" in d else n
    if width != n:
        raise SkyfixError(f"{path}: 'width' is {width} but 'rows' has {n} entries: one row per "
                          "image column")
    rows = number_list(d, "rows", path, lo=-1.0, hi=float(height), unit=f" px (image height {height})")
    conf = None
    if d.get("confidence") is not None:
        conf = number_list(d, "confidence", path, n=n, lo=0.0, hi=1.0)
    valid = None
    if d.get("valid") is not None:
        v = d["valid"]
        bad = (f"got {v!r}" if not isinstance(v, list) else
               f"it has {len(v)}" if len(v) != n else
               next((f"valid[{i}] is {x!r}" for i, x in enumerate(v) if not isinstance(x, bool)), None))
        if bad is not None:
            # "yes" or 1 would be truthy and silently change which columns are scored
            raise SkyfixError(f"{path}: 'valid' must be a list of {n} true/false values, one per "
                              f"column: {bad}")
        valid = np.array(v, dtype=bool)
    image = d.get("image", "")
    if not isinstance(image, str):
        raise SkyfixError(f"{path}: 'image' must be a file name, got {image!r}")
    return Skyline(rows=rows, width=width, height=height, image=image, confidence=conf, valid=valid)
