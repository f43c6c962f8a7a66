"""Self-collision pairs that sampled configurations find never or always in collision, saved as SRDF.

MoveIt's setup assistant chooses the pairs a planner checks the same way: a pair of links that
collides in every sampled configuration is in contact by construction (fitted shapes overlapping
at a joint) and would make every configuration "in collision"; a pair that collides in none cannot
reach each other (or only in configurations the sample missed: a statistical answer, stronger with
more samples). Both are written to an SRDF as ``<disable_collisions reason="Always"|"Never">``,
which :func:`diffkin.collision.load` reads back (``srdf=``).
"""

from __future__ import annotations

import dataclasses
from xml.sax.saxutils import quoteattr

import jax
import numpy as np

from diffkin._checks import positive_int
from diffkin.collision._geometry import Geometry
from diffkin.collision._robot import check_geometry, self_distances
from diffkin.models.ranges import ball_starts, sampling_ranges, uniform
from diffkin.models.robot import Robot


@dataclasses.dataclass(frozen=True)
class PairSample:
    """How often each checked link pair collides over sampled configurations (:func:`sample_pairs`).

    Attributes:
        link_pairs: the link pairs (names of the links that carry the shapes) with a checked shape pair.
        colliding: ``(L,)`` per link pair, the fraction of the samples in which some shape pair of
            the two links is within ``margin`` (distance ``<= margin``).
        n: the number of sampled configurations.
        margin: the distance at or below which a pair counts as colliding (metres).
        robot_name: the robot's name (the SRDF's ``<robot name=>``).
    """

    link_pairs: tuple[tuple[str, str], ...]
    colliding: np.ndarray
    n: int
    margin: float
    robot_name: str

    @property
    def never(self) -> tuple[tuple[str, str], ...]:
        """The link pairs that collided in no sample."""
        return tuple(p for p, f in zip(self.link_pairs, self.colliding, strict=True) if f == 0.0)

    @property
    def always(self) -> tuple[tuple[str, str], ...]:
        """The link pairs that collided in every sample."""
        return tuple(p for p, f in zip(self.link_pairs, self.colliding, strict=True) if f == 1.0)

    def apply(self, geom: Geometry) -> Geometry:
        """``geom`` without the shape pairs of the link pairs that never or always collide."""
        disabled = {frozenset(p) for p in self.never + self.always}
        links = geom.shape_links
        return geom.replace_pairs(p for p in geom.pair_list if frozenset((links[p[0]], links[p[1]])) not in disabled)

    def to_srdf(self) -> str:
        """An SRDF disabling the pairs that never or always collide (``srdf=`` of :func:`diffkin.collision.load`)."""
        lines = [f"<robot name={quoteattr(self.robot_name)}>"]
        lines.append(
            f"  <!-- diffkin.collision.sample_pairs: {self.n} configurations uniform within the joint limits,"
            f" colliding at distance <= {self.margin} m -->"
        )
        for reason, pairs in (("Always", self.always), ("Never", self.never)):
            lines += [
                f"  <disable_collisions link1={quoteattr(a)} link2={quoteattr(b)} reason={quoteattr(reason)}/>"
                for a, b in pairs
            ]
        return "\n".join(lines + ["</robot>", ""])


def sample_pairs(robot: Robot, geom: Geometry, n: int = 10_000, *, key, margin: float = 0.0) -> PairSample:
    """How often each self-collision link pair of ``geom`` collides over ``n`` random configurations.

    Configurations are uniform within the joint limits (one turn for an unlimited revolute joint; a
    prismatic joint needs finite limits); the root stays put (self distances do not depend on it).

    Args:
        robot: the :class:`diffkin.Robot`.
        geom: its :class:`Geometry` (:func:`diffkin.collision.load`).
        n: number of configurations (MoveIt's setup assistant samples 10,000 by default).
        key: a JAX PRNG key.
        margin: a pair collides where its distance is at most this (metres, default 0: touching).

    Returns:
        A :class:`PairSample`: ``.never``, ``.always``, ``.apply(geom)`` and ``.to_srdf()``.

    Raises:
        TypeError, ValueError: bad arguments, named (a prismatic joint without finite limits included).
    """
    check_geometry(robot, geom)
    n = positive_int(n, "n")
    if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not np.isfinite(margin):
        raise ValueError(f"margin: expected a finite distance in metres, got {margin!r}")
    lo, hi = sampling_ranges(robot)
    q = uniform(key, lo, hi, n, jax.numpy.result_type(float), ball_starts(robot)).T
    d = np.asarray(jax.jit(lambda q: self_distances(robot, geom, q))(q))  # (n, P)
    groups: dict[tuple[str, str], list[int]] = {}
    for k, (i, j) in enumerate(geom.pair_list):
        a, b = sorted((geom.shape_links[i], geom.shape_links[j]))
        groups.setdefault((a, b), []).append(k)
    link_pairs = tuple(groups)
    colliding = np.array([np.mean(d[:, groups[p]].min(axis=1) <= margin) for p in link_pairs]).reshape(-1)
    return PairSample(link_pairs, colliding, n, float(margin), robot.name)
