"""Data drawn over the robot: reachability maps as coloured points, and a colour map."""

from __future__ import annotations

import numpy as np

# viridis at five stops (matplotlib's values), interpolated linearly
_VIRIDIS = np.array(
    [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]]
)

QUANTITIES = ("counts", "manipulability", "dexterity")


def colormap(values: np.ndarray) -> np.ndarray:
    """``(n, 3)`` uint8 viridis colours of ``values`` scaled to their own min..max."""
    values = np.asarray(values, dtype=np.float64)
    lo, hi = (values.min(), values.max()) if values.size else (0.0, 1.0)
    t = (values - lo) / (hi - lo) if hi > lo else np.full_like(values, 0.5)
    x = t * (len(_VIRIDIS) - 1)
    i = np.clip(np.floor(x).astype(int), 0, len(_VIRIDIS) - 2)
    f = (x - i)[:, None]
    return np.round(255 * ((1 - f) * _VIRIDIS[i] + f * _VIRIDIS[i + 1])).astype(np.uint8)


def map_points(wmap, quantity: str = "counts") -> tuple[np.ndarray, np.ndarray]:
    """The centres of the reached voxels of a reachability map and their colours.

    Args:
        wmap: a ``dk.workspace.ReachabilityMap`` (or anything with ``counts``, ``manipulability``,
            ``dexterity`` ``(nx, ny, nz)``, ``origin (3,)`` and ``voxel_size``).
        quantity: ``counts``, ``manipulability`` or ``dexterity``: what the colour shows.

    Returns:
        ``points (n, 3)`` metres in the robot's base frame and ``colors (n, 3)`` uint8.
    """
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity: expected one of {QUANTITIES}, got {quantity!r}")
    counts = np.asarray(wmap.counts)
    index = np.argwhere(counts > 0)
    points = np.asarray(wmap.origin, dtype=np.float64) + (index + 0.5) * float(wmap.voxel_size)
    values = np.asarray(getattr(wmap, quantity), dtype=np.float64)[tuple(index.T)]
    return points, colormap(values)
