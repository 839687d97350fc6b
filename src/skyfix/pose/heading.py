"""Heading-only mode (scenario 3): the position is known roughly, the heading is searched in a
window about the prior.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ..errors import ParameterError
from ..match import prepare_query, score_profiles, tilt_determinable
from ..north import heading_360, meridian_convergence_deg, true_heading_deg, wrap_deg
from .attitude import fit_attitude
from .basin_sigma import wrong_basin_sigma
from .confidence import (calibrated_sigma, confidence_features, confidence_from_features,
                         load_confidence_model, residual_correlation_bins, structureless_cap)
from .fix import (DETERMINED_MIN_CONFIDENCE, DETERMINED_SIGMA_DEG, PRIOR_TRUST_DEG,
                  UNKNOWN_HEADING_SIGMA_DEG, UNKNOWN_TILT_SIGMA_DEG, HeadingFix, crs_and_lonlat,
                  near_skyline, prior_disagreement)
from .forward import body_profile, harmonic_tilt, residual_profile
from .image_plane import (IMAGE_PLANE_DEM_SIGMA_M, IMAGE_PLANE_MAX_SPAN_DEG,
                          SOLVES_DISAGREE_CONFIDENCE, image_plane_attitude, view_span_deg)
from .map_error import POSITION_STEP_M
from .scoring import profile_arrays


log = logging.getLogger(__name__)

#: Confidence at most, of a heading pinned to the edge of its search window.
PINNED_HEADING_CONFIDENCE = 0.05
#: [deg] scenario 3's tolerance: a heading within it is right (the confidence model's)
HEADING_TOLERANCE_DEG = 1.0
#: [m] how far scenario 3's rough position is taken to be off unless told (``skyfix heading
#: --position-sigma-m``): its rover knows where it is from odometry to metres, every 50 m
HEADING_POSITION_SIGMA_M = 10.0
#: [deg] the noise floor the position weights are measured against (a profile's own noise
#: estimate can be far smaller on a clean render)
POSITION_WEIGHT_NOISE_DEG = 0.1



def at_window_edge(heading_deg, prior_deg, window_deg, tol_deg=1e-6) -> bool:
    """Whether ``heading_deg`` [deg] sits on the edge of ``prior_deg +/- window_deg`` [deg]."""
    d = abs(wrap_deg(heading_deg - prior_deg))
    return d >= window_deg - tol_deg


def position_weights(skyline_distance_m, position_sigma_m, noise_deg):
    """Per-bin trust [0, 1] of a horizon rendered at a position known to ``position_sigma_m`` [m]:
    a camera that far off sees a skyline point ``d`` [m] away moved by about
    ``position_sigma_m / d`` rad, in azimuth and in elevation alike (a ridge 100 m away by 6 deg
    for 10 m), against the profile's noise ``noise_deg`` [deg]:
    ``noise^2 / (noise^2 + (position_sigma_m / d)^2)``. Bins without a skyline distance weigh 1."""
    d = np.asarray(skyline_distance_m, np.float64)
    e = np.degrees(position_sigma_m / np.maximum(np.nan_to_num(d, nan=np.inf), 1.0))
    return noise_deg ** 2 / (noise_deg ** 2 + e * e)


def position_heading_sigma_deg(yaw_at, yaw_deg, position_sigma_m, step_m=POSITION_STEP_M):
    """The heading's 1-sigma [deg] from a rough position known to ``position_sigma_m`` [m] per
    axis: ``position_sigma_m * |grad yaw|``, the gradient [deg/m] of the fit's own answer with the
    position, by central differences of ``yaw_at(dx, dy)`` [deg] over ``step_m`` [m]: the fit run
    again on the horizon rendered ``(dx, dy)`` [m] from the position (None where that is off the
    DEM; the difference is then one-sided, from ``yaw_deg``, the fit's answer at the position).

    Not from the skyline's geometry alone (each point ``d`` away turning by about
    ``(dx cos a - dy sin a) / d`` rad, their weighted mean): the fit reads the yaw from the
    profile's slopes, steep bins most, and a moved camera also raises or lowers what it sees.
    Against the spread of refits over positions drawn about hilly scenes (the heading as it is),
    that mean was 0.57-1.41x of it over seven draws and 2.6-3.4x too small in one with a ridge
    350 m away; this share is 0.88-1.36x (``tests/test_heading_position.py``). Both sides off
    the DEM (a DEM a few metres wide): 0 on that axis."""
    if not (position_sigma_m > 0):
        return 0.0
    grad = []
    for ex, ey in ((1.0, 0.0), (0.0, 1.0)):
        hi = yaw_at(ex * step_m, ey * step_m)
        lo = yaw_at(-ex * step_m, -ey * step_m)
        span = 2.0 * step_m
        if hi is None or lo is None:
            hi, lo, span = (yaw_deg, lo, step_m) if hi is None else (hi, yaw_deg, step_m)
        grad.append(0.0 if hi is None or lo is None else wrap_deg(hi - lo) / span)
    return float(position_sigma_m * math.hypot(*grad))


def estimate_heading(profile, dem, x, y, heading_prior_deg, window_deg=10.0, *,
                     camera_height_m=1.5, planet=None, prior_pitch_deg=0.0, prior_roll_deg=0.0,
                     render_bins=1440, model=None, frames=None, dem_sigma_m=None,
                     position_sigma_m=HEADING_POSITION_SIGMA_M, notes: tuple = ()) -> HeadingFix:
    """Scenario 3: heading [deg] from a rough position (x, y) [m] and a heading prior [deg].

    ``heading_prior_deg`` is from grid north, as every azimuth inside skyfix (the CLI converts a
    true-north prior with :func:`skyfix.north.grid_heading_from_true`); the result carries both
    norths. The shift search is restricted to ``heading_prior_deg +/- window_deg``; the attitude is then
    refined by Gauss-Newton with restarts, yaw kept within the window. A heading on the window's
    edge (the best lies beyond it) gets confidence at most PINNED_HEADING_CONFIDENCE.

    ``frames`` (:class:`~skyfix.pose.image_plane.FrameRows`, the detected rows of each frame):
    a view spanning at most IMAGE_PLANE_MAX_SPAN_DEG is then solved again in the image plane
    from the profile fit's answer (:func:`~skyfix.pose.image_plane.fit_attitude_image`), and
    that answer, with its own sigmas, is the one reported; the confidence stays the profile
    fit's. ``dem_sigma_m`` [m]: the DEM's height error those sigmas allow for (None:
    :data:`~skyfix.pose.image_plane.IMAGE_PLANE_DEM_SIGMA_M`; 0: the DEM is the world).
    ``position_sigma_m`` [m]: how far the rough position may be off; the attitude fit weighs
    each bin by :func:`position_weights` (0: every bin alike): near skylines, which a few metres
    of position error move by degrees, no longer pull the heading (scenario 3 with map errors,
    Sierra: 17 -> 20 of 20 within 1 deg), and the heading's sigma is at least what that position
    error does to it (:func:`position_heading_sigma_deg`). ``notes``: what the caller already knows the
    result should say (as :func:`~skyfix.pose.locate.locate`'s); the search adds its own.

    The sigmas [deg] returned allow for a wrong basin
    (:func:`~skyfix.pose.basin_sigma.wrong_basin_sigma`): with probability 1 - confidence the
    heading is anywhere in the window and pitch and roll anywhere within PRIOR_TRUST_DEG of the
    inclinometer's prior. Single frames with map errors (``bench_single_frame.py``, seeds 0 and
    2): the errors beyond the bars within 1 sigma, heading 55 -> 91 % and 71 -> 88 %, roll
    31 -> 92 % and 44 -> 76 %; all errors, heading 86 -> 93 % and 91 -> 94 % (68 % claimed).
    """
    from ..horizon import render_horizons

    if not 0 < window_deg <= 180:
        raise ParameterError(f"window must be in (0, 180] deg, got {window_deg}")
    if not math.isfinite(heading_prior_deg):
        raise ParameterError(f"heading prior must be a finite angle [deg], got {heading_prior_deg}")
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ParameterError(f"rough position must be finite [m], got ({x}, {y})")
    if model is None:  # read once: the confidence and the sigma both use it
        model = load_confidence_model()
    t0 = time.perf_counter()
    q, noise = profile_arrays(profile)
    n = q.size
    dem.require_inside(np.array([x]), np.array([y]), "rough position")
    if not (math.isfinite(position_sigma_m) and position_sigma_m >= 0):
        raise ParameterError(f"position sigma must be a finite number of metres >= 0, got "
                             f"{position_sigma_m}")
    hb = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                         azimuth_bins=render_bins)
    world = hb.elevation_deg[0]
    trust = (position_weights(hb.skyline_distance_m[0], position_sigma_m,
                              max(noise, POSITION_WEIGHT_NOISE_DEG))
             if position_sigma_m > 0 else None)
    world_n = np.nan_to_num(body_profile(world, 0.0, n_bins=n))
    # A frame spanning a narrow arc cannot tell a tilt from a constant and a shift: match without
    # the tilt harmonic there (the Gauss-Newton fit below still refines pitch and roll).
    tilt = tilt_determinable(np.isfinite(q))
    # the image plane has the frames' columns: a skyline of a few bins is still solved there
    in_image = bool(frames) and view_span_deg(frames) <= IMAGE_PLANE_MAX_SPAN_DEG
    query = prepare_query(q, tilt, min_observed=4 if in_image else 8)
    s = score_profiles(world_n[None].astype(np.float32), query, all_shifts=True)[0]
    shifts = np.arange(n) * 360.0 / n
    dist = np.abs(wrap_deg(shifts - heading_prior_deg))
    # A window narrower than half a bin holds no bin centre: take the nearest one as the start.
    inwin = dist <= max(window_deg, float(dist.min()))
    k = int(np.flatnonzero(inwin)[np.argmin(s[inwin])])
    h0 = shifts[k]
    p0, r0 = harmonic_tilt(q, body_profile(world, h0, n_bins=n)) if tilt else (0.0, 0.0)
    att = fit_attitude(q, world, h0, prior_pitch_deg + p0, prior_roll_deg + r0,
                       prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                       yaw_window_deg=window_deg, yaw_center_deg=heading_prior_deg,
                       restarts_deg=(-2.5, 0.0, 2.5),
                       accept_deg=2.0 * max(noise, 0.05), world_weights=trust)
    # Landscape inside the window: best vs best shift more than 3 deg away.
    far = inwin & (np.abs(wrap_deg(shifts - att.yaw_deg)) > 3.0)
    other = float(s[far].min()) if far.any() else np.inf
    # -v: what the search saw (a rival close to the best says why a confidence is low)
    log.info("heading search at (%.1f, %.1f): grid %.1f +- %g deg, %d of %d bins observed, tilt "
             "harmonic %s: best shift %.1f deg (score %.4g), best beyond 3 deg %.4g (%.2f s)",
             x, y, heading_prior_deg, window_deg, int(np.isfinite(q).sum()), n,
             "removed" if tilt else "kept (narrow view)", h0, float(s[k]), other,
             time.perf_counter() - t0)
    log.info("attitude fit: yaw %.2f, pitch %.2f, roll %.2f deg, robust rms %.3f deg against a "
             "noise of %.3f", att.yaw_deg, att.pitch_deg, att.roll_deg, att.robust_rms_deg, noise)
    relief = float(np.nanstd(q))
    feat = confidence_features(float(s[inwin].min()), other, att.robust_rms_deg, noise,
                               relief, float(np.isfinite(q).mean()),
                               att.yaw_sigma_deg,
                               math.hypot(att.pitch_deg - prior_pitch_deg, att.roll_deg - prior_roll_deg))
    conf = structureless_cap(confidence_from_features(feat, model, "heading"), relief, noise)
    if window_deg < 180.0 and at_window_edge(att.yaw_deg, heading_prior_deg, window_deg):
        # Pinned to the window's edge: the fit still improves beyond it, so this is no minimum
        # and the true heading most likely lies outside the window (truth 20 deg from the prior
        # with a +-10 deg window gave the edge at confidence 0.9).
        conf = min(conf, PINNED_HEADING_CONFIDENCE)
    img = None
    if in_image:
        img = image_plane_attitude(frames, dem, x, y, att.yaw_deg, att.pitch_deg, att.roll_deg,
                                   camera_height_m=camera_height_m, planet=planet,
                                   prior=(heading_prior_deg, prior_pitch_deg, prior_roll_deg),
                                   window_deg=window_deg, dem_sigma_m=dem_sigma_m)
    if img is not None:
        log.info("image-plane solve: yaw %.2f (%+.2f from the profile fit), pitch %.2f, roll %.2f "
                 "deg", img.yaw_deg, wrap_deg(img.yaw_deg - att.yaw_deg), img.pitch_deg,
                 img.roll_deg)
    yaw, pitch, roll = (img.yaw_deg, img.pitch_deg, img.roll_deg) if img is not None else \
        (att.yaw_deg, att.pitch_deg, att.roll_deg)
    if img is not None and abs(wrap_deg(img.yaw_deg - att.yaw_deg)) > 1.0:
        # the two solves found different basins: the confidence is the profile fit's, about
        # another answer
        conf = min(conf, SOLVES_DISAGREE_CONFIDENCE)
        notes = (*notes, f"the image-plane heading lies more than 1 deg from the profile fit's: "
                         f"confidence at most {SOLVES_DISAGREE_CONFIDENCE}")
    notes = (*notes, *prior_disagreement(pitch, roll, prior_pitch_deg, prior_roll_deg))
    # the skyline distance of each observed bin, at the azimuth the answer puts it
    az = (np.flatnonzero(np.isfinite(q)) * 360.0 / n + yaw) % 360.0
    dists = hb.skyline_distance_m[0][np.rint(az * render_bins / 360.0).astype(int) % render_bins]
    notes = (*notes, *near_skyline(dists, IMAGE_PLANE_DEM_SIGMA_M if dem_sigma_m is None
                                   else dem_sigma_m, narrow=img is not None))
    grid = heading_360(yaw)
    conv = meridian_convergence_deg(dem.crs_wkt, x, y)
    crs, lon, lat = crs_and_lonlat(dem.crs_wkt, x, y)
    # the fit's sigma counts every bin as independent; neighbouring residuals are not
    corr = residual_correlation_bins(residual_profile(q, world, att, prior_pitch_deg=prior_pitch_deg,
                                                      prior_roll_deg=prior_roll_deg))
    inflate = math.sqrt(max(1.0, corr))
    hsig = calibrated_sigma(att.yaw_sigma_deg * inflate, feat, model, "heading")
    if trust is not None:
        def yaw_at(dx, dy):  # the same fit, from its answer, on the horizon seen (dx, dy) away
            px, py = np.array([x + dx]), np.array([y + dy])
            if not (dem.contains(px, py).all() and np.isfinite(dem.height_at(px, py)).all()):
                return None
            moved = render_horizons(dem, px, py, camera_height_m=camera_height_m, planet=planet,
                                    azimuth_bins=render_bins)
            return fit_attitude(q, moved.elevation_deg[0], att.yaw_deg, att.pitch_deg,
                                att.roll_deg, restarts_deg=(0.0,), prior_pitch_deg=prior_pitch_deg,
                                prior_roll_deg=prior_roll_deg, yaw_window_deg=window_deg,
                                yaw_center_deg=heading_prior_deg, world_weights=position_weights(
                                    moved.skyline_distance_m[0], position_sigma_m,
                                    max(noise, POSITION_WEIGHT_NOISE_DEG))).yaw_deg

        # The calibration's cases had rough positions 0-20 m off, as scenario 3 draws them: its
        # sigma already holds a typical position share, and adding this one to it counted that
        # twice (scenario 3, Sierra REF: 95 % within 1 sigma, the calibrated sigma alone 65 %).
        # The larger of the two: this one where the view's near skyline or a larger
        # --position-sigma-m makes the position matter more than in those cases.
        hsig = max(hsig, position_heading_sigma_deg(yaw_at, att.yaw_deg, position_sigma_m))
    psig, rsig = att.pitch_sigma_deg * inflate, att.roll_sigma_deg * inflate
    if img is not None:
        # the image fit's formal sigmas see the detection noise but not the map's and the
        # model's systematic errors (12 % of pitch errors within 1 sigma on simulated frames):
        # the profile fit's, which carry the calibration, stay the floor
        hsig = max(hsig, img.yaw_sigma_deg)
        psig = max(psig, img.pitch_sigma_deg)
        rsig = max(rsig, img.roll_sigma_deg)
    hsig = min(hsig, UNKNOWN_HEADING_SIGMA_DEG)
    # what the confidence says of the basin: the cap below speaks of the sigma's own width,
    # which the sigma already carries (counted twice, a right heading came out +-94 deg)
    basin_conf = conf
    # A heading is not likelier right than a normal error of its own sigma stays within the
    # tolerance, however well the profile fits: a rough position known to kilometres gave 7.8 M
    # deg at confidence 0.9999997 with 1e9 m, and one 60 m off 1.8 deg at 0.9999 with a sigma of
    # 1.9 (the cap held only above 2 deg then). Below 0.3 deg of sigma it is above 0.999.
    conf = min(conf, math.erf(HEADING_TOLERANCE_DEG / (hsig * math.sqrt(2.0))))
    log.debug("heading confidence features: %s",
              ", ".join(f"{k} {v:.3g}" for k, v in feat.items()))
    # the sigmas so far are the basin's own; the confidence says how likely that basin is
    local = hsig
    feat["heading_sigma_basin_deg"] = local  # for a filter that settles the basin by its track
    hsig = min(wrong_basin_sigma(hsig, basin_conf, window_deg,
                                 wrap_deg(yaw - heading_prior_deg)), UNKNOWN_HEADING_SIGMA_DEG)
    # the tilts' basin is the heading's
    psig = wrong_basin_sigma(psig, basin_conf, PRIOR_TRUST_DEG, pitch - prior_pitch_deg)
    rsig = wrong_basin_sigma(rsig, basin_conf, PRIOR_TRUST_DEG, roll - prior_roll_deg)
    if hsig > 2.0 * local:
        notes = (*notes, f"the heading may lie in another basin of the +-{window_deg:g} deg window "
                         f"(a chance of {1.0 - basin_conf:.2f}), and the sigmas allow for that "
                         f"(the fit's own heading sigma is {local:.2f} deg)")
    psig, rsig = min(psig, UNKNOWN_TILT_SIGMA_DEG), min(rsig, UNKNOWN_TILT_SIGMA_DEG)
    log.info("heading %.2f deg (grid) +- %.2f, confidence %.2f (%.2f s in all)", grid, hsig, conf,
             time.perf_counter() - t0)
    determined = {k: bool(math.isfinite(v) and v <= DETERMINED_SIGMA_DEG
                          and conf >= DETERMINED_MIN_CONFIDENCE)
                  for k, v in (("heading", hsig), ("pitch", psig), ("roll", rsig))}
    return HeadingFix(true_heading_deg(grid, conv), hsig, pitch, roll,
                      conf, att.rms_deg ** 2, float(x), float(y), grid_heading_deg=grid,
                      meridian_convergence_deg=conv, crs=crs, lon=lon, lat=lat,
                      pitch_sigma_deg=psig, roll_sigma_deg=rsig, determined=determined,
                      features=feat, notes=tuple(notes))
