"""Imaging conditions of a simulated acquisition: dust, clouds, snow, a lake, rocks, glare, exposure
faults and blur, each with a strength in [0, 1]. A new condition enters as a field here and a term in
:mod:`.shading` (or :mod:`.scene` when it changes the world, as rocks do).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from ..errors import ParameterError


@dataclass(frozen=True)
class Conditions:
    """Degradations of an acquisition, each a strength in [0, 1] (0 = absent).

    dust : airborne dust: short haze distance, low contrast at the horizon
    clouds : bright cloud structures above the skyline (Earth only)
    snow : snow on the terrain above a snow line that falls with strength, on slopes under about
        50 deg (Earth only): bright summits against a bright sky, the skyline's contrast gone
    lake : still water filling the terrain around the rover up to a level that rises with strength,
        never above the rover's feet (Earth only): the sky mirrored below the skyline, a shoreline
        for an edge
    rocks : boulders near the rover that the DEM does not contain and that cut the skyline
    glare : the sun in view, with veiling glare and lens flare
    overexposed, dark : exposure faults (gain up to x3 and clipped; gain down to x0.15, noisier)
    blur : defocus / motion blur (up to about 4 px)
    """

    dust: float = 0.0
    clouds: float = 0.0
    snow: float = 0.0
    lake: float = 0.0
    rocks: float = 0.0
    glare: float = 0.0
    overexposed: float = 0.0
    dark: float = 0.0
    blur: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise ParameterError(f"condition {f.name} strength must be in [0, 1], got {v!r}")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def parse(cls, spec: str | None) -> "Conditions":
        """``"dust,rocks:0.5"``: comma-separated names, each optionally ``:strength`` (default 1)."""
        if spec is None or not str(spec).strip():
            return cls()
        kw = {}
        for item in str(spec).split(","):
            item = item.strip()
            if not item:  # "dust,,rocks" and ",," said nothing: refused, not read as nominal
                raise ParameterError(f"conditions {spec!r}: an empty item between commas; write "
                                     "NAME or NAME:STRENGTH, comma-separated (e.g. dust:0.5,rocks)")
            name, colon, val = item.partition(":")
            name = name.strip().lower()
            if name not in cls.names():
                raise ParameterError(
                    f"unknown condition {name!r}: choose from {', '.join(cls.names())} "
                    "(e.g. --conditions dust:0.5,rocks)")
            if name in kw:  # the last one won, silently
                raise ParameterError(f"condition {name} is given twice in {spec!r}: give it once")
            if colon and not val.strip():  # "dust:" meant 1, silently
                raise ParameterError(f"condition {name}: the strength after ':' is missing (a "
                                     "number in [0, 1]; NAME alone means 1)")
            try:
                kw[name] = float(val) if colon else 1.0
            except ValueError:
                raise ParameterError(f"condition {name}: strength {val!r} is not a number in [0, 1]") from None
        return cls(**kw)

    def active(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v > 0}

    def __str__(self) -> str:
        return ",".join(f"{k}:{v:g}" for k, v in self.active().items()) or "nominal"


#: conditions that only Earth has
EARTH_ONLY = ("clouds", "snow", "lake")


def check_planet(c: Conditions, planet: str) -> None:
    """Refuse a condition that ``planet`` (``earth``, ``mars``) does not have."""
    for name in EARTH_ONLY:
        if getattr(c, name) > 0 and planet != "earth":
            raise ParameterError(f"the {name} condition is for Earth only: drop it or use "
                                 "--planet earth")


def as_conditions(c) -> Conditions:
    """:class:`Conditions` from None (none), a Conditions, or what :meth:`Conditions.parse` takes."""
    if c is None:
        return Conditions()
    if isinstance(c, Conditions):
        return c
    if isinstance(c, str):
        return Conditions.parse(c)
    if isinstance(c, dict):
        return Conditions(**c)
    raise ParameterError(f"conditions must be a Conditions, a dict or a string, got {type(c).__name__}")
