"""Settings of the pose search (:class:`PoseConfig`) and its limits.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..match import MatchConfig
from .map_error import MAP_DEM_SIGMA_M


@dataclass(frozen=True)
class PoseConfig:
    """Pose estimation settings.

    refine_candidates : how many of the matcher's candidates are refined from the DEM
    levels : refinement levels (each 4x finer, 5 x 5 grid)
    grid_step_m : [m] first grid step without a database (scenario 2)
    render_bins : azimuth bins of the horizons rendered for the attitude fit
    restarts_deg : [deg] offsets of the Gauss-Newton restarts per axis
    tolerance_m : [m] what "correct" means for the confidence (scenario 1: 5 m)
    polish : finish every refined candidate by a search on the attitude-refitted
        cost (:func:`polish_position`)
    retry_below, retry_rms_ratio : with a database, a fix whose confidence is below
        ``retry_below``, or whose robust residual rms exceeds ``retry_rms_ratio`` times the
        profile's noise, is searched again with each of ``retry_segments`` contiguous parts of
        the observed skyline left out in turn (:func:`_segment_candidates`); the new candidates
        are refined and ranked with the others on the whole profile. A false skyline fragment a
        few degrees wide (a shade boundary seen in two frames) can outweigh the rest of the view
        in the database's sum of squares and keep the true basin out of the candidates. In the
        whole-pipeline scenario-1 cases (59 correct, 6 wrong) either trigger catches all the
        wrong fixes; the rms one also fires on 3 correct ones (time only). 0 / inf = never
    retry_segments, retry_per_segment : how many parts, and candidates kept from each search
    dem_sigma_m : [m] the DEM's height error (rms) the final position search allows for (None:
        the DEM is taken as the world). Each bin's residual is then weighted by
        ``noise^2 / (noise^2 + atan(dem_sigma_m / d)^2)``, d the distance of the terrain that makes
        that bin's skyline (a near-field bin under a 2 m error is worth little, a ridge 5 km away
        nearly all), and the camera's height above the true ground is fitted (a residual
        ``dh / d``): the DEM's error under the rover moves every bin by that much
        (:func:`skyfix.pose.scoring.robust_cost`). Off by default: on map-error cases the
        weighting pulled fixes farther than plain least squares (docs/map-errors.md)
    map_sigma_m : [m] the DEM's height error (rms, correlated over MAP_CORRELATION_M) the reported
        sigmas allow for: the position and heading sigmas add what it does to the fit in
        quadrature (:func:`skyfix.pose.map_error.fit_map_covariance`), and the image-plane solve
        of a narrow view (:mod:`skyfix.pose.image_plane`) widens its sigmas alike; 0: the DEM is
        the world. The answer itself does not depend on it
    """

    match: MatchConfig = MatchConfig()
    refine_candidates: int = 4
    levels: int = 3
    grid_step_m: float = 2.0
    render_bins: int = 1440
    restarts_deg: tuple = (-2.5, 0.0, 2.5)
    tolerance_m: float = 5.0
    polish: bool = True
    retry_below: float = 0.5
    retry_rms_ratio: float = 3.0
    retry_segments: int = 4
    retry_per_segment: int = 2
    dem_sigma_m: float | None = None
    map_sigma_m: float = MAP_DEM_SIGMA_M


#: Most grid points a search without a database renders: each costs ~3 ms and ~30 kB, so this
#: (a 100 m radius at the 2 m step) is about a minute and 300 MB more; a radius of 1e7 m asked
#: for 728 TiB. Larger areas are what the database is for.
MAX_PRIOR_GRID_POINTS = 101 * 101
