"""A humanoid crouching and reaching in balance: IK of Talos' two soles and two grippers with its root
pose solved and its centre of mass over the middle of the feet.

The feet stay where they stand at the zero posture; the hands go where random arm postures put
them with the root 12 cm lower, so the legs must bend; the centre of mass (horizontal components)
stays above the midpoint of the soles. One solve (float64), re-checked against the targets (FK and
``dk.com``), drawn as the skeleton of the solution with the centre of mass and its ground
projection (PNG).

Run: ``python experiments/humanoid_ik.py`` (writes ``experiments/out/humanoid_ik.png``)
"""

import os
from importlib import metadata

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import diffkin as dk  # noqa: E402

ERD = metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
TALOS = os.path.join(str(ERD), "talos_data/robots/talos_reduced.urdf")
FEET = ["left_sole_link", "right_sole_link"]
HANDS = ["gripper_left_base_link", "gripper_right_base_link"]
OUT = os.path.join(os.path.dirname(__file__), "out")


def skeleton(robot, T_frames):
    """Segments ``(start, end)`` between each body's frame and its parent body's frame."""
    first = {}
    for f, b in enumerate(robot.frame_bodies):
        first.setdefault(b, f)
    return [
        (T_frames[first[robot.parents[j]], :3, 3], T_frames[first[j + 1], :3, 3])
        for j in range(len(robot.parents))
        if robot.parents[j] in first and j + 1 in first
    ]


def main():
    talos = dk.load_robot(TALOS, floating=True)
    stand = jnp.zeros(talos.dof)
    feet = dk.fk(talos, stand, FEET)
    arms = [i for i, name in enumerate(talos.joint_names) if name.startswith("arm_")]
    rng = np.random.default_rng(3)
    q_reach = np.zeros(talos.dof)
    lo, hi = np.asarray(talos.lower)[arms], np.asarray(talos.upper)[arms]
    q_reach[arms] = rng.uniform(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))
    low = jnp.eye(4).at[2, 3].set(-0.12)
    hands = dk.fk(talos, q_reach, HANDS, base=low)
    targets = {FEET[0]: feet[0], FEET[1]: feet[1], HANDS[0]: hands[0], HANDS[1]: hands[1]}
    middle = 0.5 * (feet[0, :2, 3] + feet[1, :2, 3])  # the centre of mass over the middle of the soles
    res = dk.ik.solve(talos, targets, com=middle, solve_base=True, rest=stand, key=jax.random.key(0))
    print(
        f"success {bool(res.success)}, position errors {np.asarray(res.pos_err)} m, "
        f"rotation errors {np.asarray(res.rot_err)} rad, centre of mass error {float(res.com_err):.1e} m, "
        f"iterations {int(res.iters)}"
    )
    com = dk.com(talos, res.q, base=res.base)
    off = float(jnp.linalg.norm(com[:2] - middle))
    print(f"re-checked by dk.com: horizontal distance to the middle of the feet {off:.1e} m")
    print(f"root height {float(res.base[2, 3]):+.3f} m (standing: 0)")
    check = dk.fk(talos, res.q, FEET + HANDS, base=res.base)
    target_stack = jnp.stack([targets[name] for name in FEET + HANDS])
    print(f"re-checked by FK: largest position error {float(jnp.abs(check - target_stack)[:, :3, 3].max()):.1e} m")

    fig = plt.figure(figsize=(9, 6))
    for k, (title, q, base) in enumerate(
        (("standing (zero posture)", stand, jnp.eye(4)), ("solved: feet fixed, hands reaching", res.q, res.base))
    ):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        T = np.asarray(dk.link_poses(talos, q, base=base))
        for a, b in skeleton(talos, T):
            ax.plot(*zip(a, b, strict=True), color="0.3", lw=2)
        for name, color in zip(FEET + HANDS, ("tab:blue", "tab:blue", "tab:red", "tab:red"), strict=True):
            p = np.asarray(targets[name])[:3, 3]
            ax.scatter(*p, color=color, s=60, marker="o" if k else "x")
        c = np.asarray(dk.com(talos, q, base=base))
        ground = float(np.asarray(feet)[0, 2, 3])
        ax.scatter(*c, color="tab:green", s=80, marker="D")
        ax.plot([c[0], c[0]], [c[1], c[1]], [c[2], ground], color="tab:green", ls="--", lw=1)
        ax.set_title(title)
        ax.set_xlim(-0.6, 0.6), ax.set_ylim(-0.6, 0.6), ax.set_zlim(-1.1, 0.6)
        ax.set_box_aspect((1.2, 1.2, 1.7))
        ax.view_init(elev=15, azim=-60)
    fig.suptitle(
        "Talos: IK of 2 soles (blue), 2 grippers (red) and the centre of mass (green) over the feet, root solved"
    )
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, "humanoid_ik.png")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
