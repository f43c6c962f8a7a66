"""What the packages built on IK use beyond its public names (internal: not in API.md).

The trajectories (:mod:`diffkin.traj`) check and cast their arguments as ``dk.ik.solve`` does, and build
their clearance rows from IK's problem and its clearance term (:class:`AvoidTerm`, whose ``measure``
gives the distances per pair block). Every function that takes ``avoid=`` checks it with
:func:`check_avoid`.
"""

from diffkin.ik._args import check_batched, default_key, finite
from diffkin.ik._keywords import terms_of
from diffkin.ik._prepare import cast, detach
from diffkin.ik._problem import Kinematics, Problem, Spec
from diffkin.ik._terms.avoid import BAND, AvoidTerm, check_avoid

__all__ = [
    "BAND",
    "AvoidTerm",
    "Kinematics",
    "Problem",
    "Spec",
    "cast",
    "check_avoid",
    "check_batched",
    "default_key",
    "detach",
    "finite",
    "target_batch",
]


def target_batch(model, target) -> tuple[int, ...]:
    """The batch shape of :func:`diffkin.ik.solve`'s result for ``target`` (checked as ``solve`` checks it)."""
    return tuple(terms_of(model, target, {}, None).batch)
