"""A slice of a map as an image (matplotlib, the ``plot`` extra)."""

from __future__ import annotations

import math

import numpy as np

from diffkin.workspace._map import ReachabilityMap
from diffkin.workspace._placement import Placement

_QUANTITIES = ("count", "manipulability", "dexterity")
_AXES = ("x", "y", "z")


def plot_slice(
    reach_map: ReachabilityMap, axis: str = "y", value: float = 0.0, quantity: str = "count", *, path=None, ax=None
):
    """Heatmap of one quantity on the voxel layer that contains the plane ``axis = value``.

    The layer is a slab one voxel thick; the title and colour bar say what is plotted: samples
    per voxel (of ``n_samples`` configurations uniform in joint space), the best Yoshikawa
    manipulability per voxel (of the end effector's ``(6, dof)`` world Jacobian), or the number
    of orientation bins reached per voxel (out of ``orientation_bins``, the colour bar's maximum).
    Needs matplotlib (the ``plot`` extra), imported here only.

    Args:
        reach_map: the :class:`ReachabilityMap`.
        axis: ``"x"``, ``"y"`` or ``"z"``, the normal of the slicing plane (base frame).
        value: position of the plane along ``axis``, metres; it must cross the grid.
        quantity: ``"count"``, ``"manipulability"`` or ``"dexterity"``.
        path: if given, the figure is written there as a PNG.
        ax: a matplotlib axes to draw into; default a new figure.

    Returns:
        The matplotlib axes.
    """
    m = reach_map
    if axis not in _AXES:
        raise ValueError(f"axis: expected one of {_AXES}, got {axis!r}")
    if quantity not in _QUANTITIES:
        raise ValueError(f"quantity: expected one of {_QUANTITIES}, got {quantity!r}")
    a = _AXES.index(axis)
    layer = math.floor((float(value) - m.origin[a]) / m.voxel_size)
    if not 0 <= layer < m.counts.shape[a]:
        lo, hi = m.origin[a], m.origin[a] + m.voxel_size * m.counts.shape[a]
        raise ValueError(f"value: expected {axis} in [{lo:.4g}, {hi:.4g}) (the grid), got {value}")
    if ax is None:
        from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

        ax = Figure(figsize=(7, 5.5), layout="constrained").add_subplot()
    data = {"count": m.counts, "manipulability": m.manipulability, "dexterity": m.dexterity}[quantity]
    plane = np.take(data, layer, axis=a).astype(np.float64)
    plane[np.take(m.counts, layer, axis=a) == 0] = np.nan  # unreached voxels blank
    u, v = (i for i in range(3) if i != a)
    extent = [
        m.origin[u],
        m.origin[u] + m.voxel_size * data.shape[u],
        m.origin[v],
        m.origin[v] + m.voxel_size * data.shape[v],
    ]
    slab = (m.origin[a] + layer * m.voxel_size, m.origin[a] + (layer + 1) * m.voxel_size)
    limits = {"vmin": 0, "vmax": m.orientation_bins} if quantity == "dexterity" else {}
    image = ax.imshow(plane.T, origin="lower", extent=extent, interpolation="nearest", **limits)
    label = {
        "count": "samples per voxel",
        "manipulability": "best Yoshikawa manipulability sqrt(det(J J^T)) in the voxel",
        "dexterity": f"orientation bins reached (of {m.orientation_bins})",
    }[quantity]
    ax.figure.colorbar(image, ax=ax, label=label)
    what = {
        "count": "reachability: samples per voxel",
        "manipulability": "best manipulability per voxel (J: world Jacobian of the end effector)",
        "dexterity": f"dexterity: orientation bins of {m.orientation_bins} reached per voxel",
    }[quantity]
    ax.set(
        xlabel=f"{_AXES[u]} (m)",
        ylabel=f"{_AXES[v]} (m)",
        aspect="equal",
        title=f"{m.chain_name} {what}\nslab {axis} in [{slab[0]:.3g}, {slab[1]:.3g}) m ({m.voxel_size:g} m "
        f"voxels)\n{m.n_samples:,} samples uniform in joint space; blank: none reached",
    )
    ax.title.set_fontsize("medium")
    if path is not None:
        ax.figure.savefig(path, dpi=120)
    return ax


def plot_placement(placement: Placement, yaw: int | None = None, *, path=None, ax=None):
    """Heatmap of a base placement's score over ``(x, y)`` at one yaw, with the tasks drawn.

    Each pixel is a base cell: the fraction of the tasks the capability map says a base there
    reaches. The tasks are drawn at their ``(x, y)`` in the world (their tool x axis as a short
    arrow), and the best base of that yaw as a cross with its heading; with obstacles
    (``base_placement(..., avoid=)``), the blocked bases of that yaw grey and the blocked tasks as
    black crosses. Needs matplotlib (the ``plot`` extra), imported here only.

    Args:
        placement: the :class:`Placement`.
        yaw: index into ``placement.yaw``; default the yaw of the best base.
        path: if given, the figure is written there as a PNG.
        ax: a matplotlib axes to draw into; default a new figure.

    Returns:
        The matplotlib axes.
    """
    p = placement
    if yaw is None:
        yaw = int(p.best_cells(1)[0, 2])
    if isinstance(yaw, bool) or not isinstance(yaw, (int, np.integer)) or not 0 <= yaw < len(p.yaw):
        raise ValueError(f"yaw: expected an index in [0, {len(p.yaw)}), got {yaw!r}")
    if ax is None:
        from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

        ax = Figure(figsize=(7, 5.5), layout="constrained").add_subplot()
    score = p.score[:, :, yaw]
    half_x = (p.x[1] - p.x[0]) / 2 if len(p.x) > 1 else 0.5
    half_y = (p.y[1] - p.y[0]) / 2 if len(p.y) > 1 else 0.5
    extent = [p.x[0] - half_x, p.x[-1] + half_x, p.y[0] - half_y, p.y[-1] + half_y]
    top = max(float(p.score.max()), 1e-9)
    image = ax.imshow(score.T, origin="lower", extent=extent, interpolation="nearest", vmin=0, vmax=top)
    ax.figure.colorbar(image, ax=ax, label="fraction of the tasks reached (capability map; scale to the best)")
    tasks = p.tasks[:, :3, 3]
    ax.quiver(
        tasks[:, 0], tasks[:, 1], p.tasks[:, 0, 0], p.tasks[:, 1, 0], color="white", width=0.003, scale=40, alpha=0.8
    )
    ax.scatter(tasks[:, 0], tasks[:, 1], s=6, c="red", label=f"{len(tasks)} tasks (tool x axis)")
    if p.blocked_bases is not None and p.blocked_tasks is not None:  # avoid=: grey bases, crossed tasks
        blocked = p.blocked_bases[:, :, yaw]
        grey = np.ma.masked_where(~blocked.T, np.ones(blocked.T.shape))
        ax.imshow(grey, origin="lower", extent=extent, interpolation="nearest", cmap="gray", vmin=0, vmax=2)
        ax.fill([], [], color="0.5", label=f"{int(blocked.sum())} bases blocked by obstacles at this yaw")
        out = p.blocked_tasks
        ax.scatter(tasks[out, 0], tasks[out, 1], s=24, c="black", marker="x", label=f"{int(out.sum())} tasks blocked")
    i, j = np.unravel_index(np.argmax(score), score.shape)
    heading = p.yaw[yaw]
    ax.plot(p.x[i], p.y[j], "wx", ms=12, mew=3)
    ax.arrow(p.x[i], p.y[j], 0.15 * np.cos(heading), 0.15 * np.sin(heading), color="w", width=0.01)
    ax.plot([], [], "wx", label=f"best base at this yaw: {score[i, j]:.0%}")
    ax.legend(loc="upper right", fontsize="small")
    ax.set(
        xlabel="base x (m, world)",
        ylabel="base y (m, world)",
        aspect="equal",
        title=f"base placement: tasks reached from each base cell\nyaw {np.degrees(heading):.0f} deg "
        f"(of {len(p.yaw)}), base height {p.base_height:g} m; best overall {p.score.max():.0%}",
    )
    ax.title.set_fontsize("medium")
    if path is not None:
        ax.figure.savefig(path, dpi=120)
    return ax
