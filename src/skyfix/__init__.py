"""skyfix: absolute rover localisation from the skyline.

Ground segment: DEM -> skyline database. Board segment: images -> skyline -> angular profile ->
match against the database -> position, heading, attitude and a calibrated confidence.
"""

__version__ = "0.1.0"
