"""The ``diffkin`` command line: demo, robot info, FK, IK, workspace maps and the benchmark suite.

    diffkin demo [--out DIR] [--quick]
    diffkin info ROBOT_OR_URDF [--end-link L] [--base-link B]
    diffkin fk ROBOT_OR_URDF q1 ... qn | --q-file configs.npy [--format text|json|npy] [--output FILE]
    diffkin ik ROBOT_OR_URDF --pose x y z qw qx qy qz | --position x y z [--seeds N] [--q0 ...] [--all ...]
    diffkin workspace ROBOT_OR_URDF --samples N --voxel V --out map.npz [--plot slice.png]
    diffkin bench [--quick] [--only fk,jacobian,ik,srs,workspace] [--write | --out PATH]

``ROBOT_OR_URDF`` is a built-in robot (``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560``) or a
URDF file. Every computation runs in float64 (``jax_enable_x64`` is switched on by :func:`main`).
User errors print one line ``diffkin: error: ...`` to stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROBOTS = ("iiwa7", "iiwa14", "panda", "ur5", "puma560")
SRS_ROBOTS = ("iiwa7", "iiwa14")
_IK_CHUNK = 64  # targets per jitted IK call: one compilation serves every batch size


class CLIError(Exception):
    """A user error: reported as one line ``diffkin: error: ...`` with exit status 2."""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr and exit status 2."""

    def error(self, message):
        raise CLIError(message)


# --------------------------------------------------------------------------------------------- helpers


def _finite(text: str) -> float:
    """argparse type: a finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    """argparse type: an int >= 1 (underscores allowed, as in ``1_000_000``)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    """argparse type: a finite float > 0."""
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _parts(text: str) -> tuple[str, ...]:
    """argparse type: a comma-separated list of names (``fk,ik``)."""
    parts = tuple(part.strip() for part in text.split(",") if part.strip())
    if not parts:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of names, got {text!r}")
    return parts


def _sign(text: str) -> float:
    """argparse type: ``+1`` or ``-1`` (a global-configuration sign)."""
    value = _finite(text)
    if value not in (1.0, -1.0):
        raise argparse.ArgumentTypeError(f"expected +1 or -1, got {text!r}")
    return value


def _jax():
    """Import jax with float64 enabled."""
    import jax

    jax.config.update("jax_enable_x64", True)
    return jax


def _robot_key(spec: str, end_link: str | None, base_link: str | None) -> tuple:
    """A hashable key of a robot argument (URDF files by absolute path and modification time)."""
    if spec in ROBOTS:
        if end_link is not None or base_link is not None:
            raise CLIError(f"--end-link/--base-link apply to URDF files only, not to the built-in robot {spec!r}")
        return (spec,)
    path = Path(spec)
    if not path.is_file():
        raise CLIError(f"unknown robot {spec!r}: expected one of {', '.join(ROBOTS)} or the path of a URDF file")
    if not os.access(path, os.R_OK):
        raise CLIError(f"cannot read {spec!r}")
    return (str(path.resolve()), path.stat().st_mtime_ns, end_link, base_link)


@functools.lru_cache(maxsize=16)
def _chain_for(key: tuple):
    import diffkin as dk

    if len(key) == 1:
        return getattr(dk.robots, key[0])()
    path, _, end_link, base_link = key
    return dk.load_urdf(path, end_link, base_link=base_link)


def load_robot(spec: str, end_link: str | None = None, base_link: str | None = None):
    """The chain of a built-in robot name or a URDF path.

    Args:
        spec: ``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560`` or a URDF file path.
        end_link: end link of a URDF chain (default: the single leaf).
        base_link: base link of a URDF chain (default: the root).

    Returns:
        A ``DHChain`` (built-in robots) or ``PoEChain`` (URDF).

    Raises:
        CLIError: an unknown name, a missing or unreadable file, link options with a built-in robot.
        ValueError: a malformed URDF (from :func:`diffkin.load_urdf`).
    """
    _jax()
    return _chain_for(_robot_key(spec, end_link, base_link))


def _clean(x) -> np.ndarray:
    """float64 copy with rounding noise below 1e-12 (and negative zeros) set to 0, for printing."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.abs(x) < 1e-12, 0.0, x)


def _indent(text: str, pad: str = "  ") -> str:
    return "\n".join(pad + line for line in text.splitlines())


def _fmt(x, digits: int = 6) -> str:
    """Numbers as ``[a b c]`` with ``digits`` significant digits."""
    return "[" + " ".join(f"{v: .{digits}g}" for v in np.atleast_1d(_clean(x))) + "]"


def quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0`` of a ``(3, 3)`` rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    i = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + 2 * R[0, 0] - tr)
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + 2 * R[1, 1] - tr)
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + 2 * R[2, 2] - tr)
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def pose_from_quaternion(position, quat) -> np.ndarray:
    """``(4, 4)`` pose from a position ``(x, y, z)`` and a quaternion ``(w, x, y, z)`` (normalised here).

    Raises:
        CLIError: a quaternion of (near) zero norm.
    """
    q = np.asarray(quat, dtype=np.float64)
    norm = np.linalg.norm(q)
    if norm < 1e-12:
        raise CLIError(f"--pose: the quaternion (qw qx qy qz) must not be zero, got {list(q)}")
    w, x, y, z = q / norm
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = position
    return T


def dh_fk_numpy(chain, q) -> np.ndarray:
    """Independent FK of a ``DHChain`` in plain numpy: the product of the DH matrices of its table.

    Standard DH multiplies ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` per joint, modified DH
    ``Rx(alpha) Tx(a) Rz(theta) Tz(d)``, between ``chain.base`` and ``chain.tool``.

    Args:
        chain: a ``DHChain``.
        q: ``(..., dof)`` joint values.

    Returns:
        ``(..., 4, 4)`` float64 poses.
    """
    q = np.asarray(q, dtype=np.float64)
    batch = q.shape[:-1]

    def rot(axis, angle):
        c, s = np.cos(angle), np.sin(angle)
        M = np.zeros(batch + (4, 4))
        M[..., 3, 3] = 1.0
        i, j = (0, 1) if axis == "z" else (1, 2)
        k = 2 if axis == "z" else 0
        M[..., i, i], M[..., i, j], M[..., j, i], M[..., j, j], M[..., k, k] = c, -s, s, c, 1.0
        return M

    def trans(axis, dist):
        M = np.broadcast_to(np.eye(4), batch + (4, 4)).copy()
        M[..., "xyz".index(axis), 3] = dist
        return M

    a, alpha, d, off = (np.asarray(v, dtype=np.float64) for v in (chain.a, chain.alpha, chain.d, chain.theta_offset))
    T = np.broadcast_to(np.asarray(chain.base, dtype=np.float64), batch + (4, 4)).copy()
    for i, kind in enumerate(chain.joint_types):
        theta = q[..., i] + off[i] if kind == "R" else np.full(batch, off[i])
        di = d[i] + q[..., i] if kind == "P" else np.full(batch, d[i])
        if chain.modified:
            A = rot("x", np.full(batch, alpha[i])) @ trans("x", np.full(batch, a[i])) @ rot("z", theta) @ trans("z", di)
        else:
            A = rot("z", theta) @ trans("z", di) @ trans("x", np.full(batch, a[i])) @ rot("x", np.full(batch, alpha[i]))
        T = T @ A
    return T @ np.asarray(chain.tool, dtype=np.float64)


def _pose_errors(T, T_ref) -> tuple[float, float]:
    """Max position error (m) and max rotation angle error (rad) between two stacks of poses."""
    T, T_ref = np.asarray(T, dtype=np.float64), np.asarray(T_ref, dtype=np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - T_ref[..., :3, 3], axis=-1)
    R = np.swapaxes(T_ref[..., :3, :3], -1, -2) @ T[..., :3, :3]
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    # arccos loses accuracy near 0: use the norm of the skew part there
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    rot = np.arctan2(np.linalg.norm(skew, axis=-1) / 2, cos)
    return float(pos.max(initial=0.0)), float(rot.max(initial=0.0))


@functools.lru_cache(maxsize=16)
def _ik_fn(key: tuple, num_seeds: int, with_q0: bool):
    """A jitted ``dk.ik.solve`` of one robot on ``_IK_CHUNK`` targets (compiled once per target kind)."""
    jax = _jax()
    import diffkin as dk

    chain = _chain_for(key)
    if with_q0:
        return jax.jit(lambda T, k, q0: dk.ik.solve(chain, T, key=k, q0=q0, num_seeds=num_seeds))
    return jax.jit(lambda T, k: dk.ik.solve(chain, T, key=k, num_seeds=num_seeds))


def solve_ik(key: tuple, targets: np.ndarray, *, num_seeds: int = 32, q0=None, seed: int = 1):
    """Batched IK of ``(n, 4, 4)`` or ``(n, 3)`` targets in fixed-size jitted chunks.

    Returns:
        ``dict`` of numpy arrays ``q (n, dof)``, ``success``, ``pos_err``, ``rot_err``, ``iters`` ``(n,)``.
    """
    jax = _jax()
    targets = np.asarray(targets, dtype=np.float64)
    n = targets.shape[0]
    fn = _ik_fn(key, num_seeds, q0 is not None)
    parts = []
    for c, start in enumerate(range(0, n, _IK_CHUNK)):
        chunk = targets[start:start + _IK_CHUNK]
        pad = _IK_CHUNK - chunk.shape[0]
        chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)]) if pad else chunk
        k = jax.random.fold_in(jax.random.key(seed), c)
        res = fn(chunk, k) if q0 is None else fn(chunk, k, np.asarray(q0, dtype=np.float64))
        parts.append({f: np.asarray(getattr(res, f))[:_IK_CHUNK - pad] for f in ("q", "success", "pos_err",
                                                                               "rot_err", "iters")})
    return {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}


@functools.lru_cache(maxsize=4)
def _srs_fns(name: str):
    """The SRS arm of ``name`` and jitted ``sample_self_motion`` (by sample count), ``ik``, ``arm_angle``."""
    jax = _jax()
    import diffkin as dk

    arm = getattr(dk.srs, name)()

    @functools.lru_cache(maxsize=8)
    def sampler(n: int, with_gc: bool):
        if with_gc:
            return jax.jit(lambda T, gc: dk.srs.sample_self_motion(arm, T, n, gc=gc))
        return jax.jit(lambda T: dk.srs.sample_self_motion(arm, T, n))

    return (arm, sampler, jax.jit(lambda T, psi, gc: dk.srs.ik(arm, T, psi, gc)),
            jax.jit(lambda q: dk.srs.arm_angle(arm, q)))


# --------------------------------------------------------------------------------------------- demo


def _timed(fn, *args):
    """``(result, seconds)`` of ``fn(*args)``, outputs blocked on."""
    import jax

    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start


def _plot_self_motion(name: str, q: np.ndarray, path: Path) -> None:
    """Plot the self-motion through ``q`` of the iiwa ``name``: its joints along the arm angle.

    One panel for the global configuration of ``q``: each joint as a fraction of its range
    (-1 lower, +1 upper limit, drawn) against the arm angle ``psi``, the arm angles whose solution
    is within every limit shaded, ``q``'s own arm angle dotted.

    Args:
        name: ``iiwa7`` or ``iiwa14``.
        q: ``(7,)`` configuration (rad) whose flange pose and global configuration are shown.
        path: the PNG to write.
    """
    from matplotlib.figure import Figure

    arm, _, srs_ik, arm_angle = _srs_fns(name)
    psi0, gc = (np.asarray(x) for x in arm_angle(q))
    psi = np.linspace(-np.pi, np.pi, 721)
    qs, valid = (np.asarray(x) for x in srs_ik(dh_fk_numpy(arm.chain(), q), psi, gc))
    lower, upper = np.asarray(arm.lower), np.asarray(arm.upper)
    frac = (2 * qs - (lower + upper)) / (upper - lower)
    frac[1:][np.abs(np.diff(frac, axis=0)) > 1] = np.nan  # do not draw the +-pi wraps of a joint
    fig = Figure(figsize=(9, 5), layout="constrained")
    ax = fig.add_subplot()
    ax.fill_between(psi, -1, 1, where=valid, color="tab:green", alpha=0.15, lw=0, label="within all limits")
    for j in range(7):
        ax.plot(psi, frac[:, j], lw=1.5, label=f"joint {j + 1}")
    for limit in (-1, 1):
        ax.axhline(limit, color="k", ls="--", lw=1)
    ax.axvline(psi0, color="k", ls=":", lw=1, label="arm angle of q")
    signs = ", ".join(f"{int(g):+d}" for g in gc)
    ax.set(xlim=(-np.pi, np.pi), ylim=(-1.6, 1.6), xlabel="arm angle psi (rad)",
           ylabel="joint position in its range (-1 lower, +1 upper limit)",
           title=f"{name} self-motion of one pose, global configuration ({signs}): "
           f"{valid.mean():.0%} of arm angles feasible")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=5, fontsize="small")
    fig.savefig(path, dpi=120)


def cmd_demo(args) -> int:
    """The main job on the built-in iiwa14: FK and its check, batched IK, self-motion, reachability, plots."""
    jax = _jax()
    import jax.numpy as jnp

    import diffkin as dk

    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"--out: cannot create {str(out)!r}: {e.strerror}") from None
    quick = args.quick
    n_fk, n_ik, n_sm = (2_000, 50, 200) if quick else (100_000, 1_000, 500)
    n_ws, voxel = (20_000, 0.2) if quick else (500_000, 0.05)
    t_all = time.perf_counter()
    chain = load_robot("iiwa14")
    key = ("iiwa14",)
    lines = [f"diffkin {dk.__version__} demo{' (quick)' if quick else ''}: {chain.name}, standard DH, "
             f"{chain.dof} joints, float64, jax {jax.__version__} on {jax.devices()[0].platform}"]

    # FK
    q = jax.random.uniform(jax.random.key(0), (n_fk, chain.dof), jnp.float64, chain.lower, chain.upper)
    fk = jax.jit(lambda q: dk.fk(chain, q))
    T, t_first = _timed(fk, q)
    T, t_fk = _timed(fk, q)
    pos_e, rot_e = _pose_errors(T, dh_fk_numpy(chain, np.asarray(q)))
    fk_ok = pos_e < 1e-9 and rot_e < 1e-9
    lines.append(f"FK      {n_fk:,} random configs (jit): {t_fk * 1e3:.2f} ms warm ({n_fk / t_fk / 1e6:.2f} M/s), "
                 f"first call {t_first:.2f} s")
    lines.append(f"        FK check vs numpy DH product Rz(theta) Tz(d) Tx(a) Rx(alpha): max position error "
                 f"{pos_e:.1e} m, max rotation error {rot_e:.1e} rad: {'OK' if fk_ok else 'FAILED'}")

    # IK
    q_t = jax.random.uniform(jax.random.key(1), (n_ik, chain.dof), jnp.float64, chain.lower, chain.upper)
    targets = np.asarray(fk(q_t))
    start = time.perf_counter()
    res = solve_ik(key, targets[:1])
    t_compile = time.perf_counter() - start
    start = time.perf_counter()
    res = solve_ik(key, targets)
    t_ik = time.perf_counter() - start
    ok = res["success"]
    check_pos, check_rot = _pose_errors(dh_fk_numpy(chain, res["q"][ok]), targets[ok]) if ok.any() else (0.0, 0.0)
    lines.append(f"IK      {n_ik:,} random reachable targets, LM, 32 seeds: success {ok.mean():.1%} "
                 f"({ok.sum():,}/{n_ik:,}) at 1e-5 m / 1e-4 rad in {t_ik:.2f} s ({n_ik / t_ik:,.0f} targets/s; "
                 f"compile {t_compile:.1f} s)")
    med_pos, med_rot = np.median(res["pos_err"]), np.median(res["rot_err"])
    lines.append(f"        median pos_err {med_pos:.1e} m, rot_err {med_rot:.1e} rad;"
                 f" successes re-checked with numpy FK: max {check_pos:.1e} m, {check_rot:.1e} rad")

    # self-motion of one pose
    arm, sampler, _, arm_angle = _srs_fns("iiwa14")
    pose = targets[0]
    (qs, valid), t_sm = _timed(sampler(n_sm, False), pose)
    qs, valid = np.asarray(qs), np.asarray(valid)
    psi, gc = (np.asarray(x) for x in arm_angle(qs))
    psi_v, gc_v, qs_v = psi[valid], gc[valid], qs[valid]
    sm_pos, sm_rot = _pose_errors(dh_fk_numpy(chain, qs_v), pose) if valid.any() else (0.0, 0.0)
    n_gc = len({tuple(g) for g in gc_v.astype(int)})
    psi_range = f"psi in [{psi_v.min():+.3f}, {psi_v.max():+.3f}] rad" if valid.any() else "no feasible arm angle"
    lines.append(f"SRS     self-motion of target 0 (dk.srs.sample_self_motion): {int(valid.sum())}/{n_sm} valid "
                 f"samples over {n_gc} global configurations, {psi_range}, max FK error {sm_pos:.1e} m / "
                 f"{sm_rot:.1e} rad ({t_sm:.2f} s incl. compile)")

    # reachability
    start = time.perf_counter()
    wmap = dk.workspace.reachability(chain, n_ws, key=jax.random.key(2), voxel_size=voxel, progress=False)
    t_ws = time.perf_counter() - start
    reached = int((wmap.counts > 0).sum())
    lines.append(f"Reach   {n_ws:,} samples, voxel {voxel:g} m, grid {'x'.join(map(str, wmap.counts.shape))}: "
                 f"{reached:,} voxels reached ({reached * voxel**3:.2f} m^3), {t_ws:.2f} s incl. compile")

    # plots
    pngs = []
    for quantity in ("count", "manipulability"):
        path = out / f"reachability_{quantity}_y0.png"
        dk.workspace.plot_slice(wmap, "y", 0.0, quantity, path=path)
        pngs.append(path.name)
    _plot_self_motion("iiwa14", np.asarray(q_t[0]), out / "self_motion.png")
    pngs.append("self_motion.png")

    lines.append(f"Plots   {', '.join(pngs)}")
    lines.append(f"Done in {time.perf_counter() - t_all:.1f} s; wrote {out.resolve()}")
    print("\n".join(lines))
    return 0 if fk_ok else 1


# --------------------------------------------------------------------------------------------- info, fk


def cmd_info(args) -> int:
    """Joints, limits, the DH or screw table and the home pose of a robot."""
    import diffkin as dk

    chain = load_robot(args.robot, args.end_link, args.base_link)
    is_dh = isinstance(chain, dk.DHChain)
    kind = ("modified (Craig) DH" if chain.modified else "standard DH") if is_dh else "product of exponentials"
    lines = [f"{chain.name or args.robot}: {type(chain).__name__}, {kind}, {chain.dof} joints ({chain.joint_types})",
             "", f"{'#':>2}  {'joint':<24} {'type':<10} {'lower':>11} {'upper':>11}"]
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
        lines += [f"DH table, {kind}, rows Rz(theta) Tz(d) Tx(a) Rx(alpha)" if not chain.modified else
                  f"DH table, {kind}, rows Rx(alpha) Tx(a) Rz(theta) Tz(d)",
                  f" #  {'a (m)':>10} {'alpha (rad)':>12} {'d (m)':>10} {'theta_offset (rad)':>19}"]
        for i in range(chain.dof):
            lines.append(f"{i + 1:>2}  {float(chain.a[i]):>10.5f} {float(chain.alpha[i]):>12.5f} "
                         f"{float(chain.d[i]):>10.5f} {float(chain.theta_offset[i]):>19.5f}")
        for label, M in (("base", chain.base), ("tool", chain.tool)):
            if not np.allclose(np.asarray(M), np.eye(4)):
                lines += [f"{label}:", np.array2string(_clean(M), precision=5, suppress_small=True)]
    else:
        lines += ["screw table: space-frame unit screw axes [v; w] at q = 0",
                  " #  " + " ".join(f"{c:>9}" for c in ("vx", "vy", "vz", "wx", "wy", "wz"))]
        for i, screw in enumerate(_clean(chain.screws)):
            lines.append(f"{i + 1:>2}  " + " ".join(f"{v:>9.5f}" for v in screw))
    home = np.asarray(dk.fk(chain, np.zeros(chain.dof)))
    home = _clean(home)
    lines += ["", f"home pose (q = 0): position {_fmt(home[:3, 3])} m, "
              f"quaternion (w x y z) {_fmt(quaternion(home[:3, :3]))}",
              np.array2string(home, precision=6, suppress_small=True)]
    print("\n".join(lines))
    return 0


def _read_configs(path: str) -> np.ndarray:
    """Joint values from ``.npy`` or a text file (whitespace- or comma-separated, one config per row)."""
    p = Path(path)
    if not p.is_file():
        raise CLIError(f"--q-file: no such file {path!r}")
    try:
        if p.suffix == ".npy":
            data = np.load(p, allow_pickle=False)
        else:
            data = np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, ndmin=2)
        return np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError) as e:
        raise CLIError(f"--q-file: cannot read {path!r}: {e}") from None


def cmd_fk(args) -> int:
    """Poses of configurations given on the command line or in a file."""
    jax = _jax()
    import diffkin as dk

    chain = load_robot(args.robot, args.end_link, args.base_link)
    if (args.q_file is None) == (not args.q):
        raise CLIError("fk: give the joint values either on the command line or with --q-file (one of the two)")
    q = np.asarray(args.q, dtype=np.float64) if args.q else _read_configs(args.q_file)
    if q.ndim not in (1, 2) or q.shape[-1] != chain.dof:
        raise CLIError(f"{chain.name or args.robot} has {chain.dof} joints: expected {chain.dof} joint values "
                       f"(or an (N, {chain.dof}) array), got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise CLIError("joint values must be finite")
    if args.format == "npy" and args.output is None:
        raise CLIError("--format npy needs --output FILE")
    T = np.asarray(jax.jit(lambda q: dk.fk(chain, q))(q))
    if args.format == "npy":
        np.save(args.output, T)
        print(f"wrote {T.shape} poses to {args.output}")
        return 0
    qs, Ts = q.reshape(-1, chain.dof), T.reshape(-1, 4, 4)
    if args.format == "json":
        doc = {"robot": chain.name or args.robot, "poses": [
            {"q": qi.tolist(), "position": Ti[:3, 3].tolist(), "quaternion_wxyz": quaternion(Ti[:3, :3]).tolist(),
             "T": Ti.tolist()} for qi, Ti in zip(qs, Ts, strict=True)]}
        text = json.dumps(doc, indent=2)
    else:
        blocks = []
        for i, (qi, Ti) in enumerate(zip(qs, Ts, strict=True)):
            blocks.append(f"config {i}: q = {_fmt(qi)}\n  position {_fmt(Ti[:3, 3])} m, quaternion (w x y z) "
                          f"{_fmt(quaternion(Ti[:3, :3]))}\n"
                          + _indent(np.array2string(_clean(Ti), precision=6, suppress_small=True)))
        text = "\n".join(blocks)
    if args.output:
        Path(args.output).write_text(text + "\n")
        print(f"wrote {len(Ts)} poses to {args.output}")
    else:
        print(text)
    return 0


# --------------------------------------------------------------------------------------------- ik


def _ik_all(args, T: np.ndarray) -> int:
    """The exact iiwa solutions of one pose along its self-motion (``dk.srs``)."""
    if args.robot not in SRS_ROBOTS:
        raise CLIError(f"--all: the closed-form arm-angle IK needs a built-in {' or '.join(SRS_ROBOTS)}, "
                       f"got {args.robot!r}")
    if T.shape != (4, 4):
        raise CLIError("--all needs a full --pose (position and orientation)")
    _, sampler, srs_ik, arm_angle = _srs_fns(args.robot)
    gc = None if args.gc is None else np.asarray(args.gc)
    if args.psi is not None:
        gcs = np.array([[g2, g4, g6] for g2 in (1, -1) for g4 in (1, -1) for g6 in (1, -1)], np.float64)
        gcs = gcs if gc is None else gc[None]
        q, valid = (np.asarray(x) for x in srs_ik(T, np.full(len(gcs), args.psi), gcs))
        psi = np.full(len(gcs), args.psi)
        which = "all global configurations" if gc is None else "gc " + _fmt(gc)
        title = f"arm angle psi = {args.psi:+.4f} rad, {which}"
    else:
        q, valid = (np.asarray(x) for x in (sampler(args.samples, False)(T) if gc is None
                                             else sampler(args.samples, True)(T, gc)))
        psi, gcs = (np.asarray(x) for x in arm_angle(q))
        title = f"{args.samples} samples of the self-motion (dk.srs.sample_self_motion)"
    print(f"{args.robot}: {title}; {int(valid.sum())} of {len(valid)} valid (within limits)")
    print(f"{'psi (rad)':>10}  {'gc':>10}  valid  q (rad)")
    for p, g, v, qi in zip(psi, gcs, valid, q, strict=True):
        print(f"{p:>+10.4f}  {' '.join(f'{int(x):+d}' for x in g):>10}  {'yes' if v else 'no ':<5}  {_fmt(qi)}")
    return 0 if valid.any() else 1


def cmd_ik(args) -> int:
    """IK of one pose or position: LM from random seeds, or every exact iiwa solution with ``--all``."""
    key = _robot_key(args.robot, args.end_link, args.base_link)
    chain = load_robot(args.robot, args.end_link, args.base_link)
    T = pose_from_quaternion(args.pose[:3], args.pose[3:]) if args.pose else np.asarray(args.position)
    if not args.all and (args.psi is not None or args.gc is not None or args.samples is not None):
        raise CLIError("--psi, --gc and --samples go with --all")
    if args.all:
        if args.q0 is not None:
            raise CLIError("--q0 does not apply to --all")
        args.samples = 16 if args.samples is None else args.samples
        return _ik_all(args, T)
    if args.q0 is not None and len(args.q0) != chain.dof:
        raise CLIError(f"--q0: {chain.name or args.robot} has {chain.dof} joints, got {len(args.q0)} values")
    res = solve_ik(key, T[None], num_seeds=args.seeds, q0=args.q0, seed=args.seed)
    ok = bool(res["success"][0])
    what = "pose" if T.shape == (4, 4) else "position (orientation free)"
    print(f"{chain.name or args.robot}: IK of a {what}, LM, {args.seeds} seeds{' + q0' if args.q0 else ''}")
    print(f"q        {_fmt(res['q'][0], 10)} rad")
    print(f"success  {ok}")
    print(f"pos_err  {res['pos_err'][0]:.3e} m")
    print(f"rot_err  {res['rot_err'][0]:.3e} rad{' (not constrained)' if T.shape == (3,) else ''}")
    print(f"iters    {int(res['iters'][0])}")
    return 0 if ok else 1


# --------------------------------------------------------------------------------------------- workspace, bench


def cmd_workspace(args) -> int:
    """A reachability map of ``--samples`` configurations on a ``--voxel`` grid, saved as ``.npz``."""
    jax = _jax()
    import diffkin as dk

    chain = load_robot(args.robot, args.end_link, args.base_link)
    out = Path(args.out)
    if not out.parent.is_dir():
        raise CLIError(f"--out: no such directory {str(out.parent)!r}")
    if args.plot and not Path(args.plot).parent.is_dir():
        raise CLIError(f"--plot: no such directory {str(Path(args.plot).parent)!r}")
    start = time.perf_counter()
    wmap = dk.workspace.reachability(chain, args.samples, key=jax.random.key(args.seed), voxel_size=args.voxel,
                                     progress=not args.no_progress)
    seconds = time.perf_counter() - start
    wmap.save(out)
    saved = out if out.suffix == ".npz" else out.with_name(out.name + ".npz")
    reached = int((wmap.counts > 0).sum())
    print(f"{chain.name or args.robot}: {args.samples:,} samples in {seconds:.2f} s "
          f"({args.samples / seconds / 1e6:.2f} M/s incl. compile), voxel {wmap.voxel_size:g} m, "
          f"grid {'x'.join(map(str, wmap.counts.shape))}, origin {_fmt(wmap.origin, 4)} m")
    print(f"reached {reached:,} voxels ({reached * wmap.voxel_size**3:.3f} m^3), {wmap.n_outside:,} samples outside; "
          f"max manipulability {wmap.manipulability.max():.4g}; saved {saved}")
    if args.plot:
        dk.workspace.plot_slice(wmap, args.axis, args.value, args.quantity, path=args.plot)
        print(f"plot: {args.quantity} on the slice {args.axis} = {args.value:g} m -> {args.plot}")
    return 0


def experiments_dir() -> Path:
    """``experiments/`` next to the package (present in a source checkout only)."""
    return Path(__file__).resolve().parent.parent / "experiments"


def _load_bench():
    """``experiments/bench.py`` of the source checkout, as a module.

    Raises:
        CLIError: not a source checkout (a pip-installed diffkin has no ``experiments/``).
    """
    exp = experiments_dir()
    if not (exp / "bench.py").is_file():
        raise CLIError("bench needs the source checkout (experiments/bench.py next to the diffkin package): "
                       "git clone the repository and pip install -e '.[test]'")
    sys.path.insert(0, str(exp))  # for its ``from _bench import ...``
    try:
        spec = importlib.util.spec_from_file_location("_diffkin_bench", exp / "bench.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(exp))
    return module


def cmd_bench(args) -> int:
    """The benchmark suite ``experiments/bench.py``: diffkin vs pytorch-kinematics, one markdown table."""
    bench = _load_bench()
    unknown = [part for part in args.only or () if part not in bench.PARTS]
    if unknown:
        raise CLIError(f"--only: unknown part {unknown[0]!r}: expected a comma-separated list of "
                       f"{', '.join(bench.PARTS)}")
    if args.out and not Path(args.out).parent.is_dir():
        raise CLIError(f"--out: no such directory {str(Path(args.out).parent)!r}")
    return bench.main(args)


# --------------------------------------------------------------------------------------------- view (issue 16)


def cmd_view(args) -> int:
    """An interactive 3D view of a robot in the browser (``dk.viewer.show``), served until Ctrl-C."""
    _jax()
    try:
        from diffkin import viewer
    except ImportError as e:
        raise CLIError(str(e)) from None
    if args.robot not in ROBOTS and not Path(args.robot).is_file():
        raise CLIError(f"unknown robot {args.robot!r}: expected one of {', '.join(ROBOTS)} or a URDF/MJCF file")
    for flag, path in (("--map", args.map), ("--ik-results", args.ik_results)):
        if path is not None and not Path(path).is_file():
            raise CLIError(f"{flag}: no such file {path!r}")
    viewer.show(args.robot, ends=args.end, host=args.host, port=args.port, workspace_map=args.map,
                results=args.ik_results, block=True)
    return 0


# --------------------------------------------------------------------------------------------- parser, main


def _add_robot(p: argparse.ArgumentParser) -> None:
    p.add_argument("robot", metavar="ROBOT_OR_URDF",
                   help=f"built-in robot ({', '.join(ROBOTS)}) or the path of a URDF file")
    p.add_argument("--end-link", metavar="L", help="URDF end link (default: the single leaf)")
    p.add_argument("--base-link", metavar="B", help="URDF base link (default: the root)")


def build_parser() -> argparse.ArgumentParser:
    """The ``diffkin`` argument parser with its subcommands."""
    parser = _Parser(prog="diffkin", description="Differentiable robot kinematics in JAX: demo, robot info, "
                     "forward and inverse kinematics, workspace maps. Numbers in float64, angles in radians.")
    from diffkin import __version__

    parser.add_argument("--version", action="version", version=f"diffkin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)

    p = sub.add_parser("demo", help="FK check, batched IK, iiwa self-motion and a reachability map with plots",
                       description="The main job on the built-in iiwa14: random batched FK (jitted) checked against "
                       "a numpy DH product, batched IK of 1,000 targets, the arm-angle self-motion of one pose, a "
                       "reachability map; prints a report and writes PNG plots.")
    p.add_argument("--out", default="diffkin-demo", metavar="DIR", help="folder for the PNGs (default ./diffkin-demo)")
    p.add_argument("--quick", action="store_true", help="small sizes (50 IK targets, tiny map)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("info", help="joints, limits, DH or screw table, home pose",
                       description="Joints, types, limits, the DH table (DHChain) or the space-frame screw table "
                       "(PoEChain, URDFs) and the home pose (FK at q = 0) of a robot.")
    _add_robot(p)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("fk", help="end-effector poses of configurations",
                       description="End-effector poses (base frame) of joint configurations (radians / metres).")
    _add_robot(p)
    p.add_argument("q", nargs="*", type=_finite, metavar="q", help="joint values q1 ... qn")
    p.add_argument("--q-file", metavar="FILE", help=".npy (or .txt/.csv) file of (n,) or (N, n) joint values")
    p.add_argument("--format", choices=("text", "json", "npy"), default="text", help="output format (default text)")
    p.add_argument("--output", metavar="FILE", help="write to FILE (required for npy: an (..., 4, 4) array)")
    p.set_defaults(func=cmd_fk)

    p = sub.add_parser("ik", help="inverse kinematics of one pose or position",
                       description="Inverse kinematics of one target: batched Levenberg-Marquardt from random seeds "
                       "(dk.ik.solve), or with --all every exact iiwa solution along the arm angle (dk.srs). "
                       "Exit status 1 if no solution was found.")
    _add_robot(p)
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--pose", nargs=7, type=_finite, metavar=("X", "Y", "Z", "QW", "QX", "QY", "QZ"),
                        help="target position (m) and orientation quaternion (w x y z)")
    target.add_argument("--position", nargs=3, type=_finite, metavar=("X", "Y", "Z"),
                        help="target position (m), orientation free")
    p.add_argument("--seeds", type=_positive_int, default=32, metavar="N", help="random seeds (default 32)")
    p.add_argument("--q0", nargs="+", type=_finite, metavar="Q", help="warm start: one value per joint")
    p.add_argument("--seed", type=int, default=1, help="PRNG seed of the random seeds (default 1)")
    p.add_argument("--all", action="store_true", help="iiwa7/iiwa14: exact solutions along the self-motion (dk.srs)")
    p.add_argument("--psi", type=_finite, metavar="PSI", help="with --all: one arm angle (rad), via dk.srs.ik")
    p.add_argument("--gc", nargs=3, type=_sign, metavar=("G2", "G4", "G6"),
                   help="with --all: one global configuration (signs of joints 2, 4, 6; default all eight)")
    p.add_argument("--samples", type=_positive_int, metavar="N", help="with --all: number of samples (default 16)")
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("workspace", help="reachability map (.npz) and optional slice plot",
                       description="Reachability, manipulability and dexterity map of uniformly sampled "
                       "configurations (dk.workspace.reachability), saved with ReachabilityMap.save.")
    _add_robot(p)
    p.add_argument("--samples", type=_positive_int, default=1_000_000, metavar="N",
                   help="configurations to sample (default 1,000,000)")
    p.add_argument("--voxel", type=_positive_float, default=0.05, metavar="V", help="voxel edge, m (default 0.05)")
    p.add_argument("--out", required=True, metavar="MAP.npz", help="where to save the map")
    p.add_argument("--plot", metavar="SLICE.png", help="also plot one slice of the map")
    p.add_argument("--axis", choices=("x", "y", "z"), default="y", help="slice normal (default y)")
    p.add_argument("--value", type=_finite, default=0.0, help="slice position along --axis, m (default 0)")
    p.add_argument("--quantity", choices=("count", "manipulability", "dexterity"), default="count",
                   help="plotted quantity (default count)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_workspace)

    p = sub.add_parser("bench", help="benchmark suite vs pytorch-kinematics (source checkout)",
                       description="The benchmark suite experiments/bench.py (source checkout only): FK, Jacobians, "
                       "IK, the iiwa closed form, self-motion sampling and reachability maps of the iiwa14, timed for "
                       "diffkin and, where installed and where it has the feature, pytorch-kinematics; prints one "
                       "markdown table. The full run takes a few minutes on a CPU.")
    p.add_argument("--quick", action="store_true", help="small batches and fewer rows")
    p.add_argument("--only", type=_parts, metavar="PARTS",
                   help="comma-separated parts to run: fk,jacobian,ik,srs,workspace (default all)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--write", action="store_true", help="also write the table to experiments/results/<machine>.md")
    where.add_argument("--out", metavar="PATH", help="also write the table to PATH")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("view", help="interactive 3D viewer in the browser (viser; pip install 'diffkin[viewer]')",
                       description="Serve an interactive 3D view of a robot (viser): meshes or link cylinders, joint "
                       "sliders, draggable IK targets, the iiwa arm angle, a reachability map, batched results. "
                       "Prints the URL; runs until Ctrl-C.")
    p.add_argument("robot", metavar="ROBOT_OR_FILE", help=f"built-in robot ({', '.join(ROBOTS)}) or a URDF/MJCF file")
    p.add_argument("--port", type=_positive_int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--map", metavar="MAP.npz", help="reachability map from 'diffkin workspace', drawn as points")
    p.add_argument("--ik-results", metavar="FILE.npz",
                   help=".npz: q (N, dof), optional success, pos_err, rot_err (N,), to browse")
    p.add_argument("--end", nargs="+", metavar="FRAME", help="frames with an IK target (default: the leaf frames)")
    p.set_defaults(func=cmd_view)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line.

    Args:
        argv: the arguments (default ``sys.argv[1:]``).

    Returns:
        The exit status: 0 success, 1 a result that failed (no IK solution, failed FK check),
        2 a user error (reported as one line on stderr).
    """
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except SystemExit as e:  # --help, --version
        return e.code if isinstance(e.code, int) else 0
    except BrokenPipeError:  # output piped into head & co.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (CLIError, ValueError, TypeError, OSError) as e:
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"diffkin: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("diffkin: interrupted", file=sys.stderr)
        return 130
