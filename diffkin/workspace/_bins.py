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


def _sector(y, x, n: int, start: float, width: float) -> jax.Array:
    """Sector in ``[0, n)`` of the angle of ``(x, y)`` over ``n`` sectors of ``width`` radians from ``start``.

    A first guess from ``atan2``, then settled by the side of the sector's edges that ``(x, y)`` is on:
    products and sums, which round the same however XLA compiles them (atan2's division may not: see
    :func:`_flat_index`).
    """
    sector = jnp.clip(jnp.floor((atan2(y, x) - start) * (1 / width)), 0, n - 1).astype(jnp.int32)
    if n > 1:
        edge = sector.astype(x.dtype) * width + start
        (s0, c0), (s1, c1) = sincos(edge), sincos(edge + width)
        sector = sector - ((c0 * y - s0 * x) < 0) + ((c1 * y - s1 * x) >= 0)
        sector = jnp.clip(sector, 0, n - 1)
    return sector


def _orientation_bin(R: rg.Mat3, n_roll: int, n_dir: int = 1) -> jax.Array:
    """Orientation bin in ``[0, 6 n_dir^2 n_roll)`` of rotations given by entries (see the module docstring).

    The tool z axis picks a cube face ``(a, sign)`` and, with ``n_dir > 1``, one of ``n_dir x n_dir``
    cells of that face, equal in angle: the sectors of ``atan2(z_u, |z_a|)`` and ``atan2(z_v, |z_a|)``
    over ``[-45, 45]`` degrees (``u, v = (a + 1) % 3, (a + 2) % 3``); the roll sector is as for
    ``n_dir = 1``. The bin is ``((2 a + (z_a < 0)) n_dir^2 + i_u n_dir + i_v) n_roll + sector``.
    """
    z = [jnp.abs(R[i][2]) for i in range(3)]
    a = jnp.where((z[0] >= z[1]) & (z[0] >= z[2]), 0, jnp.where(z[1] >= z[2], 1, 2))

    def pick(entries):  # entries[a] of each sample
        return jnp.where(a == 0, entries[0], jnp.where(a == 1, entries[1], entries[2]))

    z_a = pick([R[0][2], R[1][2], R[2][2]])
    x_u = pick([R[1][0], R[2][0], R[0][0]])
    y_u = pick([R[1][1], R[2][1], R[0][1]])
    sector = _sector(-y_u, x_u, n_roll, -np.pi, 2 * np.pi / n_roll)  # roll in [-pi, pi]
    face = 2 * a + (z_a < 0)
    if n_dir > 1:
        z_u, z_v, width = pick([R[1][2], R[2][2], R[0][2]]), pick([R[2][2], R[0][2], R[1][2]]), np.pi / 2 / n_dir
        i_u = _sector(z_u, jnp.abs(z_a), n_dir, -np.pi / 4, width)
        i_v = _sector(z_v, jnp.abs(z_a), n_dir, -np.pi / 4, width)
        face = (face * n_dir + i_u) * n_dir + i_v
    return face * n_roll + sector


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
