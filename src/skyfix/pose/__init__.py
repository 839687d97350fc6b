"""Stage 8: position, heading and attitude from a body-frame skyline profile.

:func:`locate` (:mod:`.locate`) finds the position: candidates from the database matcher
(:mod:`skyfix.match`) or a grid rendered over the prior, refined from the DEM (:mod:`.refine`,
scored robustly by :mod:`.scoring`), the attitude by Gauss-Newton (:mod:`.attitude`) on the
forward model (:mod:`.forward`), a calibrated confidence and sigmas (:mod:`.confidence`), and a
retry with parts of the skyline left out. :func:`estimate_heading` (:mod:`.heading`) is the
heading-only mode of scenario 3; a narrow view is also solved in the image plane
(:mod:`.image_plane`: the rendered horizon through each frame's camera against its detected
rows). Both attitude fits share one Levenberg-Marquardt loop (:mod:`.lm`). Results are
:class:`Fix` and :class:`HeadingFix` (:mod:`.fix`); settings :class:`PoseConfig`
(:mod:`.config`); :func:`synthetic_profile` (:mod:`.synthetic`) renders query profiles for
tests, benchmarks and calibration.
"""

# the matcher's names, re-exported here since skyfix.pose has always offered them
from ..match import MatchConfig, brute_force_scores, match_database, prepare_query, score_profiles
from .attitude import Attitude, fit_attitude
from .confidence import (FEATURES, MODEL_PATH, SCENARIOS, confidence_features,
                         confidence_from_features, residual_correlation_bins)
from .config import MAX_PRIOR_GRID_POINTS, PoseConfig
from .fix import Fix, HeadingFix
from .forward import body_profile, relevel, residual_profile
from .heading import PINNED_HEADING_CONFIDENCE, at_window_edge, estimate_heading
from .image_plane import FrameRows, ImageAttitude, fit_attitude_image, frames_from_acquisition
from .locate import locate
from .scoring import clipped_costs, outlier_bins, robust_cost, robust_scores
from .synthetic import synthetic_profile

__all__ = ["FEATURES", "MAX_PRIOR_GRID_POINTS", "MODEL_PATH", "PINNED_HEADING_CONFIDENCE",
           "SCENARIOS", "Attitude", "Fix", "FrameRows", "HeadingFix", "ImageAttitude",
           "MatchConfig", "PoseConfig",
           "at_window_edge", "body_profile", "brute_force_scores", "clipped_costs",
           "confidence_features", "confidence_from_features", "estimate_heading", "fit_attitude",
           "fit_attitude_image", "frames_from_acquisition",
           "locate", "match_database", "outlier_bins", "prepare_query", "relevel",
           "residual_correlation_bins", "residual_profile", "robust_cost", "robust_scores",
           "score_profiles", "synthetic_profile"]
