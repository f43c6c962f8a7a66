"""Serial chains in product-of-exponentials form, and the exact conversion from DH."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin import _validate as check
from diffkin._checks import instance
from diffkin._pytree import pytree_dataclass, static
from diffkin._static import host
from diffkin._xla import segment_end
from diffkin.models import _scanned
from diffkin.models._serial import SerialChain, builder_fields
from diffkin.models.dh import DHChain, poe_arrays
from diffkin.models.forward import ChainPass, Pass


@pytree_dataclass
class PoEChain(SerialChain):
    """A serial chain as a product of exponentials, ``T(q) = exp([S1] q1) ... exp([Sn] qn) M``.

    Attributes:
        screws: ``(dof, 6)`` space-frame screw axes ``[v; w]`` at ``q = 0``: revolute
            ``[-w x p; w]`` (unit ``w`` through the point ``p``), prismatic ``[v; 0]`` (unit ``v``).
        home: ``(4, 4)`` end-effector pose ``M`` in the base frame at ``q = 0``.
        link_homes: ``(dof, 4, 4)`` pose of each moving link frame at ``q = 0``; link ``i`` moves
            as ``exp([S1] q1) ... exp([Si] qi) link_homes[i]``.
        lower, upper: ``(dof,)`` joint limits (``-inf``/``inf`` if unlimited).
        joint_types: static string of ``"R"``/``"P"``.
        joint_names: static tuple of names.
        name: static name of the robot (informational).
        velocity: ``(dof,)`` velocity limits ``|dq/dt| <= velocity`` (rad/s, m/s; ``inf``: none), the
            default of :func:`diffkin.ik.step` (a URDF chain: the file's, as :class:`~diffkin.Robot`
            reads them). The last field; built without it: ``inf`` per joint.
    """

    screws: jax.Array
    home: jax.Array
    link_homes: jax.Array
    lower: jax.Array
    upper: jax.Array
    joint_types: str = static()
    joint_names: tuple[str, ...] = static(default=())
    name: str = static(default="")
    velocity: jax.Array = None  # type: ignore[assignment]  # filled: check.no_velocity_limits

    def _check_own_leaves(self, dof: int, concrete: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The shapes of ``screws``, ``home`` and ``link_homes`` (finite when concrete); the screws and link homes."""
        S = check.leaf(self.screws, "screws", (dof, 6), concrete)
        check.leaf(self.home, "home", (4, 4), concrete)
        L = check.leaf(self.link_homes, "link_homes", (dof, 4, 4), concrete)
        return S, L

    def _check_own_values(self, own: tuple[np.ndarray | None, np.ndarray | None], lower, upper, concrete: bool) -> None:
        """When concrete: unit screws of the joint types, rigid home and link poses, then the limits."""
        if not concrete:
            return
        S, L = own
        assert S is not None and L is not None  # concrete: check.leaf returned the values
        dof = self.dof
        tol = check.tolerance(self.screws)
        for i, given in enumerate(_screw_types(S, tol)):
            if given != self.joint_types[i]:
                raise ValueError(
                    f"joint_types[{i}]: {self.joint_types[i]!r} contradicts screws[{i}], which is {given!r}"
                )
        check.rigid_transform(self.home, "home", tol=check.tolerance(self.home))
        for i in range(dof):
            check.rigid_transform(L[i], f"link_homes[{i}]", tol=check.tolerance(self.link_homes))
        check.limits(lower, upper, dof)

    @classmethod
    def from_screws(
        cls,
        screws,
        home,
        joint_types: str | None = None,
        *,
        lower=None,
        upper=None,
        link_homes=None,
        joint_names=None,
        name: str = "",
        velocity=None,
    ) -> PoEChain:
        """Build a chain from space-frame screws.

        Args:
            screws: ``(dof, 6)`` unit screws ``[v; w]``: ``|w| = 1`` (revolute) or ``w = 0`` and
                ``|v| = 1`` (prismatic).
            home: ``(4, 4)`` end-effector pose at ``q = 0``.
            joint_types: ``"R"``/``"P"`` per joint; default read from the screws.
            lower, upper: ``(dof,)`` limits; ``None`` means unlimited.
            link_homes: ``(dof, 4, 4)`` link poses at ``q = 0``; default each joint's point on its
                axis (revolute) or the previous link frame (prismatic), with identity rotation.
            joint_names: ``dof`` names; default ``joint1 ... jointN``.
            name: robot name.
            velocity: ``(dof,)`` velocity limits (rad/s, m/s), ``>= 0``; ``None`` means none (``inf``).

        Raises:
            ValueError: screws that are not unit screws, a joint type that contradicts its screw,
                a home pose that is not rigid, non-finite numbers, ``lower > upper``, a negative or
                NaN velocity limit.
        """
        S = check.float_array(screws, "screws", finite=False)
        if S.ndim != 2 or S.shape[1] != 6 or S.shape[0] == 0:
            raise ValueError(f"screws: expected shape (dof, 6) with rows [v; w], got {S.shape}")
        S = check.float_array(S, "screws")
        dof = S.shape[0]
        inferred = "".join(_screw_types(S, 1e-6))
        # Unit within tolerance: normalised exactly (|w| = 1, no pitch; or |v| = 1).
        S = S.copy()
        for i, kind in enumerate(inferred):
            v, w = S[i, :3], S[i, 3:]
            if kind == "R":  # the screw scaled to |w| = 1, its pitch (within tolerance) removed
                v, w = v / np.linalg.norm(w), w / np.linalg.norm(w)
                S[i, :3], S[i, 3:] = v - np.dot(v, w) * w, w
            else:
                S[i, :3], S[i, 3:] = v / np.linalg.norm(v), 0.0
        types = inferred if joint_types is None else check.joint_types(joint_types, dof)
        for i, (given, seen) in enumerate(zip(types, inferred, strict=True)):
            if given != seen:
                raise ValueError(f"joint_types[{i}]: {given!r} contradicts screws[{i}], which is {seen!r}")
        M = check.rigid_transform(home, "home")
        if link_homes is None:
            L = np.tile(np.eye(4), (dof, 1, 1))
            for i in range(dof):
                w, v = S[i, 3:], S[i, :3]
                L[i, :3, 3] = np.cross(w, v) if types[i] == "R" else (L[i - 1, :3, 3] if i else 0.0)
        else:
            L = check.float_array(link_homes, "link_homes", (dof, 4, 4))
            for i in range(dof):
                check.rigid_transform(L[i], f"link_homes[{i}]")
        lo, hi = check.limits(lower, upper, dof)
        f = jnp.asarray
        return cls(
            screws=f(S),
            home=f(M),
            link_homes=f(L),
            lower=f(lo),
            upper=f(hi),
            joint_types=types,
            **builder_fields(joint_names, name, velocity, dof),
        )

    def forward(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> Pass:
        """The forward pass (:mod:`diffkin.models.forward`): the product of exponentials (more than
        :data:`~diffkin.models._scanned.LONG` joints: scanned, :func:`~diffkin.models._scanned.chain_forward`)."""
        if self.scanned:
            return _scanned.chain_forward(self.screws, self.link_homes, self.home, q, base)
        S, L = host(self.screws), host(self.link_homes)
        T = base
        links, screws = [T], []
        axes = [(rg.vector(S[i, :3]), rg.vector(S[i, 3:])) for i in range(self.dof)]
        exps = rg.screw_exps(axes, q)
        for i, (v, w) in enumerate(axes):
            w_now = rg.rotate(T.R, w)
            screws.append((rg.vadd(rg.rotate(T.R, v), rg.cross(T.p, w_now)), w_now))
            T = rg.compose(T, exps[i])
            if segment_end(i, self.dof):
                T = rg.checkpoint(T)
            links.append(rg.compose(T, rg.from_matrix(L[i])))
        return ChainPass(links, rg.compose(T, rg.from_matrix(self.home)), screws)


def _screw_types(S: np.ndarray, tol: float) -> list[str]:
    """``"R"``/``"P"`` of each screw row ``[v; w]``; raises on rows that are not unit screws.

    Revolute: ``|w| = 1`` and no pitch (``v . w = 0``: the screw of a rotation about a line);
    prismatic: ``w = 0`` and ``|v| = 1``; within ``tol``.
    """
    types = []
    for i, (v, w) in enumerate(zip(S[:, :3], S[:, 3:], strict=True)):
        nw, nv = np.linalg.norm(w), np.linalg.norm(v)
        if abs(nw - 1.0) < tol:
            pitch = float(np.dot(v, w))
            if abs(pitch) > tol * max(1.0, float(nv)):
                raise ValueError(
                    f"screws[{i}]: expected a revolute screw without pitch (v . w = 0), got v . w = {pitch:.6g}"
                )
            types.append("R")
        elif nw < 1e-12 and abs(nv - 1.0) < tol:
            types.append("P")
        else:
            raise ValueError(
                f"screws[{i}]: expected a unit screw (|w| = 1, or w = 0 and |v| = 1), "
                f"got |w| = {nw:.6g}, |v| = {nv:.6g}"
            )
    return types


def to_poe(chain: DHChain) -> PoEChain:
    """Exact, differentiable conversion of a :class:`DHChain` (either convention) to a :class:`PoEChain`.

    The screws are the chain's joint axes at ``q = 0`` in the world frame, ``home`` its
    end-effector pose at ``q = 0`` and ``link_homes`` its DH frames at ``q = 0``, all computed
    with JAX operations on the chain's arrays (so gradients flow through the conversion).
    The DH ``base`` is folded into the screws and poses: the PoE base frame is the world frame.
    """
    instance(chain, DHChain, "chain", "a DHChain")
    screws, home, link_homes = poe_arrays(chain)
    return PoEChain(
        screws=screws,
        home=home,
        link_homes=link_homes,
        lower=chain.lower,
        upper=chain.upper,
        joint_types=chain.joint_types,
        joint_names=chain.joint_names,
        name=chain.name,
        velocity=chain.velocity,
    )
