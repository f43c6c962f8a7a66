"""The :class:`Viewer`: a viser server showing one diffkin model, driven from the browser or from Python."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any, TypedDict, Unpack

import jax
import jax.numpy as jnp
import numpy as np
import viser
import viser.transforms as vtf

import diffkin as dk
from diffkin._checks import positive_int
from diffkin._npz import read_npz
from diffkin.ik.interface import check_avoid
from diffkin.viewer import _overlays, _visuals
from diffkin.viewer._arm_panel import ArmPanel
from diffkin.viewer._gui import Page, node, plain, shown
from diffkin.viewer._model import kinematics, make_ik, make_ik_avoiding
from diffkin.viewer._panels import (
    FPS_RANGE,
    DisplayPanel,
    JointPanel,
    MapPanel,
    ObstaclePanel,
    PlacementPanel,
    ResultsPanel,
    TargetPanel,
)
from diffkin.viewer._results import check_results, describe

IIWA_READY = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.7, 0.0])  # a bent pose: the arm angle is defined
_ARM_NAMES = ("iiwa7", "iiwa14")
BUILTIN = dk.robots.BUILTIN


CLEAR, NEAR = (70, 130, 220), (230, 50, 40)  # a robot's collision shape: clear of everything, within the margin


def _wxyz(R: np.ndarray) -> np.ndarray:
    return vtf.SO3.from_matrix(np.asarray(R, dtype=np.float64)).wxyz


def _pose(position, wxyz) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = vtf.SO3(np.asarray(wxyz, dtype=np.float64)).as_matrix()
    T[:3, 3] = position
    return T


def _clearance_text(clearance: float, margin: float) -> str:
    """``clearance 0.034 m (margin 0.01 m): collision-free`` (or ``within the margin``, ``in collision``)."""
    word = "collision-free" if clearance >= margin else "within the margin" if clearance >= 0 else "in collision"
    return f"clearance {clearance:.4f} m (margin {margin:g} m): {word}"


class Viewer:
    """A running viser page showing one model; every control is also a method.

    Scene tree (``<frame>``: the frame's name with ``%`` and ``/`` percent-encoded, one path
    component): ``/robot/<frame>`` is a frame node per model frame at its world pose (axes
    toggled by "Show frames"), its visual meshes below it at their fixed pose in the frame;
    ``/skeleton/<frame>`` cylinders join each frame to its parent frame; ``/targets/<frame>``
    are the IK gizmos; ``/map`` the reachability point cloud; ``/obstacles/<kind><i>`` the obstacles
    of ``avoid`` (a capsule as ``axis``, ``a`` and ``b`` below its node); ``/placement/tasks`` the task
    poses of a base placement. The model is drawn with its root at :attr:`T_world_root` (the identity,
    the ``base`` of the batch result shown, or the placement's base shown); IK targets are world poses,
    solved for the chain from the root at that pose.

    Attributes:
        server: the ``viser.ViserServer``.
        kin: the model's frames, joints and jitted poses (``diffkin.viewer._model.Kinematics``).
        q: ``(dof,)`` float64, the configuration shown (actuated joints; mimic joints follow).
        T_world_root: ``(4, 4)`` float64, the pose of the model's root frame (a chain's ``base``
            frame, a robot's root) in the world as drawn: the identity unless a batch result with
            ``base`` or a placement's base (:meth:`show_base`) was shown.
        frames: ``{frame name: FrameHandle}``.
        skeleton: ``{frame name: cylinder}`` from each frame (but the root) to its parent frame.
        joint_spheres: ``{frame name: sphere}`` at each frame (shown with the skeleton).
        visuals: ``{frame name: [mesh handles]}`` of the meshes and primitives drawn.
        missing: mesh references that could not be found or read (not drawn; "Show skeleton"
            draws every link as a cylinder).
        ik_results: ``{end frame: last IKResult}`` (numpy fields).
        results: the batch results browsed, ``{field: array}`` as checked, or ``None``.
        result_index: the batch result shown last (``None`` before the first).
        arm: the ``dk.srs.SRSArm`` driving the arm-angle controls, or ``None``.
        display_panel, joint_panel, target_panel: the page's folders (``diffkin.viewer._panels``) of what is
            drawn, the joint sliders (``joint_panel.sliders``, in ``q`` order) and the IK gizmos
            (``target_panel.targets``: ``{end frame: TransformControlsHandle}``).
        obstacle_panel, map_panel, results_panel, arm_panel: the folders of the obstacles (with ``avoid``),
            the workspace map, the batch results (``results_panel.play_fps``, ``play_loop``,
            ``play_button``: the playback) and the arm angle, each ``None`` without what it shows.
        placement_panel: the "Base placement" folder (``placement_panel.bases``, ``scores``, ``base_slider``,
            ``task_axes``; ``diffkin.viewer._panels.PlacementPanel``), ``None`` without a placement.
        avoid: the ``dk.ik.Avoid`` every drag is solved with (the whole robot, clear of its obstacles
            by its margin), or ``None`` (the chain of the dragged frame, no collision check).
        obstacles: ``{scene path: handle}`` of the obstacles drawn (empty without ``avoid``).
        clearance: the clearance (m) of the configuration shown (``inf`` without ``avoid``).
        url: ``http://host:port``.
    """

    def __init__(
        self,
        model,
        *,
        source=None,
        ends: Sequence[str] | None = None,
        arm=None,
        q0=None,
        workspace_map=None,
        results=None,
        avoid=None,
        placement=None,
        best_bases: int = 10,
        host: str = "127.0.0.1",
        port: int = 8080,
        num_seeds: int = 8,
        warmup: bool = True,
    ):
        self.kin = kinematics(model, ends)
        self.model = model
        self.arm = arm
        self.avoid = _checked_avoid(avoid, model)
        if placement is not None and not isinstance(placement, dk.workspace.Placement):
            raise TypeError(
                f"placement: expected a dk.workspace.Placement (base_placement), got {type(placement).__name__}"
            )
        best_bases = positive_int(best_bases, "best_bases")
        self.clearance = float("inf")
        self._key = jax.random.key(0)
        self._ik: dict[str, tuple] = {}
        self._num_seeds = num_seeds
        self.ik_results: dict[str, object] = {}
        dof = self.kin.dof
        if q0 is None:
            q0 = IIWA_READY if arm is not None and dof == 7 else np.zeros(dof)
        q0 = np.asarray(q0, dtype=np.float64)
        if q0.shape != (dof,):
            raise ValueError(f"q0: expected shape ({dof},), got {q0.shape}")
        self.q = np.clip(q0, self.kin.lower, self.kin.upper)
        floating = isinstance(model, dk.Robot) and model.floating
        self.results = check_results(results, dof, floating) if results is not None else None
        self.result_index: int | None = None
        self.T_world_root = np.eye(4)
        self._player: tuple[threading.Thread, threading.Event] | None = None

        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.url = f"http://{host}:{self.server.get_port()}"
        self._page = Page(self.server.gui, self._apply)
        poses = np.asarray(self.kin.poses(jnp.asarray(self.q)), dtype=np.float64)
        origins = poses[:, :3, 3]
        if self.results is not None and "base" in self.results:  # the scene spans the root poses too
            origins = np.concatenate([origins, self.results["base"][:, :3, 3]])
        if placement is not None:  # and the tasks and the best bases
            origins = np.concatenate([origins, placement.tasks[:, :3, 3], placement.best(best_bases)[:, :3, 3]])
        lo, hi = origins.min(0), origins.max(0)
        self.size = size = max(float(np.max(hi - lo)), 0.3)
        center = (lo + hi) / 2
        self.server.initial_camera.position = center + size * np.array([1.3, 1.1, 0.6])
        self.server.initial_camera.look_at = center
        self.server.scene.add_grid(
            "/grid", width=2 * size, height=2 * size, cell_size=size / 10, position=(0.0, 0.0, float(min(lo[2], 0.0)))
        )

        self._build_robot(source, size)
        self.obstacles: dict[str, Any] = {}
        self.collision: list[list[Any]] = []
        if self.avoid is not None and self.avoid.world is not None:
            self._build_obstacles(center, 2 * size)
        if self.avoid is not None:
            self._build_collision()
        self._build_gui(workspace_map)
        self.placement_panel = None
        if placement is not None:
            self.placement_panel = PlacementPanel(
                self._page, self.server.scene, placement, best_bases, self.show_base, 0.06 * size
            )
        self._apply(self.q, source=None)
        if self.placement_panel is not None:
            self.show_base(0)
        if warmup:
            threading.Thread(target=self._warmup, daemon=True).start()

    # ------------------------------------------------------------------------------------- scene

    def _build_robot(self, source, size: float) -> None:
        scene = self.server.scene
        names = self.kin.frame_names
        self.visuals: dict[str, list] = {name: [] for name in names}
        self.missing: list[str] = []
        visuals = _visuals.read_visuals(source) if source is not None else []
        has_meshes = False
        self.frames: dict[str, viser.FrameHandle] = {}
        axes = 0.08 * size
        for name in names:
            self.frames[name] = scene.add_frame(
                f"/robot/{node(name)}", show_axes=True, axes_length=axes, axes_radius=axes / 25
            )
        for k, visual in enumerate(visuals):
            if visual.frame not in self.frames:
                continue
            mesh = _visuals.load_trimesh(visual)
            if mesh is None:
                self.missing.append(visual.filename or visual.kind)
                continue
            has_meshes = True
            handle = scene.add_mesh_trimesh(
                f"/robot/{node(visual.frame)}/visual{k}",
                mesh,
                position=visual.T_frame_visual[:3, 3],
                wxyz=_wxyz(visual.T_frame_visual[:3, :3]),
            )
            self.visuals[visual.frame].append(handle)
        self.has_meshes = has_meshes
        radius = 0.025 * size
        self.skeleton: dict[str, Any] = {}
        self.joint_spheres: dict[str, Any] = {}
        for f, parent in enumerate(self.kin.frame_parents):
            name = names[f]
            self.joint_spheres[name] = scene.add_icosphere(
                f"/robot/{node(name)}/joint", radius=radius * 1.3, color=(240, 140, 40), visible=not has_meshes
            )
            if parent >= 0:
                self.skeleton[name] = scene.add_cylinder(
                    f"/skeleton/{node(name)}", radius=radius, height=1.0, color=(120, 130, 150), visible=not has_meshes
                )
        self._lengths = {name: 1.0 for name in self.skeleton}
        for frame in self.frames.values():
            frame.show_axes = not has_meshes

    def _build_obstacles(self, center: np.ndarray, extent: float) -> None:
        """The obstacles of :attr:`avoid` as translucent red primitives (half-spaces as slabs ``extent`` wide)."""
        for shape in _overlays.obstacle_primitives(self.avoid.world, center, extent):
            self.obstacles[shape.name] = self._add_primitive(shape, (220, 70, 60), opacity=0.6)

    def _build_collision(self) -> None:
        """The robot's own collision shapes (:attr:`avoid`'s geometry) on the frames that carry them, hidden
        until shown; :attr:`collision` holds each shape's handles (a capsule has three), coloured by
        :meth:`_colour_collision`; :attr:`shape_gaps` the distance of each to whatever it is checked against."""
        avoid, model = self.avoid, self.model
        geom = avoid.geom
        paths = [f"/robot/{node(link)}/collision{k}" for k, link in enumerate(geom.shape_links)]
        index = {path: k for k, path in enumerate(paths)}
        self.collision = [[] for _ in paths]
        for shape in _overlays.shape_primitives(geom.shapes, paths):
            k = index[shape.name] if shape.name in index else index[shape.name.rsplit("/", 1)[0]]  # capsule: 3 parts
            self.collision[k].append(self._add_primitive(shape, CLEAR, opacity=0.5, visible=False))
        pairs = geom.pairs if avoid.self_collision else np.zeros((0, 2), np.int64)

        def gaps(q, base) -> jax.Array:
            """``(shapes,)`` each shape's smallest distance over its checked pairs and the obstacles (``inf``: none)."""
            out = jnp.full(len(paths), jnp.inf, q.dtype)
            if len(pairs):
                d = dk.collision.self_distances(model, geom, q, base)
                out = out.at[pairs[:, 0]].min(d).at[pairs[:, 1]].min(d)
            if avoid.world is not None:
                out = jnp.minimum(out, dk.collision.world_distances(model, geom, q, avoid.world, base).min(axis=-1))
            return out

        self._shape_gaps = jax.jit(gaps)
        self.shape_gaps = np.full(len(paths), np.inf)

    def _colour_collision(self) -> None:
        """Each collision shape red where it is within the margin of what it is checked against, else blue."""
        self.shape_gaps = np.asarray(self._shape_gaps(jnp.asarray(self.q), jnp.asarray(self.T_world_root)))
        margin = float(self.avoid.margin)
        for handles, gap in zip(self.collision, self.shape_gaps, strict=True):
            color = NEAR if gap < margin else CLEAR
            for handle in handles:
                if tuple(handle.color) != color:
                    handle.color = color

    def _add_primitive(self, shape: _overlays.Primitive, color, opacity: float, visible: bool = True) -> Any:
        """A sphere, cylinder or box of the scene (:class:`_overlays.Primitive`)."""
        scene = self.server.scene
        position, wxyz = shape.position, _wxyz(shape.rotation)
        if shape.kind == "sphere":
            return scene.add_icosphere(
                shape.name, shape.size[0], color=color, opacity=opacity, position=position, wxyz=wxyz, visible=visible
            )
        if shape.kind == "cylinder":
            radius, height = shape.size
            return scene.add_cylinder(
                shape.name, radius, height, color, opacity=opacity, position=position, wxyz=wxyz, visible=visible
            )
        if shape.kind == "mesh" and shape.mesh is not None:
            vertices, faces = shape.mesh
            return scene.add_mesh_simple(
                shape.name, vertices, faces, color=color, opacity=opacity, position=position, wxyz=wxyz, visible=visible
            )
        size = np.asarray(shape.size)
        return scene.add_box(shape.name, color, size, opacity=opacity, position=position, wxyz=wxyz, visible=visible)

    def _update_scene(self, poses: np.ndarray) -> None:
        names = self.kin.frame_names
        with self.server.atomic():
            for f, name in enumerate(names):
                self.frames[name].position = poses[f, :3, 3]
                self.frames[name].wxyz = _wxyz(poses[f, :3, :3])
            for f, parent in enumerate(self.kin.frame_parents):
                if parent < 0:
                    continue
                a, b = poses[parent, :3, 3], poses[f, :3, 3]
                length = float(np.linalg.norm(b - a))
                handle = self.skeleton[names[f]]
                if abs(length - self._lengths[names[f]]) > 1e-9:
                    handle.height = max(length, 1e-6)
                    self._lengths[names[f]] = length
                handle.position = (a + b) / 2
                handle.wxyz = _wxyz(_visuals.z_to(b - a))

    # ------------------------------------------------------------------------------------- gui

    def _build_gui(self, workspace_map) -> None:
        page, scene = self._page, self.server.scene
        name = getattr(self.model, "name", "") or type(self.model).__name__
        page.gui.add_markdown(f"**{plain(name)}**: {self.kin.dof} joints, {len(self.kin.frame_names)} frames")
        self.display_panel = DisplayPanel(
            page, self.frames, self.skeleton, self.joint_spheres, self.visuals, self.has_meshes
        )
        self.joint_panel = JointPanel(
            page, self.kin, self.q, self._on_slider, lambda: self.set_q(np.zeros(self.kin.dof))
        )
        self.target_panel = TargetPanel(page, scene, self.kin.ends, 0.18 * self.size, self._on_gizmo)
        self._pending = dict.fromkeys(self.kin.ends, False)
        self._solving = threading.Lock()
        self.obstacle_panel = None
        if self.avoid is not None:
            avoid, model = self.avoid, self.model
            self._clearance = jax.jit(lambda q, base: avoid.clearance(model, q, base))
            self.obstacle_panel = ObstaclePanel(page, avoid, self.obstacles, self.collision)
        self.arm_panel = None if self.arm is None else ArmPanel(page, self.arm)
        self.map_panel = None if workspace_map is None else MapPanel(page, scene, workspace_map)
        self.results_panel = None
        if self.results is not None:
            self.results_panel = ResultsPanel(
                page, len(self.results["q"]), self.show_result, lambda: self.pause() if self.playing else self.play()
            )

    # ------------------------------------------------------------------------------------- state

    def _apply(self, q: np.ndarray, source) -> None:
        """Show ``q``: scene, sliders, gizmos (all but the one dragged), arm angle (unless it moved the arm)."""
        with self._page.lock:
            self.q = np.asarray(q, dtype=np.float64).copy()
            poses = self.T_world_root @ np.asarray(self.kin.poses(jnp.asarray(self.q)), dtype=np.float64)
            self._update_scene(poses)
            with self._page.quietly():
                if source != "slider":
                    for slider, value in zip(self.joint_panel.sliders, self.q, strict=True):
                        slider.value = shown(value)  # type: ignore[misc]  # viser's stub: read-only; its API sets it
                for end, gizmo in self.target_panel.targets.items():
                    if source != ("gizmo", end):
                        f = self.kin.frame_names.index(end)
                        gizmo.position, gizmo.wxyz = poses[f, :3, 3], _wxyz(poses[f, :3, :3])
                if self.arm_panel is not None and source != "srs":
                    self.arm_panel.sync(self.q)
                if self.obstacle_panel is not None:  # (with avoid)
                    self.clearance = float(self._clearance(jnp.asarray(self.q), jnp.asarray(self.T_world_root)))
                    margin = float(self.avoid.margin)
                    self.obstacle_panel.clearance_status.content = _clearance_text(self.clearance, margin)
                    self._colour_collision()

    def _on_slider(self, i: int) -> None:
        if self._page.quiet:
            return
        with self._page.lock:
            q = self.q.copy()
            q[i] = float(self.joint_panel.sliders[i].value)
            self._apply(q, source="slider")

    def set_q(self, q) -> None:
        """Show the configuration ``q (dof,)`` (clipped to the joint limits), as the sliders would."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.kin.dof,):
            raise ValueError(f"q: expected shape ({self.kin.dof},), got {q.shape}")
        self._apply(np.clip(q, self.kin.lower, self.kin.upper), source=None)

    def frame_pose(self, name: str) -> np.ndarray:
        """``(4, 4)`` world pose of frame ``name`` as the scene node holds it (position and quaternion)."""
        handle = self.frames[name]
        return _pose(handle.position, handle.wxyz)

    # ------------------------------------------------------------------------------------- IK

    def _ik_fn(self, end: str):
        if end not in self._ik:
            self._ik[end] = (
                make_ik(self.kin, end, self._num_seeds)
                if self.avoid is None
                else make_ik_avoiding(self.kin, end, self._num_seeds, self.avoid)
            )
        return self._ik[end]

    def _run_ik(self, end: str, T_world_target: np.ndarray, q: np.ndarray):
        """The IK function of ``end`` on the world pose ``T_world_target`` from ``q`` (the root at
        :attr:`T_world_root`), and the indices in ``q`` of the joints it solves."""
        fn, index = self._ik_fn(end)
        if self.avoid is None:
            T_root_target = np.linalg.solve(self.T_world_root, T_world_target)
            return fn(jnp.asarray(T_root_target), jnp.asarray(q[index]), self._key), index
        return fn(jnp.asarray(T_world_target), jnp.asarray(q), self._key, jnp.asarray(self.T_world_root)), index

    def solve_ik(self, end: str, T) -> object:
        """IK for frame ``end`` to the world pose ``T (4, 4)`` from the current ``q``; shows the result.

        The root stays at :attr:`T_world_root` (the chain is solved for ``T_world_root^-1 T``). The
        chain's joints take the solver's ``q`` (the best found, even if it failed); the other
        joints keep theirs. With :attr:`avoid`, every joint of the robot is solved, clear of the
        obstacles by the margin (``success`` needs it; ``res.clearance``). Returns the
        ``IKResult`` (numpy fields; poses in the root frame).
        """
        with self._page.lock:
            res, index = self._run_ik(end, np.asarray(T, dtype=np.float64), self.q)
            res = jax.tree.map(np.asarray, res)
            q = self.q.copy()
            q[index] = res.q
            self._apply(q, source=("gizmo", end))
            self.ik_results[end] = res
            mark = "✓ solved" if bool(res.success) else "✗ not reached (best shown)"
            clear = "" if self.avoid is None else f", clearance {float(res.clearance):.4f} m"
            self.target_panel.ik_status[end].content = (
                f"{plain(end)}: {mark}, pos err {float(res.pos_err):.2e} m, "
                f"rot err {float(res.rot_err):.2e} rad{clear}, {int(res.iters)} iters"
            )
        return res

    def move_target(self, end: str, T) -> object:
        """Move the gizmo of ``end`` to ``T (4, 4)`` and solve, as a drag in the browser does."""
        T = np.asarray(T, dtype=np.float64)
        gizmo = self.target_panel.targets[end]
        gizmo.position, gizmo.wxyz = T[:3, 3], _wxyz(T[:3, :3])
        return self.solve_ik(end, _pose(gizmo.position, gizmo.wxyz))

    def _on_gizmo(self, end: str) -> None:
        """A drag update: solve to the gizmo's latest pose, skipping poses superseded during a solve."""
        self._pending[end] = True
        if not self._solving.acquire(blocking=False):
            return
        try:
            while self._pending[end]:
                self._pending[end] = False
                gizmo = self.target_panel.targets[end]
                self.solve_ik(end, _pose(gizmo.position, gizmo.wxyz))
        finally:
            self._solving.release()

    # ------------------------------------------------------------------------------------- arm angle

    def set_arm_angle(self, psi: float, gc=None, *, nearest: bool = False) -> bool:
        """Move the iiwa along the self-motion of its current flange pose to arm angle ``psi``.

        Args:
            psi: arm angle, radians.
            gc: ``(3,)`` signs of joints 2, 4, 6 (default: the current ones).
            nearest: if ``psi`` is infeasible for ``gc``, go to the nearest feasible arm angle.

        Returns:
            Whether the arm moved (``False``: no solution within the joint limits; the arm stays).
        """
        if self.arm_panel is None:
            raise ValueError("set_arm_angle: the arm-angle controls need an iiwa (show(..., arm=dk.srs.iiwa14()))")
        return self.arm_panel.set_arm_angle(psi, gc, nearest=nearest)

    # ------------------------------------------------------------------------------------- results

    def _checked_results(self, what: str) -> tuple[dict[str, np.ndarray], ResultsPanel]:
        """The batch results and their panel; a ValueError names ``what`` without results."""
        if self.results is None or self.results_panel is None:
            raise ValueError(f"{what}: the viewer has no batch results (show(..., results=...))")
        return self.results, self.results_panel

    def show_result(self, i: int) -> None:
        """Show result ``i`` of the batch results (clipped to ``[0, N)``): its ``q``, and its root pose
        ``base`` where given (the root stays where it is otherwise); the result slider follows."""
        results, panel = self._checked_results("show_result")
        i = int(np.clip(i, 0, len(results["q"]) - 1))
        with self._page.lock:
            self.result_index = i
            with self._page.quietly():
                panel.result_slider.value = i  # type: ignore[misc]  # viser's stub: read-only; its API sets it
            panel.result_status.content = describe(results, i)
            if "base" in results:
                self.T_world_root = results["base"][i]
            self.set_q(results["q"][i])

    @property
    def playing(self) -> bool:
        """Whether the batch results are being played."""
        return self._player is not None

    def play(self, fps: float | None = None, loop: bool | None = None) -> None:
        """Play the batch results in order in a background thread, from the one after the shown one.

        One result is shown every ``1 / fps`` seconds (the "frames per second" and "Loop" controls
        are read at every step: changing them changes the playback). Playback from the last result
        starts over at result 0. A playback already running goes on at the new settings.

        Args:
            fps: results shown per second, in ``[0.1, 1000]`` (default: the GUI's value; set there).
            loop: after the last result, start over at result 0 (default: the GUI's value; set
                there); otherwise stop at the last.
        """
        results, panel = self._checked_results("play")
        if fps is not None:
            if not FPS_RANGE[0] <= float(fps) <= FPS_RANGE[1]:
                raise ValueError(f"fps: expected frames per second in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}], got {fps}")
            panel.play_fps.value = float(fps)  # type: ignore[misc]  # viser's stub: read-only; its API sets it
        if loop is not None:
            panel.play_loop.value = bool(loop)  # type: ignore[misc]  # viser's stub: read-only; its API sets it
        with self._page.lock:
            if self.playing:
                return
            if self.result_index in (None, len(results["q"]) - 1):
                self.show_result(0)
            stop = threading.Event()
            thread = threading.Thread(target=self._play, args=(stop,), name="diffkin-viewer-play", daemon=True)
            self._player = thread, stop
            panel.play_button.label = "Pause"
            thread.start()

    def pause(self) -> None:
        """Stop the playback (if any) and wait for its thread to end; the shown result stays."""
        with self._page.lock:
            player, self._player = self._player, None
            if player is None:
                return
            player[1].set()
            self._checked_results("pause")[1].play_button.label = "Play"  # (a player plays results)
        if player[0] is not threading.current_thread():
            player[0].join()  # outside the lock: the thread may be waiting for it to see the stop

    def _play(self, stop: threading.Event) -> None:
        """The playback thread: the next result every ``1 / fps`` seconds until ``stop`` is set or the end."""
        results, panel = self._checked_results("play")
        n = len(results["q"])
        while not stop.wait(1.0 / float(np.clip(panel.play_fps.value, *FPS_RANGE))):  # (a browser may send any)
            with self._page.lock:
                if stop.is_set():
                    return
                i = (self.result_index or 0) + 1
                if i == n and not panel.play_loop.value:
                    self._player = None
                    panel.play_button.label = "Play"
                    return
                self.show_result(i % n)

    # ------------------------------------------------------------------------------------- base placement

    def show_base(self, rank: int = 0) -> None:
        """Draw the robot's root at the base of ``rank`` (0: the best; clipped to the bases of the "Base
        placement" folder) of the placement shown: :attr:`T_world_root` becomes its ``T_world_base``, the
        configuration stays, and the slider and the base's description follow."""
        panel = self.placement_panel
        if panel is None:
            raise ValueError("show_base: the viewer has no base placement (show(..., placement=...))")
        rank = int(np.clip(rank, 0, len(panel.bases) - 1))
        with self._page.lock:
            with self._page.quietly():
                panel.base_slider.value = rank  # type: ignore[misc]  # viser's stub: read-only; its API sets it
            panel.base_status.content = panel.describe(rank)
            self.T_world_root = panel.bases[rank].copy()
            self._apply(self.q, source=None)

    # ------------------------------------------------------------------------------------- lifecycle

    def _warmup(self) -> None:
        """Compile the IK and arm-angle functions in the background so the first drag is quick."""
        try:
            for end in self.kin.ends:
                f = self.kin.frame_names.index(end)
                T = self.T_world_root @ np.asarray(self.kin.poses(jnp.asarray(self.q)))[f]
                jax.block_until_ready(self._run_ik(end, T, self.q)[0])
        except Exception:  # warm-up only: a real solve reports its own errors
            pass

    def stop(self) -> None:
        """Stop the playback (see :meth:`pause`) and the server."""
        self.pause()
        self.server.stop()


def _checked_avoid(avoid, model):
    """``avoid`` if it is ``None`` or a ``dk.ik.Avoid`` of ``model``'s geometry (a :class:`~diffkin.Robot`)."""
    if avoid is None:
        return None
    if not isinstance(model, dk.Robot):
        raise TypeError(
            f"avoid: collision-aware IK needs a dk.Robot (a URDF or MJCF file's robot), got {type(model).__name__}"
        )
    return check_avoid(model, avoid)


class ViewerOptions(TypedDict, total=False):
    """The keywords of :class:`Viewer` (its defaults apply to those left out), which :func:`show` passes on."""

    source: Any
    ends: Sequence[str] | None
    arm: Any
    q0: Any
    workspace_map: Any
    results: Any
    avoid: Any
    placement: Any
    best_bases: int
    host: str
    port: int
    num_seeds: int
    warmup: bool


def show(model, *, block: bool = False, verbose: bool = True, **options: Unpack[ViewerOptions]) -> Viewer:
    """Serve an interactive 3D view of a robot in the browser (viser).

    Args:
        model: a ``DHChain``, ``PoEChain`` or ``Robot``; or a built-in robot name (``"iiwa14"``),
            or the path of a URDF (or MJCF, where :func:`diffkin.load_robot` reads it) file.
        block: serve until interrupted (Ctrl-C) instead of returning.
        verbose: print the URL.
        **options: the keywords of :class:`Viewer` (below), passed on after ``model``, ``workspace_map``
            and ``results`` given as names or paths are read.

    Other Parameters:
        source: the description file of ``model`` (a path or XML text), for its visual meshes;
            set automatically when ``model`` is a path.
        ends: frames that get an IK gizmo (default: a chain's ``ee``, a robot's leaf frames).
        arm: a ``dk.srs.SRSArm`` for the arm-angle controls (default: ``dk.srs.<name>()`` for
            the built-in ``iiwa7``/``iiwa14``).
        q0: initial configuration ``(dof,)`` (default zeros; a bent pose for the iiwa).
        workspace_map: a ``dk.workspace.ReachabilityMap`` (or the path of its ``.npz``) drawn as points.
        results: batched configurations to browse and play (a slider, a "Play" button; from
            Python ``viewer.show_result(i)``, ``viewer.play(fps=..., loop=...)``,
            ``viewer.pause()``): a mapping (or ``.npz`` path) with ``q (N, dof)`` and optionally
            ``success (N,)``, ``pos_err`` and ``rot_err`` ``(N,)`` or ``(N, k)`` (a whole robot's
            per-target errors), and, for a :class:`~diffkin.Robot` with a floating root,
            ``base (N, 4, 4)``: the root pose ``T_world_root`` each row is drawn at. Each field is
            checked before the page is served (``q`` finite, ``success`` booleans, errors real and
            ``>= 0``, ``base`` finite rigid transforms, one row per row of ``q``). A path solved
            by ``res = dk.ik.solve_path(robot, targets, solve_base=True)`` (one path, or
            ``dk.ik.solve`` over a batch of ``N`` targets) is
            ``{"q": res.q, "base": res.base, "success": res.success}``; reshape a larger batch to
            ``(N, ...)`` first.
        avoid: a ``dk.ik.Avoid`` of a :class:`~diffkin.Robot`'s collision geometry, obstacles and
            margin (``dk.ik.Avoid(dk.collision.load(path, robot), world, margin)``; a scene file's
            with :func:`diffkin.collision.load_scene`): the obstacles are drawn (an "Obstacles"
            folder shows them, the clearance of the configuration shown and whether it is
            collision-free), and every drag solves the whole robot clear of them by the margin.
        placement: a ``dk.workspace.Placement`` of this model's capability map
            (:func:`diffkin.workspace.base_placement`): its task poses are drawn as axes, the root is
            drawn at its best base, and a "Base placement" folder's slider (``viewer.show_base(rank)``
            from Python) goes through its ``best_bases`` best bases, each with its map score.
        best_bases: the number of best bases of ``placement`` to go through (default 10).
        host, port: where to serve (default ``127.0.0.1``, 8080; the next free port is taken if ``port`` is in use).
        num_seeds: seeds of each interactive IK solve (the warm start is one of them; default 8).
        warmup: compile the IK functions in a background thread right away (default ``True``).

    Returns:
        The :class:`Viewer` (``viewer.stop()`` ends it).
    """
    if isinstance(model, str):
        if model in BUILTIN:
            name = model
            model = getattr(dk.robots, name)()
            if options.get("arm") is None and name in _ARM_NAMES:
                options["arm"] = getattr(dk.srs, name)()
        else:
            if options.get("source") is None:
                options["source"] = model
            model = dk.load_robot(model)
    elif options.get("arm") is None and isinstance(model, dk.DHChain) and getattr(model, "name", "") in _ARM_NAMES:
        options["arm"] = getattr(dk.srs, model.name)()
    workspace_map = options.get("workspace_map")
    if isinstance(workspace_map, (str, bytes)) or hasattr(workspace_map, "__fspath__"):
        options["workspace_map"] = dk.workspace.ReachabilityMap.load(workspace_map)
    results = options.get("results")
    if isinstance(results, (str, bytes)) or hasattr(results, "__fspath__"):
        options["results"] = read_npz(results, "of batch results (q, and optionally success, pos_err, rot_err, base)")
    viewer = Viewer(model, **options)
    if verbose:
        print(f"diffkin viewer: {viewer.url}  (Ctrl-C to stop)", flush=True)
        if viewer.missing:
            print(
                f"  {len(viewer.missing)} mesh(es) not found or unreadable, drawn as skeleton: "
                f"{', '.join(sorted(set(viewer.missing))[:5])}",
                flush=True,
            )
    if block:  # until Ctrl-C: the KeyboardInterrupt goes on to the caller (the CLI exits with 130)
        try:
            threading.Event().wait()
        finally:
            viewer.stop()
    return viewer
