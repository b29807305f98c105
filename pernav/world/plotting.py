"""Town maps with their routes (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from pernav.world.towns import get_town


def lane_polyline(lane, step: float = 2.0) -> np.ndarray:
    s = np.append(np.arange(0.0, lane.length, step), lane.length)
    return np.array([lane.position(x, 0.0) for x in s])


def plot_town(name: str, path: str | Path, routes: bool = True) -> Path:
    """Draw ``name``'s lanes, junctions and fixed routes to ``path`` (PNG); returns the path.

    >>> import tempfile, os
    >>> out = plot_town("Town1", os.path.join(tempfile.mkdtemp(), "t1.png"))
    >>> out.exists()
    True
    """
    matplotlib.use("Agg")  # headless
    town = get_town(name)
    fig, ax = plt.subplots(figsize=(9, 7))
    for index in town.successors:
        pts = lane_polyline(town.lane(index))
        ax.plot(pts[:, 0], pts[:, 1], color="0.75", lw=2.5 if index in town.road_lanes else 1.0, zorder=1)
    for j in town.junctions.values():
        marker = "o" if j.kind == "roundabout" else "s"
        ax.scatter(*j.center, marker=marker, s=30, color="0.35", zorder=2)
    if routes:
        colors = plt.cm.tab10(np.linspace(0, 1, len(town.routes)))
        for k, (route, c) in enumerate(zip(town.routes, colors, strict=True)):
            off = (k - len(town.routes) / 2) * 0.6  # small offset so overlapping routes stay visible
            w = route.waypoints + off
            ax.plot(w[:, 0], w[:, 1], color=c, lw=1.4, alpha=0.9, zorder=3,
                    label=f"route {k}: {route.length:.0f} m, "
                    + "".join(m.kind[0].upper() for m in route.manoeuvres if m.decision and m.kind != "straight"))
            ax.scatter(*w[0], color=c, marker=">", s=40, zorder=4)
            ax.scatter(*w[-1], color=c, marker="*", s=80, zorder=4)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="L/R turns, E enter, X exit, P pass")
    ax.set_aspect("equal")
    ax.invert_yaxis()  # highway-env's frame is y-down, like the screen
    ax.set_title(f"{name}: {town.description}", fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
