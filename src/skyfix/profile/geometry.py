"""Camera geometry of skylines: pixel rows to (azimuth, elevation) through a frame's pointing, the
inverse (a horizon's rows in a frame), and sampling a polyline onto azimuth bins.
"""

from __future__ import annotations

import numpy as np

from ..camera import C_CAM_TO_BODY, Camera, direction_to_az_el, r_body_mast, r_world_body
from ..errors import ParameterError
from ..north import wrap_deg


def levelling_rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Body -> levelled body (yaw 0) for an attitude prior [deg]."""
    return r_world_body(0.0, pitch_deg, roll_deg)


def skyline_az_el(camera: Camera, rows: np.ndarray, pan_deg: float, tilt_deg: float = 0.0,
                  pitch_deg: float = 0.0, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame (levelled) azimuth and elevation [deg] of a frame's skyline, one per column.

    rows : (W,) skyline row per column [px, 0-based pixel-centre coordinates], NaN where none
    pan_deg, tilt_deg : [deg] mast pointing; pitch_deg, roll_deg : [deg] attitude prior
    Returns two (W,) arrays, NaN where ``rows`` is NaN.
    """
    rows = np.asarray(rows, dtype=float)
    u = np.arange(rows.size, dtype=float)
    ok = np.isfinite(rows)
    az = np.full(rows.size, np.nan)
    el = np.full(rows.size, np.nan)
    if not ok.any():
        return az, el
    ray = camera.pixel_to_ray(u[ok], rows[ok])
    rot = levelling_rotation(pitch_deg, roll_deg) @ r_body_mast(pan_deg, tilt_deg) @ C_CAM_TO_BODY
    az[ok], el[ok] = direction_to_az_el(ray @ rot.T)
    return az, el


def sample_polyline(az: np.ndarray, el: np.ndarray, bins: int, *, weight: np.ndarray | None = None,
                    max_step_deg: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Skyline elevation [deg] at the bin centres ``k * 360 / bins`` covered by a polyline.

    az, el : (M,) vertices in order along the skyline [deg]; NaN breaks the line
    weight : (M,) per-vertex weight (e.g. detection confidence), interpolated the same way
    max_step_deg : [deg] consecutive vertices further apart in azimuth are not joined (a fold or a
        jump, not a skyline segment)
    Returns ``(elevation, weight)``, each (bins,), NaN where no segment covers the bin centre. Where
    several segments cover a centre, the highest wins (a skyline is the highest terrain).
    """
    az = np.asarray(az, float)
    el = np.asarray(el, float)
    w = np.ones_like(el) if weight is None else np.where(np.isfinite(weight), weight, 0.0)
    out = np.full(bins, -np.inf)
    out_w = np.zeros(bins)
    step = 360.0 / bins
    a0, a1 = az[:-1], az[1:]
    e0, e1 = el[:-1], el[1:]
    seg = np.isfinite(a0) & np.isfinite(a1) & np.isfinite(e0) & np.isfinite(e1)
    da = wrap_deg(a1 - a0)  # shortest way round: a segment never spans 180 deg
    seg &= np.abs(da) <= max_step_deg
    idx = np.flatnonzero(seg)
    if idx.size == 0:
        return np.full(bins, np.nan), np.full(bins, np.nan)
    a0, da, e0, e1 = a0[idx], da[idx], e0[idx], e1[idx]
    w0, w1 = w[idx], w[idx + 1]
    lo = np.minimum(a0, a0 + da)
    hi = np.maximum(a0, a0 + da)
    k_lo = np.ceil(lo / step - 1e-9).astype(np.int64)
    k_hi = np.floor(hi / step + 1e-9).astype(np.int64)
    n = np.maximum(k_hi - k_lo + 1, 0)
    rep = np.repeat(np.arange(idx.size), n)
    k = k_lo[rep] + (np.arange(rep.size) - np.repeat(np.cumsum(n) - n, n))
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(da[rep] != 0, (k * step - a0[rep]) / da[rep], 0.0)
    t = np.clip(t, 0.0, 1.0)
    val = e0[rep] + t * (e1[rep] - e0[rep])
    wv = w0[rep] + t * (w1[rep] - w0[rep])
    kb = np.mod(k, bins)
    np.maximum.at(out, kb, val)
    np.maximum.at(out_w, kb, wv)
    out[~np.isfinite(out)] = np.nan
    out_w[np.isnan(out)] = np.nan
    return out, out_w


def horizon_rows(camera: Camera, az_deg: np.ndarray, el_deg: np.ndarray, r_world_cam: np.ndarray) -> np.ndarray:
    """Forward model: the skyline row [px] per image column of a horizon seen by a camera.

    az_deg, el_deg : (M,) a densely sampled closed horizon [deg] in the frame ``r_world_cam`` maps to
        (world for a rendered horizon, levelled body for a profile)
    r_world_cam : camera axes -> that frame (e.g. :func:`skyfix.camera.r_world_cam`)
    Each horizon vertex is projected (with distortion) and the row is interpolated linearly in
    column; NaN where the skyline is outside the image. Used to draw a predicted skyline over an
    image and, in tests, as the independent forward path that :func:`skyline_az_el` inverts.
    """
    from ..camera import az_el_to_direction

    az = np.asarray(az_deg, float)
    el = np.asarray(el_deg, float)
    d = az_el_to_direction(az, el) @ np.asarray(r_world_cam)  # rows: R^T d
    u, v, front = camera.ray_to_pixel(d)
    # keep a margin so columns at the image edge are interpolated, not extrapolated
    half = max(camera.width, camera.height)
    ok = front & np.isfinite(el) & (u > -half) & (u < camera.width + half)
    rows = np.full(camera.width, np.nan)
    if ok.sum() < 2:
        return rows
    # walk the closed horizon from a vertex outside the view, so the visible part is one run
    start = int(np.flatnonzero(~ok)[0]) if (~ok).any() else 0
    order = np.roll(np.arange(az.size), -start)
    uu, vv, kk = u[order], v[order], ok[order]
    cols = np.arange(camera.width, dtype=float)
    # a run of consecutive in-front vertices is one visible piece of the skyline
    breaks = np.flatnonzero(np.diff(kk.astype(np.int8)) != 0) + 1
    for piece in np.split(np.arange(az.size), breaks):
        if not kk[piece[0]] or piece.size < 2:
            continue
        pu, pv = uu[piece], vv[piece]
        if np.any(np.diff(pu) <= 0):
            srt = np.argsort(pu)
            pu, pv = pu[srt], pv[srt]
        inside = (cols >= pu[0]) & (cols <= pu[-1])
        rows[inside] = np.interp(cols[inside], pu, pv)
    rows[(rows < 0) | (rows > camera.height - 1)] = np.nan
    return rows


def check_bins(bins):
    """Refuse an azimuth bin count that is not a whole number >= 4."""
    if int(bins) != bins or bins < 4:
        raise ParameterError(f"azimuth bins must be a whole number >= 4, got {bins}")
