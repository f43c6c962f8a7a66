"""The pose (or position) of frame ``b`` in frame ``a``: two hands holding one object, a tool held
against a part (``dk.ik.solve(robot, targets, relative={(a, b): T_a_b})``).

The pose reached is ``T_a_b = T_world_a^-1 T_world_b``; its error is that of a world target
(:mod:`diffkin.ik._terms.pose`) with frame ``a`` in the place of the world, weights in the target
frame as there. Per column of the state, with ``(v_a, w_a)`` and ``(v_b, w_b)`` the velocities of
the two origins and the angular velocities (world axes) and ``d = p_b - p_a``, the relative motion
in ``a``'s axes is ``R_a^T (v_b - v_a - w_a x d)`` and ``R_a^T (w_b - w_a)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax

from diffkin import _rigid as rg
from diffkin.ik._terms import Rows, Target
from diffkin.ik._terms.pose import ONES, error_rows, screen_cost, target_entries, weights_of


def _relative(kin, a: int, b: int) -> tuple[rg.Rigid, tuple]:
    """``T_a_b``, and ``(R_a^T, d)`` for the columns."""
    T_a, T_b = kin.pose(a), kin.pose(b)
    Ra_t = tuple(rg.column(T_a.R, j) for j in range(3))
    d = rg.vadd(T_b.p, rg.scale(-1.0, T_a.p))
    return rg.Rigid(rg.matmul(Ra_t, T_b.R), rg.rotate(Ra_t, d)), (Ra_t, d)


@dataclasses.dataclass(frozen=True)
class RelativeTarget(Target):
    """The pose (or the position) of frame ``b`` in frame ``a``.

    Attributes:
        a, b: frame indices of the robot.
        position_only: the target is a position of ``b``'s origin in ``a`` ``(P, 3)``, else a pose ``(P, 4, 4)``.
        weights: six weights of ``[v; w]`` in the target frame (``a``'s axes for a position).
    """

    a: int
    b: int
    position_only: bool
    weights: tuple[float, ...] = ONES

    @property
    def frames(self) -> tuple[int | None, ...]:  # type: ignore[override]  # (Term's field, derived here)
        return (self.a, self.b)

    def bind(self, target: jax.Array) -> tuple:
        return target_entries(target, self.position_only)

    def rows(self, kin, bound: tuple, jacobian: bool) -> Rows:
        T_ab, (Ra_t, d) = _relative(kin, self.a, self.b)
        columns = []
        if jacobian:
            points_a = rg.world_from_space(kin.columns(self.a), kin.pose(self.a).p)
            points_b = rg.world_from_space(kin.columns(self.b), kin.pose(self.b).p)
            for (v_a, w_a), (v_b, w_b) in zip(points_a, points_b, strict=True):
                v = rg.vadd(v_b, rg.scale(-1.0, v_a), rg.scale(-1.0, rg.cross(w_a, d)))
                columns.append((rg.rotate(Ra_t, v), rg.rotate(Ra_t, rg.vadd(w_b, rg.scale(-1.0, w_a)))))
        p_t, R_t = bound
        return error_rows(T_ab, columns, p_t, R_t, self.weights, kin.dtype)

    def screen(self, kin, bound: tuple) -> rg.Entry:
        p_t, R_t = bound
        return screen_cost(_relative(kin, self.a, self.b)[0], p_t, R_t, self.weights, kin.dtype)


def from_mapping(robot, relative, weights) -> list[tuple[RelativeTarget, jax.Array, str]]:
    """The terms of ``relative={(a, b): T_a_b}``: ``(term, target array, label)`` each, checked on the
    host (``weights`` keyed by the same pairs)."""
    from diffkin.ik._args import check_target

    if not isinstance(relative, Mapping):
        raise TypeError(f"relative: expected a mapping (frame a, frame b) -> T_a_b, got {relative!r}")
    out = []
    for pair, target in relative.items():
        if not (isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(f, str) for f in pair)):
            raise TypeError(f"relative: expected keys (frame a, frame b), pairs of frame names, got {pair!r}")
        a, b = (robot.frame_index(f) for f in pair)
        if a == b:
            raise ValueError(f"relative[{pair!r}]: a frame relative to itself constrains nothing")
        array, position_only, _ = check_target(target, f"relative[{pair!r}]")
        w = ONES if pair not in weights else weights_of(weights[pair], repr(pair), position_only)
        out.append((RelativeTarget(a, b, position_only, w), array, repr(pair)))
    return out
