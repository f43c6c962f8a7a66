"""``diffkin info``: a robot's tree, or a chain's joints, limits, DH or screw table and home pose."""

from __future__ import annotations

import numpy as np

from diffkin.cli._errors import CLIError
from diffkin.cli._robots import load_robot, single_end, tree
from diffkin.cli._text import clean, fmt, quaternions


def _tree_lines(robot, spec: str) -> list[str]:
    """The tree of a ``dk.Robot``: joints with their parents, mimic couplings, and frames per body."""
    frames_of: dict[int, list[str]] = {}
    for f, b in enumerate(robot.frame_bodies):
        frames_of.setdefault(b, []).append(robot.frame_names[f])
    body_name = {b: names[0] for b, names in frames_of.items()} | {0: robot.frame_names[0]}
    mimic = robot.mimic  # a property that builds its dict: once, not per joint
    kind = "floating root" if robot.floating else "fixed root"
    lines = [
        f"{robot.name or spec}: Robot (tree), {robot.dof} actuated joints, {len(mimic)} mimic, "
        f"{len(robot.frame_names)} frames, {kind} {robot.frame_names[0]!r}",
        "",
        f"{'q':>3}  {'joint':<28} {'type':<10} {'parent -> child':<44} limits or coupling",
    ]
    lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
    for j, name in enumerate(robot.tree_joints):
        link = f"{body_name.get(robot.parents[j], '?')} -> {body_name.get(j + 1, '(internal)')}"
        kind = {"R": "revolute", "P": "prismatic", "B": "ball"}[robot.joint_types[j]]
        if robot.sources[j] >= robot.dof:
            index, what = "", "solved from q (closed loop)"
        elif name in mimic:
            source, m, o = mimic[name]
            index, what = "", f"mimic: {m:g} * {source} + {o:g}"
        else:
            i = robot.sources[j]
            index, what = str(i), f"[{lower[i]:.4g}, {upper[i]:.4g}] {'m' if kind == 'prismatic' else 'rad'}"
        lines.append(f"{index:>3}  {name:<28} {kind:<10} {link:<44} {what}")
    lines += [
        "",
        "frames (by body): " + "; ".join(", ".join(frames_of[body]) for body in sorted(frames_of)),
    ]
    return lines


def cmd_info(args) -> int:
    """The tree of a URDF/MJCF file; joints, limits, the DH or screw table and the home pose of a chain."""
    import diffkin as dk

    robot = tree(args.robot) if args.end_link is None and args.base_link is None else None
    if robot is not None:
        print("\n".join(_tree_lines(robot, args.robot)))
        try:
            end = single_end(robot)
        except CLIError as e:
            print(f"\n{e} (then info shows that chain)")
            return 0
        print(f"\nthe chain from the root to {end!r}:\n")
    chain = load_robot(args.robot, args.end_link, args.base_link)
    is_dh = isinstance(chain, dk.DHChain)
    kind = ("modified (Craig) DH" if chain.modified else "standard DH") if is_dh else "product of exponentials"
    lines = [
        f"{chain.name or args.robot}: {type(chain).__name__}, {kind}, {chain.dof} joints ({chain.joint_types})",
        "",
        f"{'#':>2}  {'joint':<24} {'type':<10} {'lower':>11} {'upper':>11}",
    ]
    lower, upper = np.asarray(chain.lower), np.asarray(chain.upper)
    names = chain.joint_names or tuple(f"joint{i + 1}" for i in range(chain.dof))
    for i, (name, t) in enumerate(zip(names, chain.joint_types, strict=True)):
        unit = "rad" if t == "R" else "m"
        lim = f"{lower[i]:>11.4f} {upper[i]:>11.4f} {unit}"
        if t == "R" and np.isfinite(lower[i]) and np.isfinite(upper[i]):
            lim += f" ({np.degrees(lower[i]):+.1f} .. {np.degrees(upper[i]):+.1f} deg)"
        lines.append(f"{i + 1:>2}  {name:<24} {'revolute' if t == 'R' else 'prismatic':<10} {lim}")
    lines.append("")
    if is_dh:
        lines += [
            f"DH table, {kind}, rows Rz(theta) Tz(d) Tx(a) Rx(alpha)"
            if not chain.modified
            else f"DH table, {kind}, rows Rx(alpha) Tx(a) Rz(theta) Tz(d)",
            f" #  {'a (m)':>10} {'alpha (rad)':>12} {'d (m)':>10} {'theta_offset (rad)':>19}",
        ]
        for i in range(chain.dof):
            lines.append(
                f"{i + 1:>2}  {float(chain.a[i]):>10.5f} {float(chain.alpha[i]):>12.5f} "
                f"{float(chain.d[i]):>10.5f} {float(chain.theta_offset[i]):>19.5f}"
            )
        for label, M in (("base", chain.base), ("tool", chain.tool)):
            if not np.allclose(np.asarray(M), np.eye(4)):
                lines += [f"{label}:", np.array2string(clean(M), precision=5, suppress_small=True)]
    else:
        lines += [
            "screw table: space-frame unit screw axes [v; w] at q = 0",
            " #  " + " ".join(f"{c:>9}" for c in ("vx", "vy", "vz", "wx", "wy", "wz")),
        ]
        for i, screw in enumerate(clean(chain.screws)):
            lines.append(f"{i + 1:>2}  " + " ".join(f"{v:>9.5f}" for v in screw))
    T_base_home = clean(dk.fk(chain, np.zeros(chain.dof)))
    outside = [i for i in range(chain.dof) if not lower[i] <= 0.0 <= upper[i]]
    lines += [
        "",
        f"home pose (q = 0): position {fmt(T_base_home[:3, 3])} m, "
        f"quaternion (w x y z) {fmt(quaternions(T_base_home))}",
        np.array2string(T_base_home, precision=6, suppress_small=True),
    ]
    if outside:
        joints = ", ".join(f"{i + 1} ({names[i]}: [{lower[i]:.4g}, {upper[i]:.4g}])" for i in outside)
        lines.append(
            f"note: q = 0 is outside the limits of joint{'s' if len(outside) > 1 else ''} {joints}: "
            "the home pose is not a reachable configuration"
        )
    print("\n".join(lines))
    return 0
