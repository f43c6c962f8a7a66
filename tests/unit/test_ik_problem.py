"""An IK problem's entries computed into arrays (diffkin.ik._problem.settle, settle_choosing): the Jacobian's
computed entries land in their places among the folded zeros, without a scatter."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from diffkin.ik._problem import Entries, settle, settle_choosing

P = 5


def _entries(scale: float, zero_jacobian: bool = False) -> Entries:
    """Two rows, three columns of the state; folded Python-float zeros among the Jacobian's entries."""
    a = jnp.arange(P, dtype=jnp.float32) * scale
    J = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]] if zero_jacobian else [[a + 1, 0.0, a * 2], [0.0, 0.0, a - 3]]
    return Entries(r=[a, a + 0.5], J=J, cost=a * a, pos_err=[a], rot_err=[a * 0.1])


def _dense(scale: float) -> np.ndarray:
    a = np.arange(P, dtype=np.float32) * scale
    zero = np.zeros(P, np.float32)
    return np.stack([np.stack([a + 1, zero, a * 2]), np.stack([zero, zero, a - 3])])


def test_settle_places_the_computed_jacobian_entries_among_zeros():
    ev = settle(_entries(1.0))
    assert ev.J.shape == (2, 3, P)
    np.testing.assert_array_equal(ev.J, _dense(1.0))
    np.testing.assert_array_equal(ev.r, np.stack([np.arange(P), np.arange(P) + 0.5]).astype(np.float32))


def test_settle_of_a_jacobian_without_computed_entries_is_zero():
    ev = settle(_entries(1.0, zero_jacobian=True))
    np.testing.assert_array_equal(ev.J, np.zeros((2, 3, P), np.float32))


@pytest.mark.parametrize("taken", [[True, False, True, False, True], [False] * P, [True] * P])
def test_settle_choosing_takes_the_new_jacobian_where_chosen(taken):
    old = settle(_entries(1.0))
    take = jnp.asarray(taken)
    ev, took, extra = settle_choosing(_entries(2.0), old, lambda cost: (take, cost))
    np.testing.assert_array_equal(took, taken)
    np.testing.assert_array_equal(ev.J, np.where(taken, _dense(2.0), _dense(1.0)))
    np.testing.assert_array_equal(extra, np.asarray(_entries(2.0).cost))


def test_the_jacobian_is_put_in_place_without_a_scatter():
    """XLA's CPU backend runs a scatter into zeros as a loop over the computed entries, one row at a time."""
    jaxpr = str(jax.make_jaxpr(lambda s: settle(_entries(s)).J)(1.0))
    assert "scatter" not in jaxpr and "gather" in jaxpr


def _mixed(scale: float) -> Entries:
    """Entry rows, two rows as one array ``(2, 3, P)`` (a term's Jacobian in array form), an entry row."""
    a = jnp.arange(P, dtype=jnp.float32) * scale
    block = jnp.stack([jnp.stack([a, a + 1, a + 2]), jnp.stack([-a, 0 * a, a * a])])
    r = [a, a + 0.5, a - 1, a + 2]
    return Entries(r=r, J=[[a + 1, 0.0, a * 2], block, [0.0, a - 3, 0.0]], cost=a * a, pos_err=[a], rot_err=[a * 0.1])


def _mixed_dense(scale: float) -> np.ndarray:
    a = np.arange(P, dtype=np.float32) * scale
    zero = np.zeros(P, np.float32)
    rows = [[a + 1, zero, a * 2], [a, a + 1, a + 2], [-a, zero, a * a], [zero, a - 3, zero]]
    return np.stack([np.stack(row) for row in rows])


def test_settle_keeps_the_rows_of_entries_and_arrays_in_order():
    ev = settle(_mixed(1.0))
    assert ev.J.shape == (4, 3, P) and ev.r.shape == (4, P)
    np.testing.assert_array_equal(ev.J, _mixed_dense(1.0))


@pytest.mark.parametrize("taken", [[True, False, True, False, True], [False] * P, [True] * P])
def test_settle_choosing_takes_array_rows_where_chosen(taken):
    old = settle(_mixed(1.0))
    take = jnp.asarray(taken)
    ev, _, _ = settle_choosing(_mixed(2.0), old, lambda cost: (take, cost))
    np.testing.assert_array_equal(ev.J, np.where(taken, _mixed_dense(2.0), _mixed_dense(1.0)))


def _floating_panda_problem(com: bool):
    """The Panda on a solved root, a pose target of its third link and a position of its hand (two frames of
    one arm: they share its screws), weights, a locked joint; with ``com``, a horizontal centre of mass too."""
    from _models import PANDA

    import diffkin as dk
    from diffkin.ik._keywords import terms_of
    from diffkin.ik._problem import Spec

    robot = dk.load_robot(PANDA, floating=True)
    names = ("panda_link3", "panda_hand")
    rng = np.random.default_rng(3)
    q = rng.uniform(-1.0, 1.0, (P, robot.dof))
    T = np.asarray(dk.fk(robot, q + 0.1, names))
    weights = {"panda_link3": (1.0, 0.5, 0.0, 2.0, 1.0, 0.0)}
    given = {"com": np.asarray(dk.com(robot, q))[:, :2]} if com else {}
    terms = terms_of(robot, {names[0]: T[:, 0], names[1]: T[:, 1, :3, 3]}, given, weights)  # a pose, a position
    spec = Spec(terms.targets, (), tuple(i == 2 for i in range(robot.dof)), (), True, True)
    problem = spec.problem(robot, spec.bind(tuple(terms.data), ()))
    base = np.concatenate([rng.normal(size=(3, P)), np.tile(np.eye(3).reshape(9, 1), (1, P))])
    return problem, jnp.asarray(np.concatenate([q.T, base]))


def test_the_jacobian_in_arrays_equals_the_entry_wise_one():
    """Frames that share joints read their Jacobian as one array each, from the forward pass in arrays
    (:meth:`Kinematics.point_columns`, :mod:`diffkin.models._levels`); it equals each term's entry-wise
    Jacobian from the unrolled pass (float64), weights, a position, a locked joint and a solved root included."""
    from diffkin.ik._problem import Kinematics

    problem, x = _floating_panda_problem(com=False)
    assert problem.in_arrays
    assert all(not isinstance(rows, list) for rows in problem.residual(x).J)  # both terms' rows as arrays
    arrays, at = problem.evaluate(x), 0
    for term, bound in zip(problem.terms, problem.bound, strict=True):
        alone = problem._replace(terms=(term,), bound=(bound,))  # one frame: the unrolled pass, entry by entry
        assert not alone.in_arrays
        rows = term.rows(Kinematics(alone, x), bound, True)
        dense = np.stack([np.stack([jnp.broadcast_to(e, (P,)) for e in row]) for row in rows.J])
        np.testing.assert_allclose(arrays.J[at : at + len(dense)], dense, rtol=0, atol=1e-12)
        np.testing.assert_allclose(arrays.r[at : at + len(dense)], np.stack(rows.r), rtol=0, atol=1e-12)
        at += len(dense)
    assert at == len(arrays.J)


def test_the_centre_of_mass_jacobian_in_arrays_equals_the_entry_wise_one():
    """:meth:`Kinematics.com_columns` (the bodies' first moments and the joints' screws as arrays) equals the
    unrolled pass's :meth:`Kinematics.com` (float64), a locked joint, a mimic joint and a solved root included."""
    from diffkin.ik._problem import Kinematics

    problem, x = _floating_panda_problem(com=True)
    assert problem.in_arrays
    c, J = Kinematics(problem, x).com_columns()
    alone = problem._replace(terms=problem.terms[:1], bound=problem.bound[:1])
    assert not alone.in_arrays
    c_ref, columns = Kinematics(alone, x).com()
    np.testing.assert_allclose(np.stack(c), np.stack(c_ref), rtol=0, atol=1e-12)
    dense = np.stack([np.stack([jnp.broadcast_to(e, (P,)) for e in v]) for v in columns], axis=1)  # (3, n, P)
    np.testing.assert_allclose(J, dense, rtol=0, atol=1e-12)
