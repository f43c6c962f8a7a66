"""The loop every map runs: its arguments checked on the host, the chunks stepped over the devices (one
step in flight), the partial maps reduced, and (a capability map) every sample's cell counted on the host."""

from __future__ import annotations

import math
import sys
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from diffkin._checks import positive_int
from diffkin._static import partition
from diffkin.workspace._sampling import _as_chain, voxel_grid
from diffkin.workspace._step import _AXIS, _collision_check, _compiled

_INT32_MAX = 2**31 - 1


class Maps(NamedTuple):
    """What :func:`run` gives: the chain, the grid and the reduced maps (``cells``/``cell_counts``: the
    sorted flat cells ``voxel * n_bins + bin`` reached and their counts, a capability map's; else ``None``)."""

    chain: Any
    origin: np.ndarray
    voxel_size: float
    shape: tuple[int, ...]
    counts: np.ndarray
    best: np.ndarray
    dexterity: np.ndarray
    cells: np.ndarray | None
    cell_counts: np.ndarray | None


def _host(x: jax.Array) -> np.ndarray:
    """A replicated array as numpy (one local copy; works on every process of a multi-host run)."""
    return np.asarray(x.addressable_data(0))


def _progress(total: int, show: bool | None, desc: str):
    """A tqdm bar over chunks, or ``None``: ``show=None`` shows it on a terminal on process 0."""
    if show is False or jax.process_index() != 0:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    if show is None and not sys.stderr.isatty():
        return None
    return tqdm(total=total, unit="sample", unit_scale=True, desc=desc)


class _CellCounter:
    """Counts of sparse int cells: batches buffered, sorted and merged into the sorted unique cells when the
    buffer outgrows them (each merge linear in the cells); sums, order-independent."""

    def __init__(self, sentinel: int):
        self.sentinel, self.cells, self.counts = sentinel, np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.buffer: list[np.ndarray] = []
        self.buffered = 0

    def add(self, slots: np.ndarray) -> None:
        self.buffer.append(slots[slots != self.sentinel])
        self.buffered += slots.size
        if self.buffered > max(1 << 22, self.cells.size):
            self.merge()

    def merge(self) -> tuple[np.ndarray, np.ndarray]:
        if self.buffer:
            new, n_new = np.unique(np.concatenate(self.buffer).astype(np.int64), return_counts=True)
            at = np.searchsorted(self.cells, new)  # both sorted and unique: a merge, no sort of the cells
            found = at < self.cells.size
            found[found] = self.cells[at[found]] == new[found]
            counts = self.counts.copy()
            counts[at[found]] += n_new[found]
            cells = np.insert(self.cells, at[~found], new[~found])
            counts = np.insert(counts, at[~found], n_new[~found])
            self.cells, self.counts, self.buffer, self.buffered = cells, counts, [], 0
        return self.cells, self.counts


def run(
    chain,
    n_samples,
    *,
    key,
    voxel_size,
    bounds,
    chunk,
    devices,
    orientation_bins: int,
    n_dir: int,
    cells: bool,
    dtype,
    progress: bool | None,
    avoid,
    max_grid_bytes: int,
    desc: str,
) -> Maps:
    """Sample, step and reduce one map (see :func:`diffkin.workspace.reachability`); ``cells``: a capability
    map, whose cells are counted on the host. ``orientation_bins`` and ``n_dir`` are checked by the caller."""
    collision = None if avoid is None else _collision_check(chain, avoid)
    chain = _as_chain(chain)
    n_samples = positive_int(n_samples, "n_samples")
    chunk = positive_int(chunk, "chunk")
    origin, voxel_size, shape = voxel_grid(chain, voxel_size, bounds)
    n_chunks = -(-n_samples // chunk)
    if n_chunks > _INT32_MAX:
        raise ValueError(f"n_samples: expected at most {_INT32_MAX} chunks of {chunk} samples, got {n_samples} samples")
    chunk = min(chunk, n_samples)  # a larger chunk would only compute masked samples
    n_slots = math.prod(shape) * orientation_bins
    if n_slots >= _INT32_MAX:
        raise ValueError(
            f"voxel_size: grid of {shape} voxels x {orientation_bins} orientation bins exceeds 2**31 "
            f"cells; expected a coarser voxel_size, smaller bounds or fewer orientation_bins"
        )
    devices = list(jax.devices() if devices is None else devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise TypeError(f"devices: expected a non-empty sequence of jax.Device, got {devices!r}")
    dtype = jnp.dtype(dtype or jnp.result_type(float))
    # Per voxel: every device's counts, best manipulability and orientation flags; the reduction's
    # maximum of the flags and its three maps; the host's int64 counts and copies of the maps. (A
    # capability map has no flags: its cells are counted on the host, O(cells reached).)
    item, flags = dtype.itemsize, 0 if cells else orientation_bins
    grid_bytes = math.prod(shape) * (len(devices) * (4 + item + flags) + flags + 2 * (8 + item) + 8)
    if grid_bytes > max_grid_bytes:
        raise ValueError(
            f"voxel_size: {voxel_size} m gives a grid of {shape} voxels x {orientation_bins} orientation "
            f"bins on {len(devices)} device(s), about {grid_bytes / 2**30:.1f} GiB of maps (limit "
            f"diffkin.workspace.MAX_GRID_BYTES = {max_grid_bytes / 2**30:.1f} GiB); expected a coarser "
            f"voxel_size, smaller bounds or fewer orientation_bins"
        )
    mesh = Mesh(np.array(devices), (_AXIS,))
    zeros, step, reduce = _compiled(
        partition(chain)[0], shape, orientation_bins, chunk, dtype, mesh, collision, *((n_dir, True) if cells else ())
    )

    n_full, n_last = divmod(n_samples, chunk)
    n_steps = -(-(n_full + (n_last > 0)) // len(devices))
    steps_per_flush = max(1, _INT32_MAX // (chunk * len(devices)))  # int32 device counts cannot overflow
    args = (
        jnp.asarray(n_full, jnp.int32),
        jnp.asarray(n_last, jnp.int32),
        jnp.asarray(origin, dtype),
        jnp.asarray(1.0 / voxel_size, dtype),
        jnp.asarray(n_slots, jnp.int32),
        jnp.zeros((), dtype) if avoid is None else avoid.cast(dtype),
    )
    sharded = NamedSharding(mesh, P(_AXIS))
    state, counts, bar = zeros(), np.zeros(shape, np.int64), _progress(n_samples, progress, desc)
    counter = _CellCounter(n_slots) if cells else None
    done: jax.Array | None = None  # the valid samples of the step in flight
    slots: jax.Array | None = None  # the cells of the step in flight (a capability map)
    for s in range(n_steps):
        indices = np.arange(s * len(devices), (s + 1) * len(devices), dtype=np.int32)
        chunks = jax.make_array_from_callback(indices.shape, sharded, indices.__getitem__)
        out = step(*state, key, chunks, *args)
        state, n_step = list(out[:3]), out[3]
        if counter is not None:  # a capability map's step also gives its cells
            if slots is not None:
                counter.add(np.asarray(slots))  # waits for the previous step only
            slots = out[4]
        if bar is not None:
            if done is not None:
                bar.update(int(done))  # waits for the previous step only: one step stays in flight
            done = n_step
        if (s + 1) % steps_per_flush == 0 or s + 1 == n_steps:
            counts_s, best, dexterity = reduce(*state)
            counts += _host(counts_s).reshape(shape)
            if s + 1 < n_steps:
                state = [zeros()[0], *state[1:]]
    if counter is not None and slots is not None:
        counter.add(np.asarray(slots))
    if bar is not None and done is not None:
        bar.update(int(done))
    if bar is not None:
        bar.close()
    reached, reached_counts = counter.merge() if counter is not None else (None, None)
    return Maps(
        chain,
        origin,
        voxel_size,
        shape,
        counts,
        _host(best).reshape(shape),
        _host(dexterity).reshape(shape),
        reached,
        reached_counts,
    )
