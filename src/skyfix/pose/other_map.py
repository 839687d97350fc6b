"""A DEM other than the database's: does it still describe the terrain the search compared?

``locate --force`` refines on a DEM whose checksum is not the one the database was built from.
That may be the same heights written again (another format, another compression), or another
map altogether (shifted, another survey): the search then ranked positions by skylines of
terrain the refinement does not see, and the confidence model, fitted where the two are one map,
has no grounds for its number. :func:`map_agreement` tells the two apart where it matters, at the
fix: the DEM's own skylines at the nearest database positions against the stored ones.
"""

from __future__ import annotations

import numpy as np

from ..horizon import render_horizons

#: [deg] median |stored - re-rendered| over a position's bins beyond which the DEM is taken for
#: another map: the same heights re-rendered differ by the store's quantisation (0.005 deg at
#: the default scale) and, for a sweep-built store, by a few short bins; a DEM shifted by one
#: 30 m cell moves near ridges by tenths of a degree
OTHER_MAP_MEDIAN_DEG = 0.05


def map_agreement(db, dem, x: float, y: float) -> tuple[str | None, str | None]:
    """(reason to cap the confidence or None, a note or None) for a fix at (x, y) [m].

    Nothing to say (None, None) without both a database and a DEM, or when the DEM's checksum is
    the database's (or either is not recorded). Otherwise the skylines of the grid position
    nearest the fix and its four neighbours (inside the grid) are rendered from ``dem`` as the
    database was built (its camera height, planet, bins and ray limit) and compared with the
    stored ones, bin by bin where both see terrain.
    """
    if db is None or dem is None:
        return None, None
    built = getattr(db, "dem_sha256", "") or ""
    mine = getattr(dem, "checksum", "") or ""
    if not built or not mine or built == mine:
        return None, None
    rows, cols = db.shape
    r0, c0 = (int(v) for v in db.index_of(x, y))
    r, c = min(max(r0, 0), rows - 1), min(max(c0, 0), cols - 1)
    edge = (r, c) != (r0, c0)
    pts = {(min(max(r + dr, 0), rows - 1), min(max(c + dc, 0), cols - 1))
           for dr, dc in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))}
    rr, cc = (np.array(v) for v in zip(*sorted(pts)))
    gx, gy = db.xy_of(rr, cc)
    # inside the DEM with a height (a void has none: render_horizons refuses such a point)
    inside = np.array([bool(np.all(dem.contains(a, b))) and bool(np.isfinite(dem.height_at(a, b)))
                       for a, b in zip(gx, gy)])
    if not inside.any():
        return (f"the DEM is not the database's ({mine[:12]}... against {built[:12]}...) and does "
                "not cover the database positions at the fix: the search ran on terrain the "
                "refinement cannot check"), None
    gx, gy = gx[inside], gy[inside]
    hb = render_horizons(dem, gx, gy, camera_height_m=db.camera_height_m, planet=db.planet,
                         azimuth_bins=db.azimuth_bins, max_distance_m=db.max_distance_m)
    diff = np.abs(db.profiles_at(gx, gy) - hb.elevation_deg)
    both = np.isfinite(diff)
    med = float(np.median(diff[both])) if both.any() else float("inf")
    top = float(diff[both].max()) if both.any() else float("inf")
    said = (f"the DEM is not the database's ({mine[:12]}... against {built[:12]}...): its "
            f"skylines at the {gx.size} database positions nearest the fix"
            + (" (on the grid's edge: the fix lies outside it)" if edge else "")
            + f" differ from the stored ones by a median {med:.3f} deg (at most {top:.2f} deg)")
    if med > OTHER_MAP_MEDIAN_DEG:
        return said + "; the search ranked positions on another map's terrain", None
    return None, said + ", the same terrain within the store's rounding"


__all__ = ["OTHER_MAP_MEDIAN_DEG", "map_agreement"]
