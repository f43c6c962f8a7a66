"""Forward kinematics of the URDF robots against Pinocchio and pytorch-kinematics (float64)."""

import numpy as np
import pinocchio as pin
import pytest
import pytorch_kinematics as pk
import torch
from _models import URDF_ROBOTS, random_q

import diffkin as dk

N = 200


def _pin_model(name):
    path, _ = URDF_ROBOTS[name]
    with open(path) as fh:
        model = pin.buildModelFromXML(fh.read())
    return model, model.createData()


def _pin_q(model, chain, q):
    qp = np.zeros(model.nq)
    for i, name in enumerate(chain.joint_names):
        qp[model.joints[model.getJointId(name)].idx_q] = q[i]
    return qp


@pytest.mark.parametrize("name", list(URDF_ROBOTS))
def test_fk_and_link_poses_match_pinocchio(name, urdf_chains):
    chain = urdf_chains[name]
    model, data = _pin_model(name)
    end = model.getFrameId(URDF_ROBOTS[name][1])
    joint_ids = [model.getJointId(n) for n in chain.joint_names]
    q = random_q(chain, N, seed=1)
    T = np.asarray(dk.fk(chain, q))
    links = np.asarray(dk.link_poses(chain, q))
    assert T.dtype == np.float64 and links.shape == (N, chain.dof + 1, 4, 4)
    err_T = err_links = 0.0
    for k in range(N):
        pin.framesForwardKinematics(model, data, _pin_q(model, chain, q[k]))
        err_T = max(err_T, np.abs(data.oMf[end].homogeneous - T[k]).max())
        ref = np.stack([data.oMi[j].homogeneous for j in joint_ids])
        err_links = max(err_links, np.abs(ref - links[k, 1:]).max())
    np.testing.assert_allclose(links[:, 0], np.broadcast_to(np.eye(4), (N, 4, 4)), atol=0)
    assert err_T < 1e-10 and err_links < 1e-10


@pytest.mark.parametrize("name", list(URDF_ROBOTS))
def test_fk_and_link_poses_match_pytorch_kinematics(name, urdf_chains):
    path, end = URDF_ROBOTS[name]
    with open(path, "rb") as fh:
        ref_chain = pk.build_serial_chain_from_urdf(fh.read(), end).to(dtype=torch.float64)
    chain = urdf_chains[name]
    q = random_q(chain, N, seed=2)
    ref = ref_chain.forward_kinematics(torch.tensor(q), end_only=False)
    links = np.asarray(dk.link_poses(chain, q))
    child_of = {j.name: j.child for j in _urdf_joints(path)}
    for i, joint in enumerate(chain.joint_names):
        np.testing.assert_allclose(links[:, i + 1], ref[child_of[joint]].get_matrix().numpy(), atol=1e-6)
    np.testing.assert_allclose(np.asarray(dk.fk(chain, q)), ref[end].get_matrix().numpy(), atol=1e-6)


def _urdf_joints(path):
    import xml.etree.ElementTree as ET

    class J:
        def __init__(self, el):
            self.name, self.child = el.get("name"), el.find("child").get("link")

    return [J(el) for el in ET.parse(path).getroot().findall("joint")]
