"""What the serial chains (:class:`~diffkin.DHChain`, :class:`~diffkin.PoEChain`) share: ``dof``, the
default velocity limits, the checks of the fields every chain has, and the builders' common keywords.

Each chain still declares its own fields, in its own order (a pytree's leaves and its documented
attributes); :class:`SerialChain` adds methods only.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _validate as check
from diffkin.models import _scanned


class SerialChain:
    """The methods of a serial chain: one joint per entry of ``q``, its ``joint_types`` (``"R"``/``"P"``).

    The validation hook :meth:`_check` checks the fields every chain has in one order, the chain's own
    fields in between: the static fields (``joint_types``, ``joint_names``, ``name``), then the chain's
    own leaves (:meth:`_check_own_leaves`), the ``lower``/``upper``/``velocity`` leaves, and last the
    chain's own values (:meth:`_check_own_values`, which checks the limits where it sees fit).
    """

    joint_types: str
    lower: jax.Array
    upper: jax.Array
    velocity: jax.Array

    def _fill(self) -> dict:
        return check.no_velocity_limits(self)

    @property
    def dof(self) -> int:
        return len(self.joint_types)

    @property
    def actuated_types(self) -> str:
        """``"R"``/``"P"`` of each entry of ``q`` (:attr:`joint_types`)."""
        return self.joint_types

    @property
    def scanned(self) -> bool:
        """Whether :meth:`forward` is the scanned pass (more than :data:`~diffkin.models._scanned.LONG` joints)."""
        return self.dof > _scanned.LONG

    def _check(self, concrete: bool) -> None:
        dof = check.chain_statics(self)
        own = self._check_own_leaves(dof, concrete)
        lo, hi = check.limit_leaves(self, dof, concrete)
        check.velocity_leaf(self, dof, concrete)
        self._check_own_values(own, lo, hi, concrete)

    def _check_own_leaves(self, dof: int, concrete: bool) -> Any:
        """The shapes of the chain's own leaves (their values too, when ``concrete``, as
        :func:`diffkin._validate.leaf`); returns what :meth:`_check_own_values` needs of them."""
        raise NotImplementedError

    def _check_own_values(self, own: Any, lower: np.ndarray | None, upper: np.ndarray | None, concrete: bool) -> None:
        """The values of the chain's own leaves and the limits ``lower <= upper`` (given when ``concrete``, else
        ``None``), after every shape; ``own``: what :meth:`_check_own_leaves` returned."""
        raise NotImplementedError


def builder_fields(joint_names, name: str, velocity, dof: int) -> dict[str, Any]:
    """The keywords the ``from_*`` builders of every chain pass on: ``joint_names`` (default ``joint1 ...
    jointN``), ``name`` and ``velocity`` (``None``: ``inf`` per joint), checked in that order."""
    return {
        "joint_names": check.joint_names(joint_names, dof),
        "name": name,
        "velocity": jnp.asarray(check.velocity(velocity, dof)),
    }
