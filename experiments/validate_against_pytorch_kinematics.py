"""diffkin's FK and world Jacobian against pytorch-kinematics and Pinocchio on real URDFs.

    python experiments/validate_against_pytorch_kinematics.py [--n 1000]

For each robot (the shipped iiwa7/iiwa14 URDFs, Franka's Panda and the ROS-Industrial UR5
from ``tests/data``), draws ``--n`` random configurations within the joint limits and prints,
in float64 and float32, the largest position error (m), rotation error (rad) and world-Jacobian
error of diffkin against Pinocchio (exact float64 reference) and pytorch-kinematics (which builds
its chains in float32, so it sits ~1e-7 from the exact result even in float64).
"""

from __future__ import annotations

import argparse
import os

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402
import pytorch_kinematics as pk  # noqa: E402
import torch  # noqa: E402
from _bench import machine_line, table  # noqa: E402

import diffkin as dk  # noqa: E402
from diffkin import se3  # noqa: E402

DATA = os.path.join(os.path.dirname(__file__), "..", "tests", "data")
ROBOTS = {
    "iiwa7": (dk.robots.urdf_path("iiwa7"), "iiwa7_link_ee"),
    "iiwa14": (dk.robots.urdf_path("iiwa14"), "iiwa14_link_ee"),
    "panda": (os.path.join(DATA, "panda.urdf"), "panda_link8"),
    "ur5": (os.path.join(DATA, "ur5.urdf"), "tool0"),
}


def _pinocchio(xml, chain, end, q):
    """Poses ``(n, 4, 4)`` and world Jacobians ``(n, 6, dof)`` from Pinocchio, in float64."""
    model = pin.buildModelFromXML(xml)
    data, fid = model.createData(), model.getFrameId(end)
    idx_q = [model.joints[model.getJointId(n)].idx_q for n in chain.joint_names]
    idx_v = [model.joints[model.getJointId(n)].idx_v for n in chain.joint_names]
    poses, jacs = [], []
    for qk in q:
        qp = np.zeros(model.nq)
        qp[idx_q] = qk
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        poses.append(data.oMf[fid].homogeneous.copy())
        jacs.append(pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:, idx_v])
    return np.array(poses), np.array(jacs)


def _errors(T, J, T_ref, J_ref):
    pos = np.abs(T[:, :3, 3] - T_ref[:, :3, 3]).max()
    rot = np.asarray(se3.rotation_angle(jnp.asarray(np.swapaxes(T[:, :3, :3], 1, 2) @ T_ref[:, :3, :3]))).max()
    return f"{pos:.1e}", f"{rot:.1e}", f"{np.abs(J - J_ref).max():.1e}"


def run(n: int = 1000, seed: int = 0) -> str:
    rows = []
    for name, (path, end) in ROBOTS.items():
        with open(path) as fh:
            xml = fh.read()
        chain = dk.load_urdf(path, end)
        lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
        hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
        q = np.random.default_rng(seed).uniform(lo, hi, (n, chain.dof))
        T_pin, J_pin = _pinocchio(xml, chain, end, q)
        for dtype, tdtype in ((np.float64, torch.float64), (np.float32, torch.float32)):
            qd = jnp.asarray(q.astype(dtype))
            T = np.asarray(jax.jit(lambda x, c=chain: dk.fk(c, x))(qd), np.float64)
            J = np.asarray(jax.jit(lambda x, c=chain: dk.jacobian(c, x))(qd), np.float64)
            ref = pk.build_serial_chain_from_urdf(xml.encode(), end).to(dtype=tdtype)
            qt = torch.tensor(q.astype(dtype))
            T_pk = ref.forward_kinematics(qt).get_matrix().double().numpy()
            J_pk = ref.jacobian(qt).double().numpy()
            dt = np.dtype(dtype).name
            rows.append([name, dt, "Pinocchio", *_errors(T, J, T_pin, J_pin)])
            rows.append([name, dt, "pytorch-kinematics", *_errors(T, J, T_pk, J_pk)])
            if dtype is np.float64:
                rows.append([name, dt, "(pytorch-kinematics vs Pinocchio)", *_errors(T_pk, J_pk, T_pin, J_pin)])
    head = ["robot", "dtype", "reference", "max position error (m)", "max rotation error (rad)", "max Jacobian error"]
    return f"{n} random configurations within limits per robot. {machine_line()}\n\n" + table(head, rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="configurations per robot")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(run(args.n, args.seed))


if __name__ == "__main__":
    main()
