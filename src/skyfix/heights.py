"""What a DEM file's heights mean, checked before they are used: the unit a PDS3 label gives
them (GDAL's PDS driver drops it), and heights no terrain has (a fill value left undeclared, a
unit mistake, a planet's radius given instead of the height above its datum).
"""

from __future__ import annotations

import numpy as np

from .errors import DemError

#: [m] largest height from the datum a DEM may hold (beyond: a fill value or a unit mistake)
MAX_ABS_HEIGHT_M = 100_000.0


def pds3_unit(src) -> str | None:
    """The unit a PDS3 label gives its image (``IMAGE.UNIT``, e.g. ``METER``), which GDAL's PDS
    driver does not pass on as the band's unit (a label saying KILOMETER was read as metres,
    silently); None for other files or a label without one."""
    import json

    if getattr(src, "driver", "") != "PDS":
        return None
    try:
        items = src.tags(ns="json:PDS")
    except Exception:  # noqa: BLE001 - no such metadata: nothing to say
        return None
    # rasterio splits GDAL's one JSON string at its first ':'; put it back together
    text = "".join(f"{k}:{v}" for k, v in items.items()) if items else ""
    try:
        unit = json.loads(text).get("IMAGE", {}).get("UNIT")
    except (ValueError, AttributeError):
        return None
    return str(unit).strip().strip('"') if unit else None


#: fill values DEMs are often written with and not declared as nodata
COMMON_FILL_VALUES = (-32768.0, -32767.0, -9999.0, -99999.0)


def check_fill_values(z, name: str) -> None:
    """Refuse heights ``z`` [m] whose lowest value is a common fill value (:data:`COMMON_FILL_VALUES`)
    exactly: a block of -32768 read as terrain (no nodata declared) sank the DEM there by 32 km
    without a word. Real terrain's lowest point is not such a round number."""
    if not np.isfinite(z).any():
        return
    low = float(np.nanmin(z))
    if low in COMMON_FILL_VALUES:
        n = int(np.count_nonzero(z == low))
        raise DemError(f"{name}: {n} cell{'s' * (n != 1)} hold exactly {low:g}, a common fill value, "
                       f"and no nodata value is declared: declare it (`gdal_edit.py -a_nodata "
                       f"{low:g} {name}`) so those cells are voids, not terrain")


def check_heights(z, path, body) -> None:
    """Refuse heights ``z`` [m] of the DEM file ``path`` that no terrain of ``body`` (a
    :class:`~skyfix.planets.Planet` or None) has: all about the body's radius (a radius product),
    any beyond :data:`MAX_ABS_HEIGHT_M`, or a common fill value as the lowest
    (:func:`check_fill_values`). Each refusal says what to do."""
    from pathlib import Path

    path = Path(path)
    if not np.isfinite(z).any():
        return
    with np.errstate(invalid="ignore"):
        extreme = float(np.nanmax(np.abs(z)))
        low = float(np.nanmin(np.abs(z)))
    if body is not None and extreme > MAX_ABS_HEIGHT_M and low > 0.9 * body.radius_m:
        # every height is about the body's radius: a radius product, not elevations
        raise DemError(f"{path} holds heights of {low:.4g}-{extreme:.4g} m, about {body.name}'s "
                       f"radius ({body.radius_m:.0f} m): it gives the radius, not the height "
                       f"above a datum; subtract the reference radius (e.g. `gdal_calc.py -A "
                       f"{path.name} --calc 'A-{body.radius_m:.0f}' --outfile OUT.tif`, with "
                       "the radius its label names) or give the product's elevation DEM")
    if extreme > MAX_ABS_HEIGHT_M:
        # Olympus Mons stands 22 km above the Martian datum, the Mariana trench 11 km below
        # sea level: a height beyond 100 km is a fill value or a unit mistake, not terrain
        raise DemError(f"{path} holds a height of {extreme:.3g} m, beyond the +-"
                       f"{MAX_ABS_HEIGHT_M / 1000:g} km any terrain lies from its datum: mark its "
                       "fill value as nodata (e.g. `gdal_edit.py -a_nodata VALUE`) or convert its "
                       "units to metres")
    check_fill_values(z, path.name)
