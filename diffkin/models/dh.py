"""Serial chains from Denavit-Hartenberg tables, standard (distal) and modified (Craig)."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin import _validate as check
from diffkin._pytree import pytree_dataclass, static
from diffkin._xla import segment_end
from diffkin.models import _scanned
from diffkin.models._serial import SerialChain, builder_fields
from diffkin.models.forward import ChainPass, Pass


@pytree_dataclass
class DHChain(SerialChain):
    """A serial chain described by a Denavit-Hartenberg table.

    Standard DH (``modified=False``): link ``i`` is ``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
    and joint ``i`` moves about (or along) the z axis of frame ``i - 1``.
    Modified DH (``modified=True``, Craig): row ``i`` holds ``a_{i-1}, alpha_{i-1}, d_i, theta_i``,
    link ``i`` is ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i)`` and joint ``i`` moves about
    the z axis of frame ``i``.
    For a revolute joint ``theta_i = q_i + theta_offset_i``; for a prismatic one ``d_i`` grows by
    ``q_i`` and ``theta_i = theta_offset_i``. The end-effector pose is ``base @ A_1 ... A_n @ tool``.

    Attributes:
        a: ``(dof,)`` link lengths, metres.
        alpha: ``(dof,)`` link twists, radians.
        d: ``(dof,)`` link offsets, metres.
        theta_offset: ``(dof,)`` joint angle offsets, radians.
        lower, upper: ``(dof,)`` joint limits (radians or metres; ``-inf``/``inf`` if unlimited).
        base: ``(4, 4)`` pose of DH frame 0 in the world (base) frame.
        tool: ``(4, 4)`` pose of the end effector in the last DH frame.
        joint_types: static string of ``"R"``/``"P"``, one letter per joint.
        modified: static; ``True`` for the modified (Craig) convention.
        joint_names: static tuple of names.
        name: static name of the robot (informational).
        velocity: ``(dof,)`` velocity limits ``|dq/dt| <= velocity`` (rad/s, m/s; ``inf``: none), the
            default of :func:`diffkin.ik.step`. The last field; built without it: ``inf`` per joint.
    """

    a: jax.Array
    alpha: jax.Array
    d: jax.Array
    theta_offset: jax.Array
    lower: jax.Array
    upper: jax.Array
    base: jax.Array
    tool: jax.Array
    joint_types: str = static()
    modified: bool = static(default=False)
    joint_names: tuple[str, ...] = static(default=())
    name: str = static(default="")
    velocity: jax.Array = None  # type: ignore[assignment]  # filled: check.no_velocity_limits

    def _check_own_leaves(self, dof: int, concrete: bool) -> None:
        """The convention flag and the DH parameters (finite when concrete)."""
        check.flag(self.modified, "modified")
        for field in ("a", "alpha", "d", "theta_offset"):
            check.leaf(getattr(self, field), field, (dof,), concrete)

    def _check_own_values(self, own: None, lower: np.ndarray | None, upper: np.ndarray | None, concrete: bool) -> None:
        """The limits, then base and tool: their shapes always, rigid transforms when concrete."""
        if concrete:
            check.limits(lower, upper, self.dof)
        for field in ("base", "tool"):
            value = getattr(self, field)
            if check.leaf(value, field, (4, 4), concrete) is not None:
                check.rigid_transform(value, field, tol=check.tolerance(value))

    @classmethod
    def from_table(
        cls,
        table,
        joint_types: str | None = None,
        *,
        modified: bool = False,
        lower=None,
        upper=None,
        base=None,
        tool=None,
        joint_names=None,
        name: str = "",
        velocity=None,
    ) -> DHChain:
        """Build a chain from a ``(dof, 4)`` table with columns ``[a, alpha, d, theta_offset]``.

        Args:
            table: ``(dof, 4)`` DH parameters (metres, radians); for ``modified=True`` row ``i``
                holds ``a_{i-1}, alpha_{i-1}, d_i, theta_i`` as in Craig's table.
            joint_types: ``"R"``/``"P"`` per joint; default all revolute.
            modified: use the modified (Craig) convention.
            lower, upper: ``(dof,)`` joint limits; ``None`` means unlimited.
            base: ``(4, 4)`` pose of frame 0 in the world; default identity.
            tool: ``(4, 4)`` end-effector pose in the last frame; default identity.
            joint_names: ``dof`` names; default ``joint1 ... jointN``.
            name: robot name.
            velocity: ``(dof,)`` velocity limits (rad/s, m/s), ``>= 0``; ``None`` means none (``inf``).

        Raises:
            ValueError: a table that is not ``(dof, 4)``, non-finite numbers, bad joint types,
                ``lower > upper``, a negative or NaN velocity limit, or a base/tool that is not a
                rigid transform.
            TypeError: a bool or complex table, a ``modified`` that is not a bool, ``joint_names``
                that is not a sequence of strings.
        """
        arr = check.float_array(table, "table", finite=False)
        if arr.ndim != 2 or arr.shape[1] != 4 or arr.shape[0] == 0:
            raise ValueError(
                f"table: expected shape (dof, 4) with columns [a, alpha, d, theta_offset], got {arr.shape}"
            )
        arr = check.float_array(arr, "table")
        dof = arr.shape[0]
        types = check.joint_types("R" * dof if joint_types is None else joint_types, dof)
        lo, hi = check.limits(lower, upper, dof)
        base_T = np.eye(4) if base is None else check.rigid_transform(base, "base")
        tool_T = np.eye(4) if tool is None else check.rigid_transform(tool, "tool")
        f = jnp.asarray
        return cls(
            a=f(arr[:, 0]),
            alpha=f(arr[:, 1]),
            d=f(arr[:, 2]),
            theta_offset=f(arr[:, 3]),
            lower=f(lo),
            upper=f(hi),
            base=f(base_T),
            tool=f(tool_T),
            joint_types=types,
            modified=check.flag(modified, "modified"),
            **builder_fields(joint_names, name, velocity, dof),
        )

    def forward(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> Pass:
        """The forward pass (:mod:`diffkin.models.forward`): the DH product, frame ``i`` after joint ``i`` (more than
        :data:`~diffkin.models._scanned.LONG` joints: scanned, :func:`~diffkin.models._scanned.chain_forward`)."""
        if self.scanned:
            with jax.ensure_compile_time_eval():  # a concrete chain's PoE form is a constant
                screws, home, link_homes = poe_arrays(self)
            return _scanned.chain_forward(screws, link_homes, home, q, base, first=self.base)
        return self.product(q, base)

    def product(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> ChainPass:
        """The DH product, joint by joint, at any length (:meth:`forward` scans long chains)."""
        a, alpha, d, offset = (rg.per_joint(x) for x in (self.a, self.alpha, self.d, self.theta_offset))
        T = rg.compose(base, rg.from_matrix(self.base))
        links, screws = [T], []
        thetas = [rg.add(q[i], offset[i]) if kind == "R" else offset[i] for i, kind in enumerate(self.joint_types)]
        trig_theta, trig_alpha = rg.sincos_each(thetas), rg.sincos_each(alpha)
        for i, kind in enumerate(self.joint_types):
            revolute = kind == "R"
            d_i = d[i] if revolute else rg.add(d[i], q[i])
            (st, ct), (sa, ca) = trig_theta[i], trig_alpha[i]
            if self.modified:
                A = rg.Rigid(
                    ((ct, -st, 0.0), (rg.mul(st, ca), rg.mul(ct, ca), -sa), (rg.mul(st, sa), rg.mul(ct, sa), ca)),
                    (a[i], -rg.mul(sa, d_i), rg.mul(ca, d_i)),
                )
                T = rg.compose(T, A)
                axis_frame = T  # joint i moves about z_i
            else:
                axis_frame = T  # joint i moves about z_{i-1}
                A = rg.Rigid(
                    ((ct, -rg.mul(st, ca), rg.mul(st, sa)), (st, rg.mul(ct, ca), -rg.mul(ct, sa)), (0.0, sa, ca)),
                    (rg.mul(a[i], ct), rg.mul(a[i], st), d_i),
                )
                T = rg.compose(T, A)
            z, origin = rg.column(axis_frame.R, 2), axis_frame.p
            screws.append((rg.cross(origin, z), z) if revolute else (z, (0.0, 0.0, 0.0)))
            if segment_end(i, self.dof):
                T = rg.checkpoint(T)
            links.append(T)
        return ChainPass(links, rg.compose(T, rg.from_matrix(self.tool)), screws)


def poe_arrays(chain: DHChain) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The chain at ``q = 0`` in product-of-exponentials form, ``(screws, home, link_homes)`` as
    :class:`~diffkin.PoEChain` holds them (:func:`~diffkin.to_poe`): its joint axes in the world
    frame ``(dof, 6)``, its end-effector pose ``(4, 4)`` and its DH frames ``(dof, 4, 4)``, the DH
    ``base`` folded in, all computed with JAX operations on the chain's arrays (differentiable)."""
    dtype = jnp.result_type(chain.a)
    at_zero = chain.product([jnp.zeros((), dtype) for _ in range(chain.dof)])
    screws = jnp.stack([rg.stack([*v, *w], (), dtype) for v, w in at_zero.columns()])
    home = rg.to_matrix(at_zero.pose(), (), dtype)
    return screws, home, jnp.stack([rg.to_matrix(T, (), dtype) for T in at_zero.poses()[1:]])
