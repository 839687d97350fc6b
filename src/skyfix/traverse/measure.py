"""Skyline measurements at a traverse's stops from their acquisition folders: the stop's profile is
detected once and serves the heading search and the position fix alike.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..errors import SkyfixError
from .run import Measure, Measurement

log = logging.getLogger(__name__)

#: fewest observed azimuth bins a stop's profile must hold to be measured (a heading needs 8)
MIN_BINS = 8


def acquisition_measure(trav, dem, *, db=None, pose_config=None, detector=None) -> Measure:
    """A :class:`Measure` that reads stop k's acquisition folder, detects its skyline and runs
    :func:`skyfix.pose.estimate_heading` or :func:`skyfix.pose.locate` (with ``db`` when given,
    else on ``dem`` in the prior disc). ``pose_config``: the fixes' settings, its ``map_sigma_m``
    the DEM error the headings' sigmas allow for too."""
    from ..database import nearest_position_m
    from ..formats import load_acquisition
    from ..pose import PoseConfig, estimate_heading, locate
    from ..pose.heading import HEADING_POSITION_SIGMA_M
    from ..profile import acquisition_profile, profile_bins

    cfg = pose_config or PoseConfig()
    cache = {}

    def profile(k):
        if k not in cache:
            cache.clear()  # one stop's profile at a time
            acq = load_acquisition(trav.folders[k])
            # in the database's bins: its search takes no other (the headings take any)
            prof = acquisition_profile(acq, detector=detector, azimuth_bins=profile_bins(db))
            obs = int(np.isfinite(prof.elevation_deg).sum())
            if obs < MIN_BINS:
                raise SkyfixError(f"{obs} azimuth bins of skyline detected (at least {MIN_BINS} "
                                  "are needed)")
            cache[k] = (prof, acq)
        return cache[k]

    def heading(k, x, y, prior_deg, window_deg, position_sigma_m=None):
        prof, acq = profile(k)
        # the track's own position sigma [m]: near skylines weigh by it, and the heading's sigma
        # carries it (so the Measurement has no skyline distance for run.py to widen it again)
        ps = HEADING_POSITION_SIGMA_M if position_sigma_m is None else float(position_sigma_m)
        hf = estimate_heading(prof, dem, x, y, prior_deg, window_deg,
                              camera_height_m=acq.camera_height_m, prior_pitch_deg=acq.prior_pitch_deg,
                              prior_roll_deg=acq.prior_roll_deg, position_sigma_m=ps,
                              dem_sigma_m=cfg.map_sigma_m)
        # the basin's own sigma: the track, not a sigma widened by the confidence, tells a
        # doubtful heading right or wrong (run.py's corroboration and innovation gate)
        return Measurement(hf.grid_heading_deg,
                           hf.features.get("heading_sigma_basin_deg", hf.heading_sigma_deg),
                           hf.confidence)

    def fix(k, x, y, radius_m):
        prof, acq = profile(k)
        if db is None and x is None:
            raise SkyfixError("no start and no database: the first fix needs --db or a start "
                              "in traverse.json")
        # a prior disc the database does not reach is searched on the DEM, as without --db
        use_db = db if x is None or db is None or nearest_position_m(db, x, y) <= radius_m \
            else None
        if db is not None and use_db is None:
            log.info("stop %d: no database position within %.0f m of (%.1f, %.1f): the fix is "
                     "searched on the DEM", k, radius_m, x, y)
        f = locate(prof, db=use_db, dem=dem, prior_xy=None if x is None else (x, y),
                   prior_radius_m=radius_m, prior_pitch_deg=acq.prior_pitch_deg,
                   prior_roll_deg=acq.prior_roll_deg, camera_height_m=acq.camera_height_m,
                   config=cfg if use_db is not None else dem_search_config(cfg, radius_m))
        # the basins' own sigmas, as for a heading: the track settles which basin
        return Measurement(f.grid_heading_deg,
                           f.features.get("heading_sigma_basin_deg", f.heading_sigma_deg),
                           f.confidence, f.x, f.y,
                           f.features.get("position_sigma_basin_m", f.position_sigma_m))

    return Measure(heading, fix)


def dem_search_config(cfg, radius_m):
    """``cfg`` with a first grid step [m] coarse enough for a DEM search of ``radius_m`` [m]
    to stay within MAX_PRIOR_GRID_POINTS (a 150 m disc at 2 m was refused): the refinement
    that follows is as fine as ever."""
    from dataclasses import replace

    from ..pose.config import MAX_PRIOR_GRID_POINTS

    half = (math.isqrt(MAX_PRIOR_GRID_POINTS) - 1) // 2  # grid steps from the centre to the edge
    step = radius_m / half if radius_m else 0.0
    return replace(cfg, grid_step_m=step) if step > cfg.grid_step_m else cfg
