"""The one forward pass that every model provides, and the one host-side model check.

A model is a :class:`DHChain`, a :class:`PoEChain` or a :class:`Robot`. Each provides
``model._frames(q, ...) -> Frames`` over its joint values ``q`` (a list of ``dof`` arrays of one
batch shape, or Python floats), with every pose in the world frame (the chain's base frame, or
the world in which a robot's root sits at ``base``):

- ``Frames.ee``: the pose of the frame of interest: a chain's end effector (tool included), or
  the robot frame ``frame`` (an index into ``robot.frame_names``).
- ``Frames.screws``: per entry of ``q``, the space twist ``(v, w)`` of that frame's motion per
  unit ``q_i`` (the current screw axis of joint ``i``; for a robot the sum over the joints that
  ``q_i`` drives on the frame's path, zero if none): the columns of the space Jacobian.
- ``Frames.links``: a chain's base and moving links (``dof + 1``), or every robot frame in
  ``frame_names`` order when asked for (``every=True``).

Structure (joint types, counts, names, parents) is static; concrete numbers fold at trace time
(see :mod:`diffkin._rigid`).
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin._checks import instance, real_array
from diffkin._xla import is_concrete
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

Model = DHChain | PoEChain | Robot
CHAINS = (DHChain, PoEChain)


def check(model, name: str = "chain") -> None:
    """Raise a TypeError unless ``model`` is a model of diffkin."""
    instance(model, (DHChain, PoEChain, Robot), name, "a DHChain, PoEChain or Robot")


def joint_values(model: Model, q) -> jax.Array:
    """``q`` as a float array of shape ``(..., dof)``; raises on a bad model or shape."""
    check(model)
    q = real_array(q, "q", "joint values (radians or metres)")
    if q.ndim == 0 or q.shape[-1] != model.dof:
        kind = "robot" if isinstance(model, Robot) else "chain"
        raise ValueError(f"q: expected shape (..., {model.dof}) for a {model.dof}-joint {kind}, got {q.shape}")
    if q.dtype == jnp.float64 and any(is_concrete(x) and x.dtype == jnp.float32 for x in jax.tree.leaves(model)):
        warnings.warn(
            "the model's numbers are float32 (it was built before jax_enable_x64 was switched on): "
            "float64 results are only accurate to ~1e-7; build the model after enabling x64",
            stacklevel=3,
        )
    return q


def frames(
    model: Model, q: list, frame: int | None = None, base: rg.Rigid = rg.IDENTITY, *, every: bool = False
) -> rg.Frames:
    """The forward pass of ``model`` (see the module docstring); ``frame``/``base``/``every`` are for robots."""
    if isinstance(model, Robot):
        return model._frames(q, 0 if frame is None else frame, base, every=every)
    return model._frames(q)
