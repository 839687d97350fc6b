"""The traverse's map: the track over a hillshade of the terrain."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_track(path, rows, trav, dem, convergence) -> Path:
    """A traverse over a hillshade: the truth (when known), odometry alone, the fused track, its
    position fixes and the stops where the operator was asked. ``rows``: the stop records;
    ``convergence(x, y)`` [deg] true minus grid north."""
    from .._io import save_figure
    from ..figures import hillshade, legend_outside
    from ..optional import pyplot
    from .simulate import odometry_only

    plt = pyplot()
    xs = np.array([r["x"] for r in rows])
    ys = np.array([r["y"] for r in rows])
    pad = 300.0
    x0, x1, y0, y1 = xs.min() - pad, xs.max() + pad, ys.min() - pad, ys.max() + pad
    fig, ax = plt.subplots(figsize=(7, 7))
    hs = hillshade(dem, x0, x1, y0, y1)
    if hs is not None:
        ax.imshow(hs[0], cmap="gray", extent=hs[1], origin="upper", alpha=0.6)
    if trav.truth:
        ax.plot([t["x"] for t in trav.truth], [t["y"] for t in trav.truth], "k-", lw=2, label="truth")
    if trav.start is not None:
        od = np.array(odometry_only(trav, convergence))
        ax.plot(od[: len(rows), 0], od[: len(rows), 1], "--", color="tab:orange",
                label="odometry alone")
    ax.plot(xs, ys, "-", color="tab:blue", lw=1.5, label="fused")
    fix = [k for k, r in enumerate(rows) if r["update"] == "position"]
    ax.plot(xs[fix], ys[fix], "o", color="tab:green", ms=6, label="position fix")
    ask = [k for k, r in enumerate(rows) if r["operator_request"]]
    if ask:
        ax.plot(xs[ask], ys[ask], "x", color="tab:red", ms=10, mew=2, label="operator request")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"traverse of {len(rows)} stops")
    legend_outside(ax)
    save_figure(fig, path, bbox_inches="tight", dpi=110)
    plt.close(fig)
    return Path(path)
