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
