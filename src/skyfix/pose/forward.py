"""The forward model: a world-frame horizon seen from a rover with a given attitude, as a body-frame
profile, and the residual of a measured profile against it.

Profiles in the ``world`` frame measure azimuth from grid north; in the ``body`` frame from the
rover's forward axis (levelled with the attitude prior). A world profile of a rover with yaw ``H``
satisfies ``world[az] = body[az - H]``.
"""

from __future__ import annotations

import numpy as np

from ..camera import r_world_body


def body_profile(world_el_deg, yaw_deg, pitch_deg=0.0, roll_deg=0.0, *, n_bins=360,
                 prior_pitch_deg=0.0, prior_roll_deg=0.0) -> np.ndarray:
    """The body-frame profile [deg] a camera with this attitude measures, levelled with the prior.

    world_el_deg : (m,) [deg] world-frame horizon, bin k at ``k * 360 / m`` from grid north
    A world direction ``d`` appears at ``R(0, prior) R(yaw, pitch, roll)^T d`` in the levelled body
    frame (azimuth from the forward axis); the rotated curve is re-binned by periodic linear
    interpolation at the ``n_bins`` body bin centres.
    """
    return BodyProfiler(world_el_deg, n_bins=n_bins, prior_pitch_deg=prior_pitch_deg,
                        prior_roll_deg=prior_roll_deg)(yaw_deg, pitch_deg, roll_deg)


class BodyProfiler:
    """:func:`body_profile` of one world horizon for many attitudes: what does not depend on the
    attitude (the horizon's direction vectors, the prior's rotation, the bin centres) is computed
    once. An attitude fit calls it tens of thousands of times per fix."""

    def __init__(self, world_el_deg, *, n_bins=360, prior_pitch_deg=0.0, prior_roll_deg=0.0):
        w = np.asarray(world_el_deg, np.float64)
        m = w.size
        az = np.radians(np.arange(m) * 360.0 / m)
        el = np.radians(np.nan_to_num(w))
        ce = np.cos(el)
        # (3, m) so that each coordinate is one contiguous row: numpy's vectorised arctan2 and
        # hypot take contiguous input only (strided columns of an (m, 3) array cost 3x)
        self._d = np.ascontiguousarray(np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)]))
        self._prior = r_world_body(0.0, prior_pitch_deg, prior_roll_deg)
        self._centres = np.arange(n_bins) * 360.0 / n_bins
        self._centres_wrapped = self._centres % 360.0

    def __call__(self, yaw_deg, pitch_deg=0.0, roll_deg=0.0) -> np.ndarray:
        """The body-frame profile [deg] (``n_bins``) for this yaw, pitch and roll [deg]."""
        rot = self._prior @ r_world_body(yaw_deg, pitch_deg, roll_deg).T
        bx, by, bz = rot @ self._d
        a = np.degrees(np.arctan2(bx, by))
        # ``a % 360`` for a in [-180, 180] without np.remainder's cost (a quarter of a call),
        # to the bit: a + 360 below zero (-1e-17 gives 360.0), +0.0 for -0.0
        azb = a + np.where(a < 0.0, 360.0, 0.0)
        elb = np.degrees(np.arctan2(bz, np.hypot(bx, by)))
        # Under a tilt of a few degrees the rotated azimuths still increase, only rotated round
        # the circle: one roll orders them (sorting was a quarter of an attitude fit), and the
        # periodic interpolation is np.interp's own (period=360: wrap, sort, pad) without its
        # sort. Ties or a fold (a steep tilt) take np.interp's path as it is.
        xs = np.where(azb >= 360.0, azb - 360.0, azb)  # np.interp's period wrap: 360.0 -> 0.0
        k = int(np.argmin(xs))
        xs = np.concatenate((xs[k:], xs[:k]))
        if not np.all(xs[1:] > xs[:-1]):
            order = np.argsort(azb)
            return np.interp(self._centres, azb[order], elb[order], period=360.0)
        xp = np.concatenate((xs[-1:] - 360.0, xs, xs[:1] + 360.0))
        fp = np.concatenate((elb[k - 1:k] if k else elb[-1:], elb[k:], elb[:k], elb[k:k + 1]))
        return np.interp(self._centres_wrapped, xp, fp)


def relevel(profile_deg, pitch_deg, roll_deg, *, prior_pitch_deg=0.0, prior_roll_deg=0.0):
    """Undo an estimated attitude: the profile a level camera (same heading) would measure [deg]."""
    q = np.asarray(profile_deg, np.float64)
    n = q.size
    obs = np.isfinite(q)
    az = np.radians(np.arange(n) * 360.0 / n)
    el = np.radians(np.nan_to_num(q))
    ce = np.cos(el)
    d = np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)], axis=1)
    rot = r_world_body(0.0, pitch_deg, roll_deg) @ r_world_body(0.0, prior_pitch_deg, prior_roll_deg).T
    b = d @ rot.T
    azl = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    ell = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])))
    order = np.argsort(azl)
    out = np.interp(np.arange(n) * 360.0 / n, azl[order], ell[order], period=360.0)
    # A level bin is observed when both neighbours it was interpolated from were.
    obs_l = np.interp(np.arange(n) * 360.0 / n, azl[order], obs[order].astype(float), period=360.0)
    return np.where(obs_l > 0.999, out, np.nan)


def harmonic_tilt(q, world_shifted):
    """First guess of (pitch, roll) [deg] from the first harmonic of query - prediction."""
    n = q.size
    obs = np.isfinite(q)
    az = np.radians(np.arange(n) * 360.0 / n)
    u = np.stack([np.ones(n), np.cos(az), np.sin(az)], axis=1)[obs]
    c, *_ = np.linalg.lstsq(u, (q - world_shifted)[obs], rcond=None)
    # Small pitch p lowers what is ahead: -p cos(az); small roll r raises the right side: +r sin(az).
    return float(-c[1]), float(c[2])


def residual_profile(q, world_el_deg, att, *, prior_pitch_deg=0.0, prior_roll_deg=0.0):
    """Query minus the world horizon seen with attitude ``att`` [deg] (NaN where unobserved)."""
    pred = body_profile(world_el_deg, att.yaw_deg, att.pitch_deg, att.roll_deg,
                        n_bins=np.size(q), prior_pitch_deg=prior_pitch_deg,
                        prior_roll_deg=prior_roll_deg)
    return np.asarray(q, np.float64) - pred
