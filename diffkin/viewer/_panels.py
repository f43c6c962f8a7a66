"""The viewer's panels, one folder of the page each (the iiwa's arm angle: ``_arm_panel.py``): what is
drawn, the joint sliders, the IK targets, the obstacles, the workspace map, the batch results and a base
placement's best bases.

A panel builds its controls on a :class:`~diffkin.viewer._gui.Page` and holds them; what its controls do
to the robot goes through the callables it is given: no panel knows the viewer.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import viser.transforms as vtf

from diffkin.viewer import _overlays
from diffkin.viewer._gui import Page, node, plain, shown

FPS_RANGE = (0.1, 1000.0)  # the playback's frames per second


def _toggle(checkbox, handles: Callable[[], Iterable[Any]], attribute: str = "visible") -> None:
    """On each change of ``checkbox``, set ``attribute`` of every handle of ``handles()`` to its value."""

    @checkbox.on_update
    def _(_event) -> None:
        for handle in handles():
            setattr(handle, attribute, checkbox.value)


class DisplayPanel:
    """What is drawn: the frames' axes, the skeleton (with its joint spheres), the meshes.

    Attributes:
        show_frames, show_skeleton, show_meshes: the three checkboxes.
    """

    def __init__(self, page: Page, frames: dict, skeleton: dict, joint_spheres: dict, visuals: dict, meshes: bool):
        gui = page.gui
        with gui.add_folder("Display"):
            self.show_frames = gui.add_checkbox("Show frames", initial_value=not meshes)
            self.show_skeleton = gui.add_checkbox("Show skeleton", initial_value=not meshes)
            self.show_meshes = gui.add_checkbox("Show meshes", initial_value=True, visible=meshes)
        _toggle(self.show_frames, frames.values, "show_axes")
        _toggle(self.show_skeleton, lambda: (*skeleton.values(), *joint_spheres.values()))
        _toggle(self.show_meshes, lambda: (h for handles in visuals.values() for h in handles))


class JointPanel:
    """One slider per joint, in ``q`` order, and a reset to zero.

    Attributes:
        sliders: the sliders.
    """

    def __init__(self, page: Page, kin, q: np.ndarray, moved: Callable[[int], None], reset: Callable[[], None]):
        """``moved(i)``: slider ``i`` was moved; ``reset()``: the reset button was clicked."""
        gui = page.gui
        with gui.add_folder("Joints"):
            self.sliders = []
            for i, joint in enumerate(kin.joint_names):
                lo, hi = float(kin.lower[i]), float(kin.upper[i])
                slider = gui.add_slider(joint, min=lo, max=hi, step=1e-3, initial_value=shown(q[i]))
                slider.on_update(lambda _event, i=i: moved(i))
                self.sliders.append(slider)
            gui.add_button("Reset to zero").on_click(lambda _event: reset())


class TargetPanel:
    """A draggable IK target (a gizmo of the scene) and a status line per end frame.

    Attributes:
        targets: ``{end frame: TransformControlsHandle}``.
        ik_status: ``{end frame: markdown}``, the last solve's result.
    """

    def __init__(self, page: Page, scene, ends: Iterable[str], scale: float, dragged: Callable[[str], None]):
        """``scene``: the server's scene; ``dragged(end)``: the gizmo of ``end`` was moved."""
        gui = page.gui
        self.targets: dict[str, Any] = {}
        self.ik_status: dict[str, Any] = {}
        with gui.add_folder("IK targets"):
            gui.add_markdown("Drag a gizmo: IK from the current configuration (LM, warm start).")
            for end in ends:
                self.ik_status[end] = gui.add_markdown(f"{plain(end)}: not solved yet")
                gizmo = scene.add_transform_controls(f"/targets/{node(end)}", scale=scale)
                gizmo.on_update(lambda _event, end=end: dragged(end))
                self.targets[end] = gizmo


class ObstaclePanel:
    """The obstacles of ``avoid``, the clearance shown, and toggles for the obstacles and the robot's shapes.

    Attributes:
        clearance_status: the clearance of the configuration shown.
        show_obstacles, show_collision: checkboxes.
    """

    def __init__(self, page: Page, avoid, obstacles: dict, collision: list):
        """``obstacles``: ``{scene path: handle}``; ``collision``: per robot shape, its handles."""
        gui, world = page.gui, avoid.world
        sizes = (
            {}
            if world is None
            else {
                "spheres": world.spheres.radius,
                "capsules": world.capsules.radius,
                "boxes": world.boxes.half_extents,
                "cylinders": world.cylinders.radius,
                "convex polytopes": world.convexes.pose,
                "planes": world.planes.offset,
            }
        )
        counts = ", ".join(f"{len(v)} {name}" for name, v in sizes.items() if len(v))
        with gui.add_folder("Obstacles"):
            gui.add_markdown(
                f"{counts or 'no obstacles'}; self-collision {'on' if avoid.self_collision else 'off'}; "
                "every drag is solved clear of them by the margin (the whole robot moves)."
            )
            self.clearance_status = gui.add_markdown("")
            self.show_obstacles = gui.add_checkbox("Show obstacles", initial_value=True)
            self.show_collision = gui.add_checkbox("Show the robot's collision shapes", initial_value=False)
            gui.add_markdown("Red: within the margin of an obstacle or of a link it is checked against.")
        _toggle(self.show_collision, lambda: (h for handles in collision for h in handles))
        _toggle(self.show_obstacles, obstacles.values)


class MapPanel:
    """A reachability map as a point cloud of the scene (``/map``), coloured by a quantity of the map.

    Attributes:
        show_map: checkbox; map_quantity: the quantity coloured (:data:`diffkin.viewer._overlays.QUANTITIES`);
        map_cloud: the point cloud.
    """

    def __init__(self, page: Page, scene, workspace_map):
        gui = page.gui
        self.scene, self.map = scene, workspace_map
        with gui.add_folder("Workspace map"):
            self.show_map = gui.add_checkbox("Show map", initial_value=True)
            self.map_quantity = gui.add_dropdown("colour", _overlays.QUANTITIES, initial_value="counts")
            reached = int((np.asarray(workspace_map.counts) > 0).sum())
            gui.add_markdown(
                f"{reached} reached voxels of {float(workspace_map.voxel_size):g} m, "
                f"{int(workspace_map.n_samples)} samples"
            )
        self._draw()
        self.show_map.on_update(lambda _event: setattr(self.map_cloud, "visible", self.show_map.value))
        self.map_quantity.on_update(lambda _event: self._draw())

    def _draw(self) -> None:
        points, colors = _overlays.map_points(self.map, self.map_quantity.value)
        self.map_cloud = self.scene.add_point_cloud(
            "/map",
            points,
            colors,
            point_size=0.6 * float(self.map.voxel_size),
            point_shape="rounded",
            precision="float32",
            visible=self.show_map.value,
        )


class ResultsPanel:
    """A slider through ``n`` batch results, their playback controls and the result's description.

    Attributes:
        result_slider: the result shown; result_status: its description.
        play_fps, play_loop, play_button: the playback's frames per second, whether it loops, play/pause.
    """

    def __init__(self, page: Page, n: int, show: Callable[[int], None], play_or_pause: Callable[[], None]):
        """``show(i)``: the slider was moved to result ``i``; ``play_or_pause()``: the button was clicked."""
        gui = page.gui
        with gui.add_folder("Batch results"):
            self.result_slider = gui.add_slider("result", min=0, max=max(n - 1, 1), step=1, initial_value=0)
            self.play_fps = gui.add_number(
                "frames per second", initial_value=10.0, min=FPS_RANGE[0], max=FPS_RANGE[1], step=0.1
            )
            self.play_loop = gui.add_checkbox("Loop", initial_value=True)
            self.play_button = gui.add_button("Play")
            self.result_status = gui.add_markdown(f"{n} configurations")

        @self.result_slider.on_update
        def _(_event) -> None:
            if not page.quiet:
                show(int(self.result_slider.value))

        self.play_button.on_click(lambda _event: play_or_pause())


class PlacementPanel:
    """The best bases of a base placement (``dk.workspace.base_placement``) and its task poses: the task
    poses as axes (``/placement/tasks``), a slider through the ``k`` best bases (the robot's root is drawn
    at the one chosen) and its map score.

    Attributes:
        bases: ``(k, 4, 4)`` ``T_world_base`` of the best bases, best first; scores: ``(k,)`` their map scores.
        base_slider: the rank shown (0: the best); base_status: its pose and score; show_tasks: checkbox;
        task_axes: the task poses' axes.
    """

    def __init__(self, page: Page, scene, placement, k: int, place: Callable[[int], None], scale: float):
        """``place(rank)``: the slider was moved to the base of that rank; ``scale``: the axes' length, metres."""
        gui = page.gui
        cells = placement.best_cells(k)
        self.placement = placement
        self.bases = placement.base(cells[:, 0], cells[:, 1], cells[:, 2])
        self.scores = placement.score[tuple(cells.T)]
        tasks = np.asarray(placement.tasks, np.float64)
        self.task_axes = scene.add_batched_axes(
            "/placement/tasks",
            batched_wxyzs=vtf.SO3.from_matrix(tasks[:, :3, :3]).wxyz,
            batched_positions=tasks[:, :3, 3],
            axes_length=scale,
            axes_radius=scale / 12,
        )
        with gui.add_folder("Base placement"):
            self.base_slider = gui.add_slider(
                "base rank", min=0, max=max(len(self.bases) - 1, 1), step=1, initial_value=0
            )
            self.show_tasks = gui.add_checkbox("Show task poses", initial_value=True)
            self.base_status = gui.add_markdown("")
            gui.add_markdown(
                f"{len(tasks)} task poses; score: the fraction of them the capability map reaches from the base "
                "(a prior: `Placement.verify` re-solves by IK)"
            )
        _toggle(self.show_tasks, lambda: [self.task_axes])

        @self.base_slider.on_update
        def _(_event) -> None:
            if not page.quiet:
                place(int(self.base_slider.value))

    def describe(self, rank: int) -> str:
        """``base 1 of 10: x +0.250 m, y -0.300 m, yaw 90 deg, map score 97.5%``."""
        T = self.bases[rank]
        yaw = np.degrees(np.arctan2(T[1, 0], T[0, 0])) % 360
        return (
            f"base {rank + 1} of {len(self.bases)}: x {T[0, 3]:+.3f} m, y {T[1, 3]:+.3f} m, yaw {yaw:.0f} deg, "
            f"map score {self.scores[rank]:.1%}"
        )
