"""Workspace analysis: reachability, manipulability and dexterity maps over millions of samples.

Configurations are drawn uniformly within the joint limits, chunk by chunk; each chunk is run
through forward kinematics, its end-effector positions are binned on a voxel grid and reduced
into per-voxel sample counts, best manipulability and the set of orientation bins reached.
Memory is ``O(chunk + grid)`` whatever the number of samples. Chunks are spread over devices
with a :class:`jax.sharding.Mesh` and ``shard_map``; every device keeps a partial map and the
partial maps are reduced at the end with integer sums, float maxima and logical ors, which
do not depend on the order of reduction, so the map is identical for any number of devices.
For that, each sample's bins must not depend on how its device's program is compiled: the
per-device program receives its chunk index as data (it is the same program for any number of
devices), and the binning uses no division (XLA's CPU division rounds differently in different
compilations); see ``_flat_index`` and ``_orientation_bin``.

Orientation bins are a fixed partition of SO(3) into ``orientation_bins = 6 * n_roll`` cells
of equal measure: the tool z axis picks a face of the cube (its largest component and that
component's sign), and the rotation about the tool z axis picks one of ``n_roll`` sectors of
the roll angle ``atan2(-R[u, 1], R[u, 0])``, where ``u = (a + 1) % 3`` for the face axis
``a``: the angle of the tool x axis from the projection of the base axis ``u`` on the plane
orthogonal to the tool z axis (never degenerate, since that axis is at most 54.8 degrees from
``a``). For a planar arm (rotation about the base z axis by ``phi``) the bin is the sector of
``phi``, so different planar angles land in different bins.

The package: the front doors :func:`reachability` and :func:`capability` here; the loop they share
(``_driver.py``); the map and its file format (``_map.py``), the capability map's (``_capability.py``) and
the cells around a pose that its look-up judges it by (``_cells.py``),
what is sampled and the grid (``_sampling.py``), the per-sample bins and manipulability
(``_bins.py``), the compiled sharded step and its reduction (``_step.py``), base placement
(``_placement.py``) and what obstacles rule out of it (``_blocked.py``), the plots (``_plot.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax

from diffkin._checks import positive_int
from diffkin.workspace._capability import CapabilityMap, bin_rotations, split_bins
from diffkin.workspace._driver import run
from diffkin.workspace._map import ReachabilityMap
from diffkin.workspace._placement import Placement, Verification, base_placement
from diffkin.workspace._plot import plot_placement, plot_slice
from diffkin.workspace._sampling import sample_configs
from diffkin.workspace._step import _compiled  # noqa: F401  # its cache, for the tests

MAX_GRID_BYTES = 2 * 1024**3
"""Largest memory of the maps of :func:`reachability` (an estimate: every device's counts, manipulability
and orientation flags per voxel, their reduction and the host's copies); a finer grid is a ValueError
naming ``voxel_size``. Raise it (``diffkin.workspace.MAX_GRID_BYTES = ...``) to allow more."""


def reachability(
    chain,
    n_samples: int,
    *,
    key,
    voxel_size: float = 0.05,
    bounds=None,
    chunk: int = 1 << 16,
    devices: Sequence[jax.Device] | None = None,
    orientation_bins: int = 48,
    dtype=None,
    progress: bool | None = None,
    avoid=None,
) -> ReachabilityMap:
    """Reachability, best manipulability and dexterity of ``chain`` on a voxel grid.

    ``n_samples`` configurations uniform within the joint limits (see :func:`sample_configs`)
    are drawn in ``ceil(n_samples / chunk)`` chunks, chunk ``c`` from
    ``jax.random.fold_in(key, c)`` (the last one masked to the remaining samples), and reduced
    chunk by chunk, so memory is ``O(chunk + grid)`` per device. Chunks are spread over
    ``devices``; the map is identical for any number of devices. Each step is one jitted call,
    compiled once per chain, grid shape, chunk, orientation bins, dtype and device set.

    Args:
        chain: a :class:`DHChain` or :class:`PoEChain` with concrete (not traced) numbers, or a
            ``(robot, frame_name)`` pair: the map of that frame of a :class:`Robot`, in its root
            frame (the path's joints only; see :meth:`Robot.chain`).
        n_samples: number of configurations.
        key: a JAX PRNG key.
        voxel_size: voxel edge, metres (default 0.05, as the ``diffkin workspace`` command).
        bounds: ``(2, 3)`` ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` box in the base frame,
            metres; the grid starts at the min corner and has ``ceil((max - min) / voxel_size)``
            voxels per axis. Default: a cube centred on the base origin (at a voxel centre) that
            holds every reachable point, from an upper bound on the reach (the sum of the
            distances between consecutive joint axes, plus prismatic travel).
        chunk: samples per device per step (at most ``n_samples``: a larger value is capped).
        devices: devices to use (all processes' devices in a multi-host run); default
            ``jax.devices()``.
        orientation_bins: cells of the SO(3) partition, a multiple of 6 (6 cube faces of the
            tool z axis times ``orientation_bins / 6`` roll sectors).
        dtype: float dtype of the computation; default the default float (float32, or float64
            with x64).
        progress: show a tqdm progress bar; ``None`` (default): only on a terminal.
        avoid: for a ``(robot, frame_name)`` pair, a :class:`~diffkin.ik.Avoid` (the robot's collision
            geometry, obstacles, margin): only samples whose clearance is at least the margin count
            (in every map; ``n_outside`` then also counts the colliding samples). The robot's joints
            off the frame's path are held at the middle of their limits (a one-sided limit's bound, 0
            where unlimited).

    Returns:
        The :class:`ReachabilityMap`.

    Raises:
        ValueError, TypeError: bad arguments (named in the message).
    """
    orientation_bins = positive_int(orientation_bins, "orientation_bins")
    if orientation_bins % 6:
        raise ValueError(
            f"orientation_bins: expected a multiple of 6 (6 cube faces x roll sectors), got {orientation_bins}"
        )
    maps, shared = _sampled(
        chain,
        n_samples,
        orientation_bins,
        n_dir=1,
        cells=False,
        key=key,
        voxel_size=voxel_size,
        bounds=bounds,
        chunk=chunk,
        devices=devices,
        dtype=dtype,
        progress=progress,
        avoid=avoid,
    )
    return ReachabilityMap(dexterity=maps.dexterity, **shared)


def capability(
    chain,
    n_samples: int,
    *,
    key,
    voxel_size: float = 0.05,
    orientation_bins: int = 5184,
    bounds=None,
    avoid=None,
    chunk: int = 1 << 16,
    devices: Sequence[jax.Device] | None = None,
    dtype=None,
    progress: bool | None = None,
) -> CapabilityMap:
    """Which tool poses ``chain`` reaches: sample counts per position voxel and orientation bin.

    Sampled, sharded and chunked as :func:`reachability` (the same configurations for the same key,
    ``avoid`` alike, identical for any number of devices); each sample counts in the cell of its
    position voxel and orientation bin, and the cells reached are counted on the host (memory
    ``O(chunk + grid + cells reached)``). :meth:`CapabilityMap.reaches` looks poses up, judging each by
    its cell and the cells beside it (the map's edge in the middle of its outermost cells, unsampled
    cells between held ones filled); :func:`base_placement` inverts the map to place the robot.

    The orientation bins: the tool z axis picks a face of the cube (its largest component and that
    component's sign) and one of ``d x d`` cells of that face, equal in angle (``90 / d`` degrees:
    the sectors of ``atan2(z_u, |z_a|)`` and ``atan2(z_v, |z_a|)`` over ``[-45, 45]`` degrees, ``z_a``
    the face's component and ``u, v`` the next two axes), and the roll about the tool z axis one of
    ``4 d`` sectors of ``90 / d`` degrees (measured as :func:`reachability`'s): ``orientation_bins =
    6 d^2 x 4 d = 24 d^3``. Every bin's rotations lie within an angle of its centre
    (:func:`bin_rotations`) measured over 400,000 uniform rotations (the worst angular error of a
    look-up; two rotations of one bin differ by at most twice it):

    ====  ================  ============  ========================
    d     orientation_bins  cell (deg)    worst error (deg)
    ====  ================  ============  ========================
    1     24                90            78.6
    2     192               45            45.7
    3     648               30            31.3
    4     1536              22.5          24.0
    6     5184 (default)    15            16.1
    ====  ================  ============  ========================

    Args:
        chain: a :class:`DHChain` or :class:`PoEChain` with concrete numbers, or a ``(robot,
            frame_name)`` pair (the map of that frame, in the robot's root frame).
        n_samples: number of configurations.
        key: a JAX PRNG key.
        voxel_size: voxel edge, metres.
        orientation_bins: ``24 d^3`` for ``d`` in 1..12 (see above).
        bounds: ``(2, 3)`` box in the base frame, metres (default: a cube holding the reach), as
            :func:`reachability`'s.
        avoid: for a ``(robot, frame_name)`` pair, a :class:`~diffkin.ik.Avoid`: only samples clear of
            the obstacles (and of the robot itself) by its margin count.
        chunk: samples per device per step.
        devices: devices to use; default ``jax.devices()``.
        dtype: float dtype of the computation; default the default float.
        progress: show a tqdm progress bar; ``None`` (default): only on a terminal.

    Returns:
        The :class:`CapabilityMap`.

    Raises:
        ValueError, TypeError: bad arguments (named in the message).
    """
    n_dir, _ = split_bins(orientation_bins)
    orientation_bins = int(orientation_bins)
    maps, shared = _sampled(
        chain,
        n_samples,
        orientation_bins,
        n_dir=n_dir,
        cells=True,
        key=key,
        voxel_size=voxel_size,
        bounds=bounds,
        chunk=chunk,
        devices=devices,
        dtype=dtype,
        progress=progress,
        avoid=avoid,
    )
    assert maps.cells is not None and maps.cell_counts is not None
    return CapabilityMap(cells=maps.cells, cell_counts=maps.cell_counts, **shared)


def _sampled(chain, n_samples: int, orientation_bins: int, *, n_dir: int, cells: bool, **options):
    """The sampling loop of :func:`reachability` (``cells=False``) and :func:`capability` (``cells=True``,
    the cells reached counted), and the fields both maps take from it (grid, counts, best
    manipulability, samples outside); ``options`` are the loop's (key, voxel_size, bounds, chunk, devices,
    dtype, progress, avoid)."""
    desc = "capability" if cells else "reachability"
    maps = run(
        chain,
        n_samples,
        orientation_bins=orientation_bins,
        n_dir=n_dir,
        cells=cells,
        max_grid_bytes=MAX_GRID_BYTES,
        desc=desc,
        **options,
    )
    shared = dict(
        counts=maps.counts,
        manipulability=maps.best,
        origin=maps.origin,
        voxel_size=maps.voxel_size,
        n_samples=n_samples,
        n_outside=n_samples - int(maps.counts.sum()),
        orientation_bins=orientation_bins,
        chain_name=maps.chain.name,
    )
    return maps, shared


__all__ = [
    "MAX_GRID_BYTES",
    "CapabilityMap",
    "Placement",
    "ReachabilityMap",
    "Verification",
    "base_placement",
    "bin_rotations",
    "capability",
    "plot_placement",
    "plot_slice",
    "reachability",
    "sample_configs",
]
