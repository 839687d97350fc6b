"""The exceptions a user can cause.

Every error that bad input can trigger is a :class:`SkyfixError`; the CLI prints its message
(one line that says what is wrong and what to do) and exits with status 2, never a traceback.
Anything else escaping is a bug.
"""


class SkyfixError(Exception):
    """Base class: a problem with the user's input or environment, with a message to act on."""


class DemError(SkyfixError):
    """The DEM cannot be used: unreadable, no CRS, point outside it, too many voids."""


class OutsideDemError(DemError):
    """A requested position lies outside the DEM's valid area."""


class ParameterError(SkyfixError):
    """An option or argument is out of its valid range."""


class AcquisitionError(SkyfixError):
    """An acquisition folder or its ``acquisition.json`` breaks the format."""


class DatabaseError(SkyfixError):
    """A skyline database is missing, incomplete, corrupt or built with other parameters."""


class DetectionError(SkyfixError):
    """No usable skyline in an image or acquisition."""


class OutputExistsError(SkyfixError):
    """An output exists and ``--overwrite`` was not given."""
