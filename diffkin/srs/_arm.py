"""The spherical-revolute-spherical arm model."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _validate as check
from diffkin import robots
from diffkin._checks import instance
from diffkin._pytree import pytree_dataclass
from diffkin.models.dh import DHChain

# Standard DH twists of the iiwa-type SRS arm; all a = 0 and theta_offset = 0.
ALPHA = np.array([-np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, np.pi / 2, 0.0])
_LENGTHS = ("d_bs", "d_se", "d_ew", "d_wf")
_D_INDEX = (0, 2, 4, 6)  # rows of the DH table holding d_bs, d_se, d_ew, d_wf
AN_ARM = "a diffkin.srs.SRSArm (e.g. diffkin.srs.iiwa14())"  # what the functions' ``arm`` must be


@pytree_dataclass
class SRSArm:
    """A 7-joint spherical-revolute-spherical arm (KUKA LBR iiwa kinematics).

    Standard DH with ``a = 0``, ``theta_offset = 0``, ``alpha = [-pi/2, pi/2, pi/2, -pi/2, -pi/2,
    pi/2, 0]`` and ``d = [d_bs, 0, d_se, 0, d_ew, 0, d_wf]``: joints 1-3 form the shoulder
    (centre ``[0, 0, d_bs]`` in the base frame), joint 4 the elbow, joints 5-7 the wrist.
    Build with :meth:`from_lengths`, :meth:`from_chain`, :func:`iiwa7` or :func:`iiwa14`.

    Attributes:
        d_bs: ``()`` base-to-shoulder length, metres.
        d_se: ``()`` shoulder-to-elbow length, metres.
        d_ew: ``()`` elbow-to-wrist length, metres.
        d_wf: ``()`` wrist-to-flange length, metres.
        lower, upper: ``(7,)`` joint limits, radians (``-inf``/``inf`` if unlimited).

    The arm has no static fields: arms of different lengths share compiled code.
    """

    d_bs: jax.Array
    d_se: jax.Array
    d_ew: jax.Array
    d_wf: jax.Array
    lower: jax.Array
    upper: jax.Array

    @classmethod
    def from_lengths(cls, d_bs, d_se, d_ew, d_wf, *, lower=None, upper=None) -> SRSArm:
        """Build an arm from its four lengths (metres) and ``(7,)`` joint limits (radians).

        Raises:
            ValueError: a length that is not a positive finite number, limits that are not
                ``(7,)`` or have ``lower > upper``.
        """
        values = {}
        for field, value in zip(_LENGTHS, (d_bs, d_se, d_ew, d_wf), strict=True):
            x = check.float_array(value, field, ())
            if field != "d_bs" and field != "d_wf" and not x > 0:
                raise ValueError(f"{field}: expected a positive length in metres, got {float(x)}")
            values[field] = jnp.asarray(x)
        lo, hi = check.limits(lower, upper, 7)
        return cls(**values, lower=jnp.asarray(lo), upper=jnp.asarray(hi))

    @classmethod
    def from_chain(cls, chain: DHChain) -> SRSArm:
        """The arm of a standard-DH :class:`DHChain` with the SRS structure (see the class docstring).

        Raises:
            TypeError: ``chain`` is not a :class:`DHChain`.
            ValueError: the chain is not a 7-revolute standard-DH chain with ``a = 0``,
                ``theta_offset = 0``, the SRS twists and zero ``d_2, d_4, d_6``, and an identity
                base and tool; the message names the first offending field.
        """
        instance(chain, DHChain, "chain", "a DHChain")
        if chain.joint_types != "R" * 7 or chain.modified:
            raise ValueError(
                f"chain: expected 7 revolute joints in standard DH, got joint_types={chain.joint_types!r}, "
                f"modified={chain.modified}"
            )
        d = np.asarray(chain.d, dtype=np.float64)
        expected = {
            "a": np.zeros(7),
            "theta_offset": np.zeros(7),
            "alpha": ALPHA,
            "base": np.eye(4),
            "tool": np.eye(4),
        }
        for field, want in expected.items():
            got = np.asarray(getattr(chain, field), dtype=np.float64)
            if not np.allclose(got, want, rtol=0.0, atol=1e-6):  # float32 chains included
                raise ValueError(
                    f"chain.{field}: expected {np.round(want, 6).tolist()} for an SRS arm, got {got.tolist()}"
                )
        for i in (1, 3, 5):
            if d[i] != 0.0:
                raise ValueError(f"chain.d[{i}]: expected 0 for an SRS arm, got {d[i]}")
        return cls.from_lengths(*(d[i] for i in _D_INDEX), lower=chain.lower, upper=chain.upper)

    def chain(self) -> DHChain:
        """The standard-DH :class:`DHChain` of this arm: its ``fk`` is the pose the SRS functions use.

        Built with JAX operations on the arm's arrays, so it works on a traced arm (gradients
        with respect to the lengths flow through ``dk.fk(arm.chain(), q)``).
        """
        dtype = jnp.result_type(self.d_bs, self.d_se, self.d_ew, self.d_wf)
        zero = jnp.zeros((), dtype)
        d = jnp.stack(
            [
                jnp.asarray(self.d_bs, dtype),
                zero,
                jnp.asarray(self.d_se, dtype),
                zero,
                jnp.asarray(self.d_ew, dtype),
                zero,
                jnp.asarray(self.d_wf, dtype),
            ]
        )
        return DHChain(
            a=jnp.zeros(7, dtype),
            alpha=jnp.asarray(ALPHA, dtype),
            d=d,
            theta_offset=jnp.zeros(7, dtype),
            lower=self.lower,
            upper=self.upper,
            base=jnp.eye(4, dtype=dtype),
            tool=jnp.eye(4, dtype=dtype),
            joint_types="R" * 7,
            modified=False,
            joint_names=check.joint_names(None, 7),
            name="srs",
        )


def iiwa7() -> SRSArm:
    """KUKA LBR iiwa 7 R800: the arm of :func:`diffkin.robots.iiwa7` (same lengths, limits and frames)."""
    return SRSArm.from_chain(robots.iiwa7())


def iiwa14() -> SRSArm:
    """KUKA LBR iiwa 14 R820: the arm of :func:`diffkin.robots.iiwa14` (same lengths, limits and frames)."""
    return SRSArm.from_chain(robots.iiwa14())
