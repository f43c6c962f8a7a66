"""Capability maps across device counts (4 host devices, in a subprocess), the ``diffkin workspace
--capability`` and ``diffkin place`` commands, and the placement plot (matplotlib: the plot extra)."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import diffkin as dk
from diffkin import cli
from diffkin import workspace as ws
from diffkin.workspace._placement import planar_poses

KEY = jax.random.key(7)


def test_identical_capability_maps_on_1_3_and_4_devices(tmp_path):
    script = f"""
        import json, jax, numpy as np
        import diffkin as dk
        chain, devices = dk.robots.panda(), jax.devices()
        maps = [dk.workspace.capability(chain, 10_123, key=jax.random.key(7), voxel_size=0.15, chunk=1000,
                                        orientation_bins=648, devices=devices[:k], dtype="float32") for k in (1, 3, 4)]
        maps[2].save({str(tmp_path / "four.npz")!r})
        same = [all(np.array_equal(getattr(a, f), getattr(maps[0], f)) for f in ("cells", "cell_counts", "counts",
                "manipulability")) for a in maps]
        print(json.dumps(dict(n_devices=len(devices), same=same, total=[int(a.cell_counts.sum()) for a in maps])))
    """
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        env={**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"},
        timeout=240,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result == dict(n_devices=4, same=[True, True, True], total=[10_123] * 3)
    four = ws.CapabilityMap.load(tmp_path / "four.npz")
    reach = ws.reachability(dk.robots.panda(), 10_123, key=KEY, voxel_size=0.15, chunk=1000, dtype="float32")
    np.testing.assert_array_equal(four.counts, reach.counts)  # the same samples as the reachability map's


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_capability_map_then_place(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    code, out, err = run(
        capsys, "workspace", "panda", "--capability", "--samples", 20_000, "--voxel", 0.2, "--orientation-bins", 24,
        "--out", tmp_path / "cap.npz", "--no-progress",
    )  # fmt: skip
    assert code == 0, err
    assert "capability:" in out and "cells of 24 orientation bins per voxel reached" in out
    cap = ws.CapabilityMap.load(tmp_path / "cap.npz")
    assert cap.n_samples == 20_000 and cap.orientation_bins == 24 and cap.cell_counts.sum() == 20_000
    tasks = planar_poses([0.5, 0.4, 0.6], [0.0, 0.1, -0.1], [0.0, 1.0, 2.0], 0.4)
    (tmp_path / "tasks.json").write_text(json.dumps(tasks.tolist()))
    code, out, err = run(
        capsys, "place", "panda", "--tasks", tmp_path / "tasks.json", "--region", -1, -1, 1, 1, "--map",
        tmp_path / "cap.npz", "--yaw-bins", 8, "--cell", 0.25, "--best", 3, "--plot", tmp_path / "place.png",
        "--out", tmp_path / "place.npz",
    )  # fmt: skip
    assert code == 0, err
    assert "placement: 3 tasks x 8 x 8 x 8 bases" in out and out.count("base x ") == 3
    saved = np.load(tmp_path / "place.npz")
    expected = ws.base_placement(cap, tasks, region=[[-1, -1], [1, 1]], yaw_bins=8, cell=0.25)
    np.testing.assert_array_equal(saved["score"], expected.score)
    np.testing.assert_allclose(saved["best"], expected.best(3))
    assert (tmp_path / "place.png").stat().st_size > 10_000
    code, out, err = run(
        capsys, "place", "panda", "--tasks", tmp_path / "tasks.json", "--region", -1, -1, 1, 1, "--map",
        tmp_path / "cap.npz", "--yaw-bins", 8, "--cell", 0.25, "--cell-only", "--out", tmp_path / "cells.npz",
    )  # fmt: skip
    assert code == 0, err
    cell_only = ws.base_placement(cap, tasks, region=[[-1, -1], [1, 1]], yaw_bins=8, cell=0.25, at_pose=False)
    np.testing.assert_array_equal(np.load(tmp_path / "cells.npz")["score"], cell_only.score)


# the capsule arm (without a base body), a pose and a map of nothing: the errors come before any placement
_PLACE_ARM = ["place", "ARM", "--tasks", "GOOD", "--region", "-1", "-1", "1", "1", "--map", "CAP"]


@pytest.mark.parametrize(
    "argv, match",
    [
        (["workspace", "panda", "--orientation-bins", "24", "--out", "m.npz"], "--orientation-bins goes with"),
        (["place", "panda", "--tasks", "nothing.npy", "--region", "-1", "-1", "1", "1"], "--tasks: no such file"),
        (["place", "panda", "--tasks", "BAD", "--region", "-1", "-1", "1", "1"], "--tasks: expected task poses"),
        (["place", "panda", "--tasks", "GOOD", "--region", "1", "-1", "-1", "1", "--map", "CAP"], "region"),
        ([*_PLACE_ARM, "--avoid", "nothing.json"], "--avoid: [Errno 2] No such file or directory: 'nothing.json'"),
        ([*_PLACE_ARM, "--avoid", "BAD_SCENE"], "--avoid: BAD_SCENE: planes[0].normal: expected a non-zero vector"),
        ([*_PLACE_ARM, "--avoid", "SCENE", "--margin", "-0.1"], "--margin: expected a non-negative number"),
        ([*_PLACE_ARM, "--avoid", "SCENE", "--margin", "x"], "--margin: invalid number: 'x'"),
        ([*_PLACE_ARM, "--margin", "0.1"], "--margin goes with --avoid"),
        ([*_PLACE_ARM, "--srdf", "SCENE"], "--srdf goes with --avoid"),
        ([*_PLACE_ARM, "--avoid", "SCENE", "--srdf", "nothing.srdf"], "--srdf: no such file 'nothing.srdf'"),
        ([*_PLACE_ARM, "--avoid", "SCENE", "--base-link", "l1"], "--base-link does not apply to --avoid"),
        ([*_PLACE_ARM, "--avoid", "SCENE", "--end-link", "hnd"], "--end-link: unknown frame 'hnd'"),
        (["place", "panda", "--tasks", "GOOD", "--region", "-1", "-1", "1", "1", "--avoid", "SCENE"], "no collision"),
        ([*_PLACE_ARM, "--port", "8081"], "--port goes with --view"),
        ([*_PLACE_ARM, "--host", "0.0.0.0"], "--host goes with --view"),
        ([*_PLACE_ARM, "--view", "--port", "0"], "--port: expected a positive integer, got '0'"),
        (["place", "panda", "--tasks", "ROUNDED", "--region", "-1", "-1", "1", "1", "--verify", "1"], "task 1 of"),
    ],
)
def test_cli_user_errors(capsys, tmp_path, argv, match):
    from _shapes import CAPSULE_ARM, SCENE

    (tmp_path / "arm.urdf").write_text(CAPSULE_ARM)
    (tmp_path / "scene.json").write_text(json.dumps(SCENE))
    (tmp_path / "bad_scene.json").write_text(json.dumps({"planes": [{"normal": [0, 0, 0], "offset": 0}]}))
    np.save(tmp_path / "bad.npy", np.eye(4))
    np.save(tmp_path / "good.npy", np.eye(4)[None])
    rounded = np.tile(np.eye(4), (2, 1, 1))
    rounded[1, :3, :3] = [[0.0, -1.0, 0.0], [0.707107, 0.0, 0.707107], [-0.707107, 0.0, 0.707107]]  # 6 decimals
    np.save(tmp_path / "rounded.npy", rounded)
    ws.CapabilityMap(
        *(np.zeros(0, np.int64),) * 2, np.zeros((1, 1, 1), np.int64), np.zeros((1, 1, 1)), np.zeros(3), 0.1, 1, 1, 24
    ).save(tmp_path / "cap.npz")
    names = {
        "BAD": tmp_path / "bad.npy",
        "GOOD": tmp_path / "good.npy",
        "CAP": tmp_path / "cap.npz",
        "ARM": tmp_path / "arm.urdf",
        "SCENE": tmp_path / "scene.json",
        "BAD_SCENE": tmp_path / "bad_scene.json",
        "ROUNDED": tmp_path / "rounded.npy",
    }
    code, out, err = run(capsys, *(names.get(a, a) for a in argv))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("diffkin: error: "), err
    assert match.replace("BAD_SCENE", str(names["BAD_SCENE"])) in lines[0], lines[0]
    assert "map:" not in out  # said before any map is built or read


@pytest.fixture(scope="module")
def placed_arm(tmp_path_factory):
    """The capsule arm on a base box (its root body), three tasks, a capability map of its hand (saved), and a
    scene: a post where the bases at x = 1 stand and a ball where task 1's hand goes (margin 0.02 m)."""
    from _shapes import CAPSULE_ARM

    folder = tmp_path_factory.mktemp("place")
    urdf = CAPSULE_ARM.replace(
        '<link name="base"/>',
        '<link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>',
    )
    (folder / "arm.urdf").write_text(urdf)
    chain = dk.load_robot(urdf).chain("hand")
    q = np.array([[0.3, 0.8, 1.0], [-0.4, 1.1, 0.6], [0.2, -0.9, -1.2]])
    tasks = planar_poses([0.0, 0.0, 1.0], 0.0, 0.0, 0.0) @ np.asarray(dk.fk(chain, q), np.float64)
    np.save(folder / "tasks.npy", tasks)
    scene = {
        "margin": 0.02,
        "boxes": [{"position": [1.0, 0.0, 0.05], "half_extents": [0.05, 0.05, 0.05]}],
        "spheres": [{"center": tasks[1, :3, 3].tolist(), "radius": 0.03}],
    }
    (folder / "scene.json").write_text(json.dumps(scene))
    ws.capability(chain, 100_000, key=KEY, voxel_size=0.1, orientation_bins=192).save(folder / "cap.npz")
    return folder


def _stub_viewer(monkeypatch) -> dict:
    """``dk.viewer.show`` replaced (it would serve until Ctrl-C; viser not needed): what it is called with."""
    import types

    shown: dict = {}
    fake = types.ModuleType("diffkin.viewer")
    fake.show = lambda model, **kwargs: shown.update(model=model, **kwargs)  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "diffkin.viewer", fake)
    monkeypatch.setattr(dk, "viewer", fake, raising=False)
    return shown


def test_cli_place_avoid_rules_out_the_post_and_the_ball(capsys, placed_arm, monkeypatch):
    """``--avoid``: the bases on the post and the task in the ball are reported, saved, drawn and shown, and
    ``--verify`` solves clear of the obstacles (``Placement.verify`` with ``avoid``: recorded here, it is
    checked against IK in the test below; compiling IK with obstacles takes minutes)."""
    pytest.importorskip("matplotlib")
    f = placed_arm
    shown = _stub_viewer(monkeypatch)
    verified = {}

    def verify(self, model, k=10, *, avoid=None, key=None, **kwargs):
        verified.update(model=model, k=k, avoid=avoid)
        n = len(self.tasks)
        return ws.Verification(self.best(k), self.score[tuple(self.best_cells(k).T)], np.ones((k, n), bool), np.ones(k))

    monkeypatch.setattr(ws.Placement, "verify", verify)
    code, out, err = run(
        capsys, "place", f / "arm.urdf", "--tasks", f / "tasks.npy", "--region", -0.5, -0.5, 1.5, 0.5, "--map",
        f / "cap.npz", "--yaw-bins", 2, "--cell", 1.0, "--best", 4, "--avoid", f / "scene.json", "--margin", 0.03,
        "--verify", 2, "--out", f / "place.npz", "--plot", f / "place.png", "--view", "--port", 8123,
    )  # fmt: skip
    assert code == 0, err
    assert (
        f"obstacles: 2 of 4 bases and 1 of 3 tasks ruled out (within the margin 0.03 m of the 2 obstacles of "
        f"{f / 'scene.json'} at every solution" in out
    )
    saved = np.load(f / "place.npz")
    np.testing.assert_array_equal(saved["blocked_bases"][:, 0], [[False, False], [True, True]])  # on the post
    np.testing.assert_array_equal(saved["blocked_tasks"], [False, True, False])  # in the ball
    assert np.all(saved["score"][1] == 0) and saved["score"].max() > 0  # the post's bases score 0, not the rest
    # the model, avoid and margin of the scene reach base_placement, verify and the viewer
    robot, frame = verified["model"]
    assert isinstance(robot, dk.Robot) and frame == "hand" and verified["k"] == 2
    assert float(verified["avoid"].margin) == 0.03 and verified["avoid"].world.size == 2
    assert "fraction of the tasks solved clear of the obstacles from each base" in out
    assert shown["model"] is robot and shown["source"] == str(f / "arm.urdf") and shown["ends"] == ["hand"]
    assert shown["avoid"] is verified["avoid"] and shown["best_bases"] == 4 and shown["block"]
    assert shown["port"] == 8123 and shown["host"] == "127.0.0.1"
    np.testing.assert_array_equal(shown["placement"].blocked_bases, saved["blocked_bases"])
    np.testing.assert_array_equal(shown["placement"].score, saved["score"])
    assert (f / "place.png").stat().st_size > 10_000


def test_cli_place_view_serves_the_best_bases(capsys, placed_arm, monkeypatch):
    """``--view`` without obstacles: the file's whole robot (its meshes from the file), the placement printed."""
    f = placed_arm
    shown = _stub_viewer(monkeypatch)
    code, out, err = run(
        capsys, "place", f / "arm.urdf", "--tasks", f / "tasks.npy", "--region", -0.5, -0.5, 1.5, 0.5, "--map",
        f / "cap.npz", "--yaw-bins", 2, "--cell", 1.0, "--best", 3, "--view", "--host", "0.0.0.0",
    )  # fmt: skip
    assert code == 0, err
    assert "viewer: the 3 best bases and the tasks" in out and "obstacles:" not in out
    assert isinstance(shown["model"], dk.Robot) and shown["source"] == str(f / "arm.urdf")
    assert shown["avoid"] is None and shown["placement"].blocked_bases is None and shown["best_bases"] == 3
    assert shown["host"] == "0.0.0.0" and shown["port"] == 8080 and shown["ends"] == ["hand"]
    expected = ws.base_placement(
        ws.CapabilityMap.load(f / "cap.npz"),
        np.load(f / "tasks.npy"),
        region=[[-0.5, -0.5], [1.5, 0.5]],
        yaw_bins=2,
        cell=1.0,
    )
    np.testing.assert_array_equal(shown["placement"].score, expected.score)


def test_plot_placement_draws_the_best_yaw_and_the_tasks():
    pytest.importorskip("matplotlib")
    cap = ws.capability(dk.robots.planar([0.4, 0.3]), 5000, key=KEY, voxel_size=0.1, orientation_bins=24)
    tasks = planar_poses([0.3, 0.2], [0.0, 0.3], [0.0, 1.0], 0.0)
    placement = ws.base_placement(cap, tasks, region=[[-0.5, -0.5], [0.5, 0.5]], yaw_bins=4)
    ax = ws.plot_placement(placement)
    best = placement.best_cells(1)[0]
    assert f"yaw {np.degrees(placement.yaw[best[2]]):.0f} deg (of 4)" in ax.get_title()
    np.testing.assert_array_equal(ax.images[0].get_array().T, placement.score[:, :, best[2]])
    with pytest.raises(ValueError, match="yaw"):
        ws.plot_placement(placement, yaw=4)
    # with obstacles: the blocked bases of the yaw drawn grey, the blocked tasks as crosses, both counted
    blocked = np.zeros(placement.score.shape, bool)
    blocked[:3, :2, best[2]] = True
    import dataclasses

    ruled_out = dataclasses.replace(placement, blocked_bases=blocked, blocked_tasks=np.array([True, False]))
    ax = ws.plot_placement(ruled_out)
    grey = ax.images[1].get_array()
    np.testing.assert_array_equal(~np.ma.getmaskarray(grey).T, blocked[:, :, best[2]])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "6 bases blocked by obstacles at this yaw" in labels and "1 tasks blocked" in labels


def test_capability_with_avoid_counts_the_clear_samples_and_verify_solves_clear():
    """``avoid=``: the capability map's voxels count the samples the reachability map with the same ``avoid``
    counts (the same step), and ``verify`` with ``avoid`` solves (robot, frame) tasks clear of the obstacles."""
    from _shapes import CAPSULE_ARM

    from diffkin.collision import Sphere, World

    robot = dk.load_robot(CAPSULE_ARM)
    geom = dk.collision.load(CAPSULE_ARM, robot)
    world = World(Sphere(np.array([[0.35, 0.25, 0.55]]), np.array([0.08])))
    avoid = dk.ik.Avoid(geom, world, margin=0.02)
    kw = dict(key=KEY, voxel_size=0.1, bounds=[[-1.3, -1.3, -0.9], [1.3, 1.3, 1.7]], chunk=3000)
    cap = ws.capability((robot, "hand"), 3000, avoid=avoid, orientation_bins=192, **kw)
    reach = ws.reachability((robot, "hand"), 3000, avoid=avoid, **kw)
    np.testing.assert_array_equal(cap.counts, reach.counts)
    assert cap.cell_counts.sum() == reach.counts.sum() < 3000 and cap.n_outside == reach.n_outside
    q = np.asarray(ws.sample_configs(robot.chain("hand"), 2, jax.random.key(9)))
    tasks = np.asarray(dk.fk(robot.chain("hand"), q))  # reachable from the identity base
    placement = ws.base_placement(cap, tasks, region=[[-0.1, -0.1], [0.1, 0.1]], yaw_bins=1, cell=0.2)
    check = placement.verify((robot, "hand"), k=1, avoid=avoid, key=KEY)
    assert check.success.shape == (1, 2) and check.bases.shape == (1, 4, 4)
    np.testing.assert_allclose(check.bases[0], np.eye(4), atol=1e-12)
    with pytest.raises(ValueError, match="avoid: needs a"):
        placement.verify(robot.chain("hand"), k=1, avoid=avoid)


def test_placement_with_obstacles_against_ik_from_every_base():
    """``base_placement(..., avoid=)``: the capsule arm on a base box, a post where one base stands and a
    ball where one task's hand goes. Brute force, ``verify`` with ``avoid`` from every base of the grid:
    no base or task the placement rules out is solved clear by IK (they collide at every solution),
    though IK without the obstacles solves them; everything else scores as without obstacles."""
    from _shapes import CAPSULE_ARM

    from diffkin.collision import Box, Sphere, World

    urdf = CAPSULE_ARM.replace(
        '<link name="base"/>',
        '<link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>',
    )
    robot = dk.load_robot(urdf)
    geom = dk.collision.load(urdf, robot)
    model = (robot, "hand")
    chain = robot.chain("hand")
    q = np.array([[0.3, 0.8, 1.0], [-0.4, 1.1, 0.6], [0.2, -0.9, -1.2]])
    T_root_hand = np.asarray(dk.fk(chain, q))
    at = planar_poses([0.0, 0.0, 1.0], 0.0, 0.0, 0.0)  # tasks 0, 1 from the base at the origin, 2 from x = 1
    tasks = at @ T_root_hand
    post = np.eye(4)
    post[:3, 3] = [1.0, 0.0, 0.05]
    world = World(Box(post[None], np.array([[0.05, 0.05, 0.05]])), Sphere(tasks[1, None, :3, 3], np.array([0.03])))
    avoid = dk.ik.Avoid(geom, world, margin=0.02)
    cap = ws.capability(model, 100_000, key=KEY, voxel_size=0.1, orientation_bins=192)
    # Bases at x = 0 and 1, yaws 0 and 180 deg; a 3-joint arm: its poses judged by their cells alone.
    kw = dict(region=[[-0.5, -0.5], [1.5, 0.5]], yaw_bins=2, cell=1.0, at_pose=False)
    plain = ws.base_placement(cap, tasks, **kw)
    placement = ws.base_placement(cap, tasks, model=model, avoid=avoid, **kw)
    assert placement.score.shape == (2, 1, 2) and plain.blocked_bases is None
    np.testing.assert_array_equal(placement.blocked_tasks, [False, True, False])
    np.testing.assert_array_equal(placement.blocked_bases[:, 0], [[False, False], [True, True]])  # on the post
    # Everything else scores as without the obstacles, less the blocked task.
    cells = plain.best_cells(4)
    said = cap.reaches(np.linalg.inv(plain.best(4))[:, None] @ tasks, at_pose=False)  # (4, 3) the map's look-ups
    blocked = placement.blocked_bases[tuple(cells.T)]
    expected = np.where(blocked, 0.0, (said & [True, False, True]).mean(axis=1))
    np.testing.assert_allclose(placement.score[tuple(cells.T)], expected, atol=1e-6)
    assert said[:, [0, 2]].any(axis=0).all() and plain.score.max() > placement.score.max() > 0
    # Brute force: IK from every base on every task, clear of the obstacles and not.
    clear = placement.verify(model, k=4, avoid=avoid, key=KEY, num_seeds=8)
    free = placement.verify(model, k=4, key=KEY, num_seeds=8)
    ruled_out = placement.blocked_bases[tuple(placement.best_cells(4).T)][:, None] | placement.blocked_tasks
    assert ruled_out.sum() == 8 and not np.any(clear.success & ruled_out)  # never solved clear
    on_post = clear.bases[:, 0, 3] == 1.0
    assert free.success[~on_post, 1].all() and free.success[on_post, 2].all()  # but solved without the obstacles
    assert clear.success[~on_post, 0].all()  # and the rest is solved clear
    with pytest.raises(ValueError, match=r"avoid: needs model=\(robot, frame_name\)"):
        ws.base_placement(cap, tasks, avoid=avoid, **kw)
    with pytest.raises(ValueError, match="model: only needed with avoid"):
        ws.base_placement(cap, tasks, model=model, **kw)
    with pytest.raises(TypeError, match="avoid: expected a dk.ik.Avoid"):
        ws.base_placement(cap, tasks, model=model, avoid=world, **kw)
