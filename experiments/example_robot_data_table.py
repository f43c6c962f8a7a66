"""Which URDFs of example-robot-data load as a `dk.Robot`: a markdown table for the README.

    python experiments/example_robot_data_table.py

Per file: actuated joints, mimic joints, frames, whether the root floats, the largest difference of
every frame's pose from Pinocchio's (float64, 3 random configurations), or why it is rejected.
"""

from __future__ import annotations

import glob
import os
import sys
from importlib import metadata

import jax
import numpy as np
import pinocchio as pin

import diffkin as dk


def main() -> int:
    jax.config.update("jax_enable_x64", True)
    root = str(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots"))
    lines = ["| file | dof | mimic | frames | max pose difference vs Pinocchio |", "| --- | --- | --- | --- | --- |"]
    for path in sorted(glob.glob(os.path.join(root, "**", "*.urdf"), recursive=True)):
        name = os.path.relpath(path, root)
        try:
            robot = dk.load_robot(path)
        except ValueError as err:
            lines.append(f"| `{name}` | rejected | | | {err} |")
            continue
        model = pin.buildModelFromUrdf(path)
        data = model.createData()
        lo = np.maximum(np.where(np.isfinite(robot.lower), robot.lower, -np.pi), -np.pi)
        hi = np.minimum(np.where(np.isfinite(robot.upper), robot.upper, np.pi), np.pi)
        q = np.random.default_rng(0).uniform(lo, hi, (3, robot.dof))
        poses = np.asarray(dk.link_poses(robot, q))
        worst = 0.0
        for k in range(3):
            values = dict(zip(robot.joint_names, q[k], strict=True))
            for joint, (source, m, o) in robot.mimic.items():
                values[joint] = m * values[source] + o
            qp = pin.neutral(model)
            for joint, value in values.items():
                jm = model.joints[model.getJointId(joint)]
                qp[jm.idx_q : jm.idx_q + jm.nq] = (np.cos(value), np.sin(value)) if jm.nq == 2 else value
            pin.framesForwardKinematics(model, data, qp)
            for f, frame in enumerate(robot.frame_names):
                worst = max(worst, np.abs(data.oMf[model.getFrameId(frame, pin.BODY)].homogeneous - poses[k, f]).max())
        lines.append(f"| `{name}` | {robot.dof} | {len(robot.mimic)} | {len(robot.frame_names)} | {worst:.1e} |")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
