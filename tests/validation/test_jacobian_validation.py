"""Jacobians of the URDF robots in three frames against Pinocchio and pytorch-kinematics (float64), and the
parameter gradients of the iiwa14's Jacobian (long to compile) by both methods."""

import numpy as np
import pinocchio as pin
import pytest
import pytorch_kinematics as pk
import torch
from _models import URDF_ROBOTS, jacobian_parameter_gradients, random_q

import diffkin as dk

FRAMES = ("world", "space", "body")
PIN_FRAME = {"world": pin.LOCAL_WORLD_ALIGNED, "space": pin.WORLD, "body": pin.LOCAL}
N = 100


@pytest.mark.parametrize("name", list(URDF_ROBOTS))
def test_jacobians_match_pinocchio(name, urdf_chains):
    chain = urdf_chains[name]
    path, end = URDF_ROBOTS[name]
    with open(path) as fh:
        model = pin.buildModelFromXML(fh.read())
    data, fid = model.createData(), model.getFrameId(end)
    idx_q = [model.joints[model.getJointId(n)].idx_q for n in chain.joint_names]
    idx_v = [model.joints[model.getJointId(n)].idx_v for n in chain.joint_names]
    q = random_q(chain, N, seed=20)
    ours = {f: np.asarray(dk.jacobian(chain, q, f)) for f in FRAMES}
    worst = dict.fromkeys(FRAMES, 0.0)
    for k in range(N):
        qp = np.zeros(model.nq)
        qp[idx_q] = q[k]
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        for f in FRAMES:
            ref = pin.getFrameJacobian(model, data, fid, PIN_FRAME[f])[:, idx_v]
            worst[f] = max(worst[f], np.abs(ref - ours[f][k]).max())
    assert max(worst.values()) < 1e-10, worst


@pytest.mark.parametrize("name", list(URDF_ROBOTS))
def test_world_jacobian_matches_pytorch_kinematics(name, urdf_chains):
    path, end = URDF_ROBOTS[name]
    with open(path, "rb") as fh:
        ref_chain = pk.build_serial_chain_from_urdf(fh.read(), end).to(dtype=torch.float64)
    q = random_q(urdf_chains[name], N, seed=21)
    ref = ref_chain.jacobian(torch.tensor(q)).numpy()
    np.testing.assert_allclose(dk.jacobian(urdf_chains[name], q), ref, atol=1e-6)


def test_jacobian_parameter_gradients_agree_between_methods_iiwa14_base():
    """The unit tier's check (``test_jacobian_parameter_gradients_agree_between_methods``) on the iiwa14's
    rigidly moved base: compiling the autodiff method's second derivatives takes ~15 s."""
    g = jacobian_parameter_gradients(dk.robots.iiwa14(), "base", seed=32)
    assert np.all(np.isfinite(g["analytic"])) and np.abs(g["analytic"]).max() > 1e-3
    np.testing.assert_allclose(g["analytic"], g["autodiff"], atol=1e-12)
