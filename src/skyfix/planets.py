"""Planet radius and atmospheric refraction, for the curvature drop of a line of sight.

A terrain point at horizontal distance ``d`` appears lower than on a flat world by
``(1 - k) * d**2 / (2 * R)`` (``conventions.md``).
"""

from __future__ import annotations

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
PLANETS = {"earth": EARTH, "mars": MARS}


def get_planet(spec: str | float | Planet) -> Planet:
    """``earth``, ``mars``, a radius in metres (number or numeric string), or a Planet."""
    if isinstance(spec, Planet):
        return spec
    if isinstance(spec, str) and spec.strip().lower() in PLANETS:
        return PLANETS[spec.strip().lower()]
    try:
        radius = float(spec)
    except (TypeError, ValueError):
        raise ParameterError(
            f"unknown planet {spec!r}: use 'earth', 'mars' or a radius in metres"
        ) from None
    if not radius > 0:
        raise ParameterError(f"planet radius must be > 0 m, got {radius}")
    return Planet(f"radius {radius:g} m", radius, 0.0)
