"""The viewer with a Panda's collision shapes among the obstacles of ``docs/scene.json`` (docs/collision.md's picture).

The Panda of example-robot-data (its collision meshes fitted by capsules, its finger boxes exact,
the SRDF's pairs left out), the scene's table, shelf, post and spheres, at a configuration that
reaches low over the table: shapes within the scene's margin of an obstacle or of a link they are
checked against are drawn red, the others blue. Headless Chromium (software WebGL) takes the
screenshot, as ``tests/integration/test_viewer.py`` does.

    python experiments/collision_screenshot.py [--out docs/collision_viewer.png]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time

import numpy as np
from bench_collision import panda

import diffkin as dk

HERE = os.path.dirname(os.path.abspath(__file__))
Q = np.array([-0.35, 0.865, 0.0, -1.45, 0.0, 2.3, 0.45, 0.03])  # the hand low over the table, the fingers open


def screenshot(url: str, path: str) -> None:
    """A 1024 x 768 PNG of the page at ``url`` (headless Chromium, software WebGL)."""
    names = ("chromium", "chromium-browser", "google-chrome")
    browser = next((shutil.which(n) for n in names if shutil.which(n)), None)
    if browser is None:
        raise SystemExit("no chromium binary on the PATH")
    flags = ["--headless=new", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader"]
    flags += ["--enable-unsafe-swiftshader", "--hide-scrollbars", "--window-size=1024,768"]
    flags += ["--virtual-time-budget=15000", f"--screenshot={path}"]
    subprocess.run([browser, *flags, url], check=True, timeout=180)


def drawn(path: str) -> bool:
    """Whether the scene is in the picture: its saturated (red and blue) pixels left of the GUI panel."""
    from PIL import Image

    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)[160:, :680]
    return int(((rgb.max(-1) - rgb.min(-1)) > 60).sum()) > 20_000


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(HERE, "..", "docs", "collision_viewer.png"))
    args = parser.parse_args(argv)
    robot, urdf, srdf = panda()
    scene = dk.collision.load_scene(os.path.join(HERE, "..", "docs", "scene.json"))
    avoid = dk.ik.Avoid(dk.collision.load(urdf, robot, srdf=srdf), scene.world, scene.margin)
    viewer = dk.viewer.show(robot, source=urdf, avoid=avoid, warmup=False, verbose=False, port=8790)
    try:
        viewer.set_q(Q)
        viewer.show_collision.value, viewer.show_meshes.value = True, False  # the shapes, not the meshes
        for handles in viewer.collision:
            for handle in handles:
                handle.visible = True
        for handles in viewer.visuals.values():
            for handle in handles:
                handle.visible = False
        for gizmo in viewer.targets.values():  # the IK gizmos would hide the hand
            gizmo.visible = False
        viewer.server.initial_camera.position = (1.7, -1.5, 1.3)  # from the front left, the shelf's wall behind
        viewer.server.initial_camera.look_at = (0.35, 0.0, 0.35)
        for _ in range(3):  # a busy machine can take the picture before the scene has arrived
            time.sleep(1.0)
            screenshot(viewer.url, os.path.abspath(args.out))
            if drawn(args.out):
                break
    finally:
        viewer.stop()
    print(f"{args.out}: {viewer.clearance_status.content}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
