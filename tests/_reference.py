"""The tests' one module of shared helpers, importable from every tier (``tests/conftest.py`` puts
``tests/`` on ``sys.path``; test modules do not import each other): data paths and test robots, the
model kinds of :func:`every_model_kind`, random configurations, a time limit, random collision shapes,
MJCF snippets, fuzzing budgets, independent float64 NumPy references (forward kinematics written from
the textbook formulas, not from diffkin's kernels; pose errors; the iiwa's global configurations) and,
for the validation tier, Pinocchio's view of a robot (imported on use: the unit tier needs only
diffkin, numpy, jax, optax and hypothesis)."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from importlib import metadata

import hypothesis
import hypothesis.strategies
import jax
import numpy as np
import pytest

import diffkin as dk
from diffkin import se3

# ----------------------------------------------------------------------------------------------- paths

TESTS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TESTS)
"""The source checkout (``pyproject.toml``, ``docs/``, ``experiments/``)."""
DATA = os.path.join(TESTS, "data")
EXPERIMENTS = os.path.join(ROOT, "experiments")

# ---------------------------------------------------------------------------------------------- robots

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

# --------------------------------------------------------------------------------------- model kinds

_TREE = """<robot name="tree"><link name="root"/><link name="upper"/><link name="left"/><link name="right"/>
  <joint name="shoulder" type="revolute"><parent link="root"/><child link="upper"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2"/></joint>
  <joint name="left" type="revolute"><parent link="upper"/><child link="left"/>
    <origin xyz="0.2 0.1 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2"/></joint>
  <joint name="right" type="prismatic"><parent link="upper"/><child link="right"/>
    <origin xyz="0.2 -0.1 0" rpy="0 0 -0.4"/><axis xyz="1 0 0"/><limit lower="0" upper="0.5"/></joint>
</robot>"""

MODEL_KINDS = {
    "standard DH": lambda: dk.robots.iiwa14(),
    "modified DH": lambda: dk.robots.panda(),
    "PoE": lambda: dk.load_urdf(*URDF_ROBOTS["ur5"]),
    "tree": lambda: dk.load_robot(_TREE),
}
"""Builders of one model of every kind: a standard-DH and a modified-DH chain, a product-of-exponentials
chain (a URDF), and a small tree (a ``Robot``: two branches, one prismatic joint; its functions name
frames)."""
CHAIN_KINDS = ("standard DH", "modified DH", "PoE")


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
    return pytest.mark.parametrize("model", [MODEL_KINDS[k]() for k in chosen], ids=list(chosen))


def frames_of(model) -> tuple[str, ...]:
    """The frame arguments of a model's functions: none for a chain, a tree's last frame for a ``Robot``
    (``dk.fk(model, q, *frames_of(model))``)."""
    return (model.frame_names[-1],) if isinstance(model, dk.Robot) else ()


# ---------------------------------------------------------------------------------------------- utilities


@contextlib.contextmanager
def time_limit(seconds: float, what: str):
    """Fail (``TimeoutError``) if the block runs longer than ``seconds``: a hang fails a test instead of stalling CI.

    SIGALRM interrupts Python code only (not a running XLA computation); main thread, POSIX.
    """

    def expire(signum, frame):
        raise TimeoutError(f"{what}: still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


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


# -------------------------------------------------------------------------- random collision shapes


def rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 3, 3)`` uniformly random rotations (from unit quaternions)."""
    w, x, y, z = (rng.normal(size=(n, 4)) / 1).T
    s = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / s, x / s, y / s, z / s
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


#: the primitive kinds of ``dk.collision`` and every unordered pair of them
SHAPE_KINDS = ("sphere", "capsule", "box", "plane")
SHAPE_PAIRS = [(a, b) for i, a in enumerate(SHAPE_KINDS) for b in SHAPE_KINDS[i:]]


def random_fields(kind: str, rng: np.random.Generator, n: int, points: float = 0.1) -> dict[str, np.ndarray]:
    """Fields of ``n`` random shapes of one kind in the cube ``[-0.5, 0.5]^3`` (sizes 0.02 to 0.4 m),
    so that about a third of the pairs overlap. A fraction ``points`` of the capsules have zero length."""
    if kind == "sphere":
        return {"center": rng.uniform(-0.5, 0.5, (n, 3)), "radius": rng.uniform(0.02, 0.4, n)}
    if kind == "capsule":
        a = rng.uniform(-0.5, 0.5, (n, 3))
        b = a + rng.normal(0, 0.3, (n, 3)) * (rng.uniform(size=(n, 1)) >= points)
        return {"a": a, "b": b, "radius": rng.uniform(0.01, 0.2, n)}
    if kind == "box":
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, :3, :3], T[:, :3, 3] = rotations(rng, n), rng.uniform(-0.5, 0.5, (n, 3))
        return {"pose": T, "half_extents": rng.uniform(0.02, 0.4, (n, 3))}
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return {"normal": normal, "offset": rng.uniform(-0.3, 0.3, n)}


def random_cylinders(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Fields of ``n`` random cylinders in the cube ``[-0.5, 0.5]^3`` (radii 0.02 to 0.3 m, half lengths 0 to 0.3 m)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = rotations(rng, n), rng.uniform(-0.5, 0.5, (n, 3))
    return {"pose": T, "radius": rng.uniform(0.02, 0.3, n), "half_length": rng.uniform(0.0, 0.3, n)}


def shape(kind: str, fields: dict, dtype=None):
    """A ``dk.collision`` shape of one kind (sphere, capsule, box, cylinder, plane) from :func:`random_fields`
    (:func:`random_cylinders`)."""
    classes = {"sphere": dk.collision.Sphere, "capsule": dk.collision.Capsule, "box": dk.collision.Box}
    classes["cylinder"] = dk.collision.Cylinder
    return classes.get(kind, dk.collision.Plane)(**{k: jax.numpy.asarray(v, dtype) for k, v in fields.items()})


def coal_shape(coal, kind: str, f: dict, i: int):
    """The coal geometry and placement of shape ``i`` of :func:`random_fields` (:func:`random_cylinders`)."""
    if kind == "cylinder":
        T = f["pose"][i]
        return coal.Cylinder(f["radius"][i], 2 * f["half_length"][i]), coal.Transform3s(T[:3, :3], T[:3, 3])
    if kind == "sphere":
        return coal.Sphere(f["radius"][i]), coal.Transform3s(np.eye(3), f["center"][i])
    if kind == "capsule":
        a, b = f["a"][i], f["b"][i]
        axis = b - a
        length = float(np.linalg.norm(axis))
        R = np.eye(3)
        if length > 0:
            z = axis / length
            x = np.cross([1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0], z)
            x /= np.linalg.norm(x)
            R = np.column_stack([x, np.cross(z, x), z])
        return coal.Capsule(f["radius"][i], length), coal.Transform3s(R, 0.5 * (a + b))
    if kind == "box":
        T = f["pose"][i]
        return coal.Box(*(2 * f["half_extents"][i])), coal.Transform3s(T[:3, :3], T[:3, 3])
    return coal.Halfspace(f["normal"][i], f["offset"][i]), coal.Transform3s()


# ------------------------------------------------------------------------------ a toy arm's collision geometry

TOY_COLLISION_URDF = """<robot name="toy">
  <link name="base"><collision><geometry><box size="0.4 0.4 0.1"/></geometry></collision></link>
  <link name="upper">
    <collision><origin xyz="0 0 0.25"/><geometry><cylinder radius="0.05" length="0.5"/></geometry></collision>
    <collision><origin xyz="0 0 0.5"/><geometry><sphere radius="0.07"/></geometry></collision>
  </link>
  <link name="lower"><collision><origin xyz="0 0 0.2" rpy="0 1.5707963267948966 0"/>
    <geometry><capsule radius="0.04" length="0.4"/></geometry></collision></link>
  <link name="hand"><collision><geometry><sphere radius="0.06"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="fixed" type="fixed"><parent link="lower"/><child link="hand"/><origin xyz="0 0 0.4"/></joint>
</robot>"""


def toy_robot():
    """The toy arm of :data:`TOY_COLLISION_URDF` and its collision geometry."""
    robot = dk.load_robot(TOY_COLLISION_URDF)
    return robot, dk.collision.load(TOY_COLLISION_URDF, robot)


# ------------------------------------------------------------------------------------------- MJCF snippets

HEAD = '<compiler boundmass="1" boundinertia="0.1"/>'  # masses MuJoCo needs; no kinematic effect


def mjcf(body: str, head: str = "", tail: str = "") -> str:
    """A ``<mujoco>`` model around a worldbody's contents."""
    return f"<mujoco model='m'>{HEAD}{head}<worldbody>{body}</worldbody>{tail}</mujoco>"


# Two planar arms from the ground, welded at their tips: 3 + 2 hinges, 3 planar equations; a1 and b1 driven.
WELDED_ARMS = mjcf(
    '<body name="a1"><joint name="a1" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="a2" pos=".3 0 0"><joint name="a2" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="a3" pos=".3 0 0"><joint name="a3" axis="0 0 1"/><geom size=".01" mass=".1"/></body></body></body>'
    '<body name="b1" pos=".8 0 0"><joint name="b1" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="b2" pos="-.2 .1 0" euler="0 0 30"><joint name="b2" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    "</body></body>",
    tail='<equality><weld body1="a3" body2="b2"{relpose}/></equality>'
    '<actuator><motor joint="a1"/><motor joint="b1"/></actuator>',
)


ARM = (
    '<geom size=".01"/><joint name="a" axis="1 2 3" pos=".1 0 .2" range="-90 45"/>'
    '<body name="b" pos="0 .3 0" {o}><joint name="b" axis="0 1 0" range="-1 1"/><site name="s" pos=".1 .2 .3" {o}/>'
    "</body>"
)


def nested_mjcf(kind: str, depth: int) -> str:
    """A model nested ``depth`` deep in ``kind``.

    ``bodies``: a chain of bodies (each ``pos="0 0 .01" euler="0 0 3"`` and a hinge, a site ``tip``
    in the last), then a top-level body ``side``. ``frames``: ``<frame>``s with that offset around a
    site ``tip`` and a body ``c``. ``default_classes``: classes ``c0 ... c{depth-1}`` (``c0`` sets
    the joint axis to y, ``c{depth // 2}`` a range of -30..60 degrees) used by the joints ``j``
    (innermost class, as ``childclass``) and ``k`` (the class above ``c{depth // 2}``).
    """
    step = 'pos="0 0 .01" euler="0 0 3"'
    head = ""
    if kind == "bodies":
        body = "".join(f'<body name="b{k}" {step}><joint name="j{k}" axis="1 0 0" range="-1 1"/>' for k in range(depth))
        body += '<site name="tip" pos="0 0 .5"/>' + "</body>" * depth + '<body name="side"><joint name="s"/></body>'
    elif kind == "frames":
        body = (
            '<body name="b"><joint name="j" axis="1 0 0"/>'
            + f"<frame {step}>" * depth
            + '<site name="tip"/><body name="c"><joint name="k" axis="0 1 0"/></body>'
            + "</frame>" * depth
            + "</body>"
        )
    else:
        joint = {0: '<joint axis="0 1 0"/>', depth // 2: '<joint range="-30 60"/>'}
        head = "<default>" + "".join(f'<default class="c{k}">{joint.get(k, "")}' for k in range(depth))
        head += "</default>" * (depth + 1)
        body = (
            f'<body name="b" childclass="c{depth - 1}"><joint name="j"/>'
            f'<body name="c"><joint name="k" class="c{depth // 2 - 1}"/></body></body>'
        )
    return mjcf(body, head)


# -------------------------------------------------------------------------------------- fuzzing budgets

EXAMPLES = int(os.environ.get("DIFFKIN_FUZZ_EXAMPLES", "25"))
FUZZ = hypothesis.settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize="DIFFKIN_FUZZ_EXAMPLES" not in os.environ,
    suppress_health_check=[hypothesis.HealthCheck.too_slow, hypothesis.HealthCheck.data_too_large],
)
"""Property tests: ``DIFFKIN_FUZZ_EXAMPLES`` examples each (25, derandomized, unless set)."""
# MJCF examples run under a SIGALRM limit (a hang, such as an include bomb, fails the test instead of
# stalling CI) and a hypothesis deadline (an example slower than that is reported).
MJCF_FUZZ = hypothesis.settings(FUZZ, deadline=5000)
MJCF_TIME_LIMIT = 20.0


def finite_floats(lo, hi):
    return hypothesis.strategies.floats(lo, hi, allow_nan=False, allow_infinity=False)


def number_text(values) -> str:
    """Numbers as an XML attribute's text: ``"0.1 2.0 -3.5"``."""
    return " ".join(repr(float(v)) for v in values)


# ------------------------------------------------------------------------------------ NumPy references

ALL_GC = np.array([[g2, g4, g6] for g2 in (1, -1) for g4 in (1, -1) for g6 in (1, -1)], dtype=np.float64)
"""``(8, 3)``: the eight global configurations ``(gc2, gc4, gc6)`` of an SRS arm."""


def _rot(axis: str, angle: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` rotations by ``angle`` about the x or z axis."""
    c, s = np.cos(angle), np.sin(angle)
    M = np.zeros(np.shape(angle) + (4, 4))
    M[..., 3, 3] = 1.0
    i, j, k = (0, 1, 2) if axis == "z" else (1, 2, 0)
    M[..., i, i], M[..., i, j], M[..., j, i], M[..., j, j], M[..., k, k] = c, -s, s, c, 1.0
    return M


def _trans(axis: str, dist: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` translations by ``dist`` along the x or z axis."""
    M = np.broadcast_to(np.eye(4), np.shape(dist) + (4, 4)).copy()
    M[..., "xyz".index(axis), 3] = dist
    return M


def dh_fk(chain, q) -> np.ndarray:
    """FK of a ``DHChain`` as the product of its DH matrices: ``(..., dof) -> (..., 4, 4)`` poses ``T_base_ee``.

    Standard DH multiplies ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` per joint, modified DH
    ``Rx(alpha) Tx(a) Rz(theta) Tz(d)``, between ``chain.base`` and ``chain.tool``.
    """
    q = np.asarray(q, dtype=np.float64)
    batch = q.shape[:-1]
    a, alpha, d, off = (np.asarray(v, dtype=np.float64) for v in (chain.a, chain.alpha, chain.d, chain.theta_offset))
    T = np.broadcast_to(np.asarray(chain.base, dtype=np.float64), batch + (4, 4)).copy()
    for i, kind in enumerate(chain.joint_types):
        theta = q[..., i] + off[i] if kind == "R" else np.full(batch, off[i])
        di = d[i] + q[..., i] if kind == "P" else np.full(batch, d[i])
        alpha_i, a_i = np.full(batch, alpha[i]), np.full(batch, a[i])
        if chain.modified:
            A = _rot("x", alpha_i) @ _trans("x", a_i) @ _rot("z", theta) @ _trans("z", di)
        else:
            A = _rot("z", theta) @ _trans("z", di) @ _trans("x", a_i) @ _rot("x", alpha_i)
        T = T @ A
    return T @ np.asarray(chain.tool, dtype=np.float64)


def _screw_exp(S: np.ndarray, kind: str, theta: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` ``exp([S] theta)`` of a unit screw ``S = [v; w]`` by Rodrigues' formula (``theta (...)``)."""
    v, w, t = S[:3], S[3:], theta[..., None, None]
    E = np.broadcast_to(np.eye(4), theta.shape + (4, 4)).copy()
    if kind == "R":
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        E[..., :3, :3] = np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K
        E[..., :3, 3] = (np.eye(3) * t + (1 - np.cos(t)) * K + (t - np.sin(t)) * K @ K) @ v
    else:
        E[..., :3, 3] = v * theta[..., None]
    return E


def poe_fk(chain, q) -> np.ndarray:
    """FK of a ``PoEChain``, ``exp([S1] q1) ... exp([Sn] qn) M`` by Rodrigues' formula: ``(..., dof) -> (..., 4, 4)``
    poses ``T_base_ee``."""
    q = np.asarray(q, dtype=np.float64)
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i, S in enumerate(np.asarray(chain.screws, np.float64)):
        T = T @ _screw_exp(S, chain.joint_types[i], q[..., i])
    return T @ np.asarray(chain.home, np.float64)


def robot_poses(robot, q) -> np.ndarray:
    """``(nf, 4, 4)`` world poses of a fixed-root ``Robot``'s frames at ``q (dof,)``, from its arrays by the
    tree's definition: ``T_body[j + 1] = T_body[parents[j]] @ joint_poses[j] @ exp([screws[j]] theta_j)``,
    ``theta_j = multipliers[j] q[sources[j]] + offsets[j]``, each frame at ``frame_poses[f]`` in its body."""
    q = np.asarray(q, dtype=np.float64)
    arrays = (robot.joint_poses, robot.screws, robot.multipliers, robot.offsets, robot.frame_poses)
    joint_poses, screws, multipliers, offsets, frame_poses = (np.asarray(a, np.float64) for a in arrays)
    bodies = [np.eye(4)]
    for j, parent in enumerate(robot.parents):
        theta = np.asarray(multipliers[j] * q[robot.sources[j]] + offsets[j])
        if robot.joint_types[j] != "B":
            bodies.append(bodies[parent] @ joint_poses[j] @ _screw_exp(screws[j], robot.joint_types[j], theta))
        elif robot.joint_types[: j + 1].count("B") % 3 == 1:  # the first of a ball joint's three: all three bodies
            T = bodies[parent] @ joint_poses[j]
            bodies += [T, T, T @ ball_motion(screws[j : j + 3], q[robot.sources[j] : robot.sources[j] + 3])]
    return np.stack([bodies[b] @ frame_poses[f] for f, b in enumerate(robot.frame_bodies)])


def rodrigues(r) -> np.ndarray:
    """``(3, 3)`` rotation of the rotation vector ``r``: ``cos t I + sin t [a] + (1 - cos t) a a^T``."""
    r = np.asarray(r, np.float64)
    t = np.linalg.norm(r)
    if t == 0:
        return np.eye(3)
    a = r / t
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.cos(t) * np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * np.outer(a, a)


def ball_motion(screws, r) -> np.ndarray:
    """``(4, 4)`` motion of a ball joint with screws ``[c x e_k; e_k]`` ``(3, 6)`` at rotation vector ``r``
    (in the axes ``e_k``): a rotation about the centre ``c``, read off the screws by least squares."""
    screws = np.asarray(screws, np.float64)
    E = screws[:, 3:]  # rows e_k
    K = np.concatenate([-np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]]) for e in E])
    c = np.linalg.lstsq(K, screws[:, :3].reshape(-1), rcond=None)[0]  # c x e_k = -[e_k] c
    T = np.eye(4)
    T[:3, :3] = rodrigues(E.T @ np.asarray(r, np.float64))
    T[:3, 3] = c - T[:3, :3] @ c
    return T


def fk(chain, q) -> np.ndarray:
    """:func:`dh_fk` or :func:`poe_fk`, whichever fits the chain."""
    return dh_fk(chain, q) if isinstance(chain, dk.DHChain) else poe_fk(chain, q)


def rotation_angle(R) -> np.ndarray:
    """``(..., 3, 3) -> (...,)``: angle of rotations, ``atan2(|vee(R)|, (tr R - 1) / 2)`` (accurate near 0 and pi)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.arctan2(np.linalg.norm(skew, axis=-1) / 2, cos)


def pose_errors(T, T_ref) -> tuple[np.ndarray, np.ndarray]:
    """Position errors (m) and rotation-angle errors (rad) between ``(..., 4, 4)`` poses, each ``(...,)``."""
    T, T_ref = np.asarray(T, dtype=np.float64), np.asarray(T_ref, dtype=np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - T_ref[..., :3, 3], axis=-1)
    return pos, rotation_angle(np.swapaxes(T_ref[..., :3, :3], -1, -2) @ T[..., :3, :3])


def pose(R, p) -> np.ndarray:
    """``(4, 4)`` pose of a rotation ``(3, 3)`` and a position ``(3,)``."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def frame_errors(T, targets):
    """Position (m) and rotation (rad) errors ``(n, k)`` between poses ``T`` and ``targets`` (float64)."""
    targets = np.asarray(targets, np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - targets[..., :3, 3], axis=-1)
    with jax.enable_x64(True):
        rot = np.asarray(se3.rotation_angle(targets[..., :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2)))
    return pos, rot


# ------------------------------------------------------------------ Pinocchio (the validation install)


def pin_q(model, robot, q):
    """Pinocchio's configuration for our ``q``: mimic joints set from their sources (Pinocchio's
    default URDF reader keeps them as independent joints)."""
    import pinocchio as pin

    values = dict(zip(robot.joint_names, q, strict=True))
    for name, (source, m, o) in robot.mimic.items():
        values[name] = m * values[source] + o
    qp = pin.neutral(model)
    for name, value in values.items():
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:  # continuous joints: (cos, sin)
            qp[joint.idx_q : joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            qp[joint.idx_q] = value
    return qp


def pin_poses(path, robot, q, names, base=None):
    """``(n, k, 4, 4)`` world poses of frames ``names`` by Pinocchio (float64), the root at ``base``."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    out = np.zeros((len(q), len(names), 4, 4))
    for i in range(len(q)):
        pin.framesForwardKinematics(model, data, pin_q(model, robot, np.asarray(q[i], np.float64)))
        for k, name in enumerate(names):
            M = data.oMf[model.getFrameId(name, pin.BODY)].homogeneous
            out[i, k] = M if base is None else np.asarray(base[i], np.float64) @ M
    return out


# ------------------------------------------------------------------------------ collision scenes, the CLI

#: an arm of capsules and a ball hand (URDF collision geometry), and a scene of a turned box and a floor
#: (``dk.collision.load_scene``); ``SCENE_FILE`` the documented example scene
CAPSULE_ARM = """<robot name="arm">
  <link name="base"/>
  <link name="l1"><collision><origin xyz="0 0 0.2"/><geometry><capsule radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="l2"><collision><origin xyz="0 0 0.2"/><geometry><capsule radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="l3"><collision><origin xyz="0 0 0.15"/><geometry><capsule radius="0.03" length="0.3"/></geometry>
    </collision></link>
  <link name="hand"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2.8" upper="2.8"/></joint>
  <joint name="tip" type="fixed"><parent link="l3"/><child link="hand"/><origin xyz="0 0 0.3"/></joint>
</robot>"""
BOX_CENTER = [0.45, -0.1, 0.25]
SCENE = {
    "margin": 0.02,
    "boxes": [{"position": BOX_CENTER, "quaternion": [0.9800666, 0, 0, 0.1986693], "half_extents": [0.12, 0.08, 0.1]}],
    "planes": [{"normal": [0, 0, 2], "offset": -0.2}],  # z <= -0.1, the normal's length divided out
}
SCENE_FILE = os.path.join(ROOT, "docs", "scene.json")

#: ``python -m diffkin`` with Ctrl-C handled as usual even when started from a shell's background
#: job (which inherits SIGINT ignored): ``[*INTERRUPTIBLE, "demo", ...]``.
INTERRUPTIBLE = [
    sys.executable,
    "-c",
    "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "sys.argv = sys.argv[1:]; runpy.run_module('diffkin', run_name='__main__', alter_sys=True)",
    "diffkin",
]
