"""Per sample: its voxel, its orientation bin and its manipulability, computed without division so
that a sample's bins do not depend on how its device's program is compiled (see the package docstring)."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._trig import atan2, sincos
from diffkin.models.forward import Pass


def _orientation_bin(R: rg.Mat3, n_roll: int) -> jax.Array:
    """Orientation bin in ``[0, 6 n_roll)`` of rotations given by entries (see the module docstring)."""
    z = [jnp.abs(R[i][2]) for i in range(3)]
    a = jnp.where((z[0] >= z[1]) & (z[0] >= z[2]), 0, jnp.where(z[1] >= z[2], 1, 2))
    z_a = jnp.where(a == 0, R[0][2], jnp.where(a == 1, R[1][2], R[2][2]))
    x_u = jnp.where(a == 0, R[1][0], jnp.where(a == 1, R[2][0], R[0][0]))
    y_u = jnp.where(a == 0, R[1][1], jnp.where(a == 1, R[2][1], R[0][1]))
    roll = atan2(-y_u, x_u)  # [-pi, pi]
    sector = jnp.clip(jnp.floor((roll + jnp.pi) * (n_roll / (2 * jnp.pi))), 0, n_roll - 1).astype(jnp.int32)
    if n_roll > 1:
        # Settled by the side of the sector's edges that (x_u, -y_u) is on: products and sums, which
        # round the same however XLA compiles them (atan2's division may not: see _flat_index).
        width = 2 * np.pi / n_roll
        start = sector.astype(x_u.dtype) * width - np.pi
        (s0, c0), (s1, c1) = sincos(start), sincos(start + width)
        sector = sector - ((c0 * -y_u - s0 * x_u) < 0) + ((c1 * -y_u - s1 * x_u) >= 0)
        sector = jnp.clip(sector, 0, n_roll - 1)
    return (2 * a + (z_a < 0)) * n_roll + sector


def _manipulability(kin: Pass, dof: int) -> jax.Array:
    """Yoshikawa's measure from one forward pass, by the Cauchy-Binet formula.

    ``det(J J^T)`` (or ``det(J^T J)`` for fewer than 6 joints) is the sum of the squares of the
    maximal minors of the ``(6, dof)`` world Jacobian ``J``. The minors are built row by row by
    Laplace expansion, with products and sums only: no division or pivoting, exactly 0 at a
    singularity, and a single fused XLA kernel (a division with several users would make XLA
    materialise it and recompute the forward kinematics in a kernel of its own).
    """
    columns = rg.world_from_space(kin.columns(), kin.pose().p)
    J = [[columns[i][r // 3][r % 3] for i in range(dof)] for r in range(6)]  # J[row][column]
    rows = J if dof >= 6 else [[J[r][i] for r in range(6)] for i in range(dof)]  # short side first
    minors: dict[tuple[int, ...], rg.Entry] = {(): 1.0}  # column subset -> minor over the first len(subset) rows
    for k, row in enumerate(rows):
        minors = {
            subset: rg.add(
                *(
                    rg.mul((-1.0) ** (k + j), rg.mul(row[c], minors[subset[:j] + subset[j + 1 :]]))
                    for j, c in enumerate(subset)
                )
            )
            for subset in itertools.combinations(range(len(row)), k + 1)
        }
    det = rg.add(*(rg.mul(m, m) for m in minors.values()))
    return jnp.sqrt(det)


def _flat_index(p: rg.Vec3, origin, inv_voxel, shape) -> tuple[jax.Array | int, jax.Array | bool]:
    """Flat voxel index of positions given by entries, and whether they are inside the grid.

    The cell is ``floor((p - origin) * inv_voxel)``: a subtraction and a product, which round the
    same however XLA compiles them. (XLA's CPU backend computes a division by a reciprocal
    estimate in some compilations and exactly in others: with ``/ voxel_size`` a sample on a
    voxel face changed voxels with the number of devices.)
    """
    flat: jax.Array | int = 0
    inside: jax.Array | bool = True
    for i, n in enumerate(shape):
        cell = jnp.floor((p[i] - origin[i]) * inv_voxel)
        inside = inside & (cell >= 0) & (cell < n)
        flat = flat * n + jnp.where(inside, cell, 0).astype(jnp.int32)
    return flat, inside
