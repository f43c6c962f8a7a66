"""The ``diffkin`` command line: demo, robot info, FK, IK, workspace maps and the benchmark suite.

    diffkin demo [--out DIR] [--quick]
    diffkin info ROBOT_OR_FILE [--end-link L] [--base-link B]
    diffkin fk ROBOT_OR_FILE q1 ... qn | --q-file configs.npy [--format text|json|npy] [--output FILE]
    diffkin ik ROBOT_OR_FILE --pose x y z qw qx qy qz | --position x y z [--seeds N] [--q0 ...] [--all ...]
    diffkin workspace ROBOT_OR_FILE --samples N --voxel V --out map.npz [--plot slice.png]
    diffkin bench [--quick] [--only fk,jacobian,ik,srs,workspace,compile] [--write | --out PATH]

``ROBOT_OR_FILE`` is a built-in robot (``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560``) or a
URDF or MJCF file (``info`` prints its tree; ``fk --frame NAME`` any frame of it; the other commands use
the chain from the root to ``--end-link``). Every computation runs in float64 (``jax_enable_x64`` is
switched on by :func:`main`).
User errors (and a missing optional dependency) print one line ``diffkin: error: ...`` to stderr and
exit with status 2; Ctrl-C exits with status 130. Compiled programs are kept in JAX's persistent
compilation cache (``--cache-dir``, ``--no-cache``, ``DIFFKIN_CACHE_DIR``; see :func:`cache_dir`).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

ROBOTS = ("iiwa7", "iiwa14", "panda", "ur5", "puma560")
SRS_ROBOTS = ("iiwa7", "iiwa14")
_IK_CHUNK = 64  # targets per jitted IK call: one compilation serves every batch size
_CACHE_OFF = ("", "0", "off", "false", "no", "none")  # DIFFKIN_CACHE_DIR values that disable the cache
_CACHE_MIN_SECONDS = 0.1  # compilations at least this long are cached (JAX's default, 1 s, skips FK)
_MAX_SAMPLES = 10**12  # reachability samples (int32 chunk counters; weeks of CPU time already)
_SEED_RANGE = (-(2**63), 2**63 - 1)  # jax.random.key takes a 64-bit integer
# Python parameter names in messages of diffkin's functions, and the flags that set them
_FLAGS = {"end_link": "--end-link", "base_link": "--base-link", "voxel_size": "--voxel", "n_samples": "--samples",
          "num_seeds": "--seeds", "pos_tol": "--pos-tol", "rot_tol": "--rot-tol", "q0": "--q0"}
# the extra that provides each optional module
_EXTRAS = {"optax": "ik", "matplotlib": "plot", "tqdm": "progress", "torch": "validate",
           "pytorch_kinematics": "validate", "pinocchio": "validate"}


class CLIError(Exception):
    """A user error: reported as one line ``diffkin: error: ...`` with exit status 2."""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr and exit status 2.

    Negative numbers in scientific notation (``-1e-3``, ``-2.5E+2``) are values, not options
    (argparse's own pattern knows only ``-1`` and ``-1.5``).
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

    def error(self, message):
        raise CLIError(message)


class _IntermixedParser(_Parser):
    """A subcommand parser that takes options between positionals (``fk URDF --end-link L q1 ...``)."""

    _inside = False

    def parse_known_args(self, args=None, namespace=None):
        if self._inside:  # parse_known_intermixed_args calls back here
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def _need(module: str, what: str, extra: str = "demo"):
    """Import an optional dependency, or a one-line CLIError naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise CLIError(f"{what} needs {module}, which is not installed: pip install 'diffkin[{extra}]' "
                       f"(or pip install {module})") from None


def _flags(message: str) -> str:
    """A message of diffkin's library with its Python parameter names replaced by the CLI's flags."""
    for name, flag in _FLAGS.items():
        message = re.sub(rf"(?<![\w'\"-]){name}\b(?!['\"])", flag, message)  # not a quoted link name
    return message


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


def _integer(text: str) -> int:
    """An int from ``1000``, ``1_000`` or an integral ``1e3``; ArgumentTypeError otherwise."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if math.isfinite(value) and value == int(value):
        return int(value)
    raise argparse.ArgumentTypeError(f"invalid integer: {text!r}")


def _positive_int(text: str, most: int = 10**9) -> int:
    """argparse type: an int in ``[1, most]`` (underscores allowed, as in ``1_000_000``; ``1e6``)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    if value > most:
        raise argparse.ArgumentTypeError(f"expected at most {most:,}, got {text!r}")
    return value


def _samples(text: str) -> int:
    """argparse type: a number of reachability samples, ``1 .. 10**12``."""
    return _positive_int(text, _MAX_SAMPLES)


def _seed(text: str) -> int:
    """argparse type: a PRNG seed, a 64-bit signed integer."""
    value = _integer(text)
    if not _SEED_RANGE[0] <= value <= _SEED_RANGE[1]:
        raise argparse.ArgumentTypeError(f"expected a seed in [-2**63, 2**63 - 1], got {text!r}")
    return value


def _tolerance(text: str) -> float:
    """argparse type: a finite float >= 0."""
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
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


def cache_dir(option: str | None = None, disabled: bool = False) -> Path | None:
    """The folder of JAX's persistent compilation cache for this run, or ``None`` (no cache).

    In order: ``--no-cache`` (``disabled``) turns it off; ``--cache-dir`` (``option``) names it;
    else the environment variable ``DIFFKIN_CACHE_DIR`` names it (empty, ``0``, ``off``, ``false``,
    ``no`` or ``none`` turn it off); else ``$XDG_CACHE_HOME/diffkin/jax`` (default
    ``~/.cache/diffkin/jax``).
    """
    if disabled:
        return None
    if option is not None:
        return Path(option).expanduser()
    env = os.environ.get("DIFFKIN_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in _CACHE_OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "diffkin" / "jax"


def _use_cache(folder: Path | None, chosen: bool = True) -> None:
    """Point JAX's persistent compilation cache at ``folder`` (compilations of 0.1 s or more).

    A folder that cannot be created is an error if the user ``chosen`` it, else the cache stays off.
    """
    if folder is None:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        if not chosen:
            return
        raise CLIError(f"--cache-dir: cannot create {str(folder)!r}: {e.strerror}") from None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", _CACHE_MIN_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def _robot_key(spec: str, end_link: str | None, base_link: str | None) -> tuple:
    """A hashable key of a robot argument (files by absolute path and modification time)."""
    if spec in ROBOTS:
        if end_link is not None or base_link is not None:
            raise CLIError(f"--end-link/--base-link apply to URDF and MJCF files, not to the built-in robot {spec!r}")
        return (spec,)
    path = Path(spec)
    if not path.is_file():
        raise CLIError(f"unknown robot {spec!r}: expected one of {', '.join(ROBOTS)} or a URDF or MJCF file path")
    if not os.access(path, os.R_OK):
        raise CLIError(f"cannot read {spec!r}")
    return (str(path.resolve()), path.stat().st_mtime_ns, end_link, base_link)


@functools.lru_cache(maxsize=16)
def _tree_for(path: str, _mtime: int):
    """The whole robot (``dk.Robot``) of a URDF or MJCF file."""
    import diffkin as dk

    return dk.load_robot(path)


@functools.lru_cache(maxsize=16)
def _chain_for(key: tuple):
    import diffkin as dk

    if len(key) == 1:
        return getattr(dk.robots, key[0])()
    path, mtime, end_link, base_link = key
    robot = _tree_for(path, mtime)
    for flag, name in (("--end-link", end_link), ("--base-link", base_link)):
        if name is not None and name not in robot.frame_names:
            raise CLIError(f"{flag}: unknown link {name!r}; the robot's links and frames are {list(robot.frame_names)}")
    return robot.chain(end_link or _single_end(robot), base_link)


def _single_end(robot) -> str:
    """The end frame of a robot whose tree has one leaf body: its last frame (the deepest fixed link)."""
    parents = set(robot.parents)
    leaves = [b for b in range(len(robot.parents) + 1) if b not in parents and b > 0] or [0]
    if len(leaves) > 1:
        ends = [robot.frame_names[max(f for f, b in enumerate(robot.frame_bodies) if b == leaf)] for leaf in leaves]
        raise CLIError(f"the robot is a tree with {len(leaves)} branches: choose --end-link, e.g. one of {ends}")
    return robot.frame_names[max(f for f, b in enumerate(robot.frame_bodies) if b == leaves[0])]


def _tree(spec: str):
    """The ``dk.Robot`` of a URDF or MJCF path (``None`` for a built-in robot name)."""
    key = _robot_key(spec, None, None)
    return None if len(key) == 1 else _tree_for(key[0], key[1])


def load_robot(spec: str, end_link: str | None = None, base_link: str | None = None):
    """The chain of a built-in robot name, or of one path of a URDF or MJCF file's tree.

    Args:
        spec: ``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560`` or a URDF/MJCF file path.
        end_link: end frame of the chain (default: the last frame of the single leaf).
        base_link: base frame of the chain (default: the root).

    Returns:
        A ``DHChain`` (built-in robots) or ``PoEChain`` (``robot.chain(end_link, base_link)``).

    Raises:
        CLIError: an unknown name, a missing or unreadable file, link options with a built-in robot,
            a tree with several leaves and no ``end_link``.
        ValueError: a malformed file (from :func:`diffkin.load_robot`) or an unknown frame.
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
    norm = float(np.linalg.norm(q))
    if norm < 1e-12:
        raise CLIError(f"--pose: the quaternion (qw qx qy qz) must not be zero, got {' '.join(f'{v:g}' for v in q)}")
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
def _ik_fn(key: tuple, num_seeds: int):
    """A jitted ``dk.ik.solve`` of one robot on ``_IK_CHUNK`` targets (compiled once per target kind).

    Its arguments are ``(targets, key, q0 or None, pos_tol, rot_tol)``; the tolerances are traced.
    """
    jax = _jax()
    import diffkin as dk

    chain = _chain_for(key)
    return jax.jit(lambda T, k, q0, pos_tol, rot_tol: dk.ik.solve(chain, T, key=k, q0=q0, num_seeds=num_seeds,
                                                                   pos_tol=pos_tol, rot_tol=rot_tol))


def _bar(total: int, show: bool | None, **kwargs):
    """A tqdm progress bar on stderr, or ``None``: without tqdm, ``show=False``, or (``None``) off a terminal."""
    if show is False or (show is None and not sys.stderr.isatty()):
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, file=sys.stderr, **kwargs)


def solve_ik(key: tuple, targets: np.ndarray, *, num_seeds: int = 32, q0=None, seed: int = 1,
             pos_tol: float = 1e-5, rot_tol: float = 1e-4, progress: bool | None = False):
    """Batched IK of ``(n, 4, 4)`` or ``(n, 3)`` targets in fixed-size jitted chunks.

    Args:
        progress: a tqdm bar over the targets; ``None``: only on a terminal.

    Returns:
        ``dict`` of numpy arrays ``q (n, dof)``, ``success``, ``pos_err``, ``rot_err``, ``iters`` ``(n,)``.
    """
    jax = _jax()
    targets = np.asarray(targets, dtype=np.float64)
    n = targets.shape[0]
    fn = _ik_fn(key, num_seeds)
    q0 = None if q0 is None else np.asarray(q0, dtype=np.float64)
    tolerances = np.float64(pos_tol), np.float64(rot_tol)
    bar = _bar(n, progress, desc="IK", unit="target") if n > _IK_CHUNK else None
    parts = []
    for c, start in enumerate(range(0, n, _IK_CHUNK)):
        chunk = targets[start:start + _IK_CHUNK]
        pad = _IK_CHUNK - chunk.shape[0]
        chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)]) if pad else chunk
        k = jax.random.fold_in(jax.random.key(seed), c)
        res = fn(chunk, k, q0, *tolerances)
        parts.append({f: np.asarray(getattr(res, f))[:_IK_CHUNK - pad] for f in ("q", "success", "pos_err",
                                                                               "rot_err", "iters")})
        if bar is not None:
            bar.update(_IK_CHUNK - pad)
    if bar is not None:
        bar.close()
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

    One panel for the global configuration of ``q`` (the branch ``q`` itself lies on): each joint
    angle divided by its limit (rad / rad; -1 lower, +1 upper limit, drawn) against the arm angle
    ``psi`` (rad), the arm angles whose solution is within every limit shaded, ``q``'s own arm
    angle dotted. The title gives ``q`` and the signs of joints 2, 4 and 6.

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
    fig = Figure(figsize=(10, 6), layout="constrained")
    ax = fig.add_subplot()
    ax.fill_between(psi, -1, 1, where=valid, color="tab:green", alpha=0.15, lw=0, label="within all limits")
    for j in range(7):
        ax.plot(psi, frac[:, j], lw=1.5, label=f"joint {j + 1} (limits ±{upper[j]:.2f} rad)")
    for limit in (-1, 1):
        ax.axhline(limit, color="k", ls="--", lw=1)
    ax.axvline(psi0, color="k", ls=":", lw=1, label=f"arm angle of q ({float(psi0):+.2f} rad)")
    signs = " ".join(f"{int(g):+d}" for g in gc)
    ax.set(xlim=(-np.pi, np.pi), ylim=(-1.6, 1.6), xlabel="arm angle psi (rad)",
           ylabel="joint angle / its limit (rad / rad; -1 lower, +1 upper limit)")
    ax.set_title(f"{name} self-motion: every configuration with the flange pose of q, along the arm angle psi\n"
                 f"q = {' '.join(f'{v:+.2f}' for v in q)} rad (a random in-limit configuration: IK target 0 "
                 f"of the demo)\nshown: q's own global configuration (signs of joints 2, 4, 6 = {signs});\neach of "
                 f"the other 7 has a self-motion of its own; {valid.mean():.0%} of arm angles within all limits",
                 fontsize="medium")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize="small")
    fig.savefig(path, dpi=120)


def _say(text: str = "", end: str = "\n") -> None:
    print(text, end=end, flush=True)


def cmd_demo(args) -> int:
    """The main job on the built-in iiwa14: FK and its check, batched IK, self-motion, reachability, plots.

    Each stage prints a line as it starts and its figures as it finishes (compile times apart);
    the long ones show a progress bar on a terminal (with tqdm).
    """
    _need("matplotlib", "diffkin demo")
    jax = _jax()
    import jax.numpy as jnp

    import diffkin as dk

    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"--out: cannot create {str(out)!r}: {e.strerror}") from None
    quick = args.quick
    show = False if args.no_progress else None
    n_fk, n_ik, n_sm = (2_000, 50, 200) if quick else (100_000, 1_000, 500)
    n_ws, voxel = (20_000, 0.2) if quick else (500_000, 0.05)
    t_all = time.perf_counter()
    chain = load_robot("iiwa14")
    key = ("iiwa14",)
    _say(f"diffkin {dk.__version__} demo{' (quick)' if quick else ''}: {chain.name}, standard DH, "
         f"{chain.dof} joints, float64, jax {jax.__version__} on {jax.devices()[0].platform}")
    folder = jax.config.jax_compilation_cache_dir
    _say(f"        compiled programs cached in {folder} (a second run compiles less)" if folder else
         "        persistent compilation cache off: every run compiles afresh")

    # FK
    _say(f"FK      {n_fk:,} random configurations, jitted dk.fk ...")
    q = jax.random.uniform(jax.random.key(0), (n_fk, chain.dof), jnp.float64, chain.lower, chain.upper)
    fk = jax.jit(lambda q: dk.fk(chain, q))
    T, t_first = _timed(fk, q)
    T, t_fk = _timed(fk, q)
    pos_e, rot_e = _pose_errors(T, dh_fk_numpy(chain, np.asarray(q)))
    fk_ok = pos_e < 1e-9 and rot_e < 1e-9
    _say(f"        {t_fk * 1e3:.2f} ms warm ({n_fk / t_fk / 1e6:.2f} M/s); compile and first call {t_first:.2f} s")
    _say(f"        FK check vs numpy DH product Rz(theta) Tz(d) Tx(a) Rx(alpha): max position error "
         f"{pos_e:.1e} m, max rotation error {rot_e:.1e} rad: {'OK' if fk_ok else 'FAILED'}")

    # IK
    _say(f"IK      {n_ik:,} random reachable targets, LM, 32 seeds, in jitted chunks of {_IK_CHUNK}: compiling "
         f"(the longest wait{'; cached for later runs' if folder else ''}) ...")
    q_t = jax.random.uniform(jax.random.key(1), (n_ik, chain.dof), jnp.float64, chain.lower, chain.upper)
    targets = np.asarray(fk(q_t))
    start = time.perf_counter()
    res = solve_ik(key, targets[:1])
    t_compile = time.perf_counter() - start
    _say(f"        compiled in {t_compile:.1f} s; solving ...")
    start = time.perf_counter()
    res = solve_ik(key, targets, progress=show)
    t_ik = time.perf_counter() - start
    ok = res["success"]
    check_pos, check_rot = _pose_errors(dh_fk_numpy(chain, res["q"][ok]), targets[ok]) if ok.any() else (0.0, 0.0)
    _say(f"IK      success {ok.mean():.1%} ({ok.sum():,}/{n_ik:,}) at 1e-5 m / 1e-4 rad in {t_ik:.2f} s "
         f"({n_ik / t_ik:,.0f} targets/s; compile {t_compile:.1f} s)")
    med_pos, med_rot = np.median(res["pos_err"]), np.median(res["rot_err"])
    _say(f"        median pos_err {med_pos:.1e} m, rot_err {med_rot:.1e} rad;"
         f" successes re-checked with numpy FK: max {check_pos:.1e} m, {check_rot:.1e} rad")

    # self-motion of one pose
    _say(f"SRS     self-motion of target 0 (dk.srs.sample_self_motion, {n_sm} samples) ...")
    arm, sampler, _, arm_angle = _srs_fns("iiwa14")
    pose = targets[0]
    _, t_sm_first = _timed(sampler(n_sm, False), pose)
    (qs, valid), t_sm = _timed(sampler(n_sm, False), pose)
    qs, valid = np.asarray(qs), np.asarray(valid)
    psi, gc = (np.asarray(x) for x in arm_angle(qs))
    psi_v, gc_v, qs_v = psi[valid], gc[valid], qs[valid]
    sm_pos, sm_rot = _pose_errors(dh_fk_numpy(chain, qs_v), pose) if valid.any() else (0.0, 0.0)
    n_gc = len({tuple(g) for g in gc_v.astype(int)})
    psi_range = f"psi in [{psi_v.min():+.3f}, {psi_v.max():+.3f}] rad" if valid.any() else "no feasible arm angle"
    _say(f"        {int(valid.sum())}/{n_sm} valid samples over {n_gc} global configurations, {psi_range}, max FK "
         f"error {sm_pos:.1e} m / {sm_rot:.1e} rad ({t_sm * 1e3:.2f} ms warm; compile and first call "
         f"{t_sm_first:.2f} s)")

    # reachability
    _say(f"Reach   reachability map, {n_ws:,} samples uniform in joint space, voxel {voxel:g} m: compiling ...")
    start = time.perf_counter()
    dk.workspace.reachability(chain, 1, key=jax.random.key(2), voxel_size=voxel, progress=False)
    t_ws_compile = time.perf_counter() - start
    start = time.perf_counter()
    wmap = dk.workspace.reachability(chain, n_ws, key=jax.random.key(2), voxel_size=voxel, progress=show)
    t_ws = time.perf_counter() - start
    half = dk.workspace.reachability(chain, n_ws // 2, key=jax.random.key(2), voxel_size=voxel, progress=False)
    reached, reached_half = int((wmap.counts > 0).sum()), int((half.counts > 0).sum())
    _say(f"        grid {'x'.join(map(str, wmap.counts.shape))}: {reached:,} voxels reached in {t_ws:.2f} s "
         f"(compile {t_ws_compile:.1f} s)")
    _say(f"        reached volume {reached * voxel**3:.2f} m^3 ({n_ws // 2:,} samples: {reached_half * voxel**3:.2f} "
         f"m^3): a lower bound on the workspace volume that grows with the samples")

    # plots
    _say("Plots   drawing ...")
    start = time.perf_counter()
    pngs = []
    for quantity in ("count", "manipulability"):
        path = out / f"reachability_{quantity}_y0.png"
        dk.workspace.plot_slice(wmap, "y", 0.0, quantity, path=path)
        pngs.append(path.name)
    _plot_self_motion("iiwa14", np.asarray(q_t[0]), out / "self_motion.png")
    pngs.append("self_motion.png")
    _say(f"        {', '.join(pngs)} in {time.perf_counter() - start:.1f} s")
    _say(f"Done in {time.perf_counter() - t_all:.1f} s; wrote {out.resolve()}")
    return 0 if fk_ok else 1


# --------------------------------------------------------------------------------------------- info, fk


def _tree_lines(robot, spec: str) -> list[str]:
    """The tree of a ``dk.Robot``: joints with their parents, mimic couplings, and frames per body."""
    body_name = {0: robot.frame_names[0]}
    for f, b in enumerate(robot.frame_bodies):
        body_name.setdefault(b, robot.frame_names[f])
    kind = "floating root" if robot.floating else "fixed root"
    lines = [f"{robot.name or spec}: Robot (tree), {robot.dof} actuated joints, {len(robot.mimic)} mimic, "
             f"{len(robot.frame_names)} frames, {kind} {robot.frame_names[0]!r}", "",
             f"{'q':>3}  {'joint':<28} {'type':<10} {'parent -> child':<44} limits or coupling"]
    lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
    for j, name in enumerate(robot.tree_joints):
        link = f"{body_name.get(robot.parents[j], '?')} -> {body_name.get(j + 1, '(internal)')}"
        kind = "revolute" if robot.joint_types[j] == "R" else "prismatic"
        if name in robot.mimic:
            source, m, o = robot.mimic[name]
            index, what = "", f"mimic: {m:g} * {source} + {o:g}"
        else:
            i = robot.sources[j]
            index, what = str(i), f"[{lower[i]:.4g}, {upper[i]:.4g}] {'rad' if kind == 'revolute' else 'm'}"
        lines.append(f"{index:>3}  {name:<28} {kind:<10} {link:<44} {what}")
    lines += ["", "frames (by body): " + "; ".join(
        ", ".join(robot.frame_names[f] for f, b in enumerate(robot.frame_bodies) if b == body)
        for body in sorted(set(robot.frame_bodies)))]
    return lines


def cmd_info(args) -> int:
    """The tree of a URDF/MJCF file; joints, limits, the DH or screw table and the home pose of a chain."""
    import diffkin as dk

    tree = _tree(args.robot) if args.end_link is None and args.base_link is None else None
    if tree is not None:
        print("\n".join(_tree_lines(tree, args.robot)))
        try:
            end = _single_end(tree)
        except CLIError as e:
            print(f"\n{e} (then info shows that chain)")
            return 0
        print(f"\nthe chain from the root to {end!r}:\n")
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
    outside = [i for i in range(chain.dof) if not lower[i] <= 0.0 <= upper[i]]
    lines += ["", f"home pose (q = 0): position {_fmt(home[:3, 3])} m, "
              f"quaternion (w x y z) {_fmt(quaternion(home[:3, :3]))}",
              np.array2string(home, precision=6, suppress_small=True)]
    if outside:
        joints = ", ".join(f"{i + 1} ({names[i]}: [{lower[i]:.4g}, {upper[i]:.4g}])" for i in outside)
        lines.append(f"note: q = 0 is outside the limits of joint{'s' if len(outside) > 1 else ''} {joints}: "
                     "the home pose is not a reachable configuration")
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
            delimiter = "," if p.suffix == ".csv" else None
            first = next((line for line in p.read_text().splitlines() if line.strip()), "")
            try:  # a non-numeric first line is a header (``q1,q2,...``): skipped
                [float(v) for v in first.replace(",", " ").split()]
                header = False
            except ValueError:
                header = True
            data = np.loadtxt(p, delimiter=delimiter, ndmin=2, skiprows=1 if header else 0)
        return np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError) as e:
        raise CLIError(f"--q-file: cannot read {path!r}: {e}") from None


def cmd_fk(args) -> int:
    """Poses of configurations given on the command line or in a file."""
    jax = _jax()
    import diffkin as dk

    if args.frame is not None:
        if args.end_link is not None or args.base_link is not None:
            raise CLIError("--frame: give either --frame (a frame of the whole robot) or --end-link/--base-link")
        tree = _tree(args.robot)
        if tree is None:
            raise CLIError(f"--frame: applies to URDF and MJCF files, not to the built-in robot {args.robot!r}")
        if args.frame not in tree.frame_names:
            raise CLIError(f"--frame: unknown frame {args.frame!r}; the robot's frames are {list(tree.frame_names)}")
        model, pose = tree, functools.partial(dk.fk, tree, frames=args.frame)
    else:
        model = load_robot(args.robot, args.end_link, args.base_link)
        pose = functools.partial(dk.fk, model)
    chain = model
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
    if args.output is not None:
        output = Path(args.output)
        if args.format == "npy" and output.suffix != ".npy":
            output = output.with_name(output.name + ".npy")  # where np.save writes it
        if output.is_dir():
            raise CLIError(f"--output: {str(output)!r} is a directory; expected a file name")
        if not output.parent.is_dir():
            raise CLIError(f"--output: no such directory {str(output.parent)!r}")
    T = np.asarray(jax.jit(pose)(q))
    if args.format == "npy":
        np.save(output, T)
        print(f"wrote {T.shape} poses to {output}")
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
        output.write_text(text + "\n")
        print(f"wrote {len(Ts)} poses to {output}")
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
    if args.pose and abs(np.linalg.norm(args.pose[3:]) - 1) > 1e-6:
        print(f"diffkin: note: the quaternion's norm is {np.linalg.norm(args.pose[3:]):.7g}, not 1: normalised",
              file=sys.stderr, flush=True)
    if not args.all and (args.psi is not None or args.gc is not None or args.samples is not None):
        raise CLIError("--psi, --gc and --samples go with --all")
    if args.all:
        if args.q0 is not None:
            raise CLIError("--q0 does not apply to --all")
        if args.pos_tol != 1e-5 or args.rot_tol != 1e-4:
            raise CLIError("--pos-tol and --rot-tol do not apply to --all (exact solutions)")
        args.samples = 16 if args.samples is None else args.samples
        return _ik_all(args, T)
    if args.q0 is not None and len(args.q0) != chain.dof:
        raise CLIError(f"--q0: {chain.name or args.robot} has {chain.dof} joints, got {len(args.q0)} values")
    res = solve_ik(key, T[None], num_seeds=args.seeds, q0=args.q0, seed=args.seed, pos_tol=args.pos_tol,
                   rot_tol=args.rot_tol)
    ok = bool(res["success"][0])
    what = "pose" if T.shape == (4, 4) else "position (orientation free)"
    print(f"{chain.name or args.robot}: IK of a {what}, LM, {args.seeds} seeds{' + q0' if args.q0 else ''}, "
          f"tolerances {args.pos_tol:g} m / {args.rot_tol:g} rad")
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
    if out.is_dir():
        raise CLIError(f"--out: {str(out)!r} is a directory; expected a file name such as {str(out / 'map.npz')!r}")
    saved = out if out.suffix == ".npz" else out.with_name(out.name + ".npz")  # where np.savez writes
    for flag, path in (("--out", saved), ("--plot", args.plot and Path(args.plot))):
        if path and path.is_dir():
            raise CLIError(f"{flag}: {str(path)!r} is a directory; expected a file name such as "
                           f"{str(path / ('map.npz' if flag == '--out' else 'slice.png'))!r}")
        if path and not path.parent.is_dir():
            raise CLIError(f"{flag}: no such directory {str(path.parent)!r}")
    if args.plot:
        _need("matplotlib", "--plot", "plot")
        origin, voxel, shape = dk.workspace._grid(chain, args.voxel, None)  # the map's grid, known in advance
        a = "xyz".index(args.axis)
        lo, hi = origin[a], origin[a] + voxel * shape[a]
        if not lo <= args.value < hi:
            raise CLIError(f"--value: the slice {args.axis} = {args.value:g} m is outside the grid: expected "
                           f"{args.axis} in [{lo:.4g}, {hi:.4g}) m")
    start = time.perf_counter()
    wmap = dk.workspace.reachability(chain, args.samples, key=jax.random.key(args.seed), voxel_size=args.voxel,
                                     progress=not args.no_progress)
    seconds = time.perf_counter() - start
    wmap.save(saved)
    reached = int((wmap.counts > 0).sum())
    print(f"{chain.name or args.robot}: {args.samples:,} samples in {seconds:.2f} s "
          f"({args.samples / seconds / 1e6:.2f} M/s incl. compile), voxel {wmap.voxel_size:g} m, "
          f"grid {'x'.join(map(str, wmap.counts.shape))}, origin {_fmt(wmap.origin, 4)} m")
    print(f"reached {reached:,} voxels ({reached * wmap.voxel_size**3:.3f} m^3 of voxels reached: a lower bound of "
          f"the workspace volume that grows with --samples), {wmap.n_outside:,} samples outside; "
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
    except ModuleNotFoundError as e:
        sys.modules.pop("_diffkin_bench", None)
        name = (e.name or "a package").split(".")[0]
        raise CLIError(f"bench needs {name}, which is not installed: pip install -e '.[test]' "
                       f"(or pip install {name})") from None
    finally:
        sys.path.remove(str(exp))
    return module


def cmd_bench(args) -> int:
    """The benchmark suite ``experiments/bench.py``: diffkin vs pytorch-kinematics, one markdown table."""
    bench = _load_bench()
    unknown = [part for part in args.only or () if part not in bench.ALL_PARTS]
    if unknown:
        raise CLIError(f"--only: unknown part {unknown[0]!r}: expected a comma-separated list of "
                       f"{', '.join(bench.ALL_PARTS)}")
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
    p.add_argument("robot", metavar="ROBOT_OR_FILE",
                   help=f"built-in robot ({', '.join(ROBOTS)}) or the path of a URDF or MJCF file")
    p.add_argument("--end-link", metavar="L", help="end frame of the chain in a file's tree (default: the single leaf)")
    p.add_argument("--base-link", metavar="B", help="base frame of the chain (default: the root)")


def build_parser() -> argparse.ArgumentParser:
    """The ``diffkin`` argument parser with its subcommands."""
    parser = _Parser(prog="diffkin", description="Differentiable robot kinematics in JAX: demo, robot info, "
                     "forward and inverse kinematics, workspace maps. Numbers in float64, angles in radians.")
    from diffkin import __version__

    parser.add_argument("--version", action="version", version=f"diffkin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_IntermixedParser)
    common = _Parser(add_help=False)
    cache = common.add_argument_group("compilation cache")
    cache.add_argument("--cache-dir", metavar="DIR", help="JAX's persistent compilation cache (default "
                       "$DIFFKIN_CACHE_DIR, else $XDG_CACHE_HOME/diffkin/jax or ~/.cache/diffkin/jax; "
                       "DIFFKIN_CACHE_DIR=off disables it)")
    cache.add_argument("--no-cache", action="store_true", help="compile without the persistent cache")
    add_parser = functools.partial(sub.add_parser, parents=[common])

    p = add_parser("demo", help="FK check, batched IK, iiwa self-motion and a reachability map with plots",
                       description="The main job on the built-in iiwa14: random batched FK (jitted) checked against "
                       "a numpy DH product, batched IK of 1,000 targets, the arm-angle self-motion of one pose, a "
                       "reachability map; prints a report and writes PNG plots.")
    p.add_argument("--out", default="diffkin-demo", metavar="DIR", help="folder for the PNGs (default ./diffkin-demo)")
    p.add_argument("--quick", action="store_true", help="small sizes (50 IK targets, tiny map)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_demo)

    p = add_parser("info", help="joints, limits, DH or screw table, home pose",
                       description="Joints, types, limits, the DH table (DHChain) or the space-frame screw table "
                       "(PoEChain, URDFs) and the home pose (FK at q = 0) of a robot.")
    _add_robot(p)
    p.set_defaults(func=cmd_info)

    p = add_parser("fk", help="end-effector poses of configurations",
                       description="End-effector poses (base frame) of joint configurations (radians / metres).")
    _add_robot(p)
    p.add_argument("q", nargs="*", type=_finite, metavar="q", help="joint values q1 ... qn")
    p.add_argument("--q-file", metavar="FILE", help=".npy (or .txt/.csv) file of (n,) or (N, n) joint values")
    p.add_argument("--frame", metavar="NAME", help="a frame of a file's whole robot (q: its actuated joints, "
                   "`diffkin info FILE` lists them), instead of a chain's end effector")
    p.add_argument("--format", choices=("text", "json", "npy"), default="text", help="output format (default text)")
    p.add_argument("--output", metavar="FILE", help="write to FILE (required for npy: an (..., 4, 4) array)")
    p.set_defaults(func=cmd_fk)

    p = add_parser("ik", help="inverse kinematics of one pose or position",
                       description="Inverse kinematics of one target: batched Levenberg-Marquardt from random seeds "
                       "(dk.ik.solve), or with --all every exact iiwa solution along the arm angle (dk.srs). "
                       "Exit status 1 if no solution was found.")
    _add_robot(p)
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--pose", nargs=7, type=_finite, metavar=("X", "Y", "Z", "QW", "QX", "QY", "QZ"),
                        help="target position (m) and orientation quaternion (w x y z)")
    target.add_argument("--position", nargs=3, type=_finite, metavar=("X", "Y", "Z"),
                        help="target position (m), orientation free")
    p.add_argument("--seeds", type=functools.partial(_positive_int, most=4096), default=32, metavar="N",
                   help="random seeds (default 32)")
    p.add_argument("--q0", nargs="+", type=_finite, metavar="Q", help="warm start: one value per joint")
    p.add_argument("--pos-tol", type=_tolerance, default=1e-5, metavar="M",
                   help="success tolerance on the position error, m (default 1e-5)")
    p.add_argument("--rot-tol", type=_tolerance, default=1e-4, metavar="RAD",
                   help="success tolerance on the rotation error, rad (default 1e-4)")
    p.add_argument("--seed", type=_seed, default=1, help="PRNG seed of the random seeds (default 1)")
    p.add_argument("--all", action="store_true", help="iiwa7/iiwa14: exact solutions along the self-motion (dk.srs)")
    p.add_argument("--psi", type=_finite, metavar="PSI", help="with --all: one arm angle (rad), via dk.srs.ik")
    p.add_argument("--gc", nargs=3, type=_sign, metavar=("G2", "G4", "G6"),
                   help="with --all: one global configuration (signs of joints 2, 4, 6; default all eight)")
    p.add_argument("--samples", type=functools.partial(_positive_int, most=10**6), metavar="N",
                   help="with --all: number of samples (default 16)")
    p.set_defaults(func=cmd_ik)

    p = add_parser("workspace", help="reachability map (.npz) and optional slice plot",
                       description="Reachability, manipulability and dexterity map of uniformly sampled "
                       "configurations (dk.workspace.reachability), saved with ReachabilityMap.save.")
    _add_robot(p)
    p.add_argument("--samples", type=_samples, default=1_000_000, metavar="N",
                   help="configurations to sample (default 1,000,000)")
    p.add_argument("--voxel", type=_positive_float, default=0.05, metavar="V", help="voxel edge, m (default 0.05)")
    p.add_argument("--out", required=True, metavar="MAP.npz", help="where to save the map")
    p.add_argument("--plot", metavar="SLICE.png", help="also plot one slice of the map")
    p.add_argument("--axis", choices=("x", "y", "z"), default="y", help="slice normal (default y)")
    p.add_argument("--value", type=_finite, default=0.0, help="slice position along --axis, m (default 0)")
    p.add_argument("--quantity", choices=("count", "manipulability", "dexterity"), default="count",
                   help="plotted quantity (default count)")
    p.add_argument("--seed", type=_seed, default=0, help="PRNG seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_workspace)

    p = add_parser("bench", help="benchmark suite vs pytorch-kinematics (source checkout)",
                       description="The benchmark suite experiments/bench.py (source checkout only): FK, Jacobians, "
                       "IK, the iiwa closed form, self-motion sampling and reachability maps of the iiwa14, timed for "
                       "diffkin and, where installed and where it has the feature, pytorch-kinematics; prints one "
                       "markdown table. The full run takes a few minutes on a CPU.")
    p.add_argument("--quick", action="store_true", help="small batches and fewer rows")
    p.add_argument("--only", type=_parts, metavar="PARTS",
                   help="comma-separated parts to run: fk,jacobian,ik,srs,workspace,compile (default all)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--write", action="store_true", help="also write the table to experiments/results/<machine>.md")
    where.add_argument("--out", metavar="PATH", help="also write the table to PATH")
    p.set_defaults(func=cmd_bench)

    p = add_parser("view", help="interactive 3D viewer in the browser (viser; pip install 'diffkin[viewer]')",
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
        2 a user error or a missing optional dependency (reported as one line on stderr), 130
        interrupted (Ctrl-C; called without ``argv``, the process exits at once with ``os._exit``).
    """
    try:
        args = build_parser().parse_args(argv)
        _use_cache(cache_dir(args.cache_dir, args.no_cache),
                   chosen=args.cache_dir is not None or bool(os.environ.get("DIFFKIN_CACHE_DIR")))
        return args.func(args)
    except SystemExit as e:  # --help, --version
        return e.code if isinstance(e.code, int) else 0
    except BrokenPipeError:  # output piped into head & co.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ModuleNotFoundError as e:  # an optional dependency this command needs
        name = (e.name or "a package").split(".")[0]
        print(f"diffkin: error: this command needs {name}, which is not installed: "
              f"pip install 'diffkin[{_EXTRAS.get(name, 'demo')}]' (or pip install {name})", file=sys.stderr)
        return 2
    except (CLIError, ImportError, ValueError, TypeError, OSError, OverflowError) as e:
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"diffkin: error: {message if isinstance(e, CLIError) else _flags(message)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ndiffkin: interrupted", file=sys.stderr, flush=True)
        if argv is None:  # the program, not a test: JAX's threads may crash a normal exit (status 139)
            sys.stdout.flush()
            os._exit(130)
        return 130
