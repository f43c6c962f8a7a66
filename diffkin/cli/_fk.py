"""``diffkin fk``: poses of configurations given on the command line or in a file."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from diffkin.cli._errors import CLIError
from diffkin.cli._robots import frame_of, jax_x64, load_robot, tree
from diffkin.cli._text import clean, fmt, indent, quaternions


def _read_configs(path: str) -> np.ndarray:
    """Joint values from ``.npy`` or a text file (whitespace- or comma-separated, one config per row)."""
    p = Path(path)
    if not p.is_file():
        raise CLIError(f"--q-file: no such file {path!r}")
    try:
        if p.suffix == ".npy":
            data = np.load(p, allow_pickle=False)
        else:
            delimiter = "," if p.suffix == ".csv" else None
            first = next((line for line in p.read_text().splitlines() if line.strip()), "")
            try:  # a non-numeric first line is a header (``q1,q2,...``): skipped
                [float(v) for v in first.replace(",", " ").split()]
                header = False
            except ValueError:
                header = True
            data = np.loadtxt(p, delimiter=delimiter, ndmin=2, skiprows=1 if header else 0)
        return np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError) as e:
        raise CLIError(f"--q-file: cannot read {path!r}: {e}") from None


def cmd_fk(args) -> int:
    """Poses of configurations given on the command line or in a file."""
    jax = jax_x64()
    import diffkin as dk

    if args.frame is not None:
        if args.end_link is not None or args.base_link is not None:
            raise CLIError("--frame: give either --frame (a frame of the whole robot) or --end-link/--base-link")
        robot = tree(args.robot)
        if robot is None:
            raise CLIError(f"--frame: applies to URDF and MJCF files, not to the built-in robot {args.robot!r}")
        model, pose = robot, functools.partial(dk.fk, robot, frames=frame_of(robot, args.frame, "--frame"))
    else:
        model = load_robot(args.robot, args.end_link, args.base_link)
        pose = functools.partial(dk.fk, model)
    if (args.q_file is None) == (not args.q):
        raise CLIError("fk: give the joint values either on the command line or with --q-file (one of the two)")
    q = np.asarray(args.q, dtype=np.float64) if args.q else _read_configs(args.q_file)
    if q.ndim not in (1, 2) or q.shape[-1] != model.dof:
        raise CLIError(
            f"{model.name or args.robot} has {model.dof} joints: expected {model.dof} joint values "
            f"(or an (N, {model.dof}) array), got shape {q.shape}"
        )
    if not np.all(np.isfinite(q)):
        raise CLIError("joint values must be finite")
    if args.format == "npy" and args.output is None:
        raise CLIError("--format npy needs --output FILE")
    if args.output is not None:
        output = Path(args.output)
        if args.format == "npy" and output.suffix != ".npy":
            output = output.with_name(output.name + ".npy")  # where np.save writes it
        if output.is_dir():
            raise CLIError(f"--output: {str(output)!r} is a directory; expected a file name")
        if not output.parent.is_dir():
            raise CLIError(f"--output: no such directory {str(output.parent)!r}")
    Ts = np.asarray(jax.jit(pose)(q))
    if args.format == "npy":
        np.save(output, Ts)
        print(f"wrote {Ts.shape} poses to {output}")
        return 0
    qs, Ts = q.reshape(-1, model.dof), Ts.reshape(-1, 4, 4)
    quats = quaternions(Ts)
    if args.format == "json":
        doc = {
            "robot": model.name or args.robot,
            "poses": [
                {"q": qi.tolist(), "position": Ti[:3, 3].tolist(), "quaternion_wxyz": quat.tolist(), "T": Ti.tolist()}
                for qi, Ti, quat in zip(qs, Ts, quats, strict=True)
            ],
        }
        text = json.dumps(doc, indent=2)
    else:
        blocks = []
        for i, (qi, Ti, quat) in enumerate(zip(qs, Ts, quats, strict=True)):
            blocks.append(
                f"config {i}: q = {fmt(qi)}\n  position {fmt(Ti[:3, 3])} m, quaternion (w x y z) "
                f"{fmt(quat)}\n" + indent(np.array2string(clean(Ti), precision=6, suppress_small=True))
            )
        text = "\n".join(blocks)
    if args.output:
        output.write_text(text + "\n")
        print(f"wrote {len(Ts)} poses to {output}")
    else:
        print(text)
    return 0
