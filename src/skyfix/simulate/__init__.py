"""Stage 4: realistic rover acquisitions from a DEM, with exact ground truth.

:func:`simulate_acquisition` (:mod:`.acquisition`) ray-casts every pixel of a frame set (pinhole
frames on a mast) or a body-levelled equirectangular panorama (:mod:`skyfix.raycast`), shades it
(:mod:`.shading`, with the world-fixed textures of :mod:`.noise` and the scene of :mod:`.scene`)
and writes the acquisition format of ``conventions.md`` into a folder replaced whole
(:mod:`.folders`): ``acquisition.json`` with ``truth``, the PNG images and for each image
``NAME.skyline.json``, the exact terrain skyline (sub-pixel row per column where the pixel ray
first meets the DEM, ``null`` where the column has no sky-to-ground edge). With rocks, which the
DEM lacks, ``NAME.visible.skyline.json`` holds the skyline a camera really sees.

:class:`Conditions` (:mod:`.conditions`) adds dust, clouds, snow, a lake, rocks, glare, exposure
faults and blur, each with a strength in [0, 1]. :func:`simulate_set` (:mod:`.sets`) draws the
named robustness sets (:data:`SETS`), optionally rendered from a world that differs from the map
(:mod:`.world`: the DEMERR set, or any set with map errors).
"""

from .acquisition import (PANO_ELEVATION_TOP_DEG, PANO_HEIGHT, PANO_VFOV_DEG, PANO_WIDTH,
                          check_attitude_prior, check_render_options, check_seed, frame_pans,
                          normalise_yaw, simulate_acquisition)
from .conditions import Conditions, as_conditions
from .scene import Scene, make_scene
from .sets import MAP_ERROR_SETS, SETS, default_area, plan_set, simulate_set
from .shading import shade
from .world import MapErrors, map_offset, world_dem

__all__ = ["MAP_ERROR_SETS", "MapErrors", "map_offset", "world_dem",
           "PANO_ELEVATION_TOP_DEG", "PANO_HEIGHT", "PANO_VFOV_DEG", "PANO_WIDTH", "SETS",
           "Conditions", "Scene", "as_conditions", "check_attitude_prior", "check_render_options",
           "check_seed", "default_area", "frame_pans", "make_scene", "normalise_yaw", "plan_set",
           "shade", "simulate_acquisition", "simulate_set"]
