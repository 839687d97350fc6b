"""Strict readers of JSON values shared by every format: each error names the file and the field
and says what was expected.
"""

from __future__ import annotations

import difflib
import json
import logging
import math
import re
from pathlib import Path

import numpy as np

from ..errors import AcquisitionError, SkyfixError

log = logging.getLogger(__name__)

#: [m] highest camera above the ground skyfix accepts. A rover's mast is ~2 m and a drone or
#: balloon a few km; from 100 km up the skyline is the planet's limb, not the DEM's terrain
#: (1e9 m gave -90 deg in every bin without a word), so anything higher is a unit mistake.
MAX_CAMERA_HEIGHT_M = 100_000.0


#: [deg] largest inclinometer pitch or roll: a rover on the ground (the simulator's bound too;
#: rovers are rated to ~45 deg, tipping over well before 60).
MAX_PRIOR_TILT_DEG = 60.0


def number_field(obj: dict, key: str, where: str, default=None, *, positive=False, required=True) -> float:
    """``obj[key]`` as a finite float (> 0 with ``positive``), ``default`` when absent and allowed;
    an :class:`AcquisitionError` naming ``where`` otherwise."""
    if key not in obj:
        if default is not None or not required:
            return default
        raise AcquisitionError(f"{where}: missing field '{key}'")
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise AcquisitionError(f"{where}.{key} must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise AcquisitionError(f"{where}.{key} must be > 0, got {v!r}")
    return float(v)


#: a unit written as the last word of a field name: ``pitch`` and ``pitch_rad`` are ``pitch_deg``
#: with its unit left off or changed, not another field
_UNIT_SUFFIX = re.compile(r"_(deg|degrees|rad|radians|m|mm|cm|km|px|pixels|s|ms)$", re.IGNORECASE)
#: difflib's ratio above which a field name (case, separators and unit left out) is taken for a
#: misspelling of a known one: 'pich_deg' 0.93, 'heigth' 0.83, 'distorsion' 0.9 are; outside
#: metadata such as 'exposure_ms', 'model', 'source', 'timestamp' stays under 0.45
RESEMBLANCE_CUTOFF = 0.8


def _squash(name: str) -> str:
    return re.sub(r"[\s_\-]", "", name.lower())


def _bare(name: str) -> str:
    return _squash(_UNIT_SUFFIX.sub("", name.strip()))


def resembling_field(name: str, keys) -> str | None:
    """The field among ``keys`` that ``name`` looks like a misspelling of, or None: the same
    ignoring case, underscores and a unit suffix (``K1``, ``Pitch_deg``, ``pitch``, ``tilt_rad``),
    or as close as :data:`RESEMBLANCE_CUTOFF` by :func:`difflib.get_close_matches`."""
    for k in keys:
        if _squash(name) == _squash(k) or _bare(name) == _bare(k):
            return k
    forms = {}
    for k in keys:
        forms.setdefault(_squash(k), k)
        forms.setdefault(_bare(k), k)
    for form in (_squash(name), _bare(name)):
        close = difflib.get_close_matches(form, list(forms), n=1, cutoff=RESEMBLANCE_CUTOFF)
        if close:
            return forms[close[0]]
    return None


def warn_ignored(where: str, names, keys) -> None:
    """Log that the fields ``names`` of the object at ``where`` are not read (its fields: ``keys``)."""
    names = list(dict.fromkeys(names))
    if names:
        log.warning("%s: field%s %s not read by skyfix (its fields are %s): ignored", where,
                    "s" * (len(names) > 1), ", ".join(map(repr, names)), ", ".join(keys))


def known_fields(obj: dict, keys, where: str, err=AcquisitionError, *, elsewhere=None,
                 warn: bool = True) -> list[str]:
    """Check the fields of ``obj`` (the object at ``where``) against its known ``keys``.

    An unknown field that looks like a known one (:func:`resembling_field`: ``K1`` for ``k1``,
    ``pitch`` for ``pitch_deg``) is refused with ``err``, naming both: it would otherwise be
    ignored and its value silently replaced by the default. So is one that resembles a field of
    another object (``elsewhere``: {where it belongs: its fields}), such as a camera's ``k1``
    that belongs in its ``distortion``. Any other unknown field is a producer's own metadata
    (a frame's ``exposure_ms``): conventions.md does not forbid it, so it is ignored with a
    warning naming it (``warn=False``: the caller warns, once for many objects alike). Returns
    those ignored fields."""
    unknown = [k for k in obj if k not in keys]
    if not unknown:
        return []
    wrong, extra = [], []
    for k in unknown:
        like = resembling_field(k, keys)
        if like is None:  # the right name in the wrong object is as lost as a misspelt one
            like = next((f"{w}.{f}" for w, fs in (elsewhere or {}).items()
                         if (f := resembling_field(k, fs)) is not None), None)
        if like is None:
            extra.append(k)
        else:
            wrong.append(f"{k!r} (like {like!r})")
    if wrong:
        raise err(f"{where}: unknown field{'s' * (len(wrong) > 1)} {', '.join(wrong)}; its fields are "
                  f"{', '.join(keys)}. A misspelt or misplaced field would be ignored and its value "
                  "replaced by the default: correct its name or move it (a field of your own needs a "
                  "name unlike skyfix's)")
    if warn:
        warn_ignored(where, extra, keys)
    return extra


def in_range(v: float, lo: float, hi: float, where: str, why: str) -> float:
    """``v`` if ``lo <= v <= hi``, else an AcquisitionError naming the field ``where``."""
    if not lo <= v <= hi:
        raise AcquisitionError(f"{where} must be within {lo:g} to {hi:g} ({why}), got {v:g}")
    return v


def camera_height_field(obj: dict, where: str, err=AcquisitionError) -> float:
    """``obj["camera_height_m"]`` [m], finite and at most :data:`MAX_CAMERA_HEIGHT_M`, else ``err``."""
    v = obj["camera_height_m"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise err(f"{where} must be a finite number of metres, got {v!r}")
    if not 0 <= v <= MAX_CAMERA_HEIGHT_M:
        raise err(f"{where} must be within 0 to {MAX_CAMERA_HEIGHT_M:g} m (the camera above the "
                  f"ground), got {v:g}")
    return float(v)


def attitude_prior_field(data: dict, where: str, err=AcquisitionError) -> tuple[float, float]:
    """(pitch, roll) [deg] of an optional ``attitude_prior`` object; (0, 0) when absent or null."""
    prior = data.get("attitude_prior")
    if prior is None:
        return 0.0, 0.0
    if not isinstance(prior, dict):
        raise err(f"{where}attitude_prior must be an object with pitch_deg and roll_deg [deg], "
                  f"got {prior!r}")
    known_fields(prior, ("pitch_deg", "roll_deg"), f"{where}attitude_prior", err)
    out = []
    for key in ("pitch_deg", "roll_deg"):
        v = prior.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise err(f"{where}attitude_prior.{key} must be a finite number of degrees, got {v!r}")
        if abs(v) > MAX_PRIOR_TILT_DEG:
            raise err(f"{where}attitude_prior.{key} must be within +-{MAX_PRIOR_TILT_DEG:g} deg "
                      f"(a rover on the ground), got {v:g}")
        out.append(float(v))
    return out[0], out[1]


def json_object(path: Path, what: str) -> dict:
    """The top-level JSON object of ``path``; SkyfixError naming ``what`` the file should be."""
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise SkyfixError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SkyfixError(f"{path} is not a {what} JSON file ({type(e).__name__}: {e})") from None
    if not isinstance(d, dict):
        raise SkyfixError(f"{path} is not a {what} JSON file: the top level must be an object")
    return d


def number_list(d: dict, key: str, path: Path, *, n: int | None = None, lo=-math.inf,
                 hi=math.inf, null_ok=True, unit="") -> np.ndarray:
    """``d[key]`` as a float array (null -> NaN), every entry a finite number in [lo, hi]."""
    v = d[key]
    if not isinstance(v, list):
        raise SkyfixError(f"{path}: '{key}' must be a list of numbers, got {type(v).__name__}")
    if n is not None and len(v) != n:
        raise SkyfixError(f"{path}: '{key}' has {len(v)} entries, must have {n} (one per column/bin)")
    out = np.empty(len(v))
    for i, x in enumerate(v):
        if x is None and null_ok:
            out[i] = np.nan
            continue
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise SkyfixError(f"{path}: {key}[{i}] must be a finite number{' or null' * null_ok}, "
                              f"got {x!r}")
        if not lo <= x <= hi:
            raise SkyfixError(f"{path}: {key}[{i}] = {x:g} is outside {lo:g} .. {hi:g}{unit}")
        out[i] = x
    return out


def whole_number(d: dict, key: str, path: Path) -> int:
    """``d[key]`` as a whole number >= 1 [px], else a :class:`SkyfixError` naming ``path``."""
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v < 1:
        raise SkyfixError(f"{path}: '{key}' must be a whole number of pixels >= 1, got {v!r}")
    return int(v)
