"""Motion retargeting: Talos following keypoint trajectories (hands, feet, pelvis) with its root solved.

A synthetic motion (2 s at 30 frames per second): the pelvis sways 5 cm left and right and squats
5 cm, the feet stay planted, the left hand draws a 12 cm circle in front of the body and the
right hand reaches 10 cm forward and back. The keypoints are position targets (as motion capture gives
them); ``dk.ik.solve_path`` solves frame 0 from the standing posture, then each frame from the
last with every joint moving at most 0.15 rad per frame, float64. Re-checked by FK, drawn as a
strip of frames (PNG), and saved for the viewer (``--view`` plays it in the browser).

Run: ``python experiments/retarget.py [--view]`` (writes ``experiments/out/retarget.png`` and
``experiments/out/retarget.npz``)
"""

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from humanoid_ik import OUT, TALOS, skeleton  # noqa: E402

import diffkin as dk  # noqa: E402

FEET = ["left_sole_link", "right_sole_link"]
HANDS = ["gripper_left_base_link", "gripper_right_base_link"]
PELVIS = "base_link"
FRAMES, FPS, MAX_STEP = 60, 30, 0.15


def keypoints(talos) -> dict[str, np.ndarray]:
    """``{frame: (FRAMES, 3)}`` world positions of the keypoints over time (from the standing posture)."""
    stand = np.asarray(dk.link_poses(talos, np.zeros(talos.dof)))[:, :3, 3]
    at = {name: stand[talos.frame_index(name)] for name in FEET + HANDS + [PELVIS]}
    t = np.arange(FRAMES) / FPS
    phase = 2 * np.pi * t / (FRAMES / FPS)
    out = {name: np.tile(at[name], (FRAMES, 1)) for name in FEET}
    pelvis = np.tile(at[PELVIS], (FRAMES, 1))
    pelvis[:, 1] += 0.05 * np.sin(phase)
    pelvis[:, 2] -= 0.025 * (1 - np.cos(phase))
    out[PELVIS] = pelvis
    ahead = np.array([0.25, 0.0, 0.25])  # the hands raised in front of the body
    out[HANDS[0]] = at[HANDS[0]] + ahead + 0.06 * np.stack([np.zeros_like(t), np.cos(phase) - 1, np.sin(phase)], -1)
    reach = np.tile(at[HANDS[1]] + ahead, (FRAMES, 1))
    reach[:, 0] += 0.1 * np.sin(phase / 2)
    out[HANDS[1]] = reach
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--view", action="store_true", help="play the motion in the viewer (needs diffkin[viewer])")
    args = parser.parse_args()
    talos = dk.load_robot(TALOS, floating=True)
    targets = keypoints(talos)
    start = time.perf_counter()
    res = dk.ik.solve_path(
        talos,
        {name: jnp.asarray(p) for name, p in targets.items()},
        q0=jnp.zeros(talos.dof),
        solve_base=True,
        max_step=MAX_STEP,
        key=jax.random.key(0),
    )
    jax.block_until_ready(res.q)
    print(f"solve_path of {FRAMES} frames: {time.perf_counter() - start:.1f} s (compile included)")
    print(
        f"every frame solved: {bool(res.path_ok)} ({int(res.success.sum())} of {FRAMES}), "
        f"largest joint step {float(res.max_step):.3f} rad, largest keypoint error "
        f"{float(res.pos_err.max()):.1e} m"
    )
    names = list(targets)
    reached = np.asarray(dk.fk(talos, res.q, names, base=res.base))[..., :3, 3]
    wanted = np.stack([targets[n] for n in names], axis=1)
    print(f"re-checked by FK: largest keypoint error {np.abs(reached - wanted).max():.1e} m")
    failed = np.flatnonzero(~np.asarray(res.success))
    if failed.size:
        worst = [names[k] for k in np.asarray(res.pos_err)[failed].argmax(axis=-1)]
        print(f"frames not solved: {failed.tolist()}, their worst keypoints: {worst}")
    os.makedirs(OUT, exist_ok=True)
    np.savez(
        os.path.join(OUT, "retarget.npz"),
        q=np.asarray(res.q),
        base=np.asarray(res.base),
        success=np.asarray(res.success),
        pos_err=np.asarray(res.pos_err),
    )

    shown = np.linspace(0, FRAMES - 1, 6).round().astype(int)
    fig = plt.figure(figsize=(15, 5.5))
    for k, i in enumerate(shown):
        ax = fig.add_subplot(1, len(shown), k + 1, projection="3d")
        T = np.asarray(dk.link_poses(talos, res.q[i], base=res.base[i]))
        for a, b in skeleton(talos, T):
            ax.plot(*zip(a, b, strict=True), color="0.3", lw=1.5)
        for name in names:
            color = "tab:blue" if name in FEET else "tab:red" if name in HANDS else "tab:green"
            ax.plot(*targets[name][: i + 1].T, color=color, lw=1, alpha=0.6)
            ax.scatter(*targets[name][i], color=color, s=30)
        ax.set_title(f"t = {i / FPS:.2f} s")
        ax.set_xlim(-0.4, 0.6), ax.set_ylim(-0.5, 0.5), ax.set_zlim(-1.1, 0.5)
        ax.set_box_aspect((1.0, 1.0, 1.6))
        ax.view_init(elev=8, azim=-35)
        ax.set_xticks([]), ax.set_yticks([]), ax.set_zticks([])
    fig.suptitle("Talos retargeted to keypoints (feet blue, hands red, pelvis green) with dk.ik.solve_path")
    path = os.path.join(OUT, "retarget.png")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    print(f"wrote {path}")
    if args.view:
        viewer = dk.viewer.show(
            talos,
            source=TALOS,
            results={"q": np.asarray(res.q), "base": np.asarray(res.base), "success": np.asarray(res.success)},
        )
        viewer.play(fps=FPS, loop=True)
        input("playing in the browser; press Enter to stop\n")
        viewer.stop()


if __name__ == "__main__":
    main()
