"""A model closed over by ``jit`` (its numbers folded as constants, :mod:`diffkin._static`)
and the same model passed as a ``jit`` argument (traced: the general path) give the same numbers, in
every public function. One compiled function per path and model kind, small batches. Each trick of
:mod:`diffkin._xla` keeps the values of its plain formulation."""

import itertools
import logging
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import random_q
from _paths import DATA
from _reference import dh_fk

import diffkin as dk

FINGER = os.path.join(DATA, "example-robot-data", "robots", "finger_edu_description", "robots", "finger_edu.urdf")
# Small models of every kind (the paths, not the sizes, differ): compilations of the traced path are long.
TABLE = [[0.1, 0.3, 0.2, 0.1], [0.2, -0.5, 0.1, 0.0], [0.0, 1.5707963267948966, 0.3, 0.0]]
MODELS = {
    "standard DH": lambda: dk.DHChain.from_table(TABLE, "RPR", lower=[-2, 0, -2], upper=[2, 0.5, 2]),
    "modified DH": lambda: dk.DHChain.from_table(TABLE, "RRP", modified=True, lower=[-2, -2, 0], upper=[2, 2, 0.5]),
    "PoE": lambda: dk.to_poe(dk.DHChain.from_table(TABLE, "RPR", lower=[-2, 0, -2], upper=[2, 0.5, 2])),
    "Robot": lambda: dk.load_robot(FINGER),
}


def _kinematics(model, q):
    """fk, link_poses, the world Jacobian by both methods and manipulability of a chain."""
    jacobians = tuple(dk.jacobian(model, q, method=m) for m in ("autodiff", "analytic"))
    return dk.fk(model, q), dk.link_poses(model, q), jacobians, dk.manipulability(model, q)


def _robot_kinematics(robot, q, frame="finger_tip_link"):
    """The same for a frame of a whole robot."""
    jacobians = tuple(dk.jacobian(robot, q, frame, method=m) for m in ("autodiff", "analytic"))
    return (dk.fk(robot, q, frame), dk.link_poses(robot, q), jacobians, dk.manipulability(robot, q, frame))


_passed = {fn: jax.jit(fn) for fn in (_kinematics, _robot_kinematics)}


def _assert_same(closed, passed, atol):
    for a, b in zip(jax.tree.leaves(closed), jax.tree.leaves(passed), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=atol)


@pytest.mark.parametrize("kind", ["standard DH", "modified DH", "PoE", "Robot"])
def test_kinematics(kind):
    model = MODELS[kind]()
    fn = _robot_kinematics if kind == "Robot" else _kinematics
    q = random_q(model, 3, seed=1)
    _assert_same(jax.jit(lambda q: fn(model, q))(q), _passed[fn](model, q), atol=1e-12)


def test_ik_solve():
    chain = dk.robots.planar([0.5, 0.4, 0.3])
    targets = dh_fk(chain, random_q(chain, 4, seed=2))[:, :3, 3]  # NumPy's FK: no compiles

    def solve(chain, targets):
        res = dk.ik.solve(chain, targets, key=jax.random.key(0), num_seeds=4, max_iters=20)
        return res.q, res.success, res.pos_err, res.rot_err, res.iters

    closed = jax.jit(lambda targets: solve(chain, targets))(targets)
    passed = jax.jit(solve)(chain, targets)
    assert np.all(closed[1]) and np.array_equal(closed[1], passed[1]) and np.array_equal(closed[4], passed[4])
    _assert_same(closed[:4], passed[:4], atol=1e-9)


def test_srs():
    arm = dk.srs.iiwa14()
    chain = arm.chain()
    q = random_q(chain, 3, seed=3)
    T = dh_fk(chain, q)

    def functions(arm, T, q):
        psi, gc = dk.srs.arm_angle(arm, q)
        # sample_self_motion places its samples on the feasible_arm_angles intervals of every gc
        return psi, gc, dk.srs.ik(arm, T, psi, gc), dk.srs.sample_self_motion(arm, T[0], 8, key=jax.random.key(0))

    closed = jax.jit(lambda T, q: functions(arm, T, q))(T, q)
    _assert_same(closed, jax.jit(functions)(arm, T, q), atol=1e-12)


def test_reachability_against_the_traced_path():
    """The map's samples (chunk 0 is ``sample_configs(chain, chunk, fold_in(key, 0))``) through a traced chain."""
    chain = dk.robots.iiwa14()
    n, key = 512, jax.random.key(4)
    wmap = dk.workspace.reachability(
        chain, n, key=key, voxel_size=0.2, chunk=n, devices=jax.devices()[:1], progress=False
    )
    q = dk.workspace.sample_configs(chain, n, jax.random.fold_in(key, 0))
    T, m = jax.jit(lambda chain, q: (dk.fk(chain, q), dk.manipulability(chain, q)))(chain, q)
    cells = np.floor((np.asarray(T)[:, :3, 3] - wmap.origin) / wmap.voxel_size).astype(int)
    counts = np.zeros_like(wmap.counts)
    np.add.at(counts, tuple(cells.T), 1)
    np.testing.assert_array_equal(wmap.counts, counts)
    best = np.zeros(wmap.counts.shape)
    np.maximum.at(best, tuple(cells.T), np.asarray(m))
    np.testing.assert_allclose(wmap.manipulability, best, rtol=1e-10, atol=1e-12)


def test_materialize_keeps_values_and_a_single_value_stays_an_array_of_one():
    from diffkin._xla import materialize

    x = np.random.default_rng(3).normal(size=(5,))
    one, two = jax.jit(lambda x: (materialize([x * 2.0]), materialize([x, 1.5])))(x)
    assert one.shape == (1, 5)
    np.testing.assert_array_equal(np.asarray(one)[0], x * 2.0)
    np.testing.assert_array_equal(np.asarray(two), np.stack([x, np.full(5, 1.5)]))


def test_blocks_joined_and_steps_along_the_last_axis_keep_values():
    from diffkin._xla import blocks_joined, in_steps

    rng = np.random.default_rng(4)
    blocks = [[rng.normal(size=(2, 3, 7)), rng.normal(size=(2, 0, 7)), rng.normal(size=(2, 1, 1))]]
    blocks.append([rng.normal(size=(1, 3, 7)), rng.normal(size=(1, 0, 7)), rng.normal(size=(1, 1, 7))])
    out = jax.jit(lambda b: blocks_joined(b, 7))(blocks)
    whole = np.concatenate([np.concatenate([np.broadcast_to(b, (*b.shape[:2], 7)) for b in row], 1) for row in blocks])
    np.testing.assert_array_equal(np.asarray(out), whole)
    x = rng.normal(size=(10, 2))
    for halves in (False, True):  # each step in two independent halves: the same values
        (stepped,), (first, second) = jax.jit(
            lambda x, h=halves: (
                in_steps(lambda x: (x.T * 2.0,), (x,), 4, axis=-1, halves=h),
                in_steps(lambda x: (x * 3.0, x[:, 0]), (x,), 4, halves=h),
            )
        )(x)
        np.testing.assert_array_equal(np.asarray(stepped), x.T * 2.0)
        np.testing.assert_array_equal(np.asarray(first), x * 3.0)
        np.testing.assert_array_equal(np.asarray(second), x[:, 0])


@pytest.mark.parametrize("n", [63, 64, 65, 100])
def test_configurations_last_in_steps_keep_values(n):
    """From ``LAST_STEPPED`` configurations an output with the configurations last goes through the
    stepped loop (two steps, the last overlapping for an odd count): the same values as one call."""
    from diffkin._xla import LAST_STEPPED, configurations_in_steps

    q = np.random.default_rng(5).normal(size=(n, 3))
    base = np.tile(np.eye(4), (n, 1, 1)) * np.arange(1, n + 1)[:, None, None]
    scaled = lambda q_, b_: (q_ * b_[:, :1, 0]).T[None]  # noqa: E731  (1, 3, N): the configurations last
    fn = jax.jit(lambda q, b: configurations_in_steps(scaled, q, b, 1024, last=True))
    np.testing.assert_array_equal(np.asarray(fn(q, base)), (q * np.arange(1, n + 1)[:, None])[:, None, :])
    assert ("while" in fn.lower(q, base).as_text()) == (n >= LAST_STEPPED)


def test_summed_products_are_einsum_s():
    """Per-problem products (problems last) and support scores (batch first), empty axes too, against
    ``np.einsum`` in float64."""
    from diffkin._xla import summed_products

    rng = np.random.default_rng(3)
    J, v = rng.normal(size=(6, 7, 5)), rng.normal(size=(7, 5))
    V, m = rng.normal(size=(4, 9, 3)), rng.normal(size=(4, 3))
    gram, times, scores = jax.jit(
        lambda J, v, V, m: (
            summed_products(J[:, :, None], J[:, None, :], axis=0),
            summed_products(J, v[None], axis=1),
            summed_products(V, m[..., None, :], axis=-1),
        )
    )(J, v, V, m)
    np.testing.assert_allclose(gram, np.einsum("mip,mjp->ijp", J, J), rtol=1e-12)
    np.testing.assert_allclose(times, np.einsum("mip,ip->mp", J, v), rtol=1e-12)
    np.testing.assert_allclose(scores, np.einsum("bvi,bi->bv", V, m), rtol=1e-12)
    empty = np.zeros((0, 3, 5))
    assert summed_products(empty[:, :, None], empty[:, None, :], axis=0).shape == (3, 3, 5)
    assert summed_products(np.zeros((2, 0, 5)), np.zeros((1, 0, 5)), axis=1).shape == (2, 5)


def test_where_any_updates_only_batches_that_need_it():
    """``fn(*args)`` when some entry is needed, ``args`` as they are otherwise; under ``jit`` and ``vmap``."""
    from diffkin._xla import where_any

    def fn(needed, a, b):  # leaves a and b as they are where nothing is needed
        return jnp.where(needed, 0.0, a), jnp.where(needed, -1.0, b)

    a, b = jnp.arange(4.0), jnp.arange(4.0) + 10.0
    run = jax.jit(lambda needed, a, b: where_any(needed, lambda a, b: fn(needed, a, b), a, b))
    for needed in ([False, True, False, False], [False] * 4):
        needed = jnp.asarray(needed)
        for got, want in zip(run(needed, a, b), fn(needed, a, b), strict=True):
            np.testing.assert_array_equal(got, want)
    needed = jnp.asarray([[False, True], [False, False]])
    batched = jax.vmap(run)(needed, a.reshape(2, 2), b.reshape(2, 2))
    for got, want in zip(batched, fn(needed, a.reshape(2, 2), b.reshape(2, 2)), strict=True):
        np.testing.assert_array_equal(got, want)


def test_stable_partition_is_a_stable_sort():
    """Every row of 1 to 5 booleans: the slots are those of a stable sort that puts the ``True`` entries first."""
    from diffkin._xla import stable_partition

    for n in range(1, 6):
        masks = np.array(list(itertools.product((False, True), repeat=n)))
        slots = np.asarray(stable_partition(jnp.asarray(masks)))
        order = np.argsort(~masks, axis=-1, kind="stable")
        np.testing.assert_array_equal(slots, order[..., :, None] == np.arange(n))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_inverse_sqrt_is_one_over_sqrt_without_a_float64_rsqrt(dtype):
    """Values and derivatives of ``1 / sqrt(x)`` (float64 to 2 ulp, float32 to 2e-7 relative) over 400
    (float64) or 50 (float32) decades; the compiled float64 program holds no ``rsqrt`` (float32's may)."""
    from diffkin._xla import inverse_sqrt

    big = 200 if dtype == np.float64 else 25  # the derivative x^-1.5 finite
    x = np.geomspace(10.0**-big, 10.0**big, 1001).astype(dtype)
    fn = jax.jit(jax.vmap(jax.value_and_grad(inverse_sqrt)))
    value, slope = (np.asarray(v, np.float64) for v in fn(x))
    x64 = x.astype(np.float64)
    rtol = 4.5e-16 if dtype == np.float64 else 2.4e-7
    np.testing.assert_allclose(value, 1 / np.sqrt(x64), rtol=rtol, atol=0)
    np.testing.assert_allclose(slope, -0.5 / (x64 * np.sqrt(x64)), rtol=3 * rtol, atol=0)
    if dtype == np.float64:
        assert " rsqrt(" not in jax.jit(inverse_sqrt).lower(x).compile().as_text()


@pytest.mark.parametrize("public", [False, True], ids=["jax-internal", "public-api"])
def test_solver_jit_gives_its_options_to_top_level_calls_only(public, monkeypatch):
    """Compiler options are allowed on a top-level jit only: inside a user's jit (or vmap, grad) the plain
    one is used; by JAX's internal trace state and by the public-API fallback alike."""
    from diffkin import _xla
    from diffkin._xla import SOLVER_COMPILE, solver_jit

    if public:
        monkeypatch.setattr(_xla, "top_level", _xla._top_level_public)
    inside = []
    jax.jit(lambda x: inside.append(_xla.top_level(x)) or x)(0.0)
    jax.vmap(lambda x: inside.append(_xla.top_level(x)) or x)(np.zeros(2))
    jax.grad(lambda x: inside.append(_xla.top_level(x)) or x)(0.0)
    assert _xla.top_level(np.zeros(2)) and inside == [False, False, False]
    g = solver_jit(lambda x: x + 1.0)
    np.testing.assert_array_equal(np.asarray(jax.grad(lambda x: g(x).sum())(np.zeros(3))), np.ones(3))
    np.testing.assert_array_equal(np.asarray(g(np.zeros(3))), np.ones(3))
    np.testing.assert_array_equal(np.asarray(jax.jit(g)(np.zeros(3))), np.ones(3))  # would raise with the options
    np.testing.assert_array_equal(np.asarray(jax.vmap(g)(np.zeros((2, 3)))), np.ones((2, 3)))
    assert SOLVER_COMPILE == {"xla_cpu_use_fusion_emitters": False}


def test_solver_jit_gives_its_options_to_the_cpu_backend_only(monkeypatch):
    """A GPU's compiler rejects the CPU emitter's options ("No such compile option"): on another backend the
    plain jit is used. Posed here with an option no backend knows, which the CPU path must pass on."""
    from diffkin import _xla

    monkeypatch.setattr(_xla, "SOLVER_COMPILE", {"no_such_option_anywhere": True})
    monkeypatch.setattr(_xla, "supported", lambda options: options)  # as a jaxlib that knew it
    monkeypatch.setattr(_xla, "_default_backend", lambda: "gpu")
    np.testing.assert_array_equal(np.asarray(_xla.solver_jit(lambda x: x + 1.0)(np.zeros(3))), np.ones(3))
    monkeypatch.setattr(_xla, "_default_backend", lambda: "cpu")
    with pytest.raises(Exception, match="no_such_option_anywhere"):
        _xla.solver_jit(lambda x: x + 2.0)(np.zeros(3))


def test_compile_ahead_compiles_what_the_call_then_reuses(caplog):
    """A solver compiled ahead (in its thread) is not compiled again by the call with those arguments' shapes;
    another shape is; inside a trace there is nothing to compile ahead."""
    from diffkin._xla import solver_jit

    g = solver_jit(lambda x: x * 2.0)
    assert g.compile_ahead(np.zeros(3)).result() is None
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        np.testing.assert_array_equal(np.asarray(g(np.ones(3))), np.full(3, 2.0))
        assert not [r for r in caplog.records if "Compiling" in r.getMessage()]
        np.testing.assert_array_equal(np.asarray(g(np.ones(4))), np.full(4, 2.0))
        assert [r for r in caplog.records if "Compiling" in r.getMessage()]
    ahead = []
    jax.jit(lambda x: ahead.append(g.compile_ahead(x)) or x)(0.0)
    assert ahead == [None]


def test_supported_keeps_the_options_this_jaxlib_knows():
    """Options come and go between jaxlib versions, and an unknown one fails the compile: a solver is given
    those its jaxlib knows."""
    from diffkin import _xla

    mixed = {"xla_cpu_use_fusion_emitters": False, "no_such_option_anywhere": True}
    assert _xla.supported(mixed) == {"xla_cpu_use_fusion_emitters": False}
    g = _xla.solver_jit(lambda x: x + 1.0, mixed)
    np.testing.assert_array_equal(np.asarray(g(np.zeros(3))), np.ones(3))


def test_traj_compile_keeps_gjk_free_of_ynnpack_fusions():
    """TRAJ_COMPILE's reason: XLA hands GJK's small products to YNNPACK unless told not to; with it, none is,
    and the distances are those of the default compile (up to float32 rounding)."""
    from diffkin import _xla
    from diffkin.collision import _gjk, _shapes

    options = _xla.supported(_xla.TRAJ_COMPILE)
    if "xla_cpu_experimental_ynn_fusion_type" not in options:
        pytest.skip("this jaxlib has no YNNPACK fusion option")
    rng = np.random.default_rng(3)
    pose = np.tile(np.eye(4, dtype=np.float32), (64, 1, 1))
    pose[:, :3, 3] = rng.normal(size=(64, 3))
    a = _shapes.Convex(pose, rng.normal(scale=0.3, size=(64, 24, 3)).astype(np.float32))
    b = _shapes.Box(np.tile(np.eye(4, dtype=np.float32), (64, 1, 1)), np.full((64, 3), 0.2, np.float32))
    plain, traj = jax.jit(_gjk.distance), jax.jit(_gjk.distance, compiler_options=options)
    assert "__ynn_fusion" not in traj.lower(a, b).compile().as_text()
    np.testing.assert_allclose(np.asarray(traj(a, b)), np.asarray(plain(a, b)), rtol=0, atol=2e-6)


@pytest.mark.parametrize("n", [1, 2, 5, 8, 37])
def test_spans_in_threads_cover_the_batch_once_each(n, monkeypatch):
    """Spans of one size cover every problem (the last overlapping the one before it where the count does not
    divide ``n``); ``in_threads`` joins what each thread computed into the batch's result, as one call would
    compute it; inside a trace, or off the CPU, there is one span."""
    from diffkin import _xla

    monkeypatch.setattr(_xla, "_cores", lambda: 3)
    x = jnp.arange(n * 2.0).reshape(n, 2)
    parts = _xla.spans(n, x)
    size = -(-n // min(n, 3 * _xla.SPANS_PER_CORE))
    assert {s for _, s in parts} == {size} and len(parts) == -(-n // size)
    covered = np.zeros(n, int)
    for start, span in parts:
        assert 0 <= start and start + span <= n
        covered[start : start + span] += 1
    assert np.all(covered >= 1)
    out = _xla.in_threads(
        lambda start, size: {"y": 2 * x[start : start + size], "i": jnp.arange(start, start + size)}, parts
    )
    np.testing.assert_array_equal(out["y"], 2 * x)
    np.testing.assert_array_equal(out["i"], np.arange(n))
    assert jax.jit(lambda x: jnp.asarray(len(_xla.spans(n, x))))(x) == 1
    monkeypatch.setattr(_xla, "_default_backend", lambda: "gpu")
    assert _xla.spans(n, x) == [(0, n)]
