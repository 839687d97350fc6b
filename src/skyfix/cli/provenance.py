"""What an answer of ``locate`` or ``heading`` was made from: the skyfix version, the command, the
inputs with their checksums, the options, the frames used and dropped, which quantities were
estimated and which echoed, and the north its headings use (``conventions.md``)."""

from __future__ import annotations

import hashlib
import math
import sys
from pathlib import Path


def _sha256(path) -> str | None:
    p = Path(path)
    if not p.is_file():
        return None
    h = hashlib.sha256()
    with open(p, "rb") as f:
        while b := f.read(1 << 20):
            h.update(b)
    return h.hexdigest()


def provenance(*, acq_dir=None, profile_path=None, db=None, db_path=None, dem=None, dem_path=None,
               profile=None, options: dict | None = None, estimated=(), echoed=(),
               convergence_deg=float("nan")) -> dict:
    """A JSON-ready record of an answer's making (see the module docstring)."""
    from .. import __version__

    inputs: dict = {}
    if acq_dir is not None:
        inputs["acquisition"] = {"path": str(Path(acq_dir).resolve()),
                                 "acquisition_json_sha256": _sha256(Path(acq_dir) / "acquisition.json")}
    if profile_path is not None:
        inputs["profile"] = {"path": str(Path(profile_path).resolve()), "sha256": _sha256(profile_path)}
    if db is not None:
        inputs["database"] = {"path": str(Path(db_path).resolve()), "dem_sha256": db.dem_sha256,
                              "spacing_m": float(db.spacing_m),
                              "camera_height_m": float(db.camera_height_m)}
    if dem is not None:
        inputs["dem"] = {"path": str(dem_path), "sha256": dem.checksum,
                         "work_crs": dem.crs_name or dem.crs_wkt,
                         **({"sources": dem.sources} if hasattr(dem, "sources") else {})}
    frames = []
    if profile is not None:
        for r in profile.meta.get("frames", []) or []:
            frames.append({k: r[k] for k in ("image", "status", "reason") if k in r})
    return {
        "skyfix_version": __version__,
        "command": "skyfix " + " ".join(sys.argv[1:]),
        "inputs": inputs,
        "options": options or {},
        "frames": frames,
        "estimated": list(estimated),
        "echoed": list(echoed),
        "north": ("true (heading_deg = grid_heading_deg + meridian_convergence_deg)"
                  if math.isfinite(convergence_deg) else
                  "grid: the DEM's CRS does not say where true north is"),
    }


def ellipse_lonlat(crs_wkt: str, x: float, y: float, sigma_m: float, n: int = 48):
    """A 1-sigma circle [lon, lat] ring around (x, y) [m] (the position sigma is one number)."""
    from pyproj import CRS, Transformer

    from ..planets import EARTH, planet_from_crs

    crs = CRS.from_user_input(crs_wkt)
    geo = "EPSG:4326" if planet_from_crs(crs) in (EARTH, None) else crs.geodetic_crs
    t = Transformer.from_crs(crs, geo, always_xy=True)
    # anticlockwise (north, then west), as RFC 7946 asks of an exterior ring
    a = [-2 * math.pi * k / n for k in range(n)] + [0.0]
    lon, lat = t.transform([x + sigma_m * math.sin(v) for v in a], [y + sigma_m * math.cos(v) for v in a])
    return [[float(u), float(v)] for u, v in zip(lon, lat)]


def fix_geojson(fix) -> dict:
    """A FeatureCollection: the fix (a point with every field), its 1-sigma circle (a polygon),
    and each candidate (points), styled by the simplestyle properties QGIS and web maps read."""
    from pyproj import CRS, Transformer

    from ..planets import EARTH, planet_from_crs

    d = fix.to_dict()
    feats = [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [fix.lon, fix.lat]},
              "properties": {"role": "fix", "marker-color": "#d62728", "marker-symbol": "star",
                             "title": f"fix: heading {fix.heading_deg:.1f} deg, confidence "
                                      f"{fix.confidence:.2f}",
                             **{k: v for k, v in d.items() if k != "candidates"}}}]
    if fix.crs and math.isfinite(fix.position_sigma_m) and fix.position_sigma_m > 0:
        crs_wkt = CRS.from_user_input(fix.crs).to_wkt()
        feats.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [
            ellipse_lonlat(crs_wkt, fix.x, fix.y, fix.position_sigma_m)]},
            "properties": {"role": "1-sigma", "sigma_m": fix.position_sigma_m, "stroke": "#d62728",
                           "fill": "#d62728", "fill-opacity": 0.15,
                           "title": f"1-sigma position ({fix.position_sigma_m:.2g} m)"}})
        geo = "EPSG:4326" if planet_from_crs(crs_wkt) in (EARTH, None) else CRS(crs_wkt).geodetic_crs
        t = Transformer.from_crs(CRS(crs_wkt), geo, always_xy=True)
        for k, c in enumerate(fix.candidates):
            lon, lat = t.transform(c["x"], c["y"])
            feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon, lat]},
                          "properties": {"role": "candidate", "rank": k, **c,
                                         "marker-color": "#7f7f7f", "marker-size": "small"}})
    return with_body({"type": "FeatureCollection", "features": feats}, fix.crs)


def off_earth(crs) -> tuple[str, str] | None:
    """(body name, WKT of its geodetic CRS) when ``crs`` (any pyproj input) lies on another body
    than Earth, else None."""
    if not crs:
        return None
    from pyproj import CRS

    from ..planets import EARTH, planet_from_crs

    c = CRS.from_user_input(crs)
    body = planet_from_crs(c)
    if body in (EARTH, None):
        return None
    return body.name, c.geodetic_crs.to_wkt()


def with_body(collection: dict, crs) -> dict:
    """``collection`` with, off Earth, foreign members saying whose longitudes and latitudes its
    coordinates are: GeoJSON means Earth's WGS 84 (RFC 7946), and a GIS would put a Mars fix on
    Earth."""
    other = off_earth(crs)
    if other is not None:
        collection = {"type": collection["type"], "body": other[0], "geodetic_crs": other[1],
                      **{k: v for k, v in collection.items() if k != "type"}}
    return collection


def off_earth_warning(path, crs) -> str | None:
    """The warning to print when GeoJSON written to ``path`` holds another body's coordinates."""
    other = off_earth(crs)
    if other is None:
        return None
    return (f"{path} holds {other[0]} longitudes and latitudes (its 'body' and 'geodetic_crs' say "
            "so): GIS tools read GeoJSON as Earth's WGS 84 and will place it on Earth; set that "
            "geodetic CRS on the layer, or use the fix's x, y in its work CRS")
