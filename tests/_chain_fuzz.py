"""Random chains for the property tests (hypothesis): strategies for DH and PoE chains of a few fixed
structures with random numbers, random configurations, the compiled FK and Jacobians, and the Jacobian
properties, shared by ``tests/unit/test_fuzz.py`` and ``tests/validation/test_fuzz_validation.py``.

JAX compiles once per chain structure (joint types, convention): the chains are passed to jitted
functions as arguments, so one compilation serves all examples of a structure. Compiling every Jacobian
of a long chain takes long (about 10 s for the 8-joint DH chain, 27 s for the 7-joint PoE chain, on
one CPU core): the unit tier checks the Jacobian properties on the short structures
(``SHORT_DH_STRUCTURES``, ``SHORT_POE_STRUCTURES``), the validation tier on the long ones."""

import hypothesis.extra.numpy as hnp
import jax
import numpy as np
from _fuzzing import finite_floats as _floats
from _reference import fk as fk_reference
from hypothesis import strategies as st

import diffkin as dk

# (joint types, modified DH): 1 to 8 joints, revolute and prismatic mixes, both conventions.
DH_STRUCTURES = [("R", False), ("RPR", True), ("PRRPRRRR", False)]
POE_STRUCTURES = ["RRP", "RRRRRRR"]
SHORT_DH_STRUCTURES, LONG_DH_STRUCTURES = DH_STRUCTURES[:2], DH_STRUCTURES[2:]
SHORT_POE_STRUCTURES, LONG_POE_STRUCTURES = POE_STRUCTURES[:1], POE_STRUCTURES[1:]

fk = jax.jit(dk.fk)
# Every frame (analytic) and the world Jacobian by autodiff, in one compiled function per structure
# (test_jacobian.py compares the methods in every frame).
_JACOBIANS = (("world", "analytic"), ("space", "analytic"), ("body", "analytic"), ("world", "autodiff"))
jacobians = jax.jit(lambda chain, q: {(f, m): dk.jacobian(chain, q, f, method=m) for f, m in _JACOBIANS})


# ----- strategies -----------------------------------------------------------------------------------


@st.composite
def rigid(draw, reach=1.0):
    """A random rigid transform: unit quaternion (not too close to 0) and translation."""
    quat = draw(hnp.arrays(np.float64, 4, elements=_floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1))
    w, x, y, z = quat / np.linalg.norm(quat)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, draw(hnp.arrays(np.float64, 3, elements=_floats(-reach, reach)))
    return T


@st.composite
def limits(draw, dof):
    lower = draw(st.lists(st.one_of(_floats(-4, 0), st.just(-np.inf)), min_size=dof, max_size=dof))
    upper = draw(st.lists(st.one_of(_floats(0, 4), st.just(np.inf)), min_size=dof, max_size=dof))
    return np.array(lower), np.array(upper)


@st.composite
def dh_chains(draw, structure=None, structures=DH_STRUCTURES):
    """A DH chain of ``structure``, or of one of ``structures``."""
    types, modified = draw(st.sampled_from(structures)) if structure is None else structure
    dof = len(types)
    table = draw(hnp.arrays(np.float64, (dof, 4), elements=_floats(-2, 2)))
    lower, upper = draw(limits(dof))
    return dk.DHChain.from_table(
        table, types, modified=modified, lower=lower, upper=upper, base=draw(rigid()), tool=draw(rigid(0.3))
    )


@st.composite
def poe_chains(draw, structures=POE_STRUCTURES):
    types = draw(st.sampled_from(structures))
    screws = []
    for kind in types:
        axis = draw(hnp.arrays(np.float64, 3, elements=_floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1))
        axis = axis / np.linalg.norm(axis)
        point = draw(hnp.arrays(np.float64, 3, elements=_floats(-1, 1)))
        screws.append([*np.cross(point, axis), *axis] if kind == "R" else [*axis, 0.0, 0.0, 0.0])
    lower, upper = draw(limits(len(types)))
    link_homes = np.stack([draw(rigid()) for _ in types])
    return dk.PoEChain.from_screws(screws, draw(rigid()), types, lower=lower, upper=upper, link_homes=link_homes)


def chains(dh=DH_STRUCTURES, poe=POE_STRUCTURES):
    """DH chains of the structures ``dh`` and PoE chains of the structures ``poe``."""
    return st.one_of(dh_chains(structures=dh), poe_chains(poe))


def configs(chain, bound):
    """``(dof,)`` joint values: uniform up to ``bound``, tiny, subnormal, zero, and the chain's limits."""
    lo, hi = np.asarray(chain.lower), np.asarray(chain.upper)
    entries = []
    for i in range(chain.dof):
        special = [0.0, -0.0, 5e-324, -1e-300, 1e-12]
        special += [float(v) for v in (lo[i], hi[i]) if np.isfinite(v)]
        entries.append(st.one_of(_floats(-bound, bound), st.sampled_from(special)))
    return st.tuples(*entries).map(np.array)


# ----- the Jacobian properties ------------------------------------------------------------------------


def check_fk_and_jacobians_finite_for_any_finite_q(data, chain_strategy):
    """Any finite joint values: a finite, rigid pose and finite Jacobians (every frame and method)."""
    chain = data.draw(chain_strategy)
    types = chain.joint_types
    # Revolute: any finite float (DH), up to 1e300 (PoE: with traced screws, as here a jit argument,
    # n * theta overflows near the float maximum when |w| rounds above 1); prismatic: up to 1e150
    # metres (beyond, sums of a few such offsets leave the float range: a true position, not a defect).
    revolute = (
        st.floats(allow_nan=False, allow_infinity=False) if isinstance(chain, dk.DHChain) else _floats(-1e300, 1e300)
    )
    q = np.array([data.draw(revolute if t == "R" else _floats(-1e150, 1e150)) for t in types])
    T = np.asarray(fk(chain, q))
    assert np.all(np.isfinite(T)), (q, T)
    R = T[:3, :3]
    assert np.abs(R.T @ R - np.eye(3)).max() < 1e-9
    for J in jacobians(chain, q).values():
        assert np.all(np.isfinite(np.asarray(J)))


def check_jacobians_match_central_differences(data, chain_strategy):
    """Every frame's Jacobian (analytic and autodiff) equals central differences of the NumPy FK."""
    chain = data.draw(chain_strategy)
    q = data.draw(configs(chain, 3.0))
    all_jacobians = jacobians(chain, q)
    for (frame, _), J in all_jacobians.items():
        _check_against_differences(chain, q, frame, np.asarray(J))


def _check_against_differences(chain, q, frame, J):
    h, T = 1e-6, fk_reference(chain, q)
    columns = []
    for i in range(chain.dof):
        e = np.zeros(chain.dof)
        e[i] = h
        Tp, Tm = fk_reference(chain, q + e), fk_reference(chain, q - e)
        dT = (Tp - Tm) / (2 * h)
        R, p, dR, dp = T[:3, :3], T[:3, 3], dT[:3, :3], dT[:3, 3]
        W = dR @ R.T  # world angular velocity [w]
        w = np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2
        if frame == "world":
            v = dp
        elif frame == "space":
            v = dp + np.cross(p, w)
        else:  # body: [R^T dp; R^T w]
            v, w = R.T @ dp, R.T @ w
        columns.append(np.concatenate([v, w]))
    J_fd = np.stack(columns, axis=1)
    scale = 1 + np.abs(T[:3, 3]).max()
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=2e-7 * scale)
