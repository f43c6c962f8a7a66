"""Linear couplings of joints (MJCF ``<equality><joint>`` and ``<equality><tendon>``) as tree joints.

A coupling makes a joint's angle a linear function of other joints' angles,
``theta_j = bias_j + sum_k m_jk theta_k`` (``theta = q - ref``: radians or metres from the joint's
reference). :func:`resolve` substitutes couplings into each other until every coupled joint is a
function of free joints only. :func:`as_mimics` writes each as tree joints of
:class:`~diffkin.models._tree.JointSpec`: a coupling to one joint is a mimic joint; a coupling to
several is one tree joint per source, all with the joint's screw, chained through unnamed bodies
(``exp([S] (a + b)) = exp([S] a) exp([S] b)``: exact), the first named after the joint, the others
``{joint}:{source}``. A coupling to none (a locked joint) is left to the reader (a fixed joint).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from diffkin.models._tree import JointSpec


@dataclasses.dataclass(frozen=True)
class Coupling:
    """``theta_joint = bias + sum(m * theta_source for source, m in terms)``.

    Attributes:
        terms: ``(source joint, multiplier)`` pairs, each source once.
        bias: radians (hinge) or metres (slide).
        where: the element that declares it, for error messages.
    """

    terms: tuple[tuple[str, float], ...]
    bias: float
    where: str


def resolve(couplings: Mapping[str, Coupling]) -> dict[str, tuple[dict[str, float], float]]:
    """Every coupled joint as ``({free source: multiplier}, bias)``: couplings substituted into each other.

    Walked with an explicit stack (chains of any length).

    Raises:
        ValueError: couplings that form a cycle (naming the element that closes it and the joints).
    """
    done: dict[str, tuple[dict[str, float], float]] = {}
    for start in couplings:
        path = [start]  # a chain of couplings, each one a source of the one before
        while path:
            name = path[-1]
            pending = [k for k, _ in couplings[name].terms if k in couplings and k not in done]
            if pending:
                if pending[0] in path:
                    cycle = " -> ".join([*path[path.index(pending[0]) :], pending[0]])
                    raise ValueError(f"{couplings[name].where}: the joint couplings form a cycle: {cycle}")
                path.append(pending[0])
                continue
            terms: dict[str, float] = {}
            bias = couplings[name].bias
            for source, m in couplings[name].terms:
                inner, inner_bias = done[source] if source in couplings else ({source: 1.0}, 0.0)
                bias += m * inner_bias
                for k, mk in inner.items():
                    terms[k] = terms.get(k, 0.0) + m * mk
            done[name] = (terms, bias)
            path.pop()
    return done


def as_mimics(joints: Sequence[JointSpec], resolved: Mapping[str, tuple[dict[str, float], float]]) -> list[JointSpec]:
    """The tree joints of ``joints`` with each coupled joint (of one source or more) following its sources.

    Args:
        joints: the robot's joints; a joint's ``offset`` is ``-ref`` (``theta = q - ref``).
        resolved: :func:`resolve`'s couplings, each with at least one source.

    Returns:
        The joints in the same order, a joint coupled to ``n`` sources as ``n`` consecutive tree joints.
    """
    ref = {j.name: -j.offset for j in joints}
    out: list[JointSpec] = []
    for j in joints:
        if j.name not in resolved:
            out.append(j)
            continue
        terms, bias = resolved[j.name]
        # q_j = m q_s + (bias + ref_j - m ref_s) gives theta_j = m theta_s + bias; the further pieces
        # (offset 0) turn by m_k theta_k = m_k q_k - m_k ref_k.
        parent = j.parent
        for k, (source, m) in enumerate(terms.items()):
            last = k == len(terms) - 1
            out.append(
                dataclasses.replace(
                    j,
                    name=j.name if k == 0 else f"{j.name}:{source}",
                    parent=parent,
                    child=j.child if last else f"{j.child}\0{j.name}:{k}",
                    origin=j.origin if k == 0 else np.eye(4),
                    mimic=(source, m, (bias + ref[j.name] if k == 0 else 0.0) - m * ref[source]),
                    offset=j.offset if k == 0 else 0.0,
                )
            )
            parent = out[-1].child
    return out
