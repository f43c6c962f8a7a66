"""IK of whole robots: several targets at once, a floating base, secondary objectives.

Robots from example-robot-data (third-party URDFs). Targets are frame poses of uniform in-limit
configurations (reachable), float32, jitted, warm, median of 3 runs; compile time (first call)
apart. Every reported success is re-checked with Pinocchio's float64 forward kinematics.
pytorch-kinematics solves one end effector of one serial chain, so it has no row here.

- Dual arm: Baxter, both grippers (2 pose targets, 17 joints).
- Relative targets (``--relative``): Baxter's left gripper at a pose and the right one held in the
  left one's frame (``relative=``), beside the same targets as two world poses, same run.
- Humanoid: Talos (talos_reduced, 32 joints), both soles and both grippers (4 pose targets), the
  root pose solved too (``solve_base=True``) from the identity; targets from random root poses.
- Secondary objectives on the iiwa14 and the Panda (7 joints): a pose target with the rotation
  about the tool z axis free (5 constraints), solved without and with ``rest`` (stay near the
  zero posture) and ``limits`` (stay mid-range): the secondary cost drops, success and errors stay.

Run: ``python experiments/bench_ik_robots.py [--n 1000] [--relative]``
"""

import argparse
import os
import time
from importlib import metadata

import jax
import jax.numpy as jnp
import numpy as np
import pinocchio as pin
from _bench import machine_line, median_seconds, table

import diffkin as dk
from diffkin import se3
from diffkin.ik import _secondary

TOL = (1e-5, 1e-4)
ERD = str(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots"))
BAXTER = os.path.join(ERD, "baxter_description/urdf/baxter.urdf")
TALOS = os.path.join(ERD, "talos_data/robots/talos_reduced.urdf")
PANDA = os.path.join(ERD, "panda_description/urdf/panda.urdf")


def random_q(robot, n, seed):
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, robot.dof))


def rotations(w):
    """``(n, 3, 3)`` rotations of rotation vectors ``(n, 3)``."""
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    K = np.asarray(se3.skew(w / np.maximum(theta[..., 0], 1e-300)))
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def pinocchio_poses(path, robot, q, names, base=None):
    """``(n, k, 4, 4)`` float64 world poses of ``names`` by Pinocchio (mimic joints set from their sources)."""
    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    ids = [model.getFrameId(name, pin.BODY) for name in names]
    out = np.zeros((len(q), len(names), 4, 4))
    for i, qi in enumerate(np.asarray(q, np.float64)):
        values = dict(zip(robot.joint_names, qi, strict=True))
        for name, (source, m, o) in robot.mimic.items():
            values[name] = m * values[source] + o
        qp = pin.neutral(model)
        for name, value in values.items():
            joint = model.joints[model.getJointId(name)]
            if joint.nq == 2:
                qp[joint.idx_q : joint.idx_q + 2] = np.cos(value), np.sin(value)
            else:
                qp[joint.idx_q] = value
        pin.framesForwardKinematics(model, data, qp)
        for k, f in enumerate(ids):
            M = data.oMf[f].homogeneous
            out[i, k] = M if base is None else np.asarray(base[i], np.float64) @ M
    return out


def verified(T, targets):
    """Per problem, every target within tolerance in float64 (float32 rounding allowed)."""
    targets = np.asarray(targets, np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - targets[..., :3, 3], axis=-1)
    with jax.enable_x64(True):
        rot = np.asarray(se3.rotation_angle(targets[..., :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2)))
    return np.all((pos <= TOL[0] + 2e-6) & (rot <= TOL[1] + 2e-5), axis=-1)


def timed(fn, *args):
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - start
    return compile_s, median_seconds(fn, *args, repeats=3, warmup=0, min_time=0.0), fn(*args)


def several_targets(n: int):
    rows = []
    baxter = dk.load_robot(BAXTER)
    hands = ["left_gripper", "right_gripper"]
    T = np.asarray(dk.fk(baxter, random_q(baxter, n, 0), hands))
    fn = jax.jit(lambda t: dk.ik.solve(baxter, t))
    compile_s, dt, res = timed(fn, {h: jnp.asarray(T[:, k], jnp.float32) for k, h in enumerate(hands)})
    ok = np.asarray(res.success)
    assert np.all(verified(pinocchio_poses(BAXTER, baxter, res.q, hands), T)[ok]), "a success fails Pinocchio FK"
    rows.append(
        [
            "Baxter, two grippers (2 poses)",
            baxter.dof,
            f"{ok.mean():.1%}",
            f"{np.mean(res.iters):.1f}",
            f"{dt * 1e3:.0f}",
            f"{n / dt:,.0f}",
            f"{compile_s:.1f}",
        ]
    )

    talos = dk.load_robot(TALOS, floating=True)
    contacts = ["left_sole_link", "right_sole_link", "gripper_left_base_link", "gripper_right_base_link"]
    rng = np.random.default_rng(1)
    base = np.tile(np.eye(4), (n, 1, 1))
    base[:, :3, :3], base[:, :3, 3] = rotations(rng.normal(0, 0.3, (n, 3))), rng.normal(0, 0.2, (n, 3))
    T = np.asarray(dk.fk(talos, random_q(talos, n, 2), contacts, base=base))
    fn = jax.jit(lambda t: dk.ik.solve(talos, t, solve_base=True))
    compile_s, dt, res = timed(fn, {c: jnp.asarray(T[:, k], jnp.float32) for k, c in enumerate(contacts)})
    ok = np.asarray(res.success)
    got = pinocchio_poses(TALOS, talos, res.q, contacts, base=np.asarray(res.base))
    assert np.all(verified(got, T)[ok]), "a success fails Pinocchio FK"
    rows.append(
        [
            "Talos, 2 soles + 2 grippers (4 poses), root solved",
            f"{talos.dof} + 6",
            f"{ok.mean():.1%}",
            f"{np.mean(res.iters):.1f}",
            f"{dt * 1e3:.0f}",
            f"{n / dt:,.0f}",
            f"{compile_s:.1f}",
        ]
    )
    print(table(["problem", "joints", "success", "mean iters", "time (ms)", "problems/s", "compile (s)"], rows))


def relative_targets(n: int):
    """Baxter's hands from random in-limit configurations: two world poses, then the left one in the
    world and the right one in the left one's frame (the same problems, one term coupling both arms)."""
    baxter = dk.load_robot(BAXTER)
    hands = ["left_gripper", "right_gripper"]
    T = np.asarray(dk.fk(baxter, random_q(baxter, n, 5), hands))
    T_l_r = np.linalg.inv(T[:, 0]) @ T[:, 1]
    left, right = jnp.asarray(T[:, 0], jnp.float32), jnp.asarray(T[:, 1], jnp.float32)
    cases = {
        "two world poses": (lambda l, r: dk.ik.solve(baxter, {hands[0]: l, hands[1]: r}), right, T[:, 1]),
        "left in the world, right in left's frame": (
            lambda l, r: dk.ik.solve(baxter, {hands[0]: l}, relative={tuple(hands): r}),
            jnp.asarray(T_l_r, jnp.float32),
            T_l_r,
        ),
    }
    rows = []
    for name, (solve, second, T_second) in cases.items():
        compile_s, dt, res = timed(jax.jit(solve), left, second)
        ok = np.asarray(res.success)
        got = pinocchio_poses(BAXTER, baxter, res.q, hands)
        if T_second is T_l_r:
            got[:, 1] = np.linalg.inv(got[:, 0]) @ got[:, 1]
        assert np.all(verified(got, np.stack([T[:, 0], T_second], axis=1))[ok]), "a success fails Pinocchio FK"
        reached = np.asarray((res.pos_err <= TOL[0]) & (res.rot_err <= TOL[1]))  # (n, 2)
        rows.append(
            [
                name,
                f"{ok.mean():.1%}",
                f"{reached[:, 0].mean():.1%}",
                f"{reached[:, 1].mean():.1%}",
                f"{np.mean(res.iters):.1f}",
                f"{dt * 1e3:.0f}",
                f"{compile_s:.1f}",
            ]
        )
    headers = ["Baxter's hands", "success", "left reached", "right reached", "mean iters", "time (ms)", "compile (s)"]
    print(table(headers, rows))


def secondary_objectives(n: int):
    rows = []
    for path, frame in ((dk.robots.urdf_path("iiwa14"), "iiwa14_link_ee"), (PANDA, "panda_hand")):
        robot = dk.load_robot(path)
        T = np.array(dk.fk(robot, random_q(robot, n, 3), frame))
        T[:, :3, :3] = T[:, :3, :3] @ rotations(
            np.asarray([0.0, 0.0, 1.0]) * np.random.default_rng(4).uniform(-np.pi, np.pi, (n, 1))
        )  # the tool turned about its z axis: that rotation is free below
        target = {frame: jnp.asarray(T, jnp.float32)}
        weights = {frame: (1.0, 1.0, 1.0, 1.0, 1.0, 0.0)}
        rest = np.clip(np.zeros(robot.dof), robot.lower, robot.upper).astype(np.float32)
        free = jnp.ones(robot.dof, bool)
        for name in ("rest", "limits"):

            def cost(q, name=name, rest=rest, robot=robot, free=free):
                return np.asarray(
                    _secondary.cost_and_step(
                        ((name, 1.0),), jnp.asarray(q).T, rest[:, None], robot.lower, robot.upper, free
                    )[0]
                )

            for secondary in (None, name):
                fn = jax.jit(
                    lambda t, s=secondary, robot=robot, weights=weights, rest=rest: dk.ik.solve(
                        robot, t, weights=weights, rest=rest if s == "rest" else None, secondary=s
                    )
                )
                compile_s, dt, res = timed(fn, target)
                ok = np.asarray(res.success)
                rows.append(
                    [
                        robot.name,
                        name,
                        "with" if secondary else "without",
                        f"{ok.mean():.1%}",
                        f"{np.max(np.asarray(res.pos_err)[ok]):.1e}",
                        f"{np.max(np.asarray(res.rot_err)[ok]):.1e}",
                        f"{np.mean(cost(res.q)[ok]):.3f}",
                        f"{dt * 1e3:.0f}",
                    ]
                )
    print(
        table(
            [
                "robot",
                "objective",
                "solved",
                "success",
                "max pos err (m)",
                "max rot err (rad)",
                "mean secondary cost",
                "time (ms)",
            ],
            rows,
        )
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="problems per row")
    parser.add_argument("--relative", action="store_true", help="only the relative-target rows")
    args = parser.parse_args()
    print(f"# IK of whole robots, {args.n} problems, float32, 1e-5 m / 1e-4 rad. {machine_line()}\n")
    if args.relative:
        print("## Relative targets: the right hand in the left hand's frame\n")
        relative_targets(args.n)
        return
    print("## Several targets at once (pytorch-kinematics: not possible, one end effector per chain)\n")
    several_targets(args.n)
    print("\n## Secondary objectives in the null space (tool rotation about z free: 5 constraints, 7 joints)\n")
    secondary_objectives(args.n)


if __name__ == "__main__":
    main()
