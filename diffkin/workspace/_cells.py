"""Where a pose lies in a capability map's grid and which cells surround it: the six axes of a cell (the
voxel's x, y, z; the orientation bin's two direction angles and its roll), the half of its cell a pose
lies in along each, and every bin's neighbours along the three orientation axes (what
:meth:`CapabilityMap.reaches` and :func:`base_placement` look at beside a pose's own cell)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._trig import atan2
from diffkin.workspace._bins import _orientation_bin

STEPS = (-2, -1, 1, 2)
"""The neighbours of a cell along an axis, in cells (:func:`neighbour_bins`' last axis)."""


def _face_axes(a):
    """``(u, v)``: the axes after the face axis ``a`` (int arrays), as the bins number them."""
    return (a + 1) % 3, (a + 2) % 3


def split_bin(bins, n_dir: int, n_roll: int):
    """``(face, i_u, i_v, roll sector)`` of orientation bins (int arrays): the inverse of
    ``bin = ((face n_dir + i_u) n_dir + i_v) n_roll + sector``."""
    rest, sector = np.divmod(bins, n_roll)
    rest, i_v = np.divmod(rest, n_dir)
    face, i_u = np.divmod(rest, n_dir)
    return face, i_u, i_v, sector


def _rotations_at(face, theta_u, theta_v, roll) -> np.ndarray:
    """``(..., 3, 3)`` rotations at direction angles ``theta_u, theta_v`` of cube face ``face`` (radians,
    float arrays, any value: past 45 degrees the tool z axis leaves the face continuously) and ``roll``
    (measured from the face's axis ``u``, as the bins are; where the tool z axis lies along ``u``, which
    only happens past an edge, from the face's axis ``a`` turned away)."""
    a, sign = face // 2, np.where(face % 2, -1.0, 1.0)
    u, v = _face_axes(a)
    eye = np.eye(3)
    e_a, e_u, e_v = eye[a], eye[u], eye[v]
    cu, su, cv, sv = np.cos(theta_u), np.sin(theta_u), np.cos(theta_v), np.sin(theta_v)
    z = (sign * cu * cv)[..., None] * e_a + (su * cv)[..., None] * e_u + (cu * sv)[..., None] * e_v
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    p = e_u - np.sum(e_u * z, axis=-1, keepdims=True) * z
    norm = np.linalg.norm(p, axis=-1, keepdims=True)
    # z along e_u (only past a face's edge): p from e_a instead, the axis the face's centre points along.
    p = np.where(norm > 1e-6, p, -sign[..., None] * e_a)
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    x = np.cos(roll)[..., None] * p + np.sin(roll)[..., None] * np.cross(z, p)
    return np.stack([x, np.cross(z, x), z], axis=-1)


@functools.lru_cache(maxsize=8)
def neighbour_bins(n_dir: int, n_roll: int) -> np.ndarray:
    """The bins ``STEPS`` cells away from each of the ``6 n_dir^2 n_roll`` bins along the direction angles
    ``u``, ``v`` and the roll: ``(6 n_dir^2 n_roll, 3, 4)`` int64.

    Along the roll: the sector ``STEPS`` further round, in the same direction cell. Along ``u`` (``v``):
    the bin of the rotation whose direction angle ``theta_u`` (``theta_v``) is ``STEPS`` cells from the
    bin's centre, the other angle and the roll as the centre's; past the cube face's edge that is a bin of
    the next face (the cells there are as wide as the face's, in angle, to within a few degrees).
    """
    orientation_bins = 6 * n_dir * n_dir * n_roll
    face, i_u, i_v, sector = split_bin(np.arange(orientation_bins), n_dir, n_roll)
    width, roll_width = np.pi / 2 / n_dir, 2 * np.pi / n_roll
    theta_u, theta_v = -np.pi / 4 + (i_u + 0.5) * width, -np.pi / 4 + (i_v + 0.5) * width
    roll = -np.pi + (sector + 0.5) * roll_width
    steps = np.asarray(STEPS, float)
    out = np.zeros((orientation_bins, 3, len(STEPS)), np.int64)
    out[:, 2] = (face * n_dir + i_u)[:, None] * n_dir * n_roll + i_v[:, None] * n_roll
    out[:, 2] += (sector[:, None] + np.asarray(STEPS)) % n_roll
    R = np.stack(
        [
            _rotations_at(face[:, None], theta_u[:, None] + steps * width, theta_v[:, None], roll[:, None]),
            _rotations_at(face[:, None], theta_u[:, None], theta_v[:, None] + steps * width, roll[:, None]),
        ],
        axis=1,
    )  # (bins, 2, steps, 3, 3)
    R = R.reshape(-1, 3, 3).astype(jnp.result_type(float))
    out[:, :2] = np.asarray(_bins_of(n_dir, n_roll, R), np.int64).reshape(orientation_bins, 2, len(STEPS))
    out.flags.writeable = False  # cached: shared by every caller
    return out


@functools.partial(jax.jit, static_argnums=(0, 1))
def _bins_of(n_dir: int, n_roll: int, R) -> jax.Array:
    """Orientation bins of rotations ``R (M, 3, 3)``, as the map's."""
    return _orientation_bin(tuple(tuple(R[:, i, j] for j in range(3)) for i in range(3)), n_roll, n_dir)


def orientation_halves(R: rg.Mat3, bins, n_roll: int, n_dir: int) -> jax.Array:
    """``(..., 3)`` bool: whether rotations given by entries (``R[i][j]``) lie in the upper half of their
    bin ``bins`` along the direction angles ``u``, ``v`` and the roll (see :func:`neighbour_bins`)."""
    z_abs = [jnp.abs(R[i][2]) for i in range(3)]
    a = jnp.where((z_abs[0] >= z_abs[1]) & (z_abs[0] >= z_abs[2]), 0, jnp.where(z_abs[1] >= z_abs[2], 1, 2))

    def pick(entries):
        return jnp.where(a == 0, entries[0], jnp.where(a == 1, entries[1], entries[2]))

    z_a = pick([R[0][2], R[1][2], R[2][2]])
    z_u, z_v = pick([R[1][2], R[2][2], R[0][2]]), pick([R[2][2], R[0][2], R[1][2]])
    x_u, y_u = pick([R[1][0], R[2][0], R[0][0]]), pick([R[1][1], R[2][1], R[0][1]])
    rest, sector = jnp.divmod(bins, n_roll)
    rest, i_v = jnp.divmod(rest, n_dir)
    i_u = rest % n_dir
    width, roll_width = np.pi / 2 / n_dir, 2 * np.pi / n_roll
    upper_u = atan2(z_u, jnp.abs(z_a)) >= -np.pi / 4 + (i_u + 0.5) * width
    upper_v = atan2(z_v, jnp.abs(z_a)) >= -np.pi / 4 + (i_v + 0.5) * width
    upper_roll = atan2(-y_u, x_u) >= -np.pi + (sector + 0.5) * roll_width
    return jnp.stack([upper_u, upper_v, upper_roll], axis=-1)


@functools.partial(jax.jit, static_argnums=(1, 2))
def pose_halves(T, n_dir: int, n_roll: int, origin, inv_voxel, shape_array):
    """Cells of poses ``T (M, 4, 4)`` and the half of them each lies in: ``(cell (M, 3) int32, bin (M,)
    int32, inside (M,) bool, upper (M, 6) bool)``, ``upper`` along the voxel's x, y, z and the bin's
    ``u``, ``v``, roll (``cell`` 0 where not inside)."""
    R = tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3))
    scaled = (T[:, :3, 3] - origin) * inv_voxel
    cell = jnp.floor(scaled)
    inside = jnp.all((cell >= 0) & (cell < shape_array), axis=1)
    upper_p = scaled - cell >= 0.5
    cell = jnp.where(inside[:, None], cell, 0).astype(jnp.int32)
    bins = _orientation_bin(R, n_roll, n_dir)
    upper = jnp.concatenate([upper_p, orientation_halves(R, bins, n_roll, n_dir)], axis=1)
    return cell, bins, inside, upper


def cell_codes(held, near):
    """The rule of :meth:`CapabilityMap.reaches` applied to cells, as bits (the one implementation of it:
    ``reaches`` gathers the cells around poses, :func:`base_placement` around every cell of its slices).

    Args:
        held: bool array (numpy or JAX): whether the map holds each cell.
        near: for each of the six axes (the voxel's x, y, z; the bin's ``u``, ``v``, roll), four bool
            arrays of ``held``'s shape: whether the map holds the cells ``STEPS`` (-2, -1, +1, +2) away.

    Returns:
        uint16 of ``held``'s shape. Bit 0: the cell is held, or is a hole (both neighbours along some axis
        held); bits ``1 + 2 axis`` and ``2 + 2 axis``: a pose in the cell's lower (upper) half along
        ``axis`` is at the held set's edge (the neighbour on its side and the one beyond are not held, the
        two on the other side are). A pose is reached when bit 0 is set and its halves' bits are not
        (:func:`edge_bits`, :func:`reached`).
    """
    code = held.astype(np.uint16)
    for axis, (down2, down, up, up2) in enumerate(near):
        code = code | (down & up).astype(np.uint16)
        code = code | ((~down & ~down2 & up & up2).astype(np.uint16) << (1 + 2 * axis))
        code = code | ((~up & ~up2 & down & down2).astype(np.uint16) << (2 + 2 * axis))
    return code


def edge_bits(upper, axes):
    """The bits of :func:`cell_codes` that rule out poses lying in the halves ``upper`` of their cells:
    ``upper`` one bool array (numpy or JAX) per axis of ``axes`` (0-5), whether the pose lies in the upper
    half along it; uint16 of their shape."""
    bits = 0
    for up, axis in zip(upper, axes, strict=True):
        bits = bits | ((2 << 2 * axis) << up.astype(np.uint16))
    return bits


def reached(code, edge):
    """Whether poses are reached (bool): ``code`` their cells' :func:`cell_codes`, ``edge`` their
    :func:`edge_bits`."""
    return ((code & 1) == 1) & ((code & edge) == 0)


def _bucket(n: int) -> int:
    """``n`` rounded up to a power of two (at least 16): the codes compile once per bucket, not per size."""
    return max(16, 1 << (n - 1).bit_length())


def slice_codes(held: np.ndarray, keys: np.ndarray, needed: np.ndarray, n_dir: int, n_roll: int, nz: int):
    """The :func:`cell_codes` of every voxel of the map's ``(x, y)`` slices ``needed``: ``(len(needed), nx,
    ny)`` uint16 (a JAX array).

    Args:
        held: ``(K, nx, ny)`` bool, the held cells of the slices ``keys``.
        keys: ``(K,)`` int64, sorted slices ``bin * nz + layer``: ``needed`` and :func:`slices_around` them.
        needed: ``(S,)`` int64, the slices ``bin * nz + layer`` whose codes are wanted.
        n_dir, n_roll: the map's orientation bins (``6 n_dir^2 n_roll``).
        nz: the grid's layers.
    """
    around = slices_around(needed, n_dir, n_roll, nz)
    index = np.searchsorted(keys, np.concatenate([needed, around.ravel()]))
    index = np.where(np.concatenate([needed, around.ravel()]) < 0, len(keys), index)  # -1: nothing held
    n_held, n_needed = _bucket(len(keys) + 1), _bucket(needed.size)
    held = np.concatenate([held, np.zeros((n_held - len(keys), *held.shape[1:]), bool)])
    own = np.pad(index[: needed.size], (0, n_needed - needed.size), constant_values=len(keys))
    around = np.pad(index[needed.size :].reshape(around.shape), ((0, n_needed - needed.size), (0, 0), (0, 0)))
    return _codes(jnp.asarray(held), jnp.asarray(own), jnp.asarray(around))[: needed.size]


def slices_around(needed: np.ndarray, n_dir: int, n_roll: int, nz: int) -> np.ndarray:
    """``(S, 4, 4)`` int64: the slices ``bin * nz + layer`` ``STEPS`` cells from slices ``needed (S,)``
    along z, ``u``, ``v`` and the roll (``-1`` off the grid's layers)."""
    bins, layer = np.divmod(needed, nz)
    moved = layer[:, None] + np.asarray(STEPS)
    along_z = np.where((moved >= 0) & (moved < nz), bins[:, None] * nz + moved, -1)
    return np.concatenate([along_z[:, None], neighbour_bins(n_dir, n_roll)[bins] * nz + layer[:, None, None]], axis=1)


@jax.jit
def _codes(held, own, around):
    """:func:`slice_codes` of slices ``held[own] (S, nx, ny)``, their neighbours along z, ``u``, ``v``, roll
    ``held[around] (S, 4, 4, nx, ny)``."""
    own_held = held[own]
    nx, ny = own_held.shape[1:]
    padded = jnp.pad(own_held, ((0, 0), (2, 2), (2, 2)))  # nothing held off the grid
    near = [
        [padded[:, 2 + s : 2 + s + nx, 2 : 2 + ny] for s in STEPS],
        [padded[:, 2 : 2 + nx, 2 + s : 2 + s + ny] for s in STEPS],
    ]
    near += [[held[around[:, axis, i]] for i in range(len(STEPS))] for axis in range(4)]
    return cell_codes(own_held, near)
