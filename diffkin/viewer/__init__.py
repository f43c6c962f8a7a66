"""See the robot: an interactive 3D viewer in the browser, built on viser (``pip install "diffkin[viewer]"``).

    import diffkin as dk
    viewer = dk.viewer.show("iiwa14")            # or a chain, a Robot, a URDF path
    viewer.set_q(q); viewer.move_target("ee", T) # everything the page does, from Python

The page draws the robot (its URDF visual meshes, or cylinders between its frames), one slider per
joint, a draggable IK target per end frame, the iiwa arm-angle self-motion, a reachability map as
points, a slider and playback through batched results (with a floating robot's root poses), and
obstacles with every drag solved clear of them (``avoid=dk.ik.Avoid(...)``). viser and trimesh are
imported only here.
"""

from __future__ import annotations

try:
    import trimesh  # noqa: F401
    import viser  # noqa: F401
except ImportError as err:  # pragma: no cover - depends on the installed extras
    raise ImportError(f'diffkin.viewer needs viser and trimesh: pip install "diffkin[viewer]" ({err})') from err

from diffkin.viewer._viewer import Viewer, show

__all__ = ["Viewer", "show"]
