"""What the map's own height error does to a fit: the covariance it gives the answer.

Every real DEM is metres off the terrain. Model: the error is ``sigma`` [m] rms, correlated as
``exp(-r / MAP_CORRELATION_M)`` over ground distance ``r``. The simulator's map errors
(:mod:`skyfix.simulate.world`) have the same rms but are smoother (Gaussian-blurred, 1/e at 300 m):
within 150 m this model credits them 2-4x the height difference they have, so the sigmas are
conservative there, not the model's own test. A skyline point ``d`` away whose terrain is off by ``e_sky``,
seen from a camera whose ground is off by ``e_cam``, moves by ``g (e_sky - e_cam)`` in whatever the
fit compares (``g = 1 / d`` rad in elevation, ``f / d`` px in an image row): a camera the map puts
too low sees every ridge too high. A least-squares fit with Jacobian ``J`` and weights ``W`` then
moves by ``A^-1 J^T W S W J A^-1`` (``A = J^T W J``, ``S`` the moves' covariance): the sandwich.

Used by the image-plane attitude (:mod:`skyfix.pose.image_plane`) and by the position a
:func:`~skyfix.pose.locate.locate` refinement reports (:func:`fit_map_covariance`).
"""

from __future__ import annotations


import numpy as np

#: [m] the DEM's height error (rms) against the terrain the camera sees that sigmas allow for
#: unless told otherwise: every real DEM is metres off (the simulator's map errors: 2 m,
#: correlated over 150 m)
MAP_DEM_SIGMA_M = 2.0
#: [m] correlation length (exponential) of that error on the ground
MAP_CORRELATION_M = 150.0
#: [m] half the step of the central differences that give a profile's change with position:
#: wide enough that a 20-30 m DEM's cell edges do not make it jump, small against the distances
#: of the terrain that makes the skyline
POSITION_STEP_M = 2.0


def correlated_height_errors(shape, cell_m, sigma_m, count, rng, *, correlation_m=MAP_CORRELATION_M):
    """``count`` height-error grids [m] of ``shape`` on cells of ``cell_m`` [m] (one number, or
    (dy, dx)) drawn from this model: covariance ``sigma_m^2 exp(-r / correlation_m)``. White noise
    filtered by the square root of that covariance's 2-D spectrum, ``(1 + (2 pi f L)^2)^(-3/2)``,
    on a grid padded to a power of two at least twice the larger side, so that the periodic wrap
    does not correlate opposite edges. The Monte Carlo that checks :func:`fit_map_covariance`
    draws its worlds with it (tests, ``scripts/check_map_sigma.py``)."""
    dy, dx = (cell_m, cell_m) if np.ndim(cell_m) == 0 else cell_m
    n = 1 << int(np.ceil(np.log2(2 * max(shape))))
    f = np.hypot(np.fft.fftfreq(n, dx)[None, :], np.fft.fftfreq(n, dy)[:, None])
    h = (1.0 + (2 * np.pi * f * correlation_m) ** 2) ** -0.75
    h *= sigma_m / np.sqrt(np.mean(h ** 2))
    for _ in range(count):
        yield np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) * h).real[:shape[0], :shape[1]]


def error_covariance(points_xy, gain, dem_sigma_m, corr_m=MAP_CORRELATION_M):
    """Covariance of the moves the map's error gives each observation.

    points_xy : (m, 2) [m] each observation's skyline point relative to the camera
    gain : (m,) how far each observation moves per metre of ``e_sky - e_cam`` (its unit sets the
        result's: [deg/m] gives deg^2, [px/m] px^2)
    Returns ``sigma^2 corr(e_sky_i - e_cam, e_sky_j - e_cam) g_i g_j`` (m, m).
    """
    p = np.asarray(points_xy, float)
    g = np.asarray(gain, float)
    d = np.hypot(p[:, 0], p[:, 1])
    gap = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    near = np.exp(-d / corr_m)
    c = np.exp(-gap / corr_m) - near[:, None] - near[None, :] + 1.0
    return (dem_sigma_m ** 2) * c * g[:, None] * g[None, :]


def sandwich(jac, weights, s, info_inv=None):
    """``A^-1 J^T W S W J A^-1`` with ``A = J^T W J`` (or ``info_inv`` given as ``A^-1``)."""
    jw = np.asarray(jac, float) * np.asarray(weights, float)[:, None]
    if info_inv is None:
        info_inv = np.linalg.inv(jw.T @ jac)
    return info_inv @ (jw.T @ s @ jw) @ info_inv


def fit_map_covariance(q, world_at, x, y, yaw_deg, pitch_deg, roll_deg, *, noise_deg,
                       dem_sigma_m=MAP_DEM_SIGMA_M, prior_pitch_deg=0.0, prior_roll_deg=0.0,
                       step_m=POSITION_STEP_M):
    """The covariance that the map's height error gives a fit of the body-frame profile ``q``
    [deg] at (x, y) [m]: (6, 6) over x, y [m], yaw, pitch, roll [deg] and the offset [deg]; None
    where fewer than 8 bins remain.

    world_at(xs, ys) -> (elevation (k, m) [deg], skyline distance (k, m) [m]): world-frame
    horizons rendered on the map at those points; yaw, pitch, roll [deg]: the fitted attitude.
    The fit is taken as the refinement's: position, yaw, pitch, roll and an offset, by least
    squares over the bins within the clipped cost's bound
    (:func:`skyfix.pose.scoring.clip_bound_deg`); noise_deg [deg] the profile's noise.
    """
    from .forward import BodyProfiler
    from .scoring import body_distances, clip_bound_deg

    q = np.asarray(q, float)
    n = q.size
    h = float(step_m)
    xs = np.array([x, x + h, x - h, x, x])
    ys = np.array([y, y, y, y + h, y - h])
    el, dist = world_at(xs, ys)
    th = (float(yaw_deg), float(pitch_deg), float(roll_deg))
    kw = dict(n_bins=n, prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    profilers = [BodyProfiler(e, **kw) for e in el]
    centre = profilers[0]
    body = [p(*th) for p in profilers]
    ha = 0.02  # [deg] the attitude fit's own difference step
    cols = [(body[1] - body[2]) / (2 * h), (body[3] - body[4]) / (2 * h)]
    for i in range(3):
        e = np.zeros(3)
        e[i] = ha
        cols.append((centre(*(np.add(th, e))) - centre(*(np.subtract(th, e)))) / (2 * ha))
    cols.append(np.ones(n))
    jac = np.stack(cols, axis=1)  # d(prediction)/d(x, y, yaw, pitch, roll, offset): deg per unit
    d = body_distances(dist[0], th[0], n)
    r = q - body[0]
    ok = np.isfinite(r) & np.isfinite(jac).all(axis=1) & np.isfinite(d) & (d > 0)
    if ok.sum() < 8:
        return None
    r = r - np.median(r[ok])
    ok &= np.abs(r) < clip_bound_deg(noise_deg)  # the clipped cost's inliers
    if ok.sum() < 8:
        return None
    az = np.radians(np.arange(n) * 360.0 / n + th[0])[ok]
    pts = np.stack([d[ok] * np.sin(az), d[ok] * np.cos(az)], axis=1)
    s = error_covariance(pts, np.degrees(1.0 / d[ok]), dem_sigma_m)
    try:
        return sandwich(jac[ok], np.ones(int(ok.sum())), s)
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)


__all__ = ["MAP_DEM_SIGMA_M", "MAP_CORRELATION_M", "POSITION_STEP_M", "error_covariance",
           "fit_map_covariance", "sandwich"]


def map_error_scatter(dem, x, y, yaw_deg, *, sigma_m, draws, rng, camera_height_m=1.5,
                      azimuth_bins=1440, body_bins=360, noise_deg=0.1, step_m=1.0):
    """The Monte Carlo that :func:`fit_map_covariance` is checked against: (the covariance it
    claims (6, 6), the moves (draws, 3) of x [m], y [m] and yaw [deg]); (None, None) where too
    few skyline bins remain.

    Each draw is a world: the map ``dem`` plus a height error of this model
    (:func:`correlated_height_errors`, ``sigma_m`` [m] rms). The profile a level camera
    ``camera_height_m`` [m] above that world's ground sees at (x, y) [m] with grid heading
    ``yaw_deg`` is fitted against the map by least squares (position, yaw, pitch, roll and an
    offset), linearised with a Jacobian of its own (``step_m`` [m] and 0.01 deg central
    differences, not the one :func:`fit_map_covariance` uses). The moves' spread is what the
    claimed covariance must say (``scripts/check_map_sigma.py``, the tests).
    """
    from ..dem import Dem
    from ..horizon import render_horizons
    from .forward import BodyProfiler

    def world_at(xs, ys):
        hb = render_horizons(dem, xs, ys, camera_height_m=camera_height_m, azimuth_bins=azimuth_bins)
        return hb.elevation_deg, hb.skyline_distance_m

    level = np.array([yaw_deg, 0.0, 0.0])
    centre = BodyProfiler(world_at(np.array([x]), np.array([y]))[0][0], n_bins=body_bins)
    q0 = centre(*level)
    cov = fit_map_covariance(q0, world_at, x, y, yaw_deg, 0.0, 0.0, noise_deg=noise_deg,
                             dem_sigma_m=sigma_m)
    if cov is None:
        return None, None  # too few skyline bins there for either
    h = step_m
    els = world_at(np.array([x + h, x - h, x, x]), np.array([y, y, y + h, y - h]))[0]
    p = [BodyProfiler(e, n_bins=body_bins)(*level) for e in els]
    cols = [(p[0] - p[1]) / (2 * h), (p[2] - p[3]) / (2 * h)]
    for i in range(3):
        e = np.zeros(3)
        e[i] = 0.01
        cols.append((centre(*(level + e)) - centre(*(level - e))) / 0.02)
    jac = np.stack(cols + [np.ones(body_bins)], axis=1)
    ok = np.isfinite(jac).all(axis=1) & np.isfinite(q0)
    gain = np.linalg.solve(jac[ok].T @ jac[ok], jac[ok].T)[:3]
    moves = []
    for err in correlated_height_errors(dem.z.shape, (dem.dy, dem.dx), sigma_m, draws, rng):
        world = Dem(dem.z + err.astype(np.float32), dem.x0, dem.y0, dem.dx, dem.dy, dem.crs_wkt,
                    dem.crs_name, body=getattr(dem, "body", None))
        ground = float(render_horizons(world, [x], [y], azimuth_bins=4).ground_z_m[0])
        seen = render_horizons(world, [x], [y], azimuth_bins=azimuth_bins,
                               camera_z_m=[ground + camera_height_m]).elevation_deg[0]
        moves.append(gain @ (BodyProfiler(seen, n_bins=body_bins)(*level) - q0)[ok])
    return cov, np.array(moves)

