"""``diffkin demo``: the main job on the built-in iiwa14, stage by stage, with plots."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from diffkin.cli._compiled import IK_CHUNK, solve_ik, srs_fns
from diffkin.cli._errors import CLIError, need
from diffkin.cli._plots import plot_self_motion
from diffkin.cli._robots import jax_x64, load_robot


def _timed(fn, *args):
    """``(result, seconds)`` of ``fn(*args)``, outputs blocked on."""
    import jax

    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start


WARM_CALLS = 7  # warm timings are the median of this many calls after the first


def _median_seconds(fn, *args) -> float:
    """Median seconds of :data:`WARM_CALLS` warm calls of ``fn(*args)`` (outputs blocked on)."""
    return float(np.median([_timed(fn, *args)[1] for _ in range(WARM_CALLS)]))


def _pose_errors(T, T_ref) -> tuple[float, float]:
    """Max position error (m) and max rotation angle error (rad) between ``(..., 4, 4)`` poses (float64)."""
    from diffkin import se3

    T, T_ref = np.asarray(T, dtype=np.float64), np.asarray(T_ref, dtype=np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - T_ref[..., :3, 3], axis=-1)
    rot = np.asarray(se3.rotation_angle(np.swapaxes(T_ref[..., :3, :3], -1, -2) @ T[..., :3, :3]))
    return float(pos.max(initial=0.0)), float(rot.max(initial=0.0))


def _say(text: str = "", end: str = "\n") -> None:
    print(text, end=end, flush=True)


def cmd_demo(args) -> int:
    """The main job on the built-in iiwa14: FK and its check, batched IK, self-motion, reachability, plots.

    Each stage prints a line as it starts and its figures as it finishes (compile times apart);
    the long ones show a progress bar on a terminal (with tqdm). FK, IK solutions and self-motion
    samples are checked against the FK of the robot's shipped URDF (``dk.load_urdf``: the same
    robot from other data, by the product of exponentials).
    """
    need("matplotlib", "diffkin demo")
    jax = jax_x64()
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
    urdf = dk.load_urdf(dk.robots.urdf_path("iiwa14"))  # the same robot from other data

    def fk_urdf(q):
        return dk.fk(urdf, q)

    _say(
        f"diffkin {dk.__version__} demo{' (quick)' if quick else ''}: {chain.name}, standard DH, "
        f"{chain.dof} joints, float64, jax {jax.__version__} on {jax.devices()[0].platform}"
    )
    folder = jax.config.jax_compilation_cache_dir
    _say(
        f"        compiled programs cached in {folder} (a second run compiles less)"
        if folder
        else "        persistent compilation cache off: every run compiles afresh"
    )

    # FK
    _say(f"FK      {n_fk:,} random configurations, jitted dk.fk ...")
    q = jax.random.uniform(jax.random.key(0), (n_fk, chain.dof), jnp.float64, chain.lower, chain.upper)
    fk = jax.jit(lambda q: dk.fk(chain, q))
    T_base_ee, t_first = _timed(fk, q)
    t_fk = _median_seconds(fk, q)
    pos_e, rot_e = _pose_errors(T_base_ee, fk_urdf(q))
    fk_ok = pos_e < 1e-9 and rot_e < 1e-9
    _say(
        f"        {t_fk * 1e3:.2f} ms warm, median of {WARM_CALLS} calls ({n_fk / t_fk / 1e6:.2f} M/s); "
        f"compile and first call {t_first:.2f} s"
    )
    _say(
        f"        FK check vs the shipped URDF's product of exponentials: max position error "
        f"{pos_e:.1e} m, max rotation error {rot_e:.1e} rad: {'OK' if fk_ok else 'FAILED'}"
    )

    # IK
    _say(
        f"IK      {n_ik:,} random reachable targets, LM, 32 seeds, in jitted chunks of {IK_CHUNK}: compiling "
        f"(the longest wait{'; cached for later runs' if folder else ''}) ..."
    )
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
    check_pos, check_rot = _pose_errors(fk_urdf(res["q"][ok]), targets[ok]) if ok.any() else (0.0, 0.0)
    _say(
        f"IK      success {ok.mean():.1%} ({ok.sum():,}/{n_ik:,}) at 1e-5 m / 1e-4 rad in {t_ik:.2f} s "
        f"(one run: {n_ik / t_ik:,.0f} targets/s; compile {t_compile:.1f} s)"
    )
    med_pos, med_rot = np.median(res["pos_err"]), np.median(res["rot_err"])
    _say(
        f"        median pos_err {med_pos:.1e} m, rot_err {med_rot:.1e} rad;"
        f" successes re-checked with the URDF's FK: max {check_pos:.1e} m, {check_rot:.1e} rad"
    )

    # self-motion of one pose
    _say(f"SRS     self-motion of target 0 (dk.srs.sample_self_motion, {n_sm} samples) ...")
    arm, sampler, _, arm_angle = srs_fns("iiwa14")
    T_base_target = targets[0]
    (qs, valid), t_sm_first = _timed(sampler(n_sm, False), T_base_target)
    t_sm = _median_seconds(sampler(n_sm, False), T_base_target)
    qs, valid = np.asarray(qs), np.asarray(valid)
    psi, gc = (np.asarray(x) for x in arm_angle(qs))
    psi_v, gc_v, qs_v = psi[valid], gc[valid], qs[valid]
    sm_pos, sm_rot = _pose_errors(fk_urdf(qs_v), T_base_target) if valid.any() else (0.0, 0.0)
    n_gc = len({tuple(g) for g in gc_v.astype(int)})
    psi_range = f"psi in [{psi_v.min():+.3f}, {psi_v.max():+.3f}] rad" if valid.any() else "no feasible arm angle"
    _say(
        f"        {int(valid.sum())}/{n_sm} valid samples over {n_gc} global configurations, {psi_range}, max FK "
        f"error {sm_pos:.1e} m / {sm_rot:.1e} rad ({t_sm * 1e3:.2f} ms warm, median of {WARM_CALLS} calls; "
        f"compile and first call {t_sm_first:.2f} s)"
    )

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
    _say(
        f"        grid {'x'.join(map(str, wmap.counts.shape))}: {reached:,} voxels reached in {t_ws:.2f} s, one run "
        f"(compile {t_ws_compile:.1f} s)"
    )
    _say(
        f"        reached volume {reached * voxel**3:.2f} m^3 ({n_ws // 2:,} samples: {reached_half * voxel**3:.2f} "
        f"m^3): a lower bound on the workspace volume that grows with the samples"
    )

    # plots
    _say("Plots   drawing ...")
    start = time.perf_counter()
    pngs = []
    for quantity in ("count", "manipulability"):
        path = out / f"reachability_{quantity}_y0.png"
        dk.workspace.plot_slice(wmap, "y", 0.0, quantity, path=path)
        pngs.append(path.name)
    plot_self_motion("iiwa14", np.asarray(q_t[0]), out / "self_motion.png")
    pngs.append("self_motion.png")
    _say(f"        {', '.join(pngs)} in {time.perf_counter() - start:.1f} s")
    _say(f"Done in {time.perf_counter() - t_all:.1f} s; wrote {out.resolve()}")
    return 0 if fk_ok else 1
