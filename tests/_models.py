"""The tests' models: robot files and built-in robots, one model of every kind (:func:`every_model_kind`), a
snake of any length, random configurations within the limits, IK tolerances and success counting, and
the gradients of a Jacobian with respect to a chain's parameters."""

from __future__ import annotations

import functools
import os
from importlib import metadata

import jax
import numpy as np
import pytest
from _mjcf import mjcf
from _paths import DATA

import diffkin as dk
from diffkin import se3
from diffkin.models._scanned import LONG

# URDF robots of the validation: (name, path, end link); built once per session (``urdf_chains``).
URDF_ROBOTS = {
    "iiwa7": (dk.robots.urdf_path("iiwa7"), "iiwa7_link_ee"),
    "iiwa14": (dk.robots.urdf_path("iiwa14"), "iiwa14_link_ee"),
    "panda": (os.path.join(DATA, "panda.urdf"), "panda_link8"),
    "ur5": (os.path.join(DATA, "ur5.urdf"), "tool0"),
}
BUILTIN = dk.robots.BUILTIN
PANDA = os.path.join(DATA, "panda.urdf")
"""The Panda with its gripper: a tree (two fingers), one mimic joint."""
FINGER = os.path.join(DATA, "example-robot-data", "robots", "finger_edu_description", "robots", "finger_edu.urdf")


def _example_robot_data() -> str | None:
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        return None
    path = str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))
    return path if os.path.isdir(path) else None


ERD = _example_robot_data()
"""The robots folder of example-robot-data (validation install), or ``None``."""
BAXTER = os.path.join(ERD, "baxter_description/urdf/baxter.urdf") if ERD else ""
SOLO = os.path.join(ERD, "solo_description/robots/solo12.urdf") if ERD else ""
HANDS = ["left_gripper", "right_gripper"]
FEET = ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"]

# Whole-robot IK, every success re-checked by Pinocchio: tolerances and, float32 solutions re-checked in
# float64 against the float64 targets, no slack (the solver decides success with a margin for float32
# rounding: diffkin.ik._solve.ROUNDING_POS/ROT).
POS_TOL, ROT_TOL = 1e-5, 1e-4
SLACK_POS, SLACK_ROT = 0.0, 0.0

_TREE = """<robot name="tree"><link name="root"/><link name="upper"/><link name="left"/><link name="right"/>
  <joint name="shoulder" type="revolute"><parent link="root"/><child link="upper"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2"/></joint>
  <joint name="left" type="revolute"><parent link="upper"/><child link="left"/>
    <origin xyz="0.2 0.1 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2"/></joint>
  <joint name="right" type="prismatic"><parent link="upper"/><child link="right"/>
    <origin xyz="0.2 -0.1 0" rpy="0 0 -0.4"/><axis xyz="1 0 0"/><limit lower="0" upper="0.5"/></joint>
</robot>"""

# A ball shoulder (a 60 degree cone about a centre off the body's origin), a hinge elbow and a site at the hand.
_BALL_ARM = mjcf(
    '<body name="upper" pos="0 0 1" euler="10 20 30"><joint name="shoulder" type="ball" pos="0 0 .1" range="0 60"/>'
    '<geom size=".05" mass="1"/><body name="fore" pos="0 .1 -.5"><joint name="elbow" axis="0 1 0" range="-150 0"/>'
    '<geom size=".05" mass="1"/><site name="hand" pos=".05 0 -.4"/></body></body>'
)
# A crank-rocker (the closed loop of every_model_kind and of tests/unit/test_loops.py): ground pivots at (0, 0)
# and (0.25, 0); crank 0.1, driven; the coupler's point (0.1, 0.2) (in the coupler, from the crank's tip) pinned
# to the rocker, whose length is that point's distance from its pivot at the reference configuration; the coupler
# and the rocker solved. Grashof (0.1 + 0.25 < 0.2236 + 0.2062): the crank turns fully, every crank angle closes
# the loop. A site on the coupler off the pin.
FOUR_BAR = mjcf(
    '<body name="crank"><joint name="crank" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="coupler" pos=".1 0 0"><joint name="coupler" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<site name="tip" pos=".3 .1 0"/></body></body>'
    '<body name="rocker" pos=".25 0 0"><joint name="rocker" axis="0 0 1"/><geom size=".01" mass=".1"/></body>',
    tail='<equality><connect body1="coupler" body2="rocker" anchor=".1 .2 0"/></equality>'
    '<actuator><motor joint="crank"/></actuator>',
)

MODEL_KINDS = {
    "standard DH": lambda: dk.robots.iiwa14(),
    "modified DH": lambda: dk.robots.panda(),
    "PoE": lambda: dk.load_urdf(*URDF_ROBOTS["ur5"]),
    "tree": lambda: dk.load_robot(_TREE),
    "ball joints": lambda: dk.load_robot(_BALL_ARM),
    "closed loop": lambda: dk.load_robot(FOUR_BAR),
    "long chain": lambda: snake_robot(LONG + 1),
    "floating base": lambda: dk.load_robot(_TREE, floating=True),
}
"""Builders of one model of every kind: a standard-DH and a modified-DH chain, a product-of-exponentials
chain (a URDF), and ``Robot``s (their functions name frames): a small tree (two branches, one prismatic
joint), an arm with a ball joint (three entries of ``q``), a four-bar linkage (a closed loop: two of its
three hinges solved from the crank), a snake one joint longer than the unrolled pass takes (the scanned
pass) and the tree on a floating base (its root pose an argument)."""
CHAIN_KINDS = ("standard DH", "modified DH", "PoE")


@functools.cache
def model_of_kind(kind: str):
    """The model of ``kind`` (a key of :data:`MODEL_KINDS`), built once per process, not once per decorated
    test: every test of a kind gets the same object."""
    return MODEL_KINDS[kind]()


def every_model_kind(*kinds: str):
    """Decorator: run a test once per model kind (all of :data:`MODEL_KINDS`, or ``kinds``), the model
    passed as its ``model`` argument and named in the test's id, as in::

        @every_model_kind(*CHAIN_KINDS)
        def test_batch_shapes(model): ...
    """
    unknown = set(kinds) - set(MODEL_KINDS)
    if unknown:
        raise ValueError(f"kinds: expected some of {list(MODEL_KINDS)}, got {sorted(unknown)}")
    chosen = kinds or tuple(MODEL_KINDS)
    return pytest.mark.parametrize("model", [model_of_kind(k) for k in chosen], ids=list(chosen))


def frames_of(model) -> tuple[str, ...]:
    """The frame arguments of a model's functions: none for a chain, a tree's last frame for a ``Robot``
    (``dk.fk(model, q, *frames_of(model))``)."""
    return (model.frame_names[-1],) if isinstance(model, dk.Robot) else ()


def snake_robot(n: int):
    """A URDF snake of ``n`` joints (revolute about z and y in turn, every seventh prismatic), 1 cm apart."""
    links = "".join(f'<link name="l{i}"/>' for i in range(n + 1))
    joints = "".join(
        f'<joint name="j{i}" type="{"prismatic" if i % 7 == 3 else "revolute"}"><parent link="l{i}"/>'
        f'<child link="l{i + 1}"/><origin xyz="0 0 0.01" rpy="0.1 0 0"/><axis xyz="0 {i % 2} {1 - i % 2}"/>'
        f'<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        for i in range(n)
    )
    return dk.load_robot(f'<robot name="snake">{links}{joints}</robot>')


def random_q(chain, n, seed=0):
    """``(n, dof)`` float64 configurations uniform within limits (unlimited joints over one turn)."""
    lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, chain.dof))


def random_robot_q(robot, n, seed):
    """In-limit configurations; unlimited (or huge-limit) joints within one turn either way, and so are
    joints limited to one value (``<limit>`` without ``lower``/``upper``: wheels), for the kinematics."""
    lo = np.maximum(np.where(np.isfinite(robot.lower), robot.lower, -np.pi), -np.pi)
    hi = np.minimum(np.where(np.isfinite(robot.upper), robot.upper, np.pi), np.pi)
    lo, hi = np.where(lo < hi, lo, -np.pi), np.where(lo < hi, hi, np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, robot.dof))


def success_rate(success) -> float:
    """Fraction of successes, counted exactly (a float32 mean of 99 of 100 reads 0.98999995)."""
    success = np.asarray(success)
    return np.count_nonzero(success) / success.size


def jacobian_parameter_gradients(chain, field: str, seed: int) -> dict[str, np.ndarray]:
    """The gradient of a random linear function of the space Jacobian at 5 random configurations with
    respect to ``field`` of ``chain``, by each method (``"analytic"``, ``"autodiff"``).

    ``field="base"`` moves the base rigidly and differentiates in the twist ``xi`` at 0: off the rigid
    transforms the two Jacobian formulas extend differently, and only rigid bases are valid models. The
    motion is ``[R(xi_w) xi_v; 0 1]``, ``R`` the rotation of the quaternion ``(1, xi_w / 2)``: rigid
    everywhere and with ``expm([xi])``'s derivative at 0 (so the same gradient), without the second
    derivatives of ``jax.scipy.linalg.expm`` to compile."""
    import jax.numpy as jnp

    q = random_q(chain, 5, seed=seed)
    W = np.random.default_rng(seed + 1).normal(size=(5, 6, chain.dof))
    x0 = jnp.zeros(6) if field == "base" else jnp.asarray(getattr(chain, field))

    def loss(x, method):
        if field == "base":
            R = se3.rotation_from_quaternion(jnp.concatenate([jnp.ones(1), x[3:] / 2]))
            x = chain.base @ jnp.eye(4).at[:3, :3].set(R).at[:3, 3].set(x[:3])
        return jnp.sum(W * dk.jacobian(chain.replace(**{field: x}), q, "space", method=method))

    return {m: np.asarray(jax.jit(jax.grad(loss), static_argnums=1)(x0, m)) for m in ("analytic", "autodiff")}
