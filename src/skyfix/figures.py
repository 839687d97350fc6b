"""Figures a person reads at a glance: a fix on its map, a frame with its detected skyline, and
the hillshade under every map (the traverse's map is :mod:`skyfix.traverse.plots`). matplotlib
is imported only when a figure is drawn (the board segment never draws).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def hillshade(dem, x0, x1, y0, y1, azimuth_deg=315.0, altitude_deg=45.0):
    """(shade in [0, 1], extent (xmin, xmax, ymin, ymax) [m]) of the DEM's cells within the box
    [m]; None when the box holds fewer than 2 x 2 cells. A stack: its finest DEM."""
    dem = getattr(dem, "members", [dem])[0]
    c0 = max(int(math.floor((x0 - dem.x0) / dem.dx)), 0)
    c1 = min(int(math.ceil((x1 - dem.x0) / dem.dx)) + 1, dem.shape[1])
    r0 = max(int(math.floor((dem.y0 - y1) / dem.dy)), 0)
    r1 = min(int(math.ceil((dem.y0 - y0) / dem.dy)) + 1, dem.shape[0])
    if r1 - r0 < 2 or c1 - c0 < 2:
        return None
    z = np.asarray(dem.z[r0:r1, c0:c1], float)
    z = np.where(np.isfinite(z), z, np.nanmean(z))
    dzdy_rows, dzdx = np.gradient(z, dem.dy, dem.dx)
    dzdy = -dzdy_rows  # rows run south
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    # light from the azimuth (clockwise from north), the surface normal (-dz/dx, -dz/dy, 1)
    lx, ly, lz = math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)
    shade = (-dzdx * lx - dzdy * ly + lz) / np.sqrt(1 + dzdx ** 2 + dzdy ** 2)
    ext = (dem.x0 + (c0 - 0.5) * dem.dx, dem.x0 + (c1 - 0.5) * dem.dx,
           dem.y0 - (r1 - 0.5) * dem.dy, dem.y0 - (r0 - 0.5) * dem.dy)
    return np.clip(shade, 0, 1), ext


def legend_outside(ax):
    """The legend to the right of the axes, off the data."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=8)


def plot_fix_map(path, fix, dem, *, area=None, truth=None, pad_m=None) -> Path:
    """The fix on a hillshade: the searched area (box [m]), the candidates, the fix with its
    1-sigma circle and heading, and the truth (x, y) [m] when known. Axes in metres east and north
    of the fix (the fix's own coordinates are in the title): map coordinates of seven digits do
    not fit under an axis."""
    from ._io import save_figure
    from .optional import pyplot

    plt = pyplot()
    ox, oy = fix.x, fix.y
    pts = [(fix.x, fix.y)] + [(c["x"], c["y"]) for c in fix.candidates]
    if truth is not None:
        pts.append(tuple(truth))
    xs, ys = np.array(pts).T
    if area is not None:
        xs = np.r_[xs, area[0], area[2]]
        ys = np.r_[ys, area[1], area[3]]
    pad = pad_m if pad_m is not None else max(50.0, 0.1 * max(np.ptp(xs), np.ptp(ys)))
    x0, x1, y0, y1 = xs.min() - pad, xs.max() + pad, ys.min() - pad, ys.max() + pad
    fig, ax = plt.subplots(figsize=(7.5, 6))
    hs = hillshade(dem, x0, x1, y0, y1)
    if hs is not None:
        e = hs[1]
        ax.imshow(hs[0], cmap="gray", extent=(e[0] - ox, e[1] - ox, e[2] - oy, e[3] - oy),
                  origin="upper", alpha=0.7)
    if area is not None:
        ax.plot(np.array([area[0], area[2], area[2], area[0], area[0]]) - ox,
                np.array([area[1], area[1], area[3], area[3], area[1]]) - oy, "-",
                color="tab:purple", lw=1, label="searched area")
    if fix.candidates:
        ax.plot([c["x"] - ox for c in fix.candidates], [c["y"] - oy for c in fix.candidates], "o",
                mfc="none", color="tab:orange", ms=6, label="candidates")
    ax.plot(0, 0, "+", color="tab:blue", ms=14, mew=2, label=f"fix (confidence {fix.confidence:.2f})")
    r = fix.position_sigma_m
    if math.isfinite(r) and r > 0:
        t = np.linspace(0, 2 * np.pi, 90)
        ax.plot(r * np.cos(t), r * np.sin(t), "-", color="tab:blue", lw=1, label=f"1-sigma ({r:.2g} m)")
    # the heading as an arrow from the fix (grid north is up in this map)
    h = math.radians(fix.grid_heading_deg)
    L = 0.08 * (x1 - x0)
    ax.annotate("", xy=(L * math.sin(h), L * math.cos(h)), xytext=(0, 0),
                arrowprops=dict(arrowstyle="->", color="tab:blue", lw=1.5))
    ax.plot([], [], "-", color="tab:blue", label="heading")
    if truth is not None:
        ax.plot(truth[0] - ox, truth[1] - oy, "x", color="tab:red", ms=10, mew=2, label="truth")
    ax.set_xlim(x0 - ox, x1 - ox)
    ax.set_ylim(y0 - oy, y1 - oy)
    ax.set_aspect("equal")
    ax.set_xlabel("east of the fix [m] (grid)")
    ax.set_ylabel("north of the fix [m] (grid)")
    ax.set_title(f"fix x {fix.x:.1f}, y {fix.y:.1f} m ({fix.crs}); heading {fix.heading_deg:.1f} deg "
                 "from true north", fontsize=10)
    legend_outside(ax)
    save_figure(fig, path, bbox_inches="tight", dpi=110)
    plt.close(fig)
    return Path(path)


def plot_frame_skyline(path, rgb, skyline, title="") -> Path:
    """One image with its detected skyline drawn over it (columns without one left bare)."""
    from ._io import save_figure
    from .optional import pyplot

    plt = pyplot()
    h, w = rgb.shape[:2]
    fig, ax = plt.subplots(figsize=(7, 7 * h / w + 0.6))
    ax.imshow(rgb)
    rows = np.asarray([np.nan if r is None else r for r in skyline.rows], float)
    ax.plot(np.arange(rows.size), rows, "-", color="yellow", lw=1.2, label="detected skyline")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.01), frameon=False, fontsize=8)
    save_figure(fig, path, bbox_inches="tight", dpi=110)
    plt.close(fig)
    return Path(path)

