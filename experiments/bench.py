"""The benchmark suite: diffkin and pytorch-kinematics side by side, one markdown table.

    python experiments/bench.py [--quick] [--only fk,jacobian,ik,srs,workspace,compile] [--write | --out PATH]

Times forward kinematics, world Jacobians, batched IK, the iiwa closed form, self-motion sampling
and reachability maps of the KUKA iiwa14: diffkin's built-in DH model, and pytorch-kinematics on
diffkin's shipped URDF (the same kinematics) where it has the feature and is installed. Everything
is warmed up (JIT compiled, first call done) before timing; each figure is a median (at least 5
runs and 0.3 s of runs). On a GPU machine both libraries run there (JAX's default device, torch
CUDA) with larger batches (FK up to 10^8 configurations, IK up to 10^5 targets: :data:`GPU`); a
pytorch-kinematics call that runs out of GPU memory is noted as such. The ``compile`` part adds a
second table, what the first call costs (``experiments/bench_compile.py``: trace, lower and compile
times and peak memory of FK, Jacobians and IK for 7, 20 and 50 joints and a humanoid tree).
pytorch-kinematics' IK is timed eager and compiled (``PseudoInverseIK(..., use_compile=True)``, its
first call, which runs ``torch.compile``, in the note). ``--quick`` is a smoke run of about a minute
(:data:`QUICK`: small batches, IK at pk's tolerance against pk eager only, the closed form in float32,
one row of the compile table: FK of the 7-joint arm); the full run's figures do not depend on it.
``--write`` saves the tables as ``experiments/results/<machine>.md``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import inspect
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import bench_compile
import jax
import jax.numpy as jnp
import numpy as np
from _bench import (
    PK_IK_TOL,
    busy_note,
    duration,
    machine_line,
    machine_slug,
    median_seconds,
    page_faults_per_call,
    pk,
    pk_chain,
    pk_ik_timed,
    random_configs,
    rate,
    release_torch_memory,
    table,
    to_torch,
    torch,
    torch_synced,
)

import diffkin as dk

DTYPES = ("float32", "float64")
PK_EE = "iiwa14_link_ee"  # the flange link of the shipped iiwa14 URDF


@dataclass(frozen=True)
class Sizes:
    """Batch sizes of each part of the suite."""

    fk: tuple[int, ...]  # FK batches, each in float32 and (up to fk_float64_max) float64
    jacobian: tuple[tuple[int, str], ...]  # (batch, dtype) of the Jacobian rows
    ik: tuple[int, ...]  # IK target counts
    srs: int  # closed-form solutions, in each of srs_dtypes (float32 among them: its first pose is self-motion's)
    self_motion: int  # self-motion samples of one pose
    workspace: int  # reachability-map samples
    fk_float64_max: int | None = None  # largest float64 FK batch (None: all)
    ik_full: bool = True  # IK also at diffkin's own tolerances, and pk's compiled solver (its first call: ~10-60 s)
    srs_dtypes: tuple[str, ...] = DTYPES


FULL = Sizes(
    fk=(1, 1000, 100_000),
    jacobian=((1000, "float32"), (10_000, "float32"), (10_000, "float64"), (100_000, "float32"), (100_000, "float64")),
    ik=(1000,),
    srs=100_000,
    self_motion=2000,
    workspace=4_000_000,
)
GPU = Sizes(
    fk=(1, 1000, 100_000, 1_000_000, 10_000_000, 100_000_000),
    jacobian=((1000, "float32"), (1_000_000, "float32"), (10_000_000, "float32"), (10_000_000, "float64")),
    ik=(1, 1000, 100_000),
    srs=1_000_000,
    self_motion=2000,
    workspace=20_000_000,
    fk_float64_max=10_000_000,
)  # float64 FK at 10^8 needs 18 GB beside pytorch-kinematics' cache
# A smoke run in about a minute: every part once, the fewest compiles (each costs seconds).
QUICK = Sizes(
    fk=(1, 1000),
    jacobian=((1000, "float32"),),
    ik=(100,),
    srs=10_000,
    self_motion=200,
    workspace=200_000,
    ik_full=False,
    srs_dtypes=("float32",),
)


def sizes_for(quick: bool) -> Sizes:
    """:data:`QUICK`, or the full sizes of JAX's default backend: :data:`FULL` on the CPU, :data:`GPU` elsewhere."""
    return QUICK if quick else FULL if jax.default_backend() == "cpu" else GPU


@dataclass(frozen=True)
class Row:
    """One timed piece of work: diffkin's and (where it has it) pytorch-kinematics' median seconds."""

    work: str
    batch: int
    dtype: str
    diffkin: float
    pk: float | None = None
    note: str = ""

    def cells(self) -> list[str]:
        """The row's markdown cells."""

        def timing(seconds):
            if seconds == OUT_OF_MEMORY:
                return "out of memory"
            return "n/a" if seconds is None else f"{duration(seconds)} ({rate(self.batch, seconds)})"

        ratio = "n/a" if self.pk in (None, OUT_OF_MEMORY) else _ratio(self.pk / self.diffkin)
        return [self.work, f"{self.batch:,}", self.dtype, timing(self.diffkin), timing(self.pk), ratio, self.note]


# Quiet-machine ratios stay below ~100x (README); far above it, one side was slowed by other load.
IMPLAUSIBLE_RATIO = 300.0


def _ratio(r: float) -> str:
    """``pk / diffkin`` in bold, or plain and marked when implausibly large (a busy machine)."""
    if r > IMPLAUSIBLE_RATIO:
        return f"{r:.0f}x (implausible: busy machine? rerun)"
    return f"**{r:.2f}x**" if r < 1 else f"**{r:.1f}x**" if r < 10 else f"**{r:.0f}x**"


def _sci(x: float) -> str:
    """``1e-5`` rather than Python's ``1e-05``."""
    mantissa, exponent = f"{x:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _iiwa14():
    return dk.robots.iiwa14()


@functools.cache
def _pk_chain(dtype: str):
    return pk_chain("iiwa14", PK_EE, dtype)


OUT_OF_MEMORY = float("inf")  # pytorch-kinematics' time where it ran out of (GPU) memory


@functools.cache
def _pk_seconds(method: str, n: int, dtype: str) -> float | None:
    """Median time of pytorch-kinematics' ``method`` on ``n`` configurations; ``None`` without it,
    :data:`OUT_OF_MEMORY` where it ran out of memory."""
    if pk is None:
        return None
    try:
        q = to_torch(random_configs(_iiwa14(), n, dtype))
        return median_seconds(torch_synced(getattr(_pk_chain(dtype), method)), q)
    except torch.OutOfMemoryError:
        return OUT_OF_MEMORY
    finally:
        release_torch_memory()


def _notes(*notes: str | None) -> str:
    """The non-empty notes, joined by semicolons."""
    return "; ".join(filter(None, notes))


def _diffkin_row(work: str, n: int, dtype: str, fn, *args, pk_seconds=lambda: None, note: str = "") -> Row:
    """A row timing ``fn(*args)``, then ``pk_seconds()``; the note says so when the allocator maps fresh pages
    on every call. diffkin goes first: with torch's first call just before it, the first row (FK of one
    configuration) read 49 us instead of 5 us."""
    faults = page_faults_per_call(fn, *args)
    if faults is not None and faults >= 1000:
        note = _notes(note, f"{faults:,.0f} page faults per call (fresh output pages: see README)")
    seconds = median_seconds(fn, *args)
    return Row(work, n, dtype, seconds, pk_seconds(), note)


def _with_float64_costs(rows: list[Row]) -> list[Row]:
    """Each float64 row noted with its cost relative to the float32 row of the same work and batch."""
    f32 = {(r.work, r.batch): r.diffkin for r in rows if r.dtype == "float32"}

    def noted(r: Row) -> Row:
        return replace(r, note=_notes(f"{r.diffkin / f32[r.work, r.batch]:.1f}x float32", r.note))

    return [noted(r) if r.dtype == "float64" and (r.work, r.batch) in f32 else r for r in rows]


# --------------------------------------------------------------------------------------------- parts


def fk_rows(sizes: Sizes) -> list[Row]:
    """``dk.fk`` (jitted) vs ``forward_kinematics``."""
    chain = _iiwa14()
    fk = jax.jit(lambda q: dk.fk(chain, q))
    return [
        _diffkin_row(
            "FK",
            n,
            dtype,
            fk,
            jnp.asarray(random_configs(chain, n, dtype)),
            pk_seconds=functools.partial(_pk_seconds, "forward_kinematics", n, dtype),
        )
        for n in sizes.fk
        for dtype in DTYPES
        if dtype == "float32" or sizes.fk_float64_max is None or n <= sizes.fk_float64_max
    ]


def jacobian_rows(sizes: Sizes) -> list[Row]:
    """``dk.jacobian`` in the world frame, analytic and autodiff (jitted), vs ``jacobian``."""
    chain = _iiwa14()
    rows = []
    for n, dtype in sizes.jacobian:
        q = jnp.asarray(random_configs(chain, n, dtype))
        for method in ("analytic", "autodiff"):
            jac = jax.jit(lambda q, method=method: dk.jacobian(chain, q, "world", method=method))
            rows.append(
                _diffkin_row(
                    f"Jacobian (world, {method})",
                    n,
                    dtype,
                    jac,
                    q,
                    pk_seconds=functools.partial(_pk_seconds, "jacobian", n, dtype),
                )
            )
    return rows


def ik_rows(sizes: Sizes) -> list[Row]:
    """``dk.ik.solve`` (LM, jitted) vs ``PseudoInverseIK``, 30 iterations x 10 retries, on reachable float32 pose
    targets, for each target count: diffkin with its defaults (1e-5 m / 1e-4 rad) and at pk's own 1 mm / 0.01 rad
    against pk eager, and again at pk's tolerance against pk compiled (``use_compile=True``, its first call in the
    note); the notes give each library's success rate at its tolerances. :data:`QUICK`: pk's tolerance and pk eager
    only."""
    return [row for n in sizes.ik for row in _ik_rows(n, sizes.ik_full)]


def _pk_ik(T: np.ndarray, compiled: bool) -> tuple[float | None, str | None]:
    """pytorch-kinematics' IK of the targets ``T``: median seconds (:data:`OUT_OF_MEMORY` where it ran out of
    memory, ``None`` where every draw of retries raised) and a note with its success (and, compiled, its first
    call); ``(None, None)`` without pytorch-kinematics."""
    if pk is None:
        return None, None
    chain = _iiwa14()
    try:
        r = pk_ik_timed(
            _pk_chain("float32"), chain.lower, chain.upper, pk.Transform3d(matrix=to_torch(T)), compiled=compiled
        )
    except torch.OutOfMemoryError:
        return OUT_OF_MEMORY, "pk out of memory"
    if r.seconds is None:
        return None, r.note()
    note = f"pk {r.success:.1%} (30 iterations x 10 retries)"
    if compiled:
        cache = "caches warm from the draw that raised" if r.failures else "empty on-disk cache"
        note += f", pk's first call {duration(r.first)} (torch.compile, {cache})"
    return r.seconds, _notes(note, r.note())


def _ik_rows(n: int, full: bool = True) -> list[Row]:
    """The IK rows of ``n`` targets (``full=False``: only at pk's tolerance, against pk eager)."""
    chain = _iiwa14()
    T = np.asarray(dk.fk(chain, random_configs(chain, n, "float64", seed=1)), np.float32)
    args = (jnp.asarray(T), jax.random.key(1))
    t_pk, note_pk = _pk_ik(T, compiled=False)
    defaults = inspect.signature(dk.ik.solve).parameters
    rows = []
    tight = (defaults["pos_tol"].default, defaults["rot_tol"].default)
    for label, tol in (("defaults", tight), ("pk's tolerance", PK_IK_TOL))[0 if full else 1 :]:
        solve = jax.jit(lambda T, key, tol=tol: dk.ik.solve(chain, T, key=key, pos_tol=tol[0], rot_tol=tol[1]))
        t_dk = median_seconds(solve, *args, repeats=15, warmup=1)
        note = f"success at {_sci(tol[0])} m / {_sci(tol[1])} rad: diffkin {float(np.mean(solve(*args).success)):.1%}"
        pk_note = None if label == "defaults" else note_pk
        rows.append(Row(f"IK (LM, {label})", n, "float32", t_dk, t_pk, _notes(note, pk_note)))
    if full and pk is not None:
        t_compiled, note_compiled = _pk_ik(T, compiled=True)
        work = "IK (LM, pk's tolerance), pk compiled"
        rows.append(replace(rows[-1], work=work, pk=t_compiled, note=_notes(note, note_compiled)))
    return rows


def srs_rows(sizes: Sizes) -> list[Row]:
    """``dk.srs.ik`` (the iiwa closed form) on a batch, and ``dk.srs.sample_self_motion`` of one pose (jitted)."""
    arm = dk.srs.iiwa14()
    solve = jax.jit(lambda T, psi, gc: dk.srs.ik(arm, T, psi, gc))
    # The inputs in one jitted call (op by op, each of their operations would compile on its own).
    problems = jax.jit(lambda q: (dk.fk(arm.chain(), q), *dk.srs.arm_angle(arm, q)))
    rows = []
    for dtype in sizes.srs_dtypes:
        T, psi, gc = problems(jnp.asarray(random_configs(arm.chain(), sizes.srs, dtype)))
        if dtype == "float32":
            T_one = T[0]  # the pose of the first configuration (its draw does not depend on the batch size)
        rows.append(
            _diffkin_row(
                "SRS closed-form IK (`dk.srs.ik`)", sizes.srs, dtype, solve, T, psi, gc, note="no closed form in pk"
            )
        )
    n = sizes.self_motion
    sample = jax.jit(lambda T, key: dk.srs.sample_self_motion(arm, T, n, key=key))
    args = (T_one, jax.random.key(0))
    valid = int(sample(*args)[1].sum())
    rows.append(
        Row(
            "self-motion sampling of one pose (`dk.srs`)",
            n,
            "float32",
            median_seconds(sample, *args),
            note=f"{valid:,} of {n:,} valid, spread over every global configuration",
        )
    )
    return rows


def workspace_rows(sizes: Sizes) -> list[Row]:
    """``dk.workspace.reachability``: samples per second of a map (counts, manipulability, dexterity)."""
    chain, n = _iiwa14(), sizes.workspace
    devices = jax.devices()

    def run():
        return dk.workspace.reachability(
            chain, n, key=jax.random.key(0), voxel_size=0.05, dtype="float32", progress=False
        )

    count = len(devices)
    note = f"5 cm voxels, 48 orientation bins, {count} {devices[0].platform.upper()} device{'s' * (count > 1)}"
    return [Row("reachability map (`dk.workspace`)", n, "float32", median_seconds(run, repeats=3, warmup=1), note=note)]


PARTS = {"fk": fk_rows, "jacobian": jacobian_rows, "ik": ik_rows, "srs": srs_rows, "workspace": workspace_rows}
SECTIONS = {"compile": bench_compile.section}  # parts with a table of their own: (quick) -> markdown
ALL_PARTS = (*PARTS, *SECTIONS)


# --------------------------------------------------------------------------------------------- report


def report(parts=ALL_PARTS, quick: bool = False) -> str:
    """The suite's markdown report: a title, the machine, one table of the ``parts`` in :data:`PARTS`, then
    the table of each part in :data:`SECTIONS`."""
    jax.config.update("jax_enable_x64", True)  # for the float64 rows; float32 rows stay float32
    busy, sizes = busy_note(), sizes_for(quick)
    timed = [row for part in parts if part in PARTS for row in PARTS[part](sizes)]
    rows = [row.cells() for row in _with_float64_costs(timed)]
    header = ["work", "batch", "dtype", "diffkin", "pytorch-kinematics", "pk / diffkin", "notes"]
    only = "" if tuple(parts) == ALL_PARTS else " --only " + ",".join(parts)
    command = "python experiments/bench.py" + " --quick" * quick + only
    about = (
        f"`{command}`, {datetime.date.today()}. KUKA iiwa14 (diffkin: built-in DH model; pytorch-kinematics: "
        "the shipped URDF, the same kinematics). Median of warm runs (compiled first; at least 0.3 s and 5 runs, "
        "diffkin IK 15, pk IK and maps 3); rates are items (configurations, targets, samples) per second; "
        "pk / diffkin > 1: diffkin is faster."
    )
    paragraphs = ["# diffkin benchmark", machine_line(), busy, about, table(header, rows) if rows else ""]
    paragraphs += [SECTIONS[part](quick) for part in parts if part in SECTIONS]
    return "\n\n".join(p for p in paragraphs if p)


def default_path() -> Path:
    """``experiments/results/<machine>.md``."""
    return Path(__file__).resolve().parent / "results" / f"{machine_slug()}.md"


def main(args) -> int:
    """Print the report of ``args.only`` (default all parts; ``args.quick`` sizes) and write it
    to ``args.out`` (or, with ``args.write``, to :func:`default_path`)."""
    text = report(args.only or ALL_PARTS, args.quick)
    print(text)
    out = Path(args.out) if args.out else default_path() if args.write else None
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
        print(f"\nwrote {out}")
    return 0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options of :func:`main`; unknown parts and a missing output folder are usage errors (exit status 2)."""
    parser = argparse.ArgumentParser(
        description="FK, Jacobians, IK, the iiwa closed form, self-motion sampling and "
        "reachability maps of the iiwa14, timed for diffkin and, where installed and "
        "where it has the feature, pytorch-kinematics; prints one markdown table."
    )
    parser.add_argument("--quick", action="store_true", help="small batches and fewer rows")
    parser.add_argument(
        "--only", metavar="PARTS", help=f"comma-separated parts to run: {','.join(ALL_PARTS)} (default all)"
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--write", action="store_true", help="also write the table to experiments/results/<machine>.md")
    where.add_argument("--out", metavar="PATH", help="also write the table to PATH")
    args = parser.parse_args(argv)
    if args.only is not None:
        args.only = tuple(part.strip() for part in args.only.split(",") if part.strip())
        unknown = [part for part in args.only if part not in ALL_PARTS]
        if unknown or not args.only:
            found = f"unknown part {unknown[0]!r}" if unknown else "no part"
            parser.error(f"--only: {found}: expected a comma-separated list of {', '.join(ALL_PARTS)}")
    if args.out and not Path(args.out).parent.is_dir():
        parser.error(f"--out: no such directory {str(Path(args.out).parent)!r}")
    return args


if __name__ == "__main__":
    sys.exit(main(parse_args()))
