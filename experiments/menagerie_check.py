"""Which MuJoCo Menagerie robots load as a `dk.Robot`, and whether their bodies sit where MuJoCo puts them.

    python experiments/menagerie_check.py --root PATH/TO/mujoco_menagerie --strip-meshes

``--root`` is a Menagerie checkout (``git clone https://github.com/google-deepmind/mujoco_menagerie``);
without it, the ``mujoco-menagerie`` package's download cache (only the robots already downloaded).
The robots are the registry's entry points of kind "robot" when the ``mujoco-menagerie`` package is
importable (its category too), else every ``<robot_dir>/*.xml`` that is not a scene and has a
``<worldbody>`` or an ``<include>`` (not a file of keyframes or actuators).

Per entry point: ``dk.load_robot``, and the first line of the error if it is rejected. If it loads, the
same file is compiled by MuJoCo (``--strip-meshes``: mesh geoms, meshes and file textures removed in
memory first (geoms fitted to a mesh too, and contact pairs of those geoms), and bodies left
massless bounded by ``boundmass``/``boundinertia``, for a checkout without its binary assets: the
kinematics do not change), ``--n`` random in-range ``q`` are set as
``qpos`` (hinge/slide: ``qpos = q``, joint equalities applied as MuJoCo's ``eq_data`` says; ball:
the rotation vector as a quaternion; free root: a random base pose), and ``mj_kinematics`` is
compared with ``dk.link_poses``: the largest difference of any body's 4x4 pose, float64. A robot with
closed loops (``<equality><connect>``) is compared at diffkin's solved dependent joints where diffkin
exposes them (``dk.loop_closure``), else it reads "loads; not compared".
``--out`` writes the markdown table (default ``experiments/results/menagerie.md``).
"""

from __future__ import annotations

import argparse
import datetime
import glob
import os
import re
import subprocess
import sys

import jax
import mujoco
import numpy as np

import diffkin as dk

TOL = 1e-9  # a pose difference above this is a bug


def _text(path: str) -> str:
    with open(path) as f:
        return f.read()


def entry_points(root: str | None) -> tuple[list[tuple[str, str, str, str]], str]:
    """``[(robot dir, category, entry name, path)]`` and the Menagerie commit ("" if unknown)."""
    try:
        import mujoco_menagerie as mm
    except ImportError:
        mm = None
    if mm is None:
        if root is None:
            sys.exit("--root is required without the mujoco-menagerie package")
        paths = sorted(glob.glob(os.path.join(root, "*", "*.xml")))
        paths = [p for p in paths if "scene" not in os.path.basename(p) and re.search(r"<worldbody|<include", _text(p))]
        return [(os.path.basename(os.path.dirname(p)), "", os.path.basename(p)[:-4], p) for p in paths], ""
    cache = None if root else mm.Cache()
    out = []
    for robot in mm.robots():
        folder = os.path.join(root, robot.name) if root else str(cache.model_path(robot))
        if root is None and not cache.is_cached(robot):
            continue
        for entry in robot.entry_points:
            if entry.kind == "robot":
                out.append((robot.name, robot.category, entry.name, os.path.join(folder, entry.file)))
    return out, mm.commit()


def mujoco_model(path: str, strip_meshes: bool) -> mujoco.MjModel:
    """The compiled model; without mesh geoms (and their contact pairs), meshes and file textures when
    ``strip_meshes``."""
    spec = mujoco.MjSpec.from_file(path)
    if strip_meshes:
        meshed = [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH or g.meshname]
        names = {g.name for g in meshed if g.name}
        for pair in [p for p in spec.pairs if {p.geomname1, p.geomname2} & names]:
            spec.delete(pair)
        for geom in meshed:
            spec.delete(geom)
        for mesh in list(spec.meshes):
            spec.delete(mesh)
        textures = {t.name for t in spec.textures if t.file}
        for texture in [t for t in spec.textures if t.file]:
            spec.delete(texture)
        for material in spec.materials:
            material.textures = ["" if name in textures else name for name in material.textures]
        spec.compiler.boundmass, spec.compiler.boundinertia = 1e-6, 1e-10
    return spec.compile()


def random_q(robot, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, dof)``: hinges and slides uniform in their limits (one turn either way if unlimited or
    limited past it), ball joints uniform in their cone (``|r| <= pi`` if unlimited)."""
    lo = np.maximum(np.where(np.isfinite(robot.lower), robot.lower, -np.pi), -np.pi)
    hi = np.minimum(np.where(np.isfinite(robot.upper), robot.upper, np.pi), np.pi)
    lo, hi = np.where(lo < hi, lo, -np.pi), np.where(lo < hi, hi, np.pi)
    q = rng.uniform(lo, hi, (n, robot.dof))
    types, i = robot.actuated_types, 0
    while i < robot.dof:  # a ball joint is three consecutive "B" entries
        if types[i] == "B":
            direction = rng.normal(size=(n, 3))
            radius = hi[i] * np.cbrt(rng.uniform(size=(n, 1)))
            q[:, i : i + 3] = direction / np.linalg.norm(direction, axis=1, keepdims=True) * radius
            i += 3
        else:
            i += 1
    return q


def to_qpos(robot, model, values: dict[str, float], base: np.ndarray | None) -> np.ndarray:
    """MuJoCo's ``qpos`` for diffkin's joint ``values`` by name (and the floating root's pose ``base``)."""
    qpos = model.qpos0.copy()
    for j in range(model.njnt):
        a, name = model.jnt_qposadr[j], model.joint(j).name or f"joint{j}"
        kind = model.jnt_type[j]
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            qpos[a : a + 3] = base[:3, 3]
            mujoco.mju_mat2Quat(qpos[a + 3 : a + 7], base[:3, :3].flatten())
        elif kind == mujoco.mjtJoint.mjJNT_BALL:
            r = np.array([values[f"{name}:{axis}"] for axis in ("rx", "ry", "rz")])
            angle = np.linalg.norm(r)
            axis = r / angle if angle > 0 else np.zeros(3)
            qpos[a : a + 4] = np.cos(angle / 2), *(np.sin(angle / 2) * axis)
        elif name in values:
            qpos[a] = values[name]
    eqs = [e for e in range(model.neq) if model.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT and model.eq_active0[e]]
    for _ in eqs:  # a chain of joint equalities settles in as many sweeps
        for e in eqs:
            a1, j2 = model.jnt_qposadr[model.eq_obj1id[e]], model.eq_obj2id[e]
            c0, c1 = model.eq_data[e, :2]
            follow = 0.0 if j2 < 0 else c1 * (qpos[model.jnt_qposadr[j2]] - model.qpos0[model.jnt_qposadr[j2]])
            qpos[a1] = model.qpos0[a1] + c0 + follow
    return qpos


def random_base(rng: np.random.Generator) -> np.ndarray:
    T, quat = np.eye(4), rng.normal(size=4)
    mujoco.mju_quat2Mat(R := np.zeros(9), quat / np.linalg.norm(quat))
    T[:3, :3], T[:3, 3] = R.reshape(3, 3), rng.uniform(-1, 1, 3)
    return T


def compare(robot, model, n: int, seed: int) -> str:
    """The largest difference of any body's pose from MuJoCo's over ``n`` configurations, as text; with
    closed loops, at diffkin's solved dependent joints (``dk.loop_closure``), and the largest loop gap."""
    rng = np.random.default_rng(seed)
    Q = random_q(robot, n, rng)
    B = np.stack([random_base(rng) for _ in range(n)]) if robot.floating else None
    poses = np.asarray(dk.link_poses(robot, Q, base=B))
    values = [dict(zip(robot.joint_names, q, strict=True)) for q in Q]
    dependent, gap = getattr(robot, "dependent_names", ()), None
    if dependent:
        q_dependent, gap = map(np.asarray, dk.loop_closure(robot, Q))
        for k in range(n):
            values[k].update(zip(dependent, q_dependent[k], strict=True))
    frames = {name: f for f, name in enumerate(robot.frame_names)}
    names = [model.body(b).name or f"body{b}" for b in range(model.nbody)]
    # a floating robot leaves out the world and the static bodies welded to it (MuJoCo's body_weldid 0)
    names = [(b, name) for b, name in enumerate(names) if not (robot.floating and model.body_weldid[b] == 0)]
    missing = [name for _, name in names if name not in frames]
    if missing:
        return f"bodies missing in diffkin: {', '.join(missing[:3])}"
    data, worst = mujoco.MjData(model), 0.0
    for k in range(n):
        data.qpos[:] = to_qpos(robot, model, values[k], None if B is None else B[k])
        mujoco.mj_kinematics(model, data)
        for b, name in names:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
            worst = max(worst, np.abs(T - poses[k, frames[name]]).max())
    text = f"{worst:.1e}" + (" **MISMATCH**" if worst > TOL else "")
    return text if gap is None else f"{text} ({len(dependent)} dependent joints solved; loop gap {gap.max():.1e})"


def check(path: str, strip_meshes: bool, n: int) -> tuple[str, str, str, str]:
    """``(dof, bodies, loads?, result)`` of one file."""
    if not os.path.isfile(path):
        return "", "", "no file", "not in this checkout"
    try:
        robot = dk.load_robot(path)
    except ValueError as err:
        return "", "", "rejected", str(err).splitlines()[0]
    except Exception as err:  # noqa: BLE001 (anything but a ValueError is itself worth a row)
        return "", "", "rejected", f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
    dof, bodies = str(robot.dof), ""
    try:
        model = mujoco_model(path, strip_meshes)
    except Exception as err:  # noqa: BLE001 (MuJoCo's compile error, whatever its type)
        return dof, bodies, "yes", f"MuJoCo cannot compile it: {str(err).splitlines()[0]}"
    bodies = str(model.nbody - 1)
    loops = [e for e in range(model.neq) if model.eq_active0[e] and model.eq_type[e] != mujoco.mjtEq.mjEQ_JOINT]
    if loops and not getattr(robot, "dependent_names", ()):  # no solved dependent joints to set in qpos
        return dof, bodies, "yes", "loads; not compared (loop constraints)"
    return dof, bodies, "yes", compare(robot, model, n, seed=0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", help="a MuJoCo Menagerie checkout (default: the mujoco-menagerie cache)")
    parser.add_argument("--strip-meshes", action="store_true", help="compile for MuJoCo without mesh files")
    parser.add_argument("--n", type=int, default=8, help="random configurations per robot")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "menagerie.md"))
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    entries, commit = entry_points(args.root)
    rows = ["| robot | category | dof of q | bodies | loads? | max pose error vs MuJoCo, or why not |"]
    rows.append("| --- | --- | --- | --- | --- | --- |")
    counts = {"yes": 0, "rejected": 0, "no file": 0, "compared": 0, "mismatch": 0}
    for folder, category, entry, path in entries:
        dof, bodies, loads, result = check(path, args.strip_meshes, args.n)
        print(f"{folder}/{entry}: {loads}, {result}", flush=True)
        rows.append(f"| `{folder}/{entry}` | {category} | {dof} | {bodies} | {loads} | {result.replace('|', '/')} |")
        counts[loads] += 1
        counts["compared"] += loads == "yes" and result[:1].isdigit()
        counts["mismatch"] += "MISMATCH" in result
    table = "\n".join(rows)
    print(table)
    counted = (
        f"{len(entries)} entry points: {counts['yes']} load ({counts['compared']} compared with MuJoCo, "
        f"{counts['mismatch']} beyond {TOL:g}), {counts['rejected']} rejected, {counts['no file']} not in the checkout."
    )
    print(counted)
    command = "python experiments/menagerie_check.py" + (" --root DIR" if args.root else "")
    command += " --strip-meshes" * args.strip_meshes + (f" --n {args.n}" if args.n != 8 else "")
    head = f"# MuJoCo Menagerie in diffkin\n\n`{command}`, {datetime.date.today()}"
    if commit:
        head += f", the robots of the mujoco-menagerie package's registry (Menagerie commit {commit})"
    if args.root and os.path.isdir(os.path.join(args.root, ".git")):
        git = ["git", "-C", args.root, "rev-parse", "HEAD"]
        head += f", files of checkout {subprocess.run(git, capture_output=True, text=True).stdout.strip()}"
    with open(args.out, "w") as f:
        f.write(f"{head}, mujoco {mujoco.__version__}, jax {jax.__version__}.\n\n{counted}\n\n{table}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
