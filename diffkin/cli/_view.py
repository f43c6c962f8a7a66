"""``diffkin view``: the interactive 3D viewer in the browser (the ``viewer`` extra)."""

from __future__ import annotations

from pathlib import Path

from diffkin.cli._errors import CLIError
from diffkin.cli._robots import ROBOTS, jax_x64, robot_file


def cmd_view(args) -> int:
    """An interactive 3D view of a robot in the browser (``dk.viewer.show``), served until Ctrl-C."""
    jax_x64()
    try:
        from diffkin import viewer
    except ImportError as e:
        raise CLIError(str(e)) from None
    if args.robot not in ROBOTS:
        robot_file(args.robot)
    for flag, path in (("--map", args.map), ("--ik-results", args.ik_results)):
        if path is not None and not Path(path).is_file():
            raise CLIError(f"{flag}: no such file {path!r}")
    viewer.show(
        args.robot,
        ends=args.end,
        host=args.host,
        port=args.port,
        workspace_map=args.map,
        results=args.ik_results,
        block=True,
    )
    return 0
