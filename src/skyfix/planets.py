"""Planet radius and atmospheric refraction, for the curvature drop of a line of sight.

A terrain point at horizontal distance ``d`` appears lower than on a flat world by
``(1 - k) * d**2 / (2 * R)`` (``conventions.md``).
"""

from __future__ import annotations

import math

import re

from dataclasses import dataclass

from .errors import ParameterError


@dataclass(frozen=True)
class Planet:
    """A planet for horizon geometry.

    name : str
    radius_m : float  [m]  mean radius
    refraction_k : float  [-]  refraction coefficient (0 = none; 0.13 standard Earth)
    """

    name: str
    radius_m: float
    refraction_k: float = 0.0

    def drop_m(self, distance_m):
        """Apparent drop [m] of a point at horizontal ``distance_m`` [m] (scalar or array)."""
        return (1.0 - self.refraction_k) * distance_m**2 / (2.0 * self.radius_m)

    @property
    def curvature_coeff(self) -> float:
        """``(1 - k) / (2 R)`` [1/m]: drop = coeff * d**2."""
        return (1.0 - self.refraction_k) / (2.0 * self.radius_m)

    def to_attr(self) -> dict:
        return {"name": self.name, "radius_m": self.radius_m, "refraction_k": self.refraction_k}


EARTH = Planet("earth", 6_371_000.0, 0.13)
MARS = Planet("mars", 3_389_500.0, 0.0)
MOON = Planet("moon", 1_737_400.0, 0.0)
PLANETS = {"earth": EARTH, "mars": MARS, "moon": MOON}
#: a --planet whose radius differs from the DEM's body by more than this share contradicts it
CONTRADICTION_SHARE = 0.05


#: [m] the smallest body radius accepted (``--planet 1`` was taken as a 1 m world)
MIN_RADIUS_M = 100.0


def get_planet(spec: str | float | Planet) -> Planet:
    """``earth``, ``mars``, ``moon``, a radius in metres (number or numeric string), or a Planet."""
    if isinstance(spec, Planet):
        return spec
    if isinstance(spec, str) and spec.strip().lower() in PLANETS:
        return PLANETS[spec.strip().lower()]
    try:
        radius = float(spec)
    except (TypeError, ValueError):
        raise ParameterError(
            f"unknown planet {spec!r}: use 'earth', 'mars', 'moon' or a radius in metres"
        ) from None
    if math.isinf(radius):  # inf passed as a flat world, its radius written as null
        raise ParameterError(f"planet radius must be a finite number of metres, got {spec!r} (a "
                             "flat world has no radius: give the body's)")
    if not radius >= MIN_RADIUS_M:
        raise ParameterError(f"planet radius must be at least {MIN_RADIUS_M:g} m (no body with a DEM "
                             f"is smaller: Itokawa's mean radius is ~165 m), got {radius:g}; give it "
                             "in metres")
    return Planet(f"radius {radius:g} m", radius, 0.0)


def planet_from_crs(crs) -> Planet | None:
    """The body a CRS lives on (``conventions.md``), from its datum and ellipsoid: Earth (refraction
    0.13), Mars, the Moon (the conventions' radii), any other body pyproj knows (mean radius
    (2a + b) / 3 of its ellipsoid, no refraction). None for a CRS without a geodetic datum.
    ``crs``: anything ``pyproj.CRS.from_user_input`` takes."""
    from pyproj import CRS

    c = CRS.from_user_input(crs)
    ell = c.ellipsoid
    if ell is None:
        return None
    # whole words: "Marshall Islands 1960" (EPSG:4732) is on Earth, not Mars
    names = set(re.findall(r"[a-z]+", " ".join(
        filter(None, [getattr(c.datum, "name", ""), ell.name, c.name])).lower()))
    a, b = float(ell.semi_major_metre), float(ell.semi_minor_metre)
    radius = (2.0 * a + b) / 3.0
    for body in (MARS, MOON):
        if body.name in names and abs(radius / body.radius_m - 1) < CONTRADICTION_SHARE:
            return body
    if abs(radius / EARTH.radius_m - 1) < 0.01 and not any(
            w in names for w in ("mars", "moon", "lunar", "venus", "mercury")):
        return EARTH
    body = (getattr(c.datum, "name", "") or ell.name or "").split("(")[0].split("/")[0].strip()
    if _anonymous(body):
        # GDAL names a PDS3 or ISIS product's datum after its TARGET_NAME; a label without one
        # leaves "D_". No other body's radius lies within 0.5 % of Mars's or the Moon's (Mars's
        # own radii, 3389.5 to 3396.19 km, lie within 0.2 %), so the radius says which it is.
        for known in (MARS, MOON):
            if abs(radius / known.radius_m - 1) < 0.005:
                return known
        return Planet(f"unnamed body of radius {radius:g} m", radius, 0.0)
    return Planet(body.lower(), radius, 0.0)


def _anonymous(name: str) -> bool:
    """A datum name that names no body: empty, or GDAL's and ESRI's bare prefixes."""
    n = name.strip().lower()
    for prefix in ("d_", "gcs_", "datum"):
        if n.startswith(prefix):
            n = n[len(prefix):]
    return n.strip(" _") in ("", "unknown", "unnamed", "not specified", "not_specified", "undefined")


def resolve_planet(spec, body: Planet | None) -> Planet:
    """The planet to use: ``spec`` (:func:`get_planet`'s input) overriding the DEM's ``body``, the
    body when ``spec`` is None, Earth when neither says.

    A DEM whose CRS is on another body than Earth is that body's data: a ``spec`` naming another
    body, or a radius more than 5 % from it, is refused (it would bend every line of sight by
    the wrong curvature). An Earth CRS is also what stand-in terrain carries (this project's
    reference DEMs rendered as Mars, a generated DEM), so ``spec`` overrides it freely."""
    if spec is None:
        return body if body is not None else EARTH
    planet = get_planet(spec)
    if body is not None and body.name != EARTH.name:
        named = isinstance(spec, str) and spec.strip().lower() in PLANETS
        if (named and planet.name != body.name) or \
                abs(planet.radius_m / body.radius_m - 1) > CONTRADICTION_SHARE:
            raise ParameterError(
                f"--planet {spec} contradicts the DEM's CRS, which is on {body.name} (radius "
                f"{body.radius_m:g} m): drop --planet (the CRS says which body), or give a DEM of "
                f"{planet.name}")
    return planet
