"""``diffkin view``: the interactive 3D viewer in the browser (the ``viewer`` extra)."""

from __future__ import annotations

from pathlib import Path

from diffkin.cli._errors import CLIError
from diffkin.cli._robots import ROBOTS, jax_x64, robot_file, robot_with_geometry
from diffkin.cli._scene import read_scene


def cmd_view(args) -> int:
    """An interactive 3D view of a robot in the browser (``dk.viewer.show``), served until Ctrl-C;
    with ``--avoid``, the scene's obstacles drawn and every drag solved clear of them."""
    jax_x64()
    try:
        from diffkin import viewer
    except ImportError as e:
        raise CLIError(str(e)) from None
    for flag, value in (("--margin", args.margin), ("--srdf", args.srdf)):
        if value is not None and args.avoid is None:
            raise CLIError(f"{flag} goes with --avoid")
    if args.robot not in ROBOTS:
        robot_file(args.robot)
    for flag, path in (("--map", args.map), ("--ik-results", args.ik_results)):
        if path is not None and not Path(path).is_file():
            raise CLIError(f"{flag}: no such file {path!r}")
    model, source, avoid = args.robot, None, None
    if args.avoid is not None:
        import diffkin as dk

        model, geom = robot_with_geometry(args.robot, args.srdf)
        scene = read_scene(args.avoid, args.margin)
        source, avoid = args.robot, dk.ik.Avoid(geom, scene.world, scene.margin, scene.self_collision)
    viewer.show(
        model,
        source=source,
        avoid=avoid,
        ends=args.end,
        host=args.host,
        port=args.port,
        workspace_map=args.map,
        results=args.ik_results,
        block=True,
    )
    return 0
