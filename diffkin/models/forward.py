"""The forward pass: the one interface that every model kind implements.

A model (:class:`~diffkin.DHChain`, :class:`~diffkin.PoEChain`, :class:`~diffkin.Robot`, or a
new kind in a file of its own) provides one method::

    model.forward(q, base=rg.IDENTITY) -> Pass

``q`` holds the ``dof`` joint values, each an array of one batch shape or a Python float (a
folded constant); ``base`` is ``T_world_root``, the pose of the model's root in the world. The
:class:`Pass` it returns is the kinematics at ``q``, every pose and twist in the world frame:

- ``pass_.pose(frame)``: the pose ``T_world_frame`` of a frame.
- ``pass_.columns(frame)``: per entry of ``q``, the space twist ``(v, w)`` (world frame, about
  the world origin) of that frame's motion per unit ``q_i``: the columns of its space Jacobian.
  A joint that does not move the frame gives a zero column; a mimic joint adds its motion times
  its multiplier to the column of its source.
- ``pass_.poses()``: every frame, in the model's frame order.

A frame is an index: for a robot into ``robot.frame_names``; for a chain ``None`` is the end
effector (tool included) and ``i`` the link frame ``i`` (``0``: the base, ``1 .. dof``: the
moving links). Poses are :class:`diffkin._rigid.Rigid` (entries, so that constants fold: see
:mod:`diffkin._static`).

Besides ``forward``, a model has ``dof``, ``joint_names``, ``lower``, ``upper`` (of ``q``),
``actuated_types`` (``"R"``/``"P"`` per entry of ``q``) and ``scanned`` (whether ``forward`` returns
a :class:`StackedPass`: one scan over the joints).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin._checks import real_array
from diffkin._static import is_concrete

Twist = tuple[rg.Vec3, rg.Vec3]


class Pass(Protocol):
    """The kinematics of a model at one ``q`` (see the module docstring)."""

    def pose(self, frame: int | None = None) -> rg.Rigid: ...

    def columns(self, frame: int | None = None) -> list[Twist]: ...

    def poses(self) -> list[rg.Rigid]: ...


@runtime_checkable
class StackedPass(Pass, Protocol):
    """A pass that also gives many frames or columns at once, as one pose or twist whose entries have a
    leading axis (a scanned pass's: a thousand frames sliced into entries and stacked again would compile
    for minutes). :mod:`diffkin.kinematics` takes these methods where a pass has them.

    Attributes:
        frames: the number of frames of :meth:`poses`.
    """

    frames: int

    def stacked_poses(self, frames: Sequence[int | None]) -> rg.Rigid:
        """The world poses of ``frames``: entries ``(len(frames),) + batch``."""
        ...

    def stacked_columns(self, frame: int | None) -> Twist:
        """The columns of ``frame`` (as :meth:`columns`): one twist with entries ``(dof,) + batch``."""
        ...


@runtime_checkable
class Model(Protocol):
    """What every model provides: :meth:`forward` and the joint space of ``q``."""

    @property
    def dof(self) -> int: ...

    @property
    def actuated_types(self) -> str: ...

    @property
    def scanned(self) -> bool: ...

    def forward(self, q: Sequence[rg.Entry], base: rg.Rigid = rg.IDENTITY) -> Pass: ...


class ChainPass:
    """The :class:`Pass` of a serial chain: its link poses, end-effector pose and joint screws."""

    def __init__(self, links: list[rg.Rigid], ee: rg.Rigid, screws: list[Twist]):
        self.links, self.ee, self.screws = links, ee, screws

    def pose(self, frame: int | None = None) -> rg.Rigid:
        return self.ee if frame is None else self.links[frame]

    def columns(self, frame: int | None = None) -> list[Twist]:
        if frame is None:
            return self.screws
        zero = (0.0, 0.0, 0.0)
        return self.screws[:frame] + [(zero, zero)] * (len(self.screws) - frame)

    def poses(self) -> list[rg.Rigid]:
        return self.links


class JointValues(Sequence):
    """The ``dof`` entries of a ``(..., dof)`` array of joint values, each sliced when read.

    A model's :meth:`~Model.forward` reads ``q`` entry by entry; one that scans over its joints
    reads the whole :attr:`array` instead (slicing a thousand joints out of an array and stacking them
    again costs seconds of compile time).
    """

    def __init__(self, array: jax.Array):
        self.array = array

    def __len__(self) -> int:
        return self.array.shape[-1]

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return [self.array[..., k] for k in range(len(self))[i]]
        if not -len(self) <= i < len(self):
            raise IndexError(f"joint {i} of {len(self)}")
        return self.array[..., i]

    def __iter__(self):
        return (self.array[..., k] for k in range(len(self)))


def check(model, name: str = "chain") -> None:
    """Raise a TypeError unless ``model`` is a model (it implements :class:`Model`)."""
    if not isinstance(model, Model):
        raise TypeError(f"{name}: expected a DHChain, PoEChain or Robot, got {type(model).__name__}")


def joint_values(model: Model, q) -> jax.Array:
    """``q`` as a float array of shape ``(..., dof)``; raises on a bad model or shape."""
    check(model)
    q = real_array(q, "q", "joint values (radians or metres)")
    if q.ndim == 0 or q.shape[-1] != model.dof:
        kind = "robot" if hasattr(model, "frame_names") else "chain"
        raise ValueError(f"q: expected shape (..., {model.dof}) for a {model.dof}-joint {kind}, got {q.shape}")
    if q.dtype == jnp.float64 and any(is_concrete(x) and x.dtype == jnp.float32 for x in jax.tree.leaves(model)):
        warnings.warn(
            "the model's numbers are float32 (it was built before jax_enable_x64 was switched on): "
            "float64 results are only accurate to ~1e-7; build the model after enabling x64",
            stacklevel=3,
        )
    return q
