"""A slice of a map as an image (matplotlib, the ``plot`` extra)."""

from __future__ import annotations

import math

import numpy as np

from diffkin.workspace._map import ReachabilityMap

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
