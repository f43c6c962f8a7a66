"""``diffkin workspace``: a reachability (or, ``--capability``, capability) map saved as ``.npz``, and a slice plot."""

from __future__ import annotations

import time
from pathlib import Path

from diffkin.cli._errors import CLIError, need
from diffkin.cli._robots import jax_x64, load_robot
from diffkin.cli._text import fmt


def cmd_workspace(args) -> int:
    """A reachability map of ``--samples`` configurations on a ``--voxel`` grid, saved as ``.npz``; with
    ``--capability`` a capability map (``--orientation-bins`` per voxel), which ``diffkin place`` reads."""
    jax = jax_x64()
    import diffkin as dk
    from diffkin.workspace.interface import voxel_grid

    chain = load_robot(args.robot, args.end_link, args.base_link)
    out = Path(args.out)
    if out.is_dir():
        raise CLIError(f"--out: {str(out)!r} is a directory; expected a file name such as {str(out / 'map.npz')!r}")
    saved = out if out.suffix == ".npz" else out.with_name(out.name + ".npz")  # where np.savez writes
    for flag, path in (("--out", saved), ("--plot", args.plot and Path(args.plot))):
        if path and path.is_dir():
            raise CLIError(
                f"{flag}: {str(path)!r} is a directory; expected a file name such as "
                f"{str(path / ('map.npz' if flag == '--out' else 'slice.png'))!r}"
            )
        if path and not path.parent.is_dir():
            raise CLIError(f"{flag}: no such directory {str(path.parent)!r}")
    if args.plot:
        need("matplotlib", "--plot", "plot")
        origin, voxel, shape = voxel_grid(chain, args.voxel, None)  # the map's grid, known in advance
        a = "xyz".index(args.axis)
        lo, hi = origin[a], origin[a] + voxel * shape[a]
        if not lo <= args.value < hi:
            raise CLIError(
                f"--value: the slice {args.axis} = {args.value:g} m is outside the grid: expected "
                f"{args.axis} in [{lo:.4g}, {hi:.4g}) m"
            )
    if args.orientation_bins is not None and not args.capability:
        raise CLIError("--orientation-bins goes with --capability")
    start = time.perf_counter()
    key, progress = jax.random.key(args.seed), not args.no_progress
    if args.capability:
        bins = 5184 if args.orientation_bins is None else args.orientation_bins
        cap = dk.workspace.capability(
            chain, args.samples, key=key, voxel_size=args.voxel, orientation_bins=bins, progress=progress
        )
        cap.save(saved)
        wmap = cap.as_reachability()
    else:
        wmap = dk.workspace.reachability(chain, args.samples, key=key, voxel_size=args.voxel, progress=progress)
        wmap.save(saved)
    seconds = time.perf_counter() - start
    reached = int((wmap.counts > 0).sum())
    print(
        f"{chain.name or args.robot}: {args.samples:,} samples in {seconds:.2f} s "
        f"({args.samples / seconds / 1e6:.2f} M/s incl. compile), voxel {wmap.voxel_size:g} m, "
        f"grid {'x'.join(map(str, wmap.counts.shape))}, origin {fmt(wmap.origin, 4)} m"
    )
    print(
        f"reached {reached:,} voxels ({reached * wmap.voxel_size**3:.3f} m^3 of voxels reached: a lower bound of "
        f"the workspace volume that grows with --samples), {wmap.n_outside:,} samples outside; "
        f"max manipulability {wmap.manipulability.max():.4g}; saved {saved}"
    )
    if args.capability:
        print(
            f"capability: {cap.cells.size:,} cells of {cap.orientation_bins} orientation bins per voxel reached "
            f"(dk.workspace.CapabilityMap; 'diffkin place' reads it with --map)"
        )
    if args.plot:
        dk.workspace.plot_slice(wmap, args.axis, args.value, args.quantity, path=args.plot)
        print(f"plot: {args.quantity} on the slice {args.axis} = {args.value:g} m -> {args.plot}")
    return 0
