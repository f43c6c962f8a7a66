"""The ``diffkin`` argument parser: its subcommands, their options and the types that check them."""

from __future__ import annotations

import argparse
import functools
import math
import re

from diffkin.cli._demo import cmd_demo
from diffkin.cli._errors import CLIError
from diffkin.cli._fk import cmd_fk
from diffkin.cli._ik import cmd_ik
from diffkin.cli._info import cmd_info
from diffkin.cli._place import cmd_place
from diffkin.cli._robots import ROBOTS
from diffkin.cli._view import cmd_view
from diffkin.cli._workspace import cmd_workspace

_MAX_SAMPLES = 10**12  # reachability samples (int32 chunk counters; weeks of CPU time already)
_SEED_RANGE = (-(2**63), 2**63 - 1)  # jax.random.key takes a 64-bit integer


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr and exit status 2.

    Negative numbers in scientific notation (``-1e-3``, ``-2.5E+2``) are values, not options
    (argparse's own pattern knows only ``-1`` and ``-1.5``).
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

    def error(self, message):
        raise CLIError(message)


class _IntermixedParser(_Parser):
    """A subcommand parser that takes options between positionals (``fk URDF --end-link L q1 ...``)."""

    _inside = False

    def parse_known_args(self, args=None, namespace=None):
        if self._inside:  # parse_known_intermixed_args calls back here
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


# --------------------------------------------------------------------------------------------- argument types


def _finite(text: str) -> float:
    """argparse type: a finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _integer(text: str) -> int:
    """An int from ``1000``, ``1_000`` or an integral ``1e3``; ArgumentTypeError otherwise."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if math.isfinite(value) and value == int(value):
        return int(value)
    raise argparse.ArgumentTypeError(f"invalid integer: {text!r}")


def _positive_int(text: str, most: int = 10**9) -> int:
    """argparse type: an int in ``[1, most]`` (underscores allowed, as in ``1_000_000``; ``1e6``)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    if value > most:
        raise argparse.ArgumentTypeError(f"expected at most {most:,}, got {text!r}")
    return value


def _samples(text: str) -> int:
    """argparse type: a number of reachability samples, ``1 .. 10**12``."""
    return _positive_int(text, _MAX_SAMPLES)


def _seed(text: str) -> int:
    """argparse type: a PRNG seed, a 64-bit signed integer."""
    value = _integer(text)
    if not _SEED_RANGE[0] <= value <= _SEED_RANGE[1]:
        raise argparse.ArgumentTypeError(f"expected a seed in [-2**63, 2**63 - 1], got {text!r}")
    return value


def _tolerance(text: str) -> float:
    """argparse type: a finite float >= 0."""
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    """argparse type: a finite float > 0."""
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _sign(text: str) -> float:
    """argparse type: ``+1`` or ``-1`` (a global-configuration sign)."""
    value = _finite(text)
    if value not in (1.0, -1.0):
        raise argparse.ArgumentTypeError(f"expected +1 or -1, got {text!r}")
    return value


# --------------------------------------------------------------------------------------------- the parser


def _add_robot(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "robot",
        metavar="ROBOT_OR_FILE",
        help=f"built-in robot ({', '.join(ROBOTS)}) or the path of a URDF or MJCF file",
    )
    p.add_argument("--end-link", metavar="L", help="end frame of the chain in a file's tree (default: the single leaf)")
    p.add_argument("--base-link", metavar="B", help="base frame of the chain (default: the root)")


def _add_avoid(p: argparse.ArgumentParser, what: str) -> None:
    """``--avoid SCENE.json``, ``--margin M`` and ``--srdf`` (``ik``, ``place``, ``view``); ``what`` says what
    the command does with them."""
    p.add_argument(
        "--avoid",
        metavar="SCENE.json",
        help=f"obstacles to keep clear of (spheres, capsules, boxes, planes; docs/collision.md): {what}",
    )
    p.add_argument(
        "--margin",
        type=_tolerance,
        metavar="M",
        help="with --avoid: the clearance asked for, m (default: the scene's margin, else 0)",
    )
    p.add_argument(
        "--srdf",
        action="append",
        metavar="FILE.srdf",
        help="with --avoid: an SRDF whose <disable_collisions> link pairs are not checked for self-collision "
        "(repeat for several: the robot's own, one saved from dk.collision.sample_pairs)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``diffkin`` argument parser with its subcommands."""
    parser = _Parser(
        prog="diffkin",
        description="Differentiable robot kinematics in JAX: demo, robot info, "
        "forward and inverse kinematics, workspace maps. Numbers in float64, angles in radians.",
    )
    from diffkin import __version__

    parser.add_argument("--version", action="version", version=f"diffkin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_IntermixedParser)
    common = _IntermixedParser(add_help=False)  # the options every command shares (a parent parser)
    cache = common.add_argument_group("compilation cache")
    cache.add_argument(
        "--cache-dir",
        metavar="DIR",
        help="JAX's persistent compilation cache (default "
        "$DIFFKIN_CACHE_DIR, else $XDG_CACHE_HOME/diffkin/jax or ~/.cache/diffkin/jax; "
        "DIFFKIN_CACHE_DIR=off disables it)",
    )
    cache.add_argument("--no-cache", action="store_true", help="compile without the persistent cache")
    add_parser = functools.partial(sub.add_parser, parents=[common])

    p = add_parser(
        "demo",
        help="FK check, batched IK, iiwa self-motion and a reachability map with plots",
        description="The main job on the built-in iiwa14: random batched FK (jitted) checked against "
        "the shipped URDF, batched IK of 1,000 targets, the arm-angle self-motion of one pose, a "
        "reachability map; prints a report and writes PNG plots.",
    )
    p.add_argument("--out", default="diffkin-demo", metavar="DIR", help="folder for the PNGs (default ./diffkin-demo)")
    p.add_argument("--quick", action="store_true", help="small sizes (50 IK targets, tiny map)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_demo)

    p = add_parser(
        "info",
        help="joints, limits, DH or screw table, home pose",
        description="Joints, types, limits, the DH table (DHChain) or the space-frame screw table "
        "(PoEChain, URDFs) and the home pose (FK at q = 0) of a robot.",
    )
    _add_robot(p)
    p.set_defaults(func=cmd_info)

    p = add_parser(
        "fk",
        help="end-effector poses of configurations",
        description="End-effector poses (base frame) of joint configurations (radians / metres).",
    )
    _add_robot(p)
    p.add_argument("q", nargs="*", type=_finite, metavar="q", help="joint values q1 ... qn")
    p.add_argument("--q-file", metavar="FILE", help=".npy (or .txt/.csv) file of (n,) or (N, n) joint values")
    p.add_argument(
        "--frame",
        metavar="NAME",
        help="a frame of a file's whole robot (q: its actuated joints, "
        "`diffkin info FILE` lists them), instead of a chain's end effector",
    )
    p.add_argument("--format", choices=("text", "json", "npy"), default="text", help="output format (default text)")
    p.add_argument("--output", metavar="FILE", help="write to FILE (required for npy: an (..., 4, 4) array)")
    p.set_defaults(func=cmd_fk)

    p = add_parser(
        "ik",
        help="inverse kinematics of one pose or position",
        description="Inverse kinematics of one target: batched Levenberg-Marquardt from random seeds "
        "(dk.ik.solve), among the obstacles of a scene file with --avoid, or with --all every exact iiwa "
        "solution along the arm angle (dk.srs). Exit status 1 if no solution was found (with --avoid: none "
        "clear of the obstacles by the margin).",
    )
    _add_robot(p)
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument(
        "--pose",
        nargs=7,
        type=_finite,
        metavar=("X", "Y", "Z", "QW", "QX", "QY", "QZ"),
        help="target position (m) and orientation quaternion (w x y z)",
    )
    target.add_argument(
        "--position", nargs=3, type=_finite, metavar=("X", "Y", "Z"), help="target position (m), orientation free"
    )
    p.add_argument(
        "--seeds",
        type=functools.partial(_positive_int, most=4096),
        default=32,
        metavar="N",
        help="random seeds (default 32)",
    )
    p.add_argument("--q0", nargs="+", type=_finite, metavar="Q", help="warm start: one value per joint")
    p.add_argument(
        "--pos-tol",
        type=_tolerance,
        default=1e-5,
        metavar="M",
        help="success tolerance on the position error, m (default 1e-5)",
    )
    p.add_argument(
        "--rot-tol",
        type=_tolerance,
        default=1e-4,
        metavar="RAD",
        help="success tolerance on the rotation error, rad (default 1e-4)",
    )
    p.add_argument("--seed", type=_seed, default=1, help="PRNG seed of the random seeds (default 1)")
    _add_avoid(p, "solves the file's whole robot with its collision geometry; success needs the clearance")
    p.add_argument("--all", action="store_true", help="iiwa7/iiwa14: exact solutions along the self-motion (dk.srs)")
    p.add_argument("--psi", type=_finite, metavar="PSI", help="with --all: one arm angle (rad), via dk.srs.ik")
    p.add_argument(
        "--gc",
        nargs=3,
        type=_sign,
        metavar=("G2", "G4", "G6"),
        help="with --all: one global configuration (signs of joints 2, 4, 6; default all eight)",
    )
    p.add_argument(
        "--samples",
        type=functools.partial(_positive_int, most=10**6),
        metavar="N",
        help="with --all: number of samples (default 16)",
    )
    p.set_defaults(func=cmd_ik)

    p = add_parser(
        "workspace",
        help="reachability map (.npz) and optional slice plot",
        description="Reachability, manipulability and dexterity map of uniformly sampled "
        "configurations (dk.workspace.reachability), saved with ReachabilityMap.save.",
    )
    _add_robot(p)
    p.add_argument(
        "--samples", type=_samples, default=1_000_000, metavar="N", help="configurations to sample (default 1,000,000)"
    )
    p.add_argument("--voxel", type=_positive_float, default=0.05, metavar="V", help="voxel edge, m (default 0.05)")
    p.add_argument("--out", required=True, metavar="MAP.npz", help="where to save the map")
    p.add_argument("--plot", metavar="SLICE.png", help="also plot one slice of the map")
    p.add_argument("--axis", choices=("x", "y", "z"), default="y", help="slice normal (default y)")
    p.add_argument("--value", type=_finite, default=0.0, help="slice position along --axis, m (default 0)")
    p.add_argument(
        "--quantity",
        choices=("count", "manipulability", "dexterity"),
        default="count",
        help="plotted quantity (default count)",
    )
    p.add_argument("--seed", type=_seed, default=0, help="PRNG seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--capability",
        action="store_true",
        help="a capability map instead (dk.workspace.capability: samples per voxel and orientation bin), "
        "for 'diffkin place --map'",
    )
    p.add_argument(
        "--orientation-bins",
        type=_positive_int,
        metavar="B",
        help="with --capability: orientation bins, 24 d^3 for 90/d degree cells (default 5184: 15 degrees)",
    )
    p.set_defaults(func=cmd_workspace)

    p = add_parser(
        "place",
        help="where to put the robot: base poses scored by the tasks a capability map reaches",
        description="Base placement (dk.workspace.base_placement): a grid of planar base poses (x, y, yaw) "
        "over --region, each scored by the fraction of the task poses that a capability map says it reaches "
        "(built here, or read with --map); the best bases printed, optionally verified by IK, plotted and shown "
        "in the viewer. With --avoid, the bases and tasks that collide at every solution are ruled out.",
    )
    _add_robot(p)
    p.add_argument(
        "--tasks",
        required=True,
        metavar="TASKS",
        help="task poses T_world_task, (N, 4, 4): a .npy array, a .npz with 'tasks', or a JSON list of 4x4 matrices",
    )
    p.add_argument(
        "--region",
        nargs=4,
        type=_finite,
        required=True,
        metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
        help="where the base may stand, m (world)",
    )
    p.add_argument("--map", metavar="CAP.npz", help="capability map from 'diffkin workspace --capability'")
    p.add_argument(
        "--samples", type=_samples, default=1_000_000, metavar="N", help="without --map: samples (default 1,000,000)"
    )
    p.add_argument("--voxel", type=_positive_float, default=0.05, metavar="V", help="without --map: voxel, m")
    p.add_argument(
        "--orientation-bins", type=_positive_int, default=5184, metavar="B", help="without --map: bins (default 5184)"
    )
    p.add_argument("--yaw-bins", type=_positive_int, default=36, metavar="K", help="base yaws (default 36)")
    p.add_argument("--base-height", type=_finite, default=0.0, metavar="H", help="base z in the world, m (default 0)")
    p.add_argument("--cell", type=_positive_float, metavar="C", help="base grid cell, m (default: the map's voxel)")
    p.add_argument(
        "--cell-only",
        action="store_true",
        help="judge each task by its map cell alone, not by the cells around its pose (arms of fewer than 6 joints)",
    )
    p.add_argument("--best", type=_positive_int, default=5, metavar="K", help="bases to print (default 5)")
    p.add_argument("--verify", type=int, default=0, metavar="K", help="re-solve the K best bases by IK (default 0)")
    p.add_argument("--plot", metavar="PLACE.png", help="plot the score over (x, y) at the best yaw, tasks drawn")
    p.add_argument("--out", metavar="PLACE.npz", help="save the scores and the best bases")
    p.add_argument("--seed", type=_seed, default=0, help="PRNG seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_avoid(
        p,
        "the file's whole robot with its collision geometry; a base whose root body, or a task whose tool body, is "
        "within the margin of an obstacle is ruled out, and --verify solves clear of them",
    )
    p.add_argument(
        "--view",
        action="store_true",
        help="then serve the viewer on the --best bases and the tasks until Ctrl-C (pip install 'diffkin[viewer]')",
    )
    p.add_argument("--host", metavar="HOST", help="with --view: address to serve on (default 127.0.0.1)")
    p.add_argument(
        "--port",
        type=_positive_int,
        metavar="PORT",
        help="with --view: port (default 8080; the next free one if taken)",
    )
    p.set_defaults(func=cmd_place)

    p = add_parser(
        "view",
        help="interactive 3D viewer in the browser (viser; pip install 'diffkin[viewer]')",
        description="Serve an interactive 3D view of a robot (viser): meshes or link cylinders, joint "
        "sliders, draggable IK targets, the iiwa arm angle, a reachability map, batched results, "
        "obstacles (--avoid: drags solved clear of them). "
        "Prints the URL; runs until Ctrl-C.",
    )
    p.add_argument("robot", metavar="ROBOT_OR_FILE", help=f"built-in robot ({', '.join(ROBOTS)}) or a URDF/MJCF file")
    p.add_argument("--port", type=_positive_int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--map", metavar="MAP.npz", help="reachability map from 'diffkin workspace', drawn as points")
    p.add_argument(
        "--ik-results",
        metavar="FILE.npz",
        help=".npz: q (N, dof), optional success, pos_err, rot_err (N,), a floating root's base (N, 4, 4); "
        "to browse and play",
    )
    p.add_argument("--end", nargs="+", metavar="FRAME", help="frames with an IK target (default: the leaf frames)")
    _add_avoid(p, "a URDF/MJCF file's robot with its collision geometry; obstacles drawn, drags solved clear of them")
    p.set_defaults(func=cmd_view)
    return parser
