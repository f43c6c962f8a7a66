"""Forward kinematics against textbook closed forms, the NumPy references and identities (against Pinocchio
and pytorch-kinematics: ``tests/validation/test_fk_validation.py``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import BUILTIN, CHAIN_KINDS, URDF_ROBOTS, every_model_kind, frames_of, model_of_kind, random_q
from _reference import dh_fk, poe_fk

import diffkin as dk
from diffkin import se3

N = 200


@pytest.mark.parametrize("name", BUILTIN)
def test_dh_product_equals_to_poe(name):
    chain = getattr(dk.robots, name)()
    poe = dk.to_poe(chain)
    q = random_q(chain, N, seed=3)
    np.testing.assert_allclose(dk.fk(poe, q), dk.fk(chain, q), atol=1e-12)
    np.testing.assert_allclose(dk.link_poses(poe, q)[:, 1:], dk.link_poses(chain, q)[:, 1:], atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa7", "iiwa14"])
def test_shipped_urdf_equals_dh_model(name):
    chain = getattr(dk.robots, name)()
    urdf = dk.load_urdf(dk.robots.urdf_path(name))
    q = random_q(chain, N, seed=4)
    np.testing.assert_allclose(dk.fk(urdf, q), dk.fk(chain, q), atol=1e-12)
    np.testing.assert_array_equal(urdf.lower, chain.lower)
    # URDF links 2, 4, 6 sit at the shoulder, elbow and wrist centres, as the DH frames 2, 4, 6 do.
    for i in (2, 4, 6):
        np.testing.assert_allclose(
            dk.link_poses(urdf, q)[:, i, :3, 3], dk.link_poses(chain, q)[:, i, :3, 3], atol=1e-12
        )


def test_ur5_dh_equals_its_ros_urdf(urdf_chains):
    """UR's DH base frame is the URDF's ``base`` link (``base_link`` turned by pi about z); the flange is ``tool0``."""
    q = random_q(dk.robots.ur5(), N, seed=5)
    Rz_pi = np.diag([-1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(Rz_pi @ np.asarray(dk.fk(urdf_chains["ur5"], q)), dk.fk(dk.robots.ur5(), q), atol=1e-9)


def test_panda_dh_equals_franka_urdf(urdf_chains):
    q = random_q(dk.robots.panda(), N, seed=6)
    np.testing.assert_allclose(dk.fk(urdf_chains["panda"], q), dk.fk(dk.robots.panda(), q), atol=1e-12)


def test_iiwa_published_positions():
    q = np.full(7, 0.5)
    np.testing.assert_allclose(dk.fk(dk.robots.iiwa14(), q)[:3, 3], [0.264615, 0.065211, 1.234181], atol=1e-6)
    np.testing.assert_allclose(dk.fk(dk.robots.iiwa7(), q)[:3, 3], [0.256201, 0.060614, 1.196629], atol=1e-6)


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_planar_2r_textbook():
    a1, a2 = 0.7, 0.4
    q = random_q(dk.robots.planar([a1, a2]), N, seed=7)
    T = np.asarray(dk.fk(dk.robots.planar([a1, a2]), q))
    t1, t2 = q[:, 0], q[:, 1]
    np.testing.assert_allclose(T[:, 0, 3], a1 * np.cos(t1) + a2 * np.cos(t1 + t2), atol=1e-14)
    np.testing.assert_allclose(T[:, 1, 3], a1 * np.sin(t1) + a2 * np.sin(t1 + t2), atol=1e-14)
    np.testing.assert_allclose(T[:, 2, 3], 0.0, atol=0)
    np.testing.assert_allclose(T[:, :3, :3], np.stack([_rz(t) for t in t1 + t2]), atol=1e-14)


def test_rpr_arm_with_a_prismatic_joint():
    h, L = 0.5, 0.3
    chain = dk.DHChain.from_table(
        [[0, np.pi / 2, h, 0], [0, 0, 0.0, 0], [L, 0, 0, 0]], "RPR", lower=[-3, 0.1, -3], upper=[3, 0.9, 3]
    )
    q = random_q(chain, N, seed=8)
    q1, q2, q3 = q.T
    expected = (
        np.array([0, 0, h])[None]
        + q2[:, None] * np.stack([np.sin(q1), -np.cos(q1), 0 * q1], 1)
        + L * np.cos(q3)[:, None] * np.stack([np.cos(q1), np.sin(q1), 0 * q1], 1)
        + L * np.sin(q3)[:, None] * np.array([0, 0, 1.0])[None]
    )
    np.testing.assert_allclose(np.asarray(dk.fk(chain, q))[:, :3, 3], expected, atol=1e-14)


def test_scara_rrrp():
    a1, a2, h = 0.4, 0.3, 0.6
    chain = dk.DHChain.from_table(
        [[a1, 0, h, 0], [a2, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]],
        "RRRP",
        lower=[-2, -2, -3, -0.2],
        upper=[2, 2, 3, 0.0],
    )
    q = random_q(chain, N, seed=9)
    T = np.asarray(dk.fk(chain, q))
    t1, t2, t3, d4 = q.T
    np.testing.assert_allclose(T[:, 0, 3], a1 * np.cos(t1) + a2 * np.cos(t1 + t2), atol=1e-14)
    np.testing.assert_allclose(T[:, 1, 3], a1 * np.sin(t1) + a2 * np.sin(t1 + t2), atol=1e-14)
    np.testing.assert_allclose(T[:, 2, 3], h + d4, atol=1e-14)
    np.testing.assert_allclose(T[:, :3, :3], np.stack([_rz(t) for t in t1 + t2 + t3]), atol=1e-14)


def _modified_equivalent(chain):
    """The modified-DH description of a standard-DH chain (Tx(a) Rx(alpha) shifted to the next row)."""
    a, alpha = np.asarray(chain.a), np.asarray(chain.alpha)
    table = np.stack([np.r_[0.0, a[:-1]], np.r_[0.0, alpha[:-1]], chain.d, chain.theta_offset], 1)
    c, s = np.cos(alpha[-1]), np.sin(alpha[-1])
    last = np.array([[1, 0, 0, a[-1]], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])
    return dk.DHChain.from_table(
        table, chain.joint_types, modified=True, base=chain.base, tool=last @ np.asarray(chain.tool)
    )


@pytest.mark.parametrize("name", ["iiwa14", "ur5", "puma560"])
def test_modified_and_standard_descriptions_agree(name):
    chain = getattr(dk.robots, name)()
    q = random_q(chain, N, seed=10)
    np.testing.assert_allclose(dk.fk(_modified_equivalent(chain), q), dk.fk(chain, q), atol=1e-12)


def test_planar_3r_in_both_conventions():
    a = [0.5, 0.4, 0.2]
    standard = dk.robots.planar(a)
    tool = np.eye(4)
    tool[0, 3] = a[2]
    modified = dk.DHChain.from_table([[0, 0, 0, 0], [a[0], 0, 0, 0], [a[1], 0, 0, 0]], modified=True, tool=tool)
    q = random_q(standard, N, seed=11)
    np.testing.assert_allclose(dk.fk(modified, q), dk.fk(standard, q), atol=1e-14)


def test_base_and_tool_transforms_apply():
    chain = dk.robots.iiwa14()
    base, tool = np.eye(4), np.eye(4)
    base[:3, :3], base[:3, 3] = _rz(0.3), [0.1, -0.2, 0.3]
    tool[:3, :3], tool[:3, 3] = _rz(-1.1).T, [0.0, 0.05, 0.1]
    moved = chain.replace(base=jnp.asarray(base), tool=jnp.asarray(tool))
    q = random_q(chain, N, seed=12)
    np.testing.assert_allclose(dk.fk(moved, q), base @ np.asarray(dk.fk(chain, q)) @ tool, atol=1e-14)


# --- batching, transformations, dtypes: every model kind, or every kind of chain (standard and modified DH, PoE) ---


@every_model_kind()
@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batch_shapes(model, shape):
    """Every kind (a robot at its last frame): leading batch dimensions of ``q``, each row its own pose."""
    frames = frames_of(model)
    q = random_q(model, int(np.prod(shape)), seed=13).reshape(shape + (model.dof,))
    T = dk.fk(model, q, *frames)
    assert T.shape == shape + (4, 4)
    poses = len(model.frame_names) if isinstance(model, dk.Robot) else model.dof + 1
    assert dk.link_poses(model, q).shape == shape + (poses, 4, 4)
    flat = np.stack([np.asarray(dk.fk(model, qi, *frames)) for qi in q.reshape(-1, model.dof)])
    np.testing.assert_allclose(np.asarray(T).reshape(-1, 4, 4), flat, atol=1e-15)


@every_model_kind(*CHAIN_KINDS)
def test_jit_vmap_grad_match_eager(model):
    chain = model
    q = jnp.asarray(random_q(chain, 8, seed=14))

    def per_row(x):
        return jnp.sum(dk.fk(chain, x)[..., :3, 3] ** 2, -1)

    def loss(x):
        return jnp.sum(per_row(x))

    # the chain closed over by jit: its poses and gradient in one program (one compile)
    T_jit, g_jit = jax.jit(lambda x: (dk.fk(chain, x), jax.grad(loss)(x)))(q)
    eager = dk.fk(chain, q)
    np.testing.assert_allclose(T_jit, eager, atol=1e-15)
    np.testing.assert_allclose(jax.jit(dk.fk)(chain, q), eager, atol=1e-14)  # traced chain: general path
    np.testing.assert_allclose(jax.vmap(lambda x: dk.fk(chain, x))(q), eager, atol=1e-15)
    np.testing.assert_allclose(jax.vmap(dk.link_poses, (None, 0))(chain, q), dk.link_poses(chain, q), atol=1e-15)
    g = jax.grad(loss)(q)
    np.testing.assert_allclose(g_jit, g, atol=1e-13)
    h = 1e-6  # rows are independent: a shift of column i gives each row's partial derivative
    steps = h * np.eye(chain.dof)[:, None]  # (dof, 1, dof): column i shifted, every row, in one eager call
    shifted = per_row(jnp.concatenate([q + steps, q - steps]).reshape(-1, chain.dof)).reshape(2, chain.dof, -1)
    fd = np.stack([(shifted[0, i] - shifted[1, i]) / (2 * h) for i in range(chain.dof)], -1)
    np.testing.assert_allclose(g, fd, atol=1e-7)
    jf = jax.jacfwd(lambda x: dk.fk(chain, x))(q[0])
    assert jf.shape == (4, 4, chain.dof) and np.all(np.isfinite(jf))


@every_model_kind()
def test_float32_close_to_float64(model):
    """Every kind (a robot at its last frame), float32 against float64."""
    frames = frames_of(model)
    q = random_q(model, 100, seed=15)
    T32 = jax.jit(lambda x: dk.fk(model, x, *frames))(jnp.asarray(q, jnp.float32))
    assert T32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(T32, np.float64), dk.fk(model, q, *frames), atol=1e-5)


T_WORLD_ROOT = np.array([[0.0, -1.0, 0.0, 0.3], [0.6, 0.0, -0.8, -0.2], [0.8, 0.0, 0.6, 1.1], [0.0, 0.0, 0.0, 1.0]])
"""Where the floating kind's root is placed (a rotation about x then z, and a shift)."""


T_WORLD_ROOT = np.array([[0.0, -1.0, 0.0, 0.3], [0.6, 0.0, -0.8, -0.2], [0.8, 0.0, 0.6, 1.1], [0.0, 0.0, 0.0, 1.0]])
"""Where a floating robot's root is placed (a rotation about x, then one about z, and a shift)."""


def _placed(model) -> tuple[dict, dict]:
    """The root keywords of a model's functions: a floating robot at ``T_WORLD_ROOT`` (``base``), its Jacobians
    with the root's six columns (``include_base``); none for the other kinds."""
    if not (isinstance(model, dk.Robot) and model.floating):
        return {}, {}
    return {"base": T_WORLD_ROOT}, {"base": T_WORLD_ROOT, "include_base": True}


@every_model_kind()
def test_every_kind_compiled_equals_eager(model):
    """fk, link_poses and the analytic Jacobian of every model kind (a tree at its last frame, a floating robot
    placed by ``_placed``): compiled equals eager."""
    frames, (base, root) = frames_of(model), _placed(model)
    q = random_q(model, 4, seed=16)

    def kinematics(q):
        return dk.fk(model, q, *frames, **base), dk.link_poses(model, q, **base), dk.jacobian(model, q, *frames, **root)

    eager, compiled = kinematics(q), jax.jit(kinematics)(q)
    for a, b in zip(eager, compiled, strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-13)
    assert eager[2].shape == q.shape[:-1] + (6, 6 * bool(root) + model.dof)


@every_model_kind()
def test_every_kind_autodiff_jacobian_equals_analytic(model):
    """The autodiff Jacobian, eager and compiled, equals the analytic one."""
    frames, (_, root) = frames_of(model), _placed(model)
    q = random_q(model, 4, seed=16)

    def jacobians(q):
        return tuple(dk.jacobian(model, q, *frames, method=m, **root) for m in ("analytic", "autodiff"))

    (analytic, autodiff), compiled = jacobians(q), jax.jit(jacobians)(q)[1]
    np.testing.assert_allclose(np.asarray(autodiff), np.asarray(analytic), rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.asarray(compiled), np.asarray(autodiff), rtol=0, atol=1e-13)


def test_the_autodiff_jacobian_of_a_long_chain_scans_once():
    """A scanned pass's autodiff Jacobian is one forward-mode scan, every joint's unit tangent vmapped, as FK is
    one scan: it was one scan per joint, each compiled (the 33-joint snake's first call 6.7 s, now 0.5 s;
    issue 56)."""
    model = model_of_kind("long chain")
    q = jnp.zeros((2, model.dof))
    fk, autodiff = (
        str(jax.make_jaxpr(f)(q)).count(" scan[")
        for f in (
            lambda q: dk.fk(model, q, *frames_of(model)),
            lambda q: dk.jacobian(model, q, *frames_of(model), method="autodiff"),
        )
    )
    assert model.scanned and fk == 1 and autodiff == 1


def test_fk_at_zero_angle_is_exact_and_gradient_finite():
    chain = dk.load_urdf(*URDF_ROBOTS["iiwa14"])
    q0 = jnp.zeros(7)
    # exp(0) = I exactly: the traced (unfolded) product returns M bit for bit; the folded one snaps
    # constants within 1e-12 of 0 or 1 to exact values.
    np.testing.assert_array_equal(jax.jit(dk.fk)(chain, q0), chain.home)
    np.testing.assert_allclose(dk.fk(chain, q0), chain.home, atol=1e-15)
    g = jax.grad(lambda c: jnp.sum(dk.fk(c, q0)))(chain)
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree_util.tree_leaves(g))


def test_numpy_reference_matches_modified_and_prismatic_chains():
    """The tests' NumPy DH product (``_reference.dh_fk``) on chains the robots do not cover."""
    for chain in (
        dk.robots.panda(),
        dk.DHChain.from_table([[0.1, 0.3, 0.2, 0.1], [0.2, -0.5, 0.1, 0.0]], "RP", modified=True),
    ):
        q = np.random.default_rng(0).uniform(-1, 1, (5, chain.dof))
        np.testing.assert_allclose(dh_fk(chain, q), np.asarray(dk.fk(chain, q)), atol=1e-12)
        np.testing.assert_allclose(poe_fk(dk.to_poe(chain), q), np.asarray(dk.fk(chain, q)), atol=1e-12)


def _dh_matrix(a, alpha, d, theta, modified):
    """One DH link as a numpy matrix (the reference of the long-chain test)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    if modified:  # Rx(alpha) Tx(a) Rz(theta) Tz(d)
        return np.array(
            [[ct, -st, 0, a], [st * ca, ct * ca, -sa, -sa * d], [st * sa, ct * sa, ca, ca * d], [0, 0, 0, 1]]
        )
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])


@pytest.mark.parametrize("modified", [False, True])
def test_long_chain_against_numpy(modified):
    """20 joints (the forward pass is materialised after joints 8 and 16): poses, the Jacobian, gradients."""
    rng = np.random.default_rng(40)
    table = np.stack(
        [rng.uniform(0, 0.3, 20), rng.uniform(-2, 2, 20), rng.uniform(0, 0.3, 20), rng.uniform(-1, 1, 20)], axis=1
    )
    types = "RRRRRRRRP" + "R" * 11  # a prismatic joint right after the first materialised pose
    chain = dk.DHChain.from_table(table, types, modified=modified, lower=-np.ones(20), upper=np.ones(20))
    q = random_q(chain, 4, seed=41)

    def reference(q1, table=table):
        Ts = [np.eye(4)]
        for (a, alpha, d, off), kind, x in zip(table, types, q1, strict=True):
            theta, d = (x + off, d) if kind == "R" else (off, d + x)
            Ts.append(Ts[-1] @ _dh_matrix(a, alpha, d, theta, modified))
        return np.stack(Ts)

    ref = np.stack([reference(qk) for qk in q])
    np.testing.assert_allclose(dk.link_poses(chain, q), ref, atol=1e-12)
    np.testing.assert_allclose(dk.fk(dk.to_poe(chain), q), ref[:, -1], atol=1e-12)
    # World Jacobian against central differences of the reference.
    J, h = np.asarray(dk.jacobian(chain, q)), 1e-6
    for i in range(20):
        dq = np.zeros(20)
        dq[i] = h
        dT = (np.stack([reference(qk + dq)[-1] for qk in q]) - np.stack([reference(qk - dq)[-1] for qk in q])) / (2 * h)
        w = se3.vee(dT[:, :3, :3] @ np.swapaxes(ref[:, -1, :3, :3], 1, 2))
        np.testing.assert_allclose(J[:, :3, i], dT[:, :3, 3], atol=1e-8)
        np.testing.assert_allclose(J[:, 3:, i], w, atol=1e-8)
    # Parameter gradients flow through the materialised poses.
    W = rng.normal(size=(4, 4, 4))
    g = jax.grad(lambda a: jnp.sum(W * dk.fk(chain.replace(a=a), q)))(chain.a)
    step = h * np.eye(20)
    fd = [
        (
            np.sum(W * np.stack([reference(qk, np.c_[table[:, 0] + step[k], table[:, 1:]])[-1] for qk in q]))
            - np.sum(W * np.stack([reference(qk, np.c_[table[:, 0] - step[k], table[:, 1:]])[-1] for qk in q]))
        )
        / (2 * h)
        for k in range(20)
    ]
    np.testing.assert_allclose(g, fd, atol=1e-7)


@pytest.mark.parametrize("kind", ["tree", "floating base", "panda", "g1"])
def test_the_pass_by_depth_equals_the_unrolled_pass(kind):
    """The forward pass of a tree by depth (``Robot.forward_by_depth``: the IK's Jacobians of a whole robot read
    it) gives the unrolled pass's frame poses, their columns moved to the frames (a locked joint's zero, a solved
    root's six last) and the centre of mass's columns (float64): a prismatic joint and tilted joint frames (the
    tree), a moved root, a mimic joint (the Panda's fingers), a humanoid (joints about every coordinate axis)."""
    import os

    from _models import ERD, PANDA

    from diffkin import _rigid as rg

    if kind == "g1":
        if ERD is None:
            pytest.skip("example-robot-data is not installed")
        robot = dk.load_robot(os.path.join(ERD, "g1_description/urdf/g1_29dof_rev_1_0.urdf"))
    else:
        robot = dk.load_robot(PANDA) if kind == "panda" else model_of_kind(kind)
    assert robot.by_depth
    rng = np.random.default_rng(1)
    P = 7
    q = jnp.asarray(rng.uniform(-1.0, 1.0, (robot.dof, P)))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R = R * np.sign(np.linalg.det(R))
    p = rng.normal(size=3)
    base = jnp.asarray(np.concatenate([R, p[:, None]], axis=1))[..., None] * jnp.ones(P)  # (3, 4, P)
    root = rg.Rigid(tuple(tuple(base[i, j] for j in range(3)) for i in range(3)), tuple(base[i, 3] for i in range(3)))
    locked = tuple(i == 1 for i in range(robot.dof))
    unrolled, levels = robot.forward(list(q), root), robot.forward_by_depth(q, base)
    zero = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    def dense(columns):  # (k, n, P) from entries per column
        return np.stack([np.stack([np.broadcast_to(e, (P,)) for e in c], axis=0) for c in columns], axis=1)

    for f in range(len(robot.frame_names)):
        T, T_ref = levels.pose(f), unrolled.pose(f)
        for a, b in zip(rg.leaves(T), rg.leaves(T_ref), strict=True):
            np.testing.assert_allclose(np.broadcast_to(a, (P,)), np.broadcast_to(b, (P,)), rtol=0, atol=1e-12)
        columns = [zero if lock else c for lock, c in zip(locked, unrolled.columns(f), strict=True)]
        moved = rg.world_from_space(columns + rg.root_screws(root), T_ref.p)
        expected = dense([(*v, *w) for v, w in moved])
        np.testing.assert_allclose(levels.point_columns(f, T.p, locked, True), expected, rtol=0, atol=1e-12)
    masses, coms = np.asarray(robot.masses, np.float64), np.asarray(robot.body_coms, np.float64)
    c, J = levels.com_columns(masses, coms, locked, True)
    c_ref, velocities = unrolled.com()
    joints = [(0.0, 0.0, 0.0) if lock else v for lock, v in zip(locked, velocities, strict=True)]
    expected = dense(joints + [v for v, _ in rg.world_from_space(rg.root_screws(root), c_ref)])
    np.testing.assert_allclose(np.stack(c), np.stack([np.broadcast_to(e, (P,)) for e in c_ref]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(J, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", ["ball joints", "closed loop", "long chain"])
def test_the_pass_by_depth_takes_trees_of_one_axis_joints_only(kind):
    robot = model_of_kind(kind)
    assert not robot.by_depth
    with pytest.raises(ValueError, match="one-axis joints"):
        robot.forward_by_depth(jnp.zeros((robot.dof, 2)), jnp.zeros((3, 4)))
