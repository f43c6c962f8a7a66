"""The self-motion of an iiwa14 at one pose: joint angles against the arm angle, and the elbow circle.

    python experiments/iiwa_self_motion.py [--out experiments/out] [--q 0.4 0.7 -0.3 -1.1 0.6 0.9 -0.2]

Writes ``iiwa_self_motion_joints.png`` (for each global configuration with feasible arm angles:
the seven joint angles against ``psi``, the joint limits dashed, the feasible intervals shaded)
``iiwa_self_motion_elbow.png`` (the elbow circle about the shoulder-wrist line in 3D, feasible
arcs solid, with exact solutions sampled by ``srs.sample_self_motion`` drawn as arms) and
``iiwa_self_motion_clearance.png`` (a ball placed on the elbow circle: the arm's clearance against
the arm angle for each global configuration, and the samples ``sample_self_motion(..., avoid=...)``
keeps; the arm's collision geometry is :func:`iiwa14_with_capsules`, a sketch: the iiwa14 URDF
shipped with diffkin has none).
"""

from __future__ import annotations

import argparse
import os

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import diffkin as dk  # noqa: E402
import diffkin.srs as srs  # noqa: E402


def iiwa14_with_capsules(radius: float = 0.065) -> str:
    """diffkin's iiwa14 URDF with one capsule per link, from the link's origin to the next joint's (a
    sketch of its collision geometry: the shipped URDF has none; the real links are 6-8 cm in radius)."""
    import xml.etree.ElementTree as ET

    root = ET.parse(dk.robots.urdf_path("iiwa14")).getroot()
    links = {link.get("name"): link for link in root.iter("link")}
    for joint in root.iter("joint"):
        xyz = np.array([float(x) for x in joint.find("origin").get("xyz").split()])
        length = float(np.linalg.norm(xyz))
        if length < 1e-9:
            continue
        axis = xyz / length  # along z or y of the parent link
        rpy = "0 0 0" if abs(axis[2]) > 0.5 else f"{-np.sign(axis[1]) * np.pi / 2} 0 0"
        collision = ET.SubElement(links[joint.find("parent").get("link")], "collision")
        ET.SubElement(collision, "origin", xyz=" ".join(map(str, xyz / 2)), rpy=rpy)
        geometry = ET.SubElement(collision, "geometry")
        ET.SubElement(geometry, "capsule", radius=str(radius), length=str(length))
    return ET.tostring(root, encoding="unicode")


def clearance_plot(arm, target, gc0, out: str) -> None:
    """A ball on the elbow circle of ``gc0`` (at the middle of its first feasible interval): clearance
    against psi for every global configuration, and ``sample_self_motion(..., avoid=...)``'s samples."""
    from diffkin.collision import Sphere, World

    urdf = iiwa14_with_capsules()
    robot = dk.load_robot(urdf)
    geom = dk.collision.load(urdf, robot)
    # pairs already touching at the home configuration (the wrist's short links) are left out, as
    # MoveIt's setup assistant leaves out "default" pairs
    home = np.asarray(dk.collision.self_distances(robot, geom, np.zeros(7)))
    geom = geom.replace_pairs([pair for pair, d in zip(geom.pair_list, home, strict=True) if d > 0])
    intervals, mask = (np.asarray(x) for x in srs.feasible_arm_angles(arm, target, srs.ALL_GC))
    g0 = int(np.flatnonzero(np.all(srs.ALL_GC == np.asarray(gc0), axis=1))[0])
    psi_ball = float(np.mean(intervals[g0][mask[g0]][0]))
    q_ball, _ = srs.ik(arm, target, np.array([psi_ball]), np.asarray(gc0))
    elbow = np.asarray(dk.fk(robot, np.asarray(q_ball), "iiwa14_link_4"))[0, :3, 3]
    world = World(Sphere(elbow[None] + np.array([[0.0, 0.0, 0.12]]), np.array([0.08])))
    margin = 0.02
    avoid = dk.ik.Avoid(geom, world, margin=margin)
    psi = np.linspace(-np.pi, np.pi, 721)
    q, valid = (np.asarray(x) for x in srs.ik(arm, target, psi, srs.ALL_GC[:, None]))  # (8, P, 7), (8, P)
    clear = np.asarray(avoid.clearance(robot, q))  # (8, P)
    samples, ok = srs.sample_self_motion(arm, target, 200, avoid=avoid, model=robot)
    sample_psi, sample_gc = (np.asarray(x) for x in srs.arm_angle(arm, samples))
    shown = [g for g in range(8) if mask[g].any()]
    fig, axes = plt.subplots(len(shown), 1, figsize=(9, 2.2 * len(shown)), sharex=True, squeeze=False)
    for row, g in enumerate(shown):
        ax = axes[row, 0]
        ax.plot(np.rad2deg(psi), np.where(valid[g], clear[g], np.nan), color="tab:blue", lw=1.5)
        ax.axhline(margin, color="tab:red", ls="--", lw=0.8)
        mine = np.all(sample_gc == srs.ALL_GC[g], axis=1) & np.asarray(ok)
        ax.plot(np.rad2deg(sample_psi[mine]), np.full(mine.sum(), margin), "|", color="tab:green", ms=10)
        ax.set_ylabel(f"gc {tuple(int(x) for x in srs.ALL_GC[g])}\nclearance (m)")
    axes[-1, 0].set_xlabel("arm angle psi (deg)")
    fig.suptitle("iiwa14 self-motion beside a ball: clearance (margin dashed, collision-free samples green)")
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    path = os.path.join(out, "iiwa_self_motion_clearance.png")
    fig.savefig(path, dpi=110)
    print("wrote", path)


def main() -> None:
    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "out"))
    parser.add_argument(
        "--q",
        type=float,
        nargs=7,
        default=[0.4, 0.7, -0.3, -1.1, 0.6, 0.9, -0.2],
        help="configuration whose flange pose is the target (radians)",
    )
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    arm = srs.iiwa14()
    chain = arm.chain()
    target = np.asarray(dk.fk(chain, np.array(args.q)))
    psi = np.linspace(-np.pi, np.pi, 2001)
    q, valid = (np.asarray(x) for x in srs.ik(arm, target, psi, srs.ALL_GC[:, None]))  # (8, P, 7), (8, P)
    intervals, mask = (np.asarray(x) for x in srs.feasible_arm_angles(arm, target, srs.ALL_GC))
    shown = [g for g in range(8) if mask[g].any()]
    lower, upper = np.rad2deg(np.asarray(arm.lower)), np.rad2deg(np.asarray(arm.upper))

    fig, axes = plt.subplots(len(shown), 7, figsize=(21, 2.6 * len(shown)), sharex=True, squeeze=False)
    for row, g in enumerate(shown):
        for j in range(7):
            ax = axes[row, j]
            for lo, hi in intervals[g][mask[g]]:
                ax.axvspan(np.rad2deg(lo), np.rad2deg(hi), color="tab:green", alpha=0.15, lw=0)
            angle = np.rad2deg(q[g, :, j])
            angle[1:][np.abs(np.diff(angle)) > 90] = np.nan  # do not draw the jumps of tangent-type joints
            ax.plot(np.rad2deg(psi), angle, lw=1.2, color="tab:blue")
            ax.axhline(lower[j], color="tab:red", ls="--", lw=0.8)
            ax.axhline(upper[j], color="tab:red", ls="--", lw=0.8)
            ax.set_ylim(-185, 185)
            if row == 0:
                ax.set_title(f"joint {j + 1}")
            if j == 0:
                ax.set_ylabel(f"gc = {tuple(int(x) for x in srs.ALL_GC[g])}\nangle (deg)")
            if row == len(shown) - 1:
                ax.set_xlabel("arm angle psi (deg)")
    fig.suptitle(
        "iiwa14 self-motion at q = "
        + np.array2string(np.array(args.q), precision=2)
        + ": joint angles vs psi (limits dashed, feasible psi shaded)"
    )
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path = os.path.join(args.out, "iiwa_self_motion_joints.png")
    fig.savefig(path, dpi=110)
    print("wrote", path)

    # Elbow circle: DH frame 3 origin along psi for gc = the target's own configuration.
    _, gc0 = srs.arm_angle(arm, np.array(args.q))
    g0 = int(np.flatnonzero(np.all(srs.ALL_GC == np.asarray(gc0), axis=1))[0])
    links = np.asarray(dk.link_poses(chain, q[g0]))[:, :, :3, 3]  # (P, 8, 3)
    elbow = links[:, 3]
    fig = plt.figure(figsize=(8, 8))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*elbow.T, color="0.7", lw=1, label="elbow circle (all psi)")
    feasible_elbow = np.where(valid[g0][:, None], elbow, np.nan)
    ax.plot(*feasible_elbow.T, color="tab:green", lw=3, label="feasible psi")
    samples, ok = srs.sample_self_motion(arm, target, 12, gc=gc0)
    for k, qs in enumerate(np.asarray(samples)[np.asarray(ok)]):
        pts = np.asarray(dk.link_poses(chain, qs))[:, :3, 3]
        ax.plot(*pts.T, "-o", color="tab:blue", lw=1, ms=2, alpha=0.7, label="sampled solutions" if k == 0 else None)
    shoulder, wrist = links[0, 1], links[0, 5]
    ax.plot(*np.stack([shoulder, wrist]).T, "k--", lw=1, label="shoulder-wrist axis")
    ax.scatter(*target[:3, 3], color="tab:red", s=40, label="flange target")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_box_aspect((1, 1, 1))
    ax.set_title(f"elbow circle, gc = {tuple(int(x) for x in np.asarray(gc0))}")
    ax.legend(loc="upper left")
    path = os.path.join(args.out, "iiwa_self_motion_elbow.png")
    fig.savefig(path, dpi=110)
    print("wrote", path)
    clearance_plot(arm, target, gc0, args.out)


if __name__ == "__main__":
    main()
