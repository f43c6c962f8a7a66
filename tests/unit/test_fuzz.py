"""Property-based fuzzing with hypothesis: random valid DH and PoE chains and configurations, random MJCF
files, and garbage.

Properties: FK poses are rigid and finite, and match an independent NumPy FK; Jacobians match central
finite differences; an IK success reaches its target (checked by the NumPy FK); every output is
finite; bad input raises ValueError or TypeError, never another exception. The MJCF reader: random
kinematic trees (default classes, frames, every orientation form) give MuJoCo's frames, limits and
poses; random include structures load as MuJoCo loads them or are rejected as MuJoCo rejects them;
random arrangements of MJCF's elements load or raise ValueError/TypeError. Each MJCF example runs
under a time limit (``_fuzzing.time_limit``), so a hang fails the test. The properties against MuJoCo
(random trees and include structures) are in ``tests/validation/test_fuzz_validation.py``, with
whole-robot IK (a tree's solvers compile long) and the Jacobian properties on the long chains.

JAX compiles once per chain structure (joint types, convention): a few structures are fixed and the
numbers are random, and every chain is passed to jitted functions as an argument, so one compilation
serves all examples (the strategies: ``tests/_chain_fuzz.py``). Here the Jacobian properties run on the
short structures (1 and 3 joints); compiling every Jacobian of the 7- and 8-joint chains took most of
this file's time, so those run in the validation tier. The default budget is small
(``DIFFKIN_FUZZ_EXAMPLES=25`` examples per test, derandomized, for CI); a larger exploratory run, with
fresh random examples every time:

    DIFFKIN_FUZZ_EXAMPLES=2000 python -m pytest tests/unit/test_fuzz.py tests/validation/test_fuzz_validation.py
"""

from xml.sax.saxutils import quoteattr

import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _chain_fuzz import (
    SHORT_DH_STRUCTURES,
    SHORT_POE_STRUCTURES,
    chains,
    check_fk_and_jacobians_finite_for_any_finite_q,
    check_jacobians_match_central_differences,
    configs,
    dh_chains,
    fk,
)
from _fuzzing import FUZZ, MJCF_FUZZ, MJCF_TIME_LIMIT, time_limit
from _fuzzing import number_text as _text
from _reference import fk as fk_reference
from _reference import rotation_angle
from hypothesis import given
from hypothesis import strategies as st

import diffkin as dk
from diffkin._xla import solver_jit  # compiled as dk.ik.solve compiles itself
from diffkin.ik import _args

# ----- properties -------------------------------------------------------------------------------------


@FUZZ
@given(st.data())
def test_fk_is_rigid_finite_and_matches_numpy(data):
    chain = data.draw(chains())
    q = data.draw(configs(chain, 1e6))
    T = np.asarray(fk(chain, q))
    assert np.all(np.isfinite(T))
    R = T[:3, :3]
    assert np.abs(R.T @ R - np.eye(3)).max() < 1e-9 and abs(np.linalg.det(R) - 1) < 1e-9
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    # Against NumPy where the angles are moderate (NumPy's own sin/cos of 1e6 agree to ~1e-10 there too).
    q_small = np.clip(q, -10, 10)
    np.testing.assert_allclose(np.asarray(fk(chain, q_small)), fk_reference(chain, q_small), rtol=0, atol=1e-9)


# The Jacobian properties on the short structures (the long ones: tests/validation/test_fuzz_validation.py).
SHORT_CHAINS = chains(SHORT_DH_STRUCTURES, SHORT_POE_STRUCTURES)


@FUZZ
@given(st.data())
def test_fk_and_jacobian_finite_for_any_finite_q(data):
    check_fk_and_jacobians_finite_for_any_finite_q(data, SHORT_CHAINS)


@FUZZ
@given(st.data())
def test_jacobian_matches_central_differences(data):
    check_jacobians_match_central_differences(data, SHORT_CHAINS)


IK_STRUCTURE = ("RPR", True)
_ik_solve = solver_jit(lambda chain, T: dk.ik.solve(chain, T, key=jax.random.key(0), num_seeds=4, max_iters=20))


@FUZZ
@given(st.data())
def test_ik_success_means_the_pose_is_reached(data):
    """One compiled solve (a 3-joint DH chain as an argument, 4 targets): reachable, garbage and
    non-finite targets; a success reaches its pose (NumPy FK), every output is finite."""
    chain = data.draw(dh_chains(IK_STRUCTURE))
    targets = [fk_reference(chain, data.draw(configs(chain, 3.0))) for _ in range(2)]
    far = np.eye(4)
    far[:3, 3] = data.draw(st.sampled_from([1e3, 1e30, 1e300, 0.0]))
    nan = np.full((4, 4), data.draw(st.sampled_from([np.nan, np.inf, -np.inf])))
    res = _ik_solve(chain, np.stack(targets + [far, nan]))
    for field in (f for f in res if f is not None):  # base: None for chains
        assert np.all(np.isfinite(np.asarray(field)))
    success = np.asarray(res.success)
    assert not success[3]
    for i in np.flatnonzero(success):
        reached = fk_reference(chain, np.asarray(res.q[i]))
        target = np.stack(targets + [far])[i]
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) <= 1e-5 + 1e-9
        assert rotation_angle(reached[:3, :3].T @ target[:3, :3]) <= 1e-4 + 1e-7


# ----- the MJCF reader: random trees and include structures against MuJoCo, random elements -----------

_TAGS = [
    "body",
    "joint",
    "site",
    "frame",
    "default",
    "include",
    "freejoint",
    "geom",
    "worldbody",
    "compiler",
    "equality",
    "replicate",
]
_ATTRIBUTES = [
    "name",
    "pos",
    "quat",
    "euler",
    "axisangle",
    "xyaxes",
    "zaxis",
    "axis",
    "range",
    "limited",
    "class",
    "childclass",
    "type",
    "file",
    "ref",
    "joint1",
    "joint2",
    "polycoef",
    "angle",
    "eulerseq",
    "autolimits",
    "fromto",
    "active",
]
_VALUES = st.one_of(
    st.sampled_from(
        [
            "",
            "0",
            "1 0 0",
            "0 0 1",
            "0 0 0 0",
            "nan",
            "inf 0 0",
            "1e400",
            "-1 1",
            "true",
            "false",
            "auto",
            "hinge",
            "slide",
            "free",
            "ball",
            "degree",
            "radian",
            "xyz",
            "a",
            "c0",
            "main",
            "x.xml",
        ]
    ),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=6).map(_text),
    st.text(max_size=6),
)


@st.composite
def mjcf_elements(draw, depth: int = 0) -> str:
    """A random element of MJCF-like tags, attributes and values, nested up to 6 deep."""
    tag = draw(st.sampled_from(_TAGS))
    attributes = draw(st.dictionaries(st.sampled_from(_ATTRIBUTES), _VALUES, max_size=4))
    text = " ".join(f"{k}={quoteattr(v)}" for k, v in attributes.items())
    children = draw(st.lists(mjcf_elements(depth + 1), max_size=3)) if depth < 6 else []
    return f"<{tag} {text}>{''.join(children)}</{tag}>"


@MJCF_FUZZ
@given(st.lists(mjcf_elements(), max_size=4))
def test_random_mjcf_elements_load_or_raise_value_errors(elements):
    """Any arrangement of MJCF's elements, attributes and odd values loads a finite robot or raises a
    ValueError or TypeError, never another exception, within the time limit."""
    xml = f"<mujoco>{''.join(elements)}</mujoco>"
    with time_limit(MJCF_TIME_LIMIT, "reading random MJCF elements"):
        try:
            robot = dk.load_robot(xml)
        except (ValueError, TypeError):
            return
    for array in (robot.joint_poses, robot.screws, robot.frame_poses, robot.offsets):
        assert np.all(np.isfinite(np.asarray(array)))


# ----- garbage in: ValueError or TypeError, nothing else -------------------------------------------------

garbage = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**400), 10**400),
    st.floats(),
    st.complex_numbers(),
    st.text(max_size=8),
    st.binary(max_size=4),
    st.lists(st.floats(), max_size=9),
    st.lists(st.lists(st.floats(), max_size=6), max_size=9),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
    hnp.arrays(
        st.sampled_from([np.float64, np.float32, np.float16, np.int32, np.bool_, np.complex128, np.uint8]),
        hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=8),
    ),
    st.just(object()),
    st.just(jnp.zeros((4, 4))),
    st.just(np.eye(4) * 2),
)

_DH_FIELDS = (
    "a",
    "alpha",
    "d",
    "theta_offset",
    "lower",
    "upper",
    "base",
    "tool",
    "joint_types",
    "modified",
    "joint_names",
    "name",
)
_POE_FIELDS = ("screws", "home", "link_homes", "lower", "upper", "joint_types", "joint_names", "name")


def _value_or_type_error_only(fn, *args, **kwargs):
    try:
        fn(*args, **kwargs)
    except (ValueError, TypeError):
        pass


@FUZZ
@given(st.data())
def test_bad_inputs_raise_value_or_type_errors(data):
    chain = data.draw(dh_chains(("RPR", True)))
    poe = dk.to_poe(chain)
    junk = data.draw(garbage)
    table = np.zeros((3, 4))
    keyword = data.draw(
        st.sampled_from(["joint_types", "modified", "lower", "upper", "base", "tool", "joint_names", "name"])
    )
    _value_or_type_error_only(dk.DHChain.from_table, junk)
    _value_or_type_error_only(dk.DHChain.from_table, table, **{keyword: junk})
    _value_or_type_error_only(chain.replace, **{data.draw(st.sampled_from(_DH_FIELDS)): junk})
    _value_or_type_error_only(poe.replace, **{data.draw(st.sampled_from(_POE_FIELDS)): junk})
    _value_or_type_error_only(dk.PoEChain.from_screws, junk, np.eye(4))
    _value_or_type_error_only(dk.PoEChain.from_screws, [[0, 0, 0, 0, 0, 1.0]], junk)
    _value_or_type_error_only(dk.PoEChain.from_screws, [[0, 0, 0, 0, 0, 1.0]], np.eye(4), junk)
    _value_or_type_error_only(dk.fk, chain, junk)
    _value_or_type_error_only(dk.fk, junk, np.zeros(3))
    _value_or_type_error_only(dk.jacobian, chain, np.zeros(3), junk)
    _value_or_type_error_only(dk.jacobian, chain, np.zeros(3), method=junk)
    # IK's host-side checks (the solve itself is traced code, fuzzed above).
    _value_or_type_error_only(_args.check_target, junk)
    _value_or_type_error_only(_args.check_batched, junk, "q0", (chain.dof,), (), "for a chain")
    _value_or_type_error_only(_args.check_settings, junk, "lm", 10, 1e-5, 1e-4, None)
    _value_or_type_error_only(_args.check_settings, 4, "lm", 10, junk, 1e-4, None)


@pytest.mark.parametrize("junk", [",", "abc", b","])
def test_strings_are_type_errors(junk):
    """A string is not numbers: TypeError (``","`` raised SyntaxError from NumPy's dtype parser, found by
    test_bad_inputs_raise_value_or_type_errors)."""
    chain = dk.robots.iiwa14()
    for fn in (dk.fk, dk.jacobian):
        with pytest.raises(TypeError, match=r"^q: expected an array of joint values"):
            fn(chain, junk)
    with pytest.raises(TypeError, match=r"^a: expected an array"):
        dk.DHChain.from_table(np.zeros((7, 4))).replace(a=junk)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_garbage_examples_fixed_in_issue_18(value):
    """A few of the inputs the fuzzing found, kept as plain regression tests."""
    with pytest.raises(ValueError, match="^table: expected numbers within the float64 range"):
        dk.DHChain.from_table([[10**400, 0, 0, 0]])
    with pytest.raises(ValueError, match="^a: expected finite numbers"):
        dk.robots.ur5().replace(a=np.full(6, value))
