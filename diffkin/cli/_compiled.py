"""The jitted functions the commands share, compiled once per robot and shape: batched IK, IK among
obstacles, the iiwa closed form."""

from __future__ import annotations

import functools
import sys
from collections.abc import Sequence

import numpy as np

from diffkin.cli._robots import chain_for, jax_x64, robot_key, robot_with_geometry, srdf_key

IK_CHUNK = 64  # targets per jitted IK call: one compilation serves every batch size


@functools.lru_cache(maxsize=16)
def _ik_fn(key: tuple, num_seeds: int):
    """A jitted ``dk.ik.solve`` of one robot on ``IK_CHUNK`` targets (compiled once per target kind).

    Its arguments are ``(targets, key, q0 or None, pos_tol, rot_tol)``; the tolerances are traced.
    """
    jax_x64()
    import diffkin as dk
    from diffkin._xla import solver_jit

    chain = chain_for(key)
    return solver_jit(
        lambda T, k, q0, pos_tol, rot_tol: dk.ik.solve(
            chain, T, key=k, q0=q0, num_seeds=num_seeds, pos_tol=pos_tol, rot_tol=rot_tol
        )
    )


def progress_bar(total: int, show: bool | None, **kwargs):
    """A tqdm progress bar on stderr, or ``None``: without tqdm, ``show=False``, or (``None``) off a terminal."""
    if show is False or (show is None and not sys.stderr.isatty()):
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, file=sys.stderr, **kwargs)


def solve_ik(
    key: tuple,
    targets: np.ndarray,
    *,
    num_seeds: int = 32,
    q0=None,
    seed: int = 1,
    pos_tol: float = 1e-5,
    rot_tol: float = 1e-4,
    progress: bool | None = False,
):
    """Batched IK of ``(n, 4, 4)`` or ``(n, 3)`` targets in fixed-size jitted chunks.

    Args:
        key: the robot (:func:`diffkin.cli._robots.robot_key`).
        targets: ``(n, 4, 4)`` poses ``T_base_ee`` or ``(n, 3)`` positions (m) in the chain's base frame.
        progress: a tqdm bar over the targets; ``None``: only on a terminal.

    Returns:
        ``dict`` of numpy arrays ``q (n, dof)``, ``success``, ``pos_err``, ``rot_err``, ``iters`` ``(n,)``.
    """
    jax = jax_x64()
    targets = np.asarray(targets, dtype=np.float64)
    n = targets.shape[0]
    fn = _ik_fn(key, num_seeds)
    q0 = None if q0 is None else np.asarray(q0, dtype=np.float64)
    tolerances = np.float64(pos_tol), np.float64(rot_tol)
    bar = progress_bar(n, progress, desc="IK", unit="target") if n > IK_CHUNK else None
    parts = []
    for c, start in enumerate(range(0, n, IK_CHUNK)):
        chunk = targets[start : start + IK_CHUNK]
        pad = IK_CHUNK - chunk.shape[0]
        chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)]) if pad else chunk
        k = jax.random.fold_in(jax.random.key(seed), c)
        res = fn(chunk, k, q0, *tolerances)
        parts.append(
            {f: np.asarray(getattr(res, f))[: IK_CHUNK - pad] for f in ("q", "success", "pos_err", "rot_err", "iters")}
        )
        if bar is not None:
            bar.update(IK_CHUNK - pad)
    if bar is not None:
        bar.close()
    return {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}


@functools.lru_cache(maxsize=8)
def _avoid_ik_fn(spec: str, key: tuple, end: str, num_seeds: int, self_collision: bool, srdf: tuple):
    """A jitted one-target ``dk.ik.solve`` of a file's whole robot with ``avoid``, compiled once per
    robot file (``key``: its :func:`~diffkin.cli._robots.robot_key`), end frame, seed count,
    ``self_collision`` and SRDF files (``srdf``: :func:`~diffkin.cli._robots.srdf_key`); the robot and
    its collision geometry are closed over.

    Its arguments are ``(target, key, q0 or None, pos_tol, rot_tol, world, margin)``: the obstacles
    (a ``dk.collision.World``; one compilation per count of each kind), the tolerances and the margin
    are traced.
    """
    jax_x64()
    import diffkin as dk
    from diffkin._xla import solver_jit

    robot, geom = robot_with_geometry(spec, [path for path, _ in srdf])
    return solver_jit(
        lambda T, k, q0, pos_tol, rot_tol, world, margin: dk.ik.solve(
            robot,
            {end: T},
            key=k,
            q0=q0,
            num_seeds=num_seeds,
            pos_tol=pos_tol,
            rot_tol=rot_tol,
            avoid=dk.ik.Avoid(geom, world, margin, self_collision),
        )
    )


def solve_ik_avoiding(
    spec: str,
    end: str,
    target: np.ndarray,
    scene,
    *,
    num_seeds: int = 32,
    q0=None,
    seed: int = 1,
    pos_tol: float = 1e-5,
    rot_tol: float = 1e-4,
    srdf: Sequence[str] | None = None,
):
    """IK of one target of a URDF/MJCF file's whole robot, keeping clear of a scene's obstacles.

    Args:
        spec: the robot file (its collision geometry: :func:`diffkin.cli._robots.robot_with_geometry`).
        end: the frame that goes to ``target``.
        target: ``(4, 4)`` pose ``T_world_end`` or ``(3,)`` position (m) in the robot's root frame.
        scene: a ``dk.collision.Scene`` (obstacles in the root frame, ``margin``, ``self_collision``),
            its arrays in float64.
        q0: ``(dof,)`` warm start (every actuated joint of the robot), or ``None``.
        srdf: SRDF files whose ``<disable_collisions>`` pairs are not checked.

    Returns:
        ``dict`` of numpy values: ``q (dof,)``, ``success``, ``pos_err``, ``rot_err``, ``iters`` and
        ``clearance`` (m) scalars.
    """
    jax = jax_x64()
    import diffkin as dk

    robot, geom = robot_with_geometry(spec, srdf)
    dk.ik.Avoid(geom, scene.world, scene.margin, scene.self_collision)  # its checks on the host, before compiling
    fn = _avoid_ik_fn(spec, robot_key(spec, None, None), end, num_seeds, scene.self_collision, srdf_key(srdf))
    res = fn(
        np.asarray(target, dtype=np.float64),
        jax.random.key(seed),
        None if q0 is None else np.asarray(q0, dtype=np.float64),
        np.float64(pos_tol),
        np.float64(rot_tol),
        scene.world,
        np.float64(scene.margin),
    )
    return {
        "q": np.asarray(res.q),
        **{f: np.asarray(getattr(res, f)).reshape(()) for f in ("success", "pos_err", "rot_err", "iters", "clearance")},
    }


@functools.lru_cache(maxsize=4)
def srs_fns(name: str):
    """The SRS arm of ``name`` and jitted ``sample_self_motion`` (by sample count), ``ik``, ``arm_angle``."""
    jax = jax_x64()
    import diffkin as dk

    arm = getattr(dk.srs, name)()

    @functools.lru_cache(maxsize=8)
    def sampler(n: int, with_gc: bool):
        if with_gc:
            return jax.jit(lambda T, gc: dk.srs.sample_self_motion(arm, T, n, gc=gc))
        return jax.jit(lambda T: dk.srs.sample_self_motion(arm, T, n))

    return (
        arm,
        sampler,
        jax.jit(lambda T, psi, gc: dk.srs.ik(arm, T, psi, gc)),
        jax.jit(lambda q: dk.srs.arm_angle(arm, q)),
    )
