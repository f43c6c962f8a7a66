"""The map of :func:`diffkin.workspace.reachability`: its grid, counts, manipulability and orientation
bins, and its file format (``.npz``, read without pickle)."""

from __future__ import annotations

import dataclasses

import numpy as np

from diffkin._npz import read_dataclass_fields, save_dataclass


@dataclasses.dataclass(frozen=True, eq=False)
class ReachabilityMap:
    """Per-voxel statistics of the end-effector positions of sampled configurations.

    Voxel ``(i, j, k)`` is the box ``origin + voxel_size * ([i, i+1) x [j, j+1) x [k, k+1))`` in
    the chain's base frame; a sample whose end-effector position ``p`` (metres, base frame) has
    ``floor((p - origin) / voxel_size) == (i, j, k)`` counts in that voxel (computed as
    ``(p - origin) * (1 / voxel_size)`` in the computation's dtype, so a point within rounding of a
    face may count on either side of it, the same side on any number of devices). Samples outside
    the grid count in no voxel: ``counts.sum() + n_outside == n_samples``.

    Attributes:
        counts: ``(nx, ny, nz)`` int64, number of samples per voxel.
        manipulability: ``(nx, ny, nz)`` float, best Yoshikawa manipulability of the samples in
            the voxel (as :func:`diffkin.manipulability`), 0 where there are none.
        dexterity: ``(nx, ny, nz)`` int32, number of distinct orientation bins (of
            ``orientation_bins``, see the module docstring) reached in the voxel.
        origin: ``(3,)`` float64, corner of voxel ``(0, 0, 0)``, metres, base frame.
        voxel_size: edge of the cubic voxels, metres.
        n_samples: number of sampled configurations.
        n_outside: number of samples whose end effector fell outside the grid.
        orientation_bins: number of cells of the SO(3) partition.
        chain_name: name of the chain (informational).
    """

    counts: np.ndarray
    manipulability: np.ndarray
    dexterity: np.ndarray
    origin: np.ndarray
    voxel_size: float
    n_samples: int
    n_outside: int
    orientation_bins: int
    chain_name: str = ""

    def save(self, path) -> None:
        """Write the map to ``path`` as a ``.npz`` archive (numpy appends ``.npz`` if missing)."""
        save_dataclass(self, path)

    @classmethod
    def load(cls, path) -> ReachabilityMap:
        """Read a map written by :meth:`save` (``load("map")`` reads the ``map.npz`` that ``save("map")`` wrote).

        Raises:
            ValueError: a file that is empty, truncated, not a ``.npz`` archive, or lacks a field
                of the map (the message names the file and the field).
            FileNotFoundError: no such file.
        """
        path, fields = read_dataclass_fields(cls, path, "reachability map")
        return cls(dexterity=fields["dexterity"], **grid_fields(fields))


def grid_fields(fields: dict) -> dict:
    """The fields a reachability and a capability map share, read from a file's arrays ``fields``: the
    voxel grid's counts, manipulability and origin as stored, its scalars as Python numbers."""
    return dict(
        counts=fields["counts"],
        manipulability=fields["manipulability"],
        origin=fields["origin"],
        voxel_size=float(fields["voxel_size"]),
        n_samples=int(fields["n_samples"]),
        n_outside=int(fields["n_outside"]),
        orientation_bins=int(fields["orientation_bins"]),
        chain_name=str(fields["chain_name"]),
    )
