"""The signed distance of any two convex solids from their support functions (GJK), batched.

Each solid is a *core* swept by a ball (:mod:`diffkin.collision._shapes`: ``core_support``,
``rounding``). For a unit direction ``n`` (from ``a`` to ``b``) the *separation*

    s(n) = min_{y in b} n . y - max_{x in a} n . x

is at most the signed distance for every ``n``, and equals it for the best ``n`` (apart: the
direction between the closest points; overlapping: minus the penetration depth, the shortest
separating translation). So the distance here is ``s(n)`` at a direction found without gradients
(a certified lower bound: never more clearance than there is):

- apart: the direction of the closest points of the cores, by GJK (Gilbert, Johnson, Keerthi 1988)
  on their Minkowski difference, each step's closest point of the simplex found among all its
  faces at once (no branches: every batch entry does the same work), until the lower bound
  ``s(n)`` is within a relative ``TOLERANCE`` of the upper bound ``|x|``;
- overlapping (the simplex encloses the origin): the best of a few candidate directions (the
  centres' difference, each shape's axes, the world axes), refined by projected ascent on the
  unit sphere. ``s`` of it is never above the true value: an overlap is never reported
  shallower than it is, but may be reported deeper (by how much is measured in the tests).

The witness points (apart: the cores' closest points, from GJK's barycentric weights; overlapping:
the supports along the direction) are named by coordinates that move with their shapes; the
distance's derivative is that of ``n . (p_b - p_a)`` with ``n`` and those coordinates held fixed: by
Danskin's theorem (forward and reverse) the distance's, and
:func:`contact`'s wrenches are that derivative under rigid motions.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._xla import stable_partition
from diffkin.collision._shapes import taken

#: GJK stops when its lower bound is within this share of its upper bound (float64; float32: FLOAT32_TOLERANCE)
TOLERANCE = 1e-12
FLOAT32_TOLERANCE = 1e-6
#: the most GJK steps (polytope cores converge in a few; the curved rim of a cylinder linearly)
STEPS = 128
#: GJK stops a pair whose point nearest the origin has not got nearer in more than this many steps
IDLE = 4
#: projected-ascent steps refining an overlapping pair's direction
ASCENT_STEPS = 24
#: the overlap search runs on the overlapping pairs, 1 / OVERLAP_SHARE of a batch at a time
OVERLAP_SHARE = 8

#: directions spread over the sphere (a Fibonacci lattice of 2 * 24, both signs tried), starts of an overlap's search
_SPREAD = np.array(
    [
        (np.cos(np.pi * (1 + 5**0.5) * k) * np.sin(p), np.sin(np.pi * (1 + 5**0.5) * k) * np.sin(p), np.cos(p))
        for k, p in ((k, np.arccos(1 - (2 * k + 1) / 48)) for k in range(24))
    ]
)
#: the faces of a simplex that hold its newest point (slot 0): the closest point lies on one of them
_SUBSETS = [(0, *s) for k in (0, 1, 2, 3) for s in itertools.combinations(range(1, 4), k)]
_SUBSET_MASKS = np.array([[i in s for i in range(4)] for s in _SUBSETS])


def _dot(u: jax.Array, v: jax.Array) -> jax.Array:
    return jnp.sum(u * v, axis=-1)


def _unit(v: jax.Array, fallback: jax.Array) -> jax.Array:
    """``v / |v|``; ``fallback`` where ``v`` is zero (finite derivatives)."""
    sq = _dot(v, v)[..., None]
    ok = sq > 0
    return jnp.where(ok, v / jnp.sqrt(jnp.where(ok, sq, 1.0)), fallback)


def core_supports(a, b, n: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The cores' support points: of ``a`` along ``n``, of ``b`` along ``-n``."""
    return a.core_support(n), b.core_support(-n)


def separation(a, b, n: jax.Array) -> jax.Array:
    """``s(n)`` of the module docstring, rounding included: ``(...,)``."""
    pa, pb = core_supports(a, b, n)
    return _dot(n, pb - pa) - a.rounding() - b.rounding()


def _closest(Y: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The point of the simplex ``Y[mask]`` ``(..., 4, 3)`` closest to the origin: ``(x, weights, face)``, its
    barycentric ``weights (..., 4)`` (``x = sum_i weights_i Y_i``) and the smallest face holding it.

    The simplex's newest point is ``Y[..., 0, :]``; the closest point lies on a face holding it (the
    older points' faces were searched before). Each such face's affine projection of the origin is
    computed; a face is a candidate when all its points are in use, it is not degenerate and the
    barycentric weights are positive; the candidate nearest the origin wins (the newest point itself
    is always a candidate).
    """
    scale = jnp.max(jnp.where(mask, _dot(Y, Y), 0.0), axis=-1)
    tiny = jnp.finfo(Y.dtype).eps * 16
    one = jnp.ones(Y.shape[:-2], Y.dtype)
    points, norms, weights = [], [], []
    for subset in _SUBSETS:
        used = jnp.all(mask[..., list(subset)], axis=-1)
        y0 = Y[..., subset[0], :]
        if len(subset) == 1:
            x, valid, lam = y0, used, [one]
        elif len(subset) == 2:
            e = Y[..., subset[1], :] - y0
            ee = _dot(e, e)
            ok = ee > tiny * scale
            t = -_dot(y0, e) / jnp.where(ok, ee, 1.0)
            x, valid, lam = y0 + t[..., None] * e, used & ok & (t > 0) & (t < 1), [1 - t, t]
        elif len(subset) == 3:
            e1, e2 = Y[..., subset[1], :] - y0, Y[..., subset[2], :] - y0
            g11, g12, g22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
            r1, r2 = -_dot(y0, e1), -_dot(y0, e2)
            det = g11 * g22 - g12 * g12
            ok = det > tiny * g11 * g22
            det = jnp.where(ok, det, 1.0)
            m1, m2 = (r1 * g22 - r2 * g12) / det, (g11 * r2 - g12 * r1) / det
            x = y0 + m1[..., None] * e1 + m2[..., None] * e2
            valid = used & ok & (m1 > 0) & (m2 > 0) & (m1 + m2 < 1)
            lam = [1 - m1 - m2, m1, m2]
        else:
            e1, e2, e3 = (Y[..., k, :] - y0 for k in subset[1:])
            det = _dot(e1, jnp.cross(e2, e3))
            ok = jnp.abs(det) > tiny * jnp.sqrt(_dot(e1, e1) * _dot(e2, e2) * _dot(e3, e3))
            det = jnp.where(ok, det, 1.0)
            m1 = _dot(-y0, jnp.cross(e2, e3)) / det
            m2 = _dot(e1, jnp.cross(-y0, e3)) / det
            m3 = _dot(e1, jnp.cross(e2, -y0)) / det
            x = jnp.zeros_like(y0)
            valid = used & ok & (m1 >= 0) & (m2 >= 0) & (m3 >= 0) & (m1 + m2 + m3 <= 1)
            lam = [1 - m1 - m2 - m3, m1, m2, m3]
        full = [jnp.zeros_like(one)] * 4
        for k, w in zip(subset, lam, strict=True):
            full[k] = w
        points.append(x)
        norms.append(jnp.where(valid, _dot(x, x), jnp.inf))
        weights.append(jnp.stack(full, axis=-1))
    best = jnp.argmin(jnp.stack(norms, axis=-1), axis=-1)[..., None, None]
    x = jnp.take_along_axis(jnp.stack(points, axis=-2), best, axis=-2)[..., 0, :]
    chosen = jnp.take_along_axis(jnp.stack(weights, axis=-2), best, axis=-2)[..., 0, :]
    return x, chosen, jnp.asarray(_SUBSET_MASKS)[best[..., 0, 0]]


def _picked(slot: jax.Array, Y: jax.Array) -> jax.Array:
    """``(..., k, 3)``: the points ``Y`` ``(..., 4, 3)`` each slot of ``slot`` ``(..., k, 4)`` picks (exactly)."""
    return jnp.sum(jnp.where(slot[..., None], Y[..., None, :, :], 0.0), axis=-2)


def _gjk(a, b, dtype, beyond) -> tuple[jax.Array, jax.Array, jax.Array]:
    """GJK on the cores' Minkowski difference ``a - b``: ``(p_a, p_b, apart)``, the closest points of the cores
    (``p_a - p_b`` the difference's point nearest the origin) and whether the cores are apart (the origin
    not enclosed). A pair stops early once its lower bound ``s(n)`` (at ``n`` along ``p_b - p_a``) is at
    least ``beyond`` ``(...,)``: then only that is certain, not the closest points."""
    tol = TOLERANCE if jnp.finfo(dtype).bits >= 64 else FLOAT32_TOLERANCE
    eps = jnp.finfo(dtype).eps

    start = a.centre() - b.centre()
    start = jnp.where(_dot(start, start)[..., None] > 0, start, jnp.array([1.0, 0.0, 0.0], dtype))
    pa, pb = core_supports(a, b, -start)
    batch = jnp.broadcast_shapes(pa.shape, pb.shape)[:-1]
    pa, pb = jnp.broadcast_to(pa, batch + (3,)), jnp.broadcast_to(pb, batch + (3,))
    Ya = jnp.zeros(batch + (4, 3), dtype).at[..., 0, :].set(pa)  # each simplex point's side of a ...
    Yb = jnp.zeros(batch + (4, 3), dtype).at[..., 0, :].set(pb)  # ... and of b
    mask = jnp.zeros(batch + (4,), bool).at[..., 0].set(True)
    lam = jnp.zeros(batch + (4,), dtype).at[..., 0].set(1.0)

    def step(state):
        k, Ya, Yb, mask, lam, done, nearest, idle = state
        x = jnp.sum(lam[..., None] * (Ya - Yb), axis=-2)
        wa, wb = core_supports(a, b, -x)
        w = wa - wb
        xx = _dot(x, x)
        # no longer getting nearer in floating point (in float32 a pair can cycle a few roundings short
        # of FLOAT32_TOLERANCE, and the batch would take every step of STEPS for it): done after IDLE
        # steps; s(n) is a lower bound all the same
        nearer = xx < nearest * (1 - 4 * eps)
        nearest, idle = jnp.where(nearer, xx, nearest), jnp.where(nearer, 0, idle + 1)
        done = done | (idle > IDLE)
        Y = Ya - Yb
        scale = jnp.maximum(jnp.max(jnp.where(mask, _dot(Y, Y), 0.0), axis=-1), _dot(w, w))
        # converged: the gap between the upper bound |x|^2 and x.w within the tolerance, or within its
        # rounding (x is a difference of points of size |p|, so off by ~eps |p|: in float32 a relative
        # 1e-6 is below that for shapes near each other, and the batch would take every step of STEPS
        # for such a pair without moving it)
        size = jnp.max(jnp.abs(jnp.concatenate([Ya, Yb, wa[..., None, :], wb[..., None, :]], axis=-2)), axis=(-2, -1))
        rounding = 16 * eps * size * jnp.sqrt(_dot(w, w))
        done = done | (xx - _dot(x, w) <= tol * xx + rounding) | (xx <= (eps * 16) ** 2 * scale)
        done = done | (_dot(x, w) >= beyond * jnp.sqrt(xx))  # s(-x / |x|) = x.w / |x|: far enough
        # the points in use first (at most 3), then the new point in front of them
        slot = stable_partition(mask)[..., :3, :]  # (..., 3, 4)
        Ya_new = jnp.concatenate([wa[..., None, :], _picked(slot, Ya)], axis=-2)
        Yb_new = jnp.concatenate([wb[..., None, :], _picked(slot, Yb)], axis=-2)
        used = jnp.concatenate([jnp.ones(batch + (1,), bool), jnp.any(slot & mask[..., None, :], axis=-1)], -1)
        x_new, lam_new, mask_new = _closest(Ya_new - Yb_new, used)
        # A simplex too thin to solve in floating point can drop the new point and stall: then restart
        # from the segment between the current point and the new one (both in the difference), whose
        # closest point is always nearer (Gilbert's step).
        stalled = _dot(x_new, x_new) >= xx * (1 - 4 * eps)
        e = w - x
        t = jnp.clip(-_dot(x, e) / jnp.where(_dot(e, e) > 0, _dot(e, e), 1.0), 0.0, 1.0)
        xa, xb = jnp.sum(lam[..., None] * Ya, axis=-2), jnp.sum(lam[..., None] * Yb, axis=-2)
        pair = jnp.zeros_like(Ya)
        Ya_new = jnp.where(stalled[..., None, None], pair.at[..., 0, :].set(xa).at[..., 1, :].set(wa), Ya_new)
        Yb_new = jnp.where(stalled[..., None, None], pair.at[..., 0, :].set(xb).at[..., 1, :].set(wb), Yb_new)
        mask_new = jnp.where(stalled[..., None], jnp.array([True, True, False, False]), mask_new)
        lam_seg = jnp.zeros_like(lam).at[..., 0].set(1 - t).at[..., 1].set(t)
        lam_new = jnp.where(stalled[..., None], lam_seg, lam_new)
        keep = done[..., None]
        return (
            k + 1,
            jnp.where(keep[..., None], Ya, Ya_new),
            jnp.where(keep[..., None], Yb, Yb_new),
            jnp.where(keep, mask, mask_new),
            jnp.where(keep, lam, lam_new),
            done,
            nearest,
            idle,
        )

    state = (0, Ya, Yb, mask, lam, jnp.zeros(batch, bool), jnp.full(batch, jnp.inf, dtype), jnp.zeros(batch, jnp.int32))
    _, Ya, Yb, mask, lam, *_ = jax.lax.while_loop(lambda s: (s[0] < STEPS) & ~jnp.all(s[5]), step, state)
    pa, pb = jnp.sum(lam[..., None] * Ya, axis=-2), jnp.sum(lam[..., None] * Yb, axis=-2)
    x = pa - pb
    centres = a.centre() - b.centre()
    scale = jnp.maximum(_dot(centres, centres), 1.0)
    apart = (jnp.sum(mask, axis=-1) < 4) & (_dot(x, x) > (eps * 16) ** 2 * scale)
    return pa, pb, apart


def _axes(shape) -> list[jax.Array]:
    """Directions worth trying as a separating axis of an overlap: the shape's own axes (if posed)."""
    if hasattr(shape, "pose"):
        return [shape.pose[..., :3, k] for k in range(3)]
    if hasattr(shape, "a"):
        return [shape.b - shape.a]
    return []


def _overlap_direction(a, b, hint: jax.Array, dtype) -> jax.Array:
    """The best separating direction of overlapping shapes among candidates, refined by projected ascent."""
    batch = jnp.broadcast_shapes(hint.shape, a.centre().shape, b.centre().shape)
    spread = jnp.asarray(_SPREAD, dtype).reshape((len(_SPREAD),) + (1,) * (len(batch) - 1) + (3,))
    own = [hint, b.centre() - a.centre()] + _axes(a) + _axes(b)
    fallback = jnp.array([1.0, 0.0, 0.0], dtype)
    tries = _unit(jnp.stack([jnp.broadcast_to(c, batch) for c in own]), fallback)  # (K, ..., 3): one _unit, not K
    tries = jnp.concatenate([tries, jnp.broadcast_to(spread, (len(_SPREAD),) + batch)])
    tries = jnp.concatenate([tries, -tries])
    s = separation(a, b, tries)  # every candidate in one evaluation: (2K, ...)
    best = jnp.argmax(s, axis=0)
    best_n = jnp.take_along_axis(tries, best[None, ..., None], axis=0)[0]
    best_s = jnp.max(s, axis=0)

    def ascend(_, state):
        n, s, step = state
        pa, pb = core_supports(a, b, n)
        g = pb - pa  # the gradient of s at n
        g = g - _dot(g, n)[..., None] * n
        trial = _unit(n + step[..., None] * g, n)
        s_trial = separation(a, b, trial)
        better = s_trial > s
        return (
            jnp.where(better[..., None], trial, n),
            jnp.where(better, s_trial, s),
            jnp.where(better, step * 1.5, step * 0.5),
        )

    step = jnp.ones_like(best_s) * 2.0
    n, _, _ = jax.lax.fori_loop(0, ASCENT_STEPS, ascend, (best_n, best_s, step))
    return n


def _overlap_directions(a, b, n: jax.Array, overlap: jax.Array, dtype) -> jax.Array:
    """``n`` ``batch + (3,)`` with the direction of every ``overlap``-ping pair found by
    :func:`_overlap_direction`, for those pairs only, ``1 / OVERLAP_SHARE`` of the batch at a time
    (gathered: no step when none overlaps, one when few do)."""
    batch = overlap.shape
    total = int(np.prod(batch))
    budget = -(-total // OVERLAP_SHARE)

    def step(state):
        left, flat = state
        idx = jnp.nonzero(left, size=budget, fill_value=total)[0]
        safe = jnp.minimum(idx, total - 1)
        found = _overlap_direction(taken(a, batch, safe), taken(b, batch, safe), flat[safe], dtype)
        return left.at[idx].set(False, mode="drop"), flat.at[idx].set(found, mode="drop")

    start = (overlap.reshape(total), n.reshape(total, 3))
    return jax.lax.while_loop(lambda state: jnp.any(state[0]), step, start)[1].reshape(batch + (3,))


def witnesses(a, b, reach=jnp.inf) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``(n, p_a, p_b, s)`` without gradients: the unit direction from ``a`` to ``b`` whose separation is the
    signed distance, the cores' witness points (apart, their closest points; overlapping, their support
    points along ``n`` (``a``) and ``-n`` (``b``)) and the cores' separation along ``n``. Where the
    distance is at least ``reach`` (``(...,)``, rounding included), GJK may stop short: ``s`` less the
    roundings is then a lower bound at least ``reach`` and ``n`` and the points are not the closest."""
    a, b = jax.lax.stop_gradient((a, b))
    dtype = jnp.result_type(*jax.tree.leaves((a, b)))
    pa, pb, apart = _gjk(a, b, dtype, reach + a.rounding() + b.rounding())
    n = _overlap_directions(a, b, _unit(pb - pa, jnp.array([1.0, 0.0, 0.0], dtype)), ~apart, dtype)
    sa, sb = core_supports(a, b, n)
    return n, jnp.where(apart[..., None], pa, sa), jnp.where(apart[..., None], pb, sb), _dot(n, sb - sa)


def contact(a, b) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``(d, n, p_a, p_b)``: the signed distance, the unit direction from ``a`` to ``b`` and the witness points
    of the cores (:func:`witnesses`), which move with their shapes (``coords``/``point`` of each kind).

    ``d`` is ``s(n)`` (a lower bound of the distance, within GJK's tolerance of it) and differentiable: by
    Danskin's theorem its derivative is that of ``n . (p_b - p_a)`` with ``n`` and the witnesses'
    coordinates in their shapes held fixed. Moving ``b`` by a twist ``[v; w]`` changes
    ``d`` by ``n . v + (p_b x n) . w``, and ``a`` likewise with ``-n`` and ``p_a``.
    """
    n, pa, pb, s = witnesses(a, b)
    ua, ub = jax.lax.stop_gradient((a.coords(pa), b.coords(pb)))
    pa, pb = a.point(ua), b.point(ub)
    gap = _dot(n, pb - pa)
    below = jax.lax.stop_gradient(s - gap)  # 0 but for GJK's last step: the value is s(n)
    return gap + below - a.rounding() - b.rounding(), n, pa, pb


def distance(a, b) -> jax.Array:
    """``(...,)`` the signed distance of two convex solids (rounded cores), differentiable (:func:`contact`)."""
    return contact(a, b)[0]
