"""Golden IK results: pin them before a refactor of the solver, compare after (bit for bit).

Solves a fixed set of problems (chains and whole robots: iiwa14 1,000 targets, Panda, Baxter's two
hands, Talos floating with four contacts, locked joints and a secondary objective, a relative
target where the installed diffkin has them) and the implicit gradients of each, and writes every
``IKResult`` field to an ``.npz`` file; ``--compare`` reports, per field, whether a second run is
bit-identical and the largest difference where it is not, and the success rates of both.

Run: ``python experiments/golden_ik.py --write before.npz`` on one checkout, then
``python experiments/golden_ik.py --compare before.npz`` on the other (same machine, CPU).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from bench_ik_robots import BAXTER, TALOS, random_q

import diffkin as dk


def fields(prefix: str, res) -> dict:
    out = {f"{prefix}/{k}": np.asarray(v) for k, v in res._asdict().items() if v is not None}
    return out


def chains() -> dict:
    out = {}
    iiwa = dk.robots.iiwa14()
    T = jnp.asarray(dk.fk(iiwa, random_q(iiwa, 1000, 0)), jnp.float32)
    out |= fields("iiwa14", dk.ik.solve(iiwa, T))
    p = T[:200, :3, 3]
    q0 = jnp.asarray(random_q(iiwa, 200, 1), jnp.float32)
    out |= fields("iiwa14_position_q0", dk.ik.solve(iiwa, p, q0=q0))
    panda = dk.robots.panda()
    T = jnp.asarray(dk.fk(panda, random_q(panda, 300, 2)), jnp.float32)
    out |= fields("panda", dk.ik.solve(panda, T))
    out |= fields("panda_optax", dk.ik.solve(panda, T[:20], method="optax", max_iters=200))
    # implicit gradients: with respect to the target and to the chain's parameters
    grad_T = jax.grad(lambda t: jnp.sum(jnp.sin(dk.ik.solve(iiwa, t).q)))(T[:50])
    grad_a = jax.grad(lambda a: jnp.sum(jnp.sin(dk.ik.solve(iiwa.replace(a=a), T[:50]).q)))(iiwa.a)
    out["iiwa14/grad_target"], out["iiwa14/grad_a"] = np.asarray(grad_T), np.asarray(grad_a)
    return out


def baxter() -> dict:
    robot = dk.load_robot(BAXTER)
    hands = ["left_gripper", "right_gripper"]
    T = jnp.asarray(dk.fk(robot, random_q(robot, 200, 3), hands), jnp.float32)
    targets = {h: T[:, k] for k, h in enumerate(hands)}
    out = fields("baxter", dk.ik.solve(robot, targets))
    small = {h: t[:30] for h, t in targets.items()}
    g = jax.grad(lambda t: jnp.sum(jnp.sin(dk.ik.solve(robot, t).q)))(small)
    out |= {f"baxter/grad_{h}": np.asarray(v) for h, v in g.items()}
    weights = {"left_gripper": (1.0, 1.0, 1.0, 1.0, 1.0, 0.0), "right_gripper": (2.0, 0.5)}
    out |= fields("baxter_weights", dk.ik.solve(robot, {h: t[:100] for h, t in targets.items()}, weights=weights))
    return out


def talos() -> dict:
    robot = dk.load_robot(TALOS, floating=True)
    contacts = ["left_sole_link", "right_sole_link", "gripper_left_base_link", "gripper_right_base_link"]
    n = 100
    rng = np.random.default_rng(4)
    base = np.tile(np.eye(4), (n, 1, 1))
    quat = rng.normal(0, 1, (n, 4)) * [1, 0.15, 0.15, 0.15] + [3, 0, 0, 0]
    base[:, :3, :3] = np.asarray(dk.se3.rotation_from_quaternion(quat / np.linalg.norm(quat, axis=-1, keepdims=True)))
    base[:, :3, 3] = rng.normal(0, 0.2, (n, 3))
    q = random_q(robot, n, 5)
    locked_names = ["head_1_joint", "head_2_joint"]
    for name in locked_names:
        q[:, robot.joint_names.index(name)] = 0.0
    T = jnp.asarray(dk.fk(robot, q, contacts, base=base), jnp.float32)
    targets = {c: T[:, k] for k, c in enumerate(contacts)}
    rest = jnp.zeros(robot.dof, jnp.float32)
    res = dk.ik.solve(robot, targets, solve_base=True, locked={j: 0.0 for j in locked_names}, rest=rest)
    out = fields("talos", res)
    small = {c: t[:10] for c, t in targets.items()}
    g = jax.grad(lambda t: jnp.sum(jnp.sin(dk.ik.solve(robot, t, solve_base=True).q)))(small)
    out |= {f"talos/grad_{c}": np.asarray(v) for c, v in g.items()}
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", help="write the results to this .npz")
    group.add_argument("--compare", help="compare with the results in this .npz")
    parser.add_argument("--only", choices=["chains", "baxter", "talos"], action="append")
    args = parser.parse_args()
    out = {}
    for name, fn in (("chains", chains), ("baxter", baxter), ("talos", talos)):
        if args.only and name not in args.only:
            continue
        start = time.perf_counter()
        out |= fn()
        print(f"{name}: {time.perf_counter() - start:.1f} s", flush=True)
    if args.write:
        np.savez_compressed(args.write, **out)
        print(f"wrote {len(out)} arrays to {args.write}")
        return
    ref = np.load(args.compare)
    identical = True
    for key in sorted(out):
        if key not in ref:
            print(f"{key}: new (not in {args.compare})")
            continue
        a, b = out[key], ref[key]
        if a.shape != b.shape or a.dtype != b.dtype:
            print(f"{key}: shape/dtype {a.shape} {a.dtype} != {b.shape} {b.dtype}")
            identical = False
        elif not np.array_equal(a, b):
            identical = False
            if a.dtype == bool:
                print(f"{key}: {np.sum(a != b)} of {a.size} differ; mean {a.mean():.4f} (was {b.mean():.4f})")
            else:
                diff = np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))
                print(f"{key}: differs, max |diff| {diff:.3g}, {np.sum(a != b)} of {a.size} entries")
        if key.endswith("/success"):
            print(f"{key}: success {a.mean():.4f} (was {b.mean():.4f})")
    print("bit-identical" if identical else "NOT bit-identical")


if __name__ == "__main__":
    main()
