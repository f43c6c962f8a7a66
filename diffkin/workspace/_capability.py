"""The capability map of :func:`diffkin.workspace.capability`: sample counts per position voxel and
orientation bin, its look-up of poses (:meth:`CapabilityMap.reaches`) and its file format (``.npz``,
read without pickle)."""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

from diffkin._checks import positive_int
from diffkin._npz import read_dataclass_fields, save_dataclass
from diffkin.workspace._cells import STEPS, cell_codes, edge_bits, neighbour_bins, pose_halves, reached
from diffkin.workspace._map import ReachabilityMap, grid_fields

BIN_COUNTS = {24 * d**3: d for d in range(1, 13)}
"""The valid ``orientation_bins`` of a capability map, ``24 d^3``, and their ``d``: ``6 d^2`` cells of
the tool z axis times ``4 d`` roll sectors, cells ``90 / d`` degrees wide."""


def split_bins(orientation_bins) -> tuple[int, int]:
    """``(n_dir, n_roll)`` of ``orientation_bins = 24 d^3`` (``n_dir = d``, ``n_roll = 4 d``), checked."""
    if isinstance(orientation_bins, bool) or not isinstance(orientation_bins, (int, np.integer)):
        raise TypeError(f"orientation_bins: expected an int, got {type(orientation_bins).__name__}")
    d = BIN_COUNTS.get(int(orientation_bins))
    if d is None:
        raise ValueError(
            f"orientation_bins: expected 24 d^3 (6 d^2 directions x 4 d roll sectors, 90/d degree cells), one of "
            f"{sorted(BIN_COUNTS)}, got {orientation_bins}"
        )
    return d, 4 * d


def bin_rotations(orientation_bins: int) -> np.ndarray:
    """The centre of every orientation bin, ``(orientation_bins, 3, 3)`` rotation matrices (float64).

    The centre of bin ``((face n_dir + i_u) n_dir + i_v) n_roll + r``: the tool z axis at the middle
    angles of its direction cell, the roll at the middle of its sector (see
    :func:`diffkin.workspace.capability`).
    """
    n_dir, n_roll = split_bins(orientation_bins)
    rotations = np.zeros((6, n_dir, n_dir, n_roll, 3, 3))
    mid_dir = np.tan(-np.pi / 4 + (np.arange(n_dir) + 0.5) * np.pi / 2 / n_dir)
    rolls = -np.pi + (np.arange(n_roll) + 0.5) * 2 * np.pi / n_roll
    eye = np.eye(3)
    for face in range(6):
        a, sign = face // 2, -1.0 if face % 2 else 1.0
        u, v = (a + 1) % 3, (a + 2) % 3
        for i, tu in enumerate(mid_dir):
            for j, tv in enumerate(mid_dir):
                z = sign * eye[a] + tu * eye[u] + tv * eye[v]
                z /= np.linalg.norm(z)
                p = eye[u] - (eye[u] @ z) * z
                p /= np.linalg.norm(p)
                for r, roll in enumerate(rolls):  # roll = atan2(-R[u, 1], R[u, 0]): p = cos x - sin y
                    x = np.cos(roll) * p + np.sin(roll) * np.cross(z, p)
                    rotations[face, i, j, r] = np.stack([x, np.cross(z, x), z], axis=1)
    return rotations.reshape(-1, 3, 3)


def _bucket(n: int) -> int:
    """``n`` rounded up to a power of two (at least 64): the look-ups compile once per bucket, not per size."""
    return max(64, 1 << (n - 1).bit_length())


@dataclasses.dataclass(frozen=True, eq=False)
class CapabilityMap:
    """Sample counts per position voxel and orientation bin (see :func:`diffkin.workspace.capability`).

    Voxel ``(i, j, k)`` is the box ``origin + voxel_size * ([i, i+1) x [j, j+1) x [k, k+1))`` in the
    chain's base frame (a robot's root frame), as in :class:`ReachabilityMap`; the cells
    ``voxel * orientation_bins + bin`` (``voxel`` the flat C-order index of ``(i, j, k)``) that any
    sample reached are stored sparsely, sorted.

    Attributes:
        cells: ``(M,)`` int64, the sorted flat cells reached.
        cell_counts: ``(M,)`` int64, the samples in each of them.
        counts: ``(nx, ny, nz)`` int64, samples per voxel (any orientation).
        manipulability: ``(nx, ny, nz)`` float, best Yoshikawa manipulability per voxel, 0 where none.
        origin: ``(3,)`` float64, corner of voxel ``(0, 0, 0)``, metres, base frame.
        voxel_size: edge of the cubic voxels, metres.
        n_samples: number of sampled configurations.
        n_outside: number of samples outside the grid (or, with ``avoid``, in collision).
        orientation_bins: number of orientation bins, ``24 d^3``.
        chain_name: name of the chain (informational).
    """

    cells: np.ndarray
    cell_counts: np.ndarray
    counts: np.ndarray
    manipulability: np.ndarray
    origin: np.ndarray
    voxel_size: float
    n_samples: int
    n_outside: int
    orientation_bins: int
    chain_name: str = ""

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(nx, ny, nz)``, the voxel grid."""
        return self.counts.shape  # type: ignore[return-value]

    @functools.cached_property
    def layers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cells in the order of their ``(bin, z layer)``: ``(bin * nz + k (M,), i * ny + j (M,), count
        (M,))``, sorted by the first (what :func:`base_placement` reads: a slice per task; computed once)."""
        voxel, b = np.divmod(self.cells, self.orientation_bins)
        ij, k = np.divmod(voxel, self.shape[2])
        layers = b * self.shape[2] + k
        n_ij = self.shape[0] * self.shape[1]
        key_bits = max(int(self.orientation_bins * self.shape[2] * n_ij - 1).bit_length(), 1)
        count_bits = 63 - key_bits
        if self.cell_counts.size and int(self.cell_counts.max()) < 1 << count_bits:
            # One plain sort of (layer, ij, count) packed in an int64: the keys (layer, ij) are unique, so
            # it orders as the stable argsort by layer (ij ascending within a layer: the cells' order) at
            # a fraction of its time (the sort is vectorized).
            packed = np.sort(((layers * n_ij + ij) << count_bits) | self.cell_counts)
            key = packed >> count_bits
            return key // n_ij, key % n_ij, packed & ((1 << count_bits) - 1)
        order = np.argsort(layers, kind="stable")
        return layers[order], ij[order], self.cell_counts[order]

    def dexterity(self) -> np.ndarray:
        """``(nx, ny, nz)`` int64, the number of orientation bins reached in each voxel."""
        flat = np.bincount(self.cells // self.orientation_bins, minlength=self.counts.size)
        return flat.reshape(self.shape)

    def as_reachability(self) -> ReachabilityMap:
        """The map as a :class:`ReachabilityMap` (its dexterity: the capability bins reached per voxel),
        e.g. for :func:`diffkin.workspace.plot_slice`."""
        return ReachabilityMap(
            counts=self.counts,
            manipulability=self.manipulability,
            dexterity=self.dexterity().astype(np.int32),
            origin=self.origin,
            voxel_size=self.voxel_size,
            n_samples=self.n_samples,
            n_outside=self.n_outside,
            orientation_bins=self.orientation_bins,
            chain_name=self.chain_name,
        )

    def _cells_of(self, T) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat cells ``(M,)`` int64 of poses ``T (..., 4, 4)``, whether inside the grid ``(M,)``, their voxel
        ``(M, 3)`` int64 and halves ``(M, 6)`` bool (:func:`pose_halves`), binned in the default float dtype."""
        dtype = jnp.result_type(float)
        flat_T = np.asarray(T, dtype).reshape(-1, 4, 4)
        pad = np.broadcast_to(np.eye(4, dtype=dtype), (_bucket(len(flat_T)) - len(flat_T), 4, 4))
        n_dir, n_roll = split_bins(self.orientation_bins)
        cell, bins, inside, upper = pose_halves(
            jnp.asarray(np.concatenate([flat_T, pad])),
            n_dir,
            n_roll,
            jnp.asarray(self.origin, dtype),
            jnp.asarray(1 / self.voxel_size, dtype),
            jnp.asarray(self.shape, dtype),
        )
        n = len(flat_T)
        cell, bins = np.asarray(cell[:n], np.int64), np.asarray(bins[:n], np.int64)
        flat = np.ravel_multi_index(tuple(cell.T), self.shape) * self.orientation_bins + bins
        return flat, np.asarray(inside[:n]), cell, np.asarray(upper[:n])

    def _counts_at(self, flat: np.ndarray, inside: np.ndarray) -> np.ndarray:
        """The samples in flat cells ``flat`` (0 where not ``inside``)."""
        at = np.minimum(np.searchsorted(self.cells, flat), self.cells.size - 1)
        return np.where(inside & (self.cells[at] == flat), self.cell_counts[at], 0)

    @staticmethod
    def _checked(T) -> np.ndarray:
        T = np.asarray(T)
        if T.ndim < 2 or T.shape[-2:] != (4, 4):
            raise ValueError(f"T: expected poses of shape (..., 4, 4), got {T.shape}")
        return T

    def count(self, T) -> np.ndarray:
        """The samples in the cell of each pose (binned in the default float dtype, as the map's samples
        were unless ``capability`` was given another).

        Args:
            T: ``(..., 4, 4)`` poses of the tool in the map's base frame (metres).

        Returns:
            ``(...,)`` int64, 0 for a pose outside the grid.
        """
        T = self._checked(T)
        if self.cells.size == 0 or T.size == 0:
            return np.zeros(T.shape[:-2], np.int64)
        flat, inside, _, _ = self._cells_of(T)
        return self._counts_at(flat, inside).reshape(T.shape[:-2])

    def reaches(self, T, *, min_count: int = 1, at_pose: bool = True) -> np.ndarray:
        """Whether the map says the arm reaches each pose, judged at the pose, not only by its cell.

        A cell is *held* when it has at least ``min_count`` samples. A cell on the edge of the held set
        holds reachable and unreachable poses (the reachable part lies toward the held cells), so the
        pose is judged by the cells around it along the six axes of the grid (the voxel's x, y, z; the
        orientation bin's two direction angles and its roll, see :func:`neighbour_bins`). It is reached
        when

        - its cell is held, or is an unsampled cell between two held ones along some axis (a hole), and
        - along every axis, the neighbour on the side of the half of the cell the pose lies in is held, or
          the cell beyond it is (a hole), or the neighbour on the other side is not held either (the held
          set is one cell thin there, as the planar poses of a planar arm are along z).

        That is, the map's edge is moved from the faces of its outermost cells to their middles: the
        poses of an edge cell that lie away from the held ones are not reached. (The other side must hold
        two cells for the pose to be at an edge, so that a held set two cells thin is not cut either.)

        This suits an arm whose reachable poses fill the space of poses around them (6 or more joints).
        An arm with fewer joints reaches a thinner set of poses, oblique to the grid's axes, that the
        test would cut into: ``at_pose=False`` judges a pose by its cell alone (held, no holes filled).

        Args:
            T: ``(..., 4, 4)`` poses of the tool in the map's base frame (metres).
            min_count: samples a cell needs to be held (a higher count trades recall for precision).
            at_pose: judge the pose by the cells around it (default), or by its cell alone (``False``).

        Returns:
            ``(...,)`` bool.
        """
        T = self._checked(T)
        min_count = positive_int(min_count, "min_count")
        if not isinstance(at_pose, (bool, np.bool_)):
            raise TypeError(f"at_pose: expected a bool, got {type(at_pose).__name__}")
        if self.cells.size == 0 or T.size == 0:
            return np.zeros(T.shape[:-2], bool)
        flat, inside, cell, upper = self._cells_of(T)
        held = self._counts_at(flat, inside) >= min_count
        if not at_pose:
            return held.reshape(T.shape[:-2])
        n_dir, n_roll = split_bins(self.orientation_bins)
        neighbours, n_bins = neighbour_bins(n_dir, n_roll)[flat % self.orientation_bins], self.orientation_bins
        near: list[list[np.ndarray]] = []  # per axis, the cells STEPS away held
        for axis in range(6):
            near.append([])
            for i, step in enumerate(STEPS):
                if axis < 3:  # the voxel's x, y, z
                    moved = cell[:, axis] + step
                    valid = inside & (moved >= 0) & (moved < self.shape[axis])
                    to = flat + step * n_bins * int(np.prod(self.shape[axis + 1 :]))
                else:
                    valid, to = inside, flat - flat % n_bins + neighbours[:, axis - 3, i]
                near[axis].append(self._counts_at(to, valid) >= min_count)
        code = cell_codes(held, near)  # nothing held around a pose outside the grid: not reached
        return reached(code, edge_bits(upper.T, range(6))).reshape(T.shape[:-2])

    def save(self, path) -> None:
        """Write the map to ``path`` as a ``.npz`` archive (numpy appends ``.npz`` if missing)."""
        save_dataclass(self, path)

    @classmethod
    def load(cls, path) -> CapabilityMap:
        """Read a map written by :meth:`save` (``load("map")`` reads the ``map.npz`` that ``save("map")`` wrote).

        Raises:
            ValueError: a file that is empty, truncated, not a ``.npz`` archive, or lacks a field of the
                map (the message names the file and the field).
            FileNotFoundError: no such file.
        """
        path, fields = read_dataclass_fields(cls, path, "capability map")
        if fields["cells"].shape != fields["cell_counts"].shape or fields["cells"].ndim != 1:
            raise ValueError(f"{path}: field cells: expected one count per cell, got {fields['cells'].shape} cells")
        return cls(
            cells=fields["cells"].astype(np.int64),
            cell_counts=fields["cell_counts"].astype(np.int64),
            **grid_fields(fields),
        )
