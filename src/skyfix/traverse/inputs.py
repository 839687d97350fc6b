"""Reading a traverse folder (``docs/conventions.md``, "Traverse"): the stops in order, each an
acquisition folder; the odometry between consecutive stops; an optional start fix; the truth when
a simulator wrote one. Everything is checked before any stop is processed, and every error names
the file and the line.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import AcquisitionError, OutsideDemError, ParameterError
from .ekf import Odometry

TRAVERSE_FILE = "traverse.json"
ODOMETRY_FILE = "odometry.jsonl"
TRUTH_FILE = "truth.jsonl"
ODO_KEYS = ("forward_m", "left_m", "dheading_deg")


@dataclass(frozen=True)
class Start:
    """A starting fix: (x, y) [m] in the DEM's work CRS, heading [deg from true north], 1-sigmas."""

    x: float
    y: float
    heading_deg: float
    position_sigma_m: float
    heading_sigma_deg: float


@dataclass
class Traverse:
    """A traverse folder read and checked: stop names and folders in order, ``odometry[k]`` the
    motion from stop k to stop k + 1, the start (or None), the truth per stop (or None), and
    ``leg_length_m`` [m] (a position fix each time the rover has driven that far since the last)."""

    root: Path
    stops: list[str]
    folders: list[Path]
    odometry: list[Odometry]
    start: Start | None = None
    truth: list[dict] | None = None
    leg_length_m: float = 1000.0
    meta: dict = field(default_factory=dict)


def _number(d, key, where, *, positive=False, default=None):
    v = d.get(key, default)
    if v is None:
        raise ParameterError(f"{where}: '{key}' is missing")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ParameterError(f"{where}: '{key}' must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise ParameterError(f"{where}: '{key}' must be > 0, got {v!r}")
    return float(v)


def parse_odometry(d: dict, where: str) -> Odometry:
    """One odometry record: ``forward_m``, ``left_m``, ``dheading_deg`` and either ``cov`` (3 x 3,
    [m^2, m deg, deg^2], symmetric positive definite) or ``sigma_forward_m``, ``sigma_left_m``,
    ``sigma_heading_deg`` (> 0)."""
    if not isinstance(d, dict):
        raise ParameterError(f"{where}: expected a JSON object, got {type(d).__name__}")
    vals = [_number(d, k, where) for k in ODO_KEYS]
    both = [k for k in ("sigma_forward_m", "sigma_left_m", "sigma_heading_deg") if k in d]
    if "cov" in d and both:  # one of the two would be silently ignored
        raise ParameterError(f"{where}: give 'cov' or the sigmas ({', '.join(both)}), not both")
    if "cov" in d:
        try:
            cov = np.array(d["cov"], float)
        except (TypeError, ValueError):
            raise ParameterError(f"{where}: 'cov' must be a 3 x 3 list of numbers") from None
        if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
            raise ParameterError(f"{where}: 'cov' must be a 3 x 3 list of finite numbers")
        if not np.allclose(cov, cov.T) or np.linalg.eigvalsh(cov).min() <= 0:
            raise ParameterError(f"{where}: 'cov' must be symmetric positive definite")
        return Odometry(*vals, cov)
    sig = [_number(d, k, where, positive=True)
           for k in ("sigma_forward_m", "sigma_left_m", "sigma_heading_deg")]
    return Odometry.from_sigmas(*vals, *sig)


def _jsonl(path: Path):
    for i, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            yield i, json.loads(line)
        except json.JSONDecodeError as e:
            raise ParameterError(f"{path} line {i}: not JSON ({e.msg})") from None


def read_traverse(root) -> Traverse:
    """Read and check the traverse folder ``root``."""
    root = Path(root)
    if not root.is_dir():
        raise ParameterError(f"no traverse folder {root}")
    meta = {}
    tj = root / TRAVERSE_FILE
    if tj.is_file():
        try:
            meta = json.loads(tj.read_text())
        except json.JSONDecodeError as e:
            raise ParameterError(f"{tj}: not JSON ({e.msg} at line {e.lineno})") from None
        if not isinstance(meta, dict):
            raise ParameterError(f"{tj}: expected a JSON object")
    if "stops" in meta:
        stops = meta["stops"]
        if not isinstance(stops, list) or not all(isinstance(s, str) and s for s in stops):
            raise ParameterError(f"{tj}: 'stops' must be a list of folder names")
    else:  # the sub-folders holding an acquisition, in name order
        stops = sorted(p.name for p in root.iterdir() if (p / "acquisition.json").is_file())
    if len(set(stops)) != len(stops):
        raise ParameterError(f"{tj}: a stop is listed twice")
    if len(stops) < 1:
        raise ParameterError(f"{root} holds no stop: each stop is a sub-folder with an "
                             "acquisition.json (docs/conventions.md, 'Traverse')")
    folders = [root / s for s in stops]
    for s, f in zip(stops, folders):
        if not (f / "acquisition.json").is_file():
            raise ParameterError(f"stop '{s}': no {f / 'acquisition.json'}")
    odo_path = root / ODOMETRY_FILE
    if len(stops) > 1 and not odo_path.is_file():
        raise ParameterError(f"no {odo_path}: the odometry between the stops (one JSON line per "
                             "step, docs/conventions.md, 'Traverse')")
    odometry = []
    if len(stops) > 1:
        lines = list(_jsonl(odo_path))
        for k, (i, d) in enumerate(lines):
            where = f"{odo_path} line {i}"
            if k >= len(stops) - 1:
                raise ParameterError(f"{where}: more odometry steps than the {len(stops) - 1} "
                                     f"between {len(stops)} stops")
            if isinstance(d, dict) and ("from" in d or "to" in d):
                want = (stops[k], stops[k + 1])
                if (d.get("from"), d.get("to")) != want:
                    raise ParameterError(f"{where}: step {k} goes from '{want[0]}' to '{want[1]}', "
                                         f"the line says '{d.get('from')}' to '{d.get('to')}'")
            odometry.append(parse_odometry(d, where))
        if len(odometry) != len(stops) - 1:
            raise ParameterError(f"{odo_path}: {len(odometry)} odometry steps for {len(stops)} "
                                 f"stops; one line per step between consecutive stops is needed")
    start = None
    if meta.get("start") is not None:
        s = meta["start"]
        where = f"{tj}: start"
        if not isinstance(s, dict):
            raise ParameterError(f"{where} must be an object")
        start = Start(_number(s, "x", where), _number(s, "y", where),
                      _number(s, "heading_deg", where),
                      _number(s, "position_sigma_m", where, positive=True),
                      _number(s, "heading_sigma_deg", where, positive=True))
    leg = _number(meta, "leg_length_m", str(tj), positive=True, default=1000.0)
    truth = None
    tp = root / TRUTH_FILE
    if tp.is_file():
        truth = [d for _, d in _jsonl(tp)]
        if len(truth) != len(stops):
            raise ParameterError(f"{tp}: {len(truth)} lines for {len(stops)} stops")
    return Traverse(root, list(stops), folders, odometry, start, truth, leg, meta)


def check_stops(trav: Traverse) -> list:
    """Load every stop's acquisition (its acquisition.json, and that each image it names exists
    and decodes) before the first stop is measured: a broken stop is the traverse's input error,
    to be refused now, not a failed detection found hours into the run (a stop whose images hold
    no skyline is no input error: the run meets it and asks the operator). Returns the
    :class:`skyfix.formats.Acquisition` per stop."""
    from ..formats import load_acquisition

    acqs = []
    for name, folder in zip(trav.stops, trav.folders):
        try:
            acq = load_acquisition(folder)
            for path in acq.files()[1:]:  # after its acquisition.json: the images it names
                check_image(path)
            acqs.append(acq)
        except AcquisitionError as e:
            raise AcquisitionError(f"stop '{name}' ({folder}): {str(e).splitlines()[0]}; fix or "
                                   "replace the stop's acquisition, then run again") from None
    return acqs


def check_image(path) -> None:
    """Refuse an image file OpenCV cannot decode, or decodes only in part (a truncated or corrupt
    JPEG: :func:`skyfix.formats.images.imread_whole`). Decoded at an eighth of its size: a JPEG's
    whole stream is still read, so its damage still shows, in a third of a full decode's time
    (22 against 71 ms for 2048 x 2048 pixels); a PNG is inflated whole either way."""
    import cv2

    from ..formats.images import imread_whole

    if imread_whole(path, cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
        raise AcquisitionError(f"cannot read image {path}: not an image OpenCV can decode")


def check_start(trav: Traverse, dem) -> None:
    """Refuse a start fix (traverse.json) where ``dem`` has no height: every stop would then be
    measured about a point the map does not hold."""
    s = trav.start
    if s is None:
        return
    try:
        dem.require_inside(s.x, s.y, what="the traverse's start")
    except OutsideDemError as e:
        where = TRAVERSE_FILE if trav.root is None else Path(trav.root) / TRAVERSE_FILE
        raise OutsideDemError(f"{e}: check 'start' in {where} (x, y in the "
                              "DEM's work CRS, which `skyfix info DEM` prints) or give the DEM "
                              "that covers the traverse") from None
