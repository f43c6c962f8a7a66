"""Speed tricks for XLA's CPU backend: one name per trick, each with a line of reason.

Each function here leaves values and derivatives as they are; it only changes what XLA compiles.
The measurements that justify them are in docs/performance.md, "XLA CPU tricks".

- Model numbers known at trace time are folded into the program as Python floats (the
  static/traced rule: :mod:`diffkin._static`); only traced numbers become program inputs.
- :func:`materialize`: values that many later kernels read are computed once, behind an
  optimization barrier, instead of being recomputed inside each consumer.
- :func:`computed_once`: one array that many later kernels read, computed once (by :func:`materialize`).
- :func:`opaque_index`: an index that feeds several scatters is computed once.
- :func:`where_any`: a batch's update that most batches do not need is skipped when none of its
  problems needs it.
- :func:`entries_last`: an array of many entries that many kernels read, computed once, problems last.
- :func:`in_steps`: a large batch goes through a function in fixed-size steps, so that each
  step's intermediates stay in cache and the temporary buffer stays small; optionally each step
  as two independent halves (:func:`_in_halves`), so that both CPU threads have work.
- :func:`problems_at_once`: independent problems that each iterate until solved go one at a time
  through :func:`in_steps` on the CPU, so that none waits for the slowest.
- :func:`spans` and :func:`in_threads`: such problems, called at the top level on the CPU, are split into
  spans (:data:`SPANS_PER_CORE` per core), each planned by the same compiled program on one host thread per
  core: one problem's kernels are too small and too serial to keep more than about one core and a quarter busy.
- :func:`blocks_joined`: blocks of a result with the batch innermost, joined.
- :data:`LAST_STEPPED`: an output with the configurations last is moved to the front in a kernel
  of its own (through the stepped loop), not fused into the computation, which would then not be
  vectorised.
- :func:`inverse_sqrt`: ``1 / sqrt(x)`` in float64 written so that XLA does not turn it into its
  ``rsqrt``, which LLVM cannot vectorise on a host without AVX-512 (the whole fused loop around it
  then runs one entry at a time).
- :data:`SOLVER_COMPILE` and :func:`solver_jit`: the IK solvers are compiled by XLA's classic CPU
  kernel emitter, which compiles in two thirds of the time of the newer MLIR emitters (see there);
  a solver's ``compile_ahead`` compiles it in a background thread while the caller does other work
  (XLA compiles a program on one core: a trajectory with a pose goal compiles its solver while IK
  compiles and solves the goal).
- :data:`TRAJ_COMPILE`: the trajectory solver, whose time is GJK's loops, also without YNNPACK fusions.
- :func:`segment_end`: a long serial forward pass is materialised every :data:`SEGMENT` joints, so
  that XLA's fusion does not copy the pass into every output of a Jacobian.
- :func:`gpu_outputs`: float32 outputs are computed once behind a barrier on a GPU, whose
  concatenate would recompute the shared pass for each entry.
- :func:`stacked_sincos` (with its derivative rule) and :func:`stacked_atan2`: many sines and
  cosines, or arctangents, through one call, whose ``lax.cond`` and kernels then come once.
- :func:`summed_products`: ``sum(x * y, axis)`` over a short axis written out term by term, where an
  ``einsum`` is a batched dot of one tiny product per entry on the CPU.
- :func:`stable_partition`: the slots of a stable sort of short boolean rows, without XLA's sort,
  which on the CPU is slow for many small rows.

Elsewhere, as they are part of what those modules compute: the structure-of-arrays rigid
transforms (:mod:`diffkin._rigid`), one stack of every entry for many poses
(:func:`diffkin._rigid.to_matrices`, measured there), the fused ``sincos``/``atan2``
(:mod:`diffkin._trig`, measured there) and the IK's hashed seeds (:mod:`diffkin.ik._uniform`),
each measured there.
"""

from __future__ import annotations

import concurrent.futures
import functools
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from diffkin import _trig

#: Compiler options of the IK solvers' ``jax.jit`` (:func:`diffkin.ik.solve` and the CLI's and
#: viewer's compiled solvers): XLA's classic CPU kernel emitter instead of its MLIR fusion
#: emitters. XLA's CPU compile time is mostly per-kernel code generation, and the classic emitter
#: does it with less work (about two thirds of the compile time; docs/performance.md). The
#: option names a CPU setting only: other backends compile as they would without it. It applies to
#: the ``jit`` it is given to; a solver traced inside a user's own ``jit`` gets that ``jit``'s options.
SOLVER_COMPILE = {"xla_cpu_use_fusion_emitters": False}
#: Compiler options of the trajectory solver (:func:`diffkin.traj.optimize`): :data:`SOLVER_COMPILE`, and no
#: YNNPACK fusions. XLA's CPU backend hands batched dot products to the YNNPACK library; inside GJK's loops
#: they are products of 3-vectors with 3x3 rotations, where a library call costs more than the arithmetic
#: (measured in docs/performance.md, "XLA CPU tricks"). The IK solver's products are larger and gain from
#: them. Older jaxlibs have no such option, and are given none (:func:`supported`).
TRAJ_COMPILE = {**SOLVER_COMPILE, "xla_cpu_experimental_ynn_fusion_type": ""}


def _default_backend() -> str:
    """The backend a plain ``jit`` compiles for (a function of its own, so that a test can pose as a GPU)."""
    return jax.default_backend()


def solver_jit(fn: Callable, options: dict | None = None, **kwargs) -> SolverJit:
    """``jax.jit(fn, **kwargs)``, compiled with ``options`` (default :data:`SOLVER_COMPILE`), those this
    jaxlib knows (:func:`supported`), when called outside any trace and compiled for the CPU.

    JAX accepts compiler options only on a top-level ``jit``: inside a transformation (a user's
    ``jit``, ``vmap`` or ``grad``) the plain ``jit`` is used, and the outer one decides. The options
    are the CPU backend's: a GPU's compiler rejects them ("No such compile option").
    """
    return SolverJit(fn, SOLVER_COMPILE if options is None else options, kwargs)


class SolverJit:
    """What :func:`solver_jit` gives: called as ``fn``; :meth:`compile_ahead` compiles a call in the background."""

    def __init__(self, fn: Callable, options: dict, kwargs: dict):
        self._fn, self._options, self._kwargs = fn, options, kwargs
        self._plain = jax.jit(fn, **kwargs)
        functools.update_wrapper(self, fn)

    @functools.cached_property
    def _top(self) -> Any:  # at the first call: which options this jaxlib knows takes a compile
        return jax.jit(self._fn, compiler_options=supported(self._options), **self._kwargs)

    def _jitted(self, args: tuple, kw: dict) -> Any:
        return self._top if _default_backend() == "cpu" and top_level(args, kw) else self._plain

    def __call__(self, *args, **kw):
        return self._jitted(args, kw)(*args, **kw)

    def compile_ahead(self, *args, **kw) -> concurrent.futures.Future | None:
        """Start compiling the call with ``args`` (concrete, at the top level; else ``None``: nothing to
        compile ahead) in a background thread; the future's ``result()`` is ``None`` once it is compiled
        (a call then reuses it: JAX keeps a jit's compiled programs by their arguments' shapes)."""
        if not top_level(args, kw):
            return None
        return _AHEAD.submit(_compile, self._jitted(args, kw), args, kw)


#: the thread that compiles ahead (:meth:`SolverJit.compile_ahead`): one, as XLA compiles a program on
#: one core and the caller's own work takes the other
_AHEAD = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="diffkin-compile")


def _compile(jitted: Any, args: tuple, kw: dict) -> None:
    jitted.lower(*args, **kw).compile()


def supported(options: dict) -> dict:
    """The entries of ``options`` (XLA CPU compiler options) that this jaxlib's compiler takes: options come
    and go between versions, and an unknown one fails the compile."""
    return {name: value for name, value in options.items() if _known(name, value)}


@functools.cache
def _known(name: str, value) -> bool:
    """Whether the CPU compiler takes the option ``name`` set to ``value`` (a compile of the identity)."""
    try:
        jax.jit(lambda x: x, compiler_options={name: value}).lower(np.float32(0)).compile()
    except Exception:  # XLA's error for an unknown option is not a documented type
        return False
    return True


def top_level(*args) -> bool:
    """Whether no transformation traces a call with the arguments ``args``.

    JAX has no public query for it (checked on jax 0.10.2): JAX's own ``trace_state_clean`` where
    it exists (0.4 us); elsewhere :func:`_top_level_public`.
    """
    core = getattr(getattr(jax, "_src", None), "core", None)
    clean = getattr(core, "trace_state_clean", None)
    return bool(clean()) if clean is not None else _top_level_public(*args)


def _top_level_public(*args) -> bool:
    """:func:`top_level` through public API only (slower): no argument is a tracer (``vmap``, ``grad``
    or ``jit`` of the call) and a fresh constant is not staged out as one (a ``jit`` around it)."""
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(args)):
        return False
    return not isinstance(jnp.zeros((), jnp.int8), jax.core.Tracer)


def materialize(values: list) -> jax.Array:
    """``(len(values),) + batch``: the values (arrays of broadcastable shapes, or Python floats) computed once.

    XLA's CPU fusion duplicates an elementwise producer into every consumer kernel; in a deep
    computation with much reuse (a forward pass, a Cholesky factorisation) that recomputes the
    same values many times over. Stacking the shared values behind an optimization barrier makes
    XLA compute them once (``dk.srs.ik`` about 2x faster, the IK's step 20x).
    """
    arrays = [v for v in values if not isinstance(v, float)]
    shape = tuple(np.broadcast_shapes(*(jnp.shape(v) for v in arrays)))
    dtype = jnp.result_type(*arrays)
    entries = [jnp.broadcast_to(jnp.asarray(v, dtype=dtype), shape) for v in values]
    # XLA folds away a stack of one (and the barrier with it): a single value is stacked twice.
    stacked = jnp.stack(entries * 2 if len(entries) == 1 else entries)
    return jax.lax.optimization_barrier(stacked)[: len(entries)]


def computed_once(x: jax.Array, batch: int) -> jax.Array:
    """``x`` as it is, computed once for its many consumers (one kernel): :func:`materialize` of its rows
    ``x.reshape((-1,) + batch_shape)`` (``batch``: the number of trailing batch axes). An optimization barrier
    on ``x`` alone does not do it (XLA's CPU backend drops it before fusion and duplicates the expression
    into every consumer: a forward pass by depth, :mod:`diffkin.models._levels`, recomputed its depths
    above in each), nor does one on a stack of its slices along an axis (folded back into ``x``)."""
    rows = x.reshape((-1,) + x.shape[x.ndim - batch :])
    return materialize(list(rows)).reshape(x.shape)


def entries_last(x: jax.Array) -> jax.Array:
    """``x`` ``(P, ...)`` as it is, its entries computed once (:func:`materialize`) and stored problems last.

    A value that many kernels read entry by entry (a target pose ``(P, 4, 4)`` with the checks that made
    it safe) is otherwise recomputed inside each of them, and read across the problems' stride:
    ``dk.ik.step``'s Panda targets at 4,096, the step 15-30 % faster.
    """
    n = x.shape[0]
    flat = x.reshape(n, -1)
    return materialize([flat[:, i] for i in range(flat.shape[1])]).T.reshape(x.shape)


# A serial forward pass is materialised every this many joints (see :func:`segment_end`).
SEGMENT = 8


def segment_end(i: int, dof: int) -> bool:
    """Whether a serial chain's forward pass materialises its pose after joint ``i`` (of ``dof``).

    XLA's CPU fusion duplicates an elementwise producer into each consumer kernel, and every
    output of a Jacobian depends on the forward pass up to its joint: without a barrier the
    compiled program holds ``O(dof^2)`` copies of the pass, and compile time and memory grow
    accordingly (docs/performance.md, "The first call"). Materialising the pose every
    :data:`SEGMENT` joints (:func:`diffkin._rigid.checkpoint`) bounds each copy to one segment;
    chains of up to :data:`SEGMENT` joints (every arm) compile to the same program as without it.
    """
    return (i + 1) % SEGMENT == 0 and i + 1 < dof


def gpu_outputs(arrays: list[jax.Array], dtype) -> list[jax.Array]:
    """Computed outputs about to be stacked: in float32 off the CPU (a GPU) each computed once behind
    an optimization barrier; on the CPU, and in float64, as they are.

    XLA's GPU concatenate emits each operand's expression on its own, so a stack of the entries of a
    forward pass recomputes the shared part of the pass for every entry (3x faster FK on an H100); in
    float64 the barrier made FK slower, so float64 stays plain. Measurements: docs/performance.md,
    "GPU outputs". The platform is the one the program is compiled for (``lax.platform_dependent``).
    """
    if not arrays or jnp.dtype(dtype) != jnp.float32:
        return arrays
    return list(jax.lax.platform_dependent(*arrays, cpu=_as_is, default=_materialized))


def _as_is(*arrays):
    return arrays


def _materialized(*arrays):
    return jax.lax.optimization_barrier(arrays)


@jax.custom_jvp
def stacked_sincos(xs: tuple) -> tuple[tuple, tuple]:
    """``(sin x, cos x)`` of each array of ``xs`` (one shape), by one :func:`diffkin._trig.sincos` of their stack.

    On the CPU each call of :func:`diffkin._trig.sincos` is a ``lax.cond`` with about nine kernels of
    its own, and XLA's compile time grows with the number of kernels: one call for a whole forward
    pass instead of one per joint (docs/performance.md, "XLA CPU tricks").
    """
    s, c = _trig.sincos(jnp.stack(xs))
    return tuple(s), tuple(c)


def _stacked_sincos_jvp(primals, tangents):
    """Per entry, so that an entry without a tangent keeps a symbolic zero: a forward-mode
    Jacobian moves one joint at a time, and instantiated zeros for the others would carry tangent
    arithmetic through the whole pass (the autodiff Jacobian of 20 joints then compiled in 32 s, not 19 s)."""
    (xs,), (dxs,) = primals, tangents
    s, c = stacked_sincos(xs)
    ds = tuple(dx if isinstance(dx, SymbolicZero) else ck * dx for ck, dx in zip(c, dxs, strict=True))
    dc = tuple(dx if isinstance(dx, SymbolicZero) else -sk * dx for sk, dx in zip(s, dxs, strict=True))
    return (s, c), (ds, dc)


stacked_sincos.defjvp(_stacked_sincos_jvp, symbolic_zeros=True)


def stacked_atan2(pairs: list[tuple[jax.Array, jax.Array]]) -> list[jax.Array]:
    """:func:`diffkin._trig.atan2` of each pair ``(y, x)`` of arrays (broadcast to one shape), by one
    call on their stack: one ``lax.cond`` instead of one per pair, as :func:`stacked_sincos`."""
    arrays = jnp.broadcast_arrays(*(v for pair in pairs for v in pair))
    return list(_trig.atan2(jnp.stack(arrays[0::2]), jnp.stack(arrays[1::2])))


@jax.custom_jvp
def inverse_sqrt(x: jax.Array) -> jax.Array:
    """``1 / sqrt(x)`` for ``x > 0``, derivative ``-x^(-3/2) / 2``.

    XLA rewrites ``1 / sqrt(x)`` into ``rsqrt(x)``; its CPU backend lowers a float64 ``rsqrt`` to a
    call of its own that LLVM vectorises only with AVX-512, so on other hosts (AVX2) the whole fused
    loop that holds it runs one entry at a time: box-box distances 4x slower. ``sqrt(1 / x)`` (one
    more rounding) stays a vector square root. float32's ``rsqrt`` vectorises and is kept.
    """
    if jnp.result_type(x) == jnp.float64:
        return jnp.sqrt(1 / x)
    return jax.lax.rsqrt(x)


@inverse_sqrt.defjvp
def _inverse_sqrt_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    y = inverse_sqrt(x)
    return y, -0.5 * y * y * y * dx  # not through 1 / x^2, which overflows first


def opaque_index(index: jax.Array, bound: jax.Array) -> jax.Array:
    """``index`` itself, for ``0 <= index < bound`` with ``bound`` a traced (runtime) value: ``rem(index, bound)``.

    An identity that XLA can neither fold nor duplicate into its consumers: an index computed
    from a forward pass and used by several scatters is then computed once, instead of once per
    scatter and per index array (a reachability map: a small gain, ~4 %).
    """
    return jax.lax.rem(index, bound)


def where_any(needed: jax.Array, fn: Callable, *args):
    """``fn(*args)``, computed only when some entry of ``needed`` (bool, any shape) is true: else ``args`` as
    they are, for an ``fn`` that leaves ``args`` as they are where nothing is needed (a ``lax.cond``).

    An update that few problems need, written batched over all of them (``dk.ik.step``'s elimination of
    the joints whose bounds contradict each other), costs every batch its kernels, and XLA's CPU fusion of
    them can slow the computation around them (a branch is compiled apart): the Panda's step at 4,096 in
    float32, 11 % of its CPU time without such a joint, 10 % with one.
    Under ``vmap`` of a batch axis JAX runs both branches (a select): the same values.
    """
    return jax.lax.cond(jnp.any(needed), lambda a: fn(*a), lambda a: a, args)


def blocks_joined(blocks: list[list[jax.Array]], n: int) -> jax.Array:
    """The blocks ``(rows_i, cols_j, n or 1)`` side by side: ``(sum rows, sum cols, n)``.

    With the batch ``n`` innermost, each block's loop vectorises along it. (An optimization barrier
    over the blocks, meant to keep them apart, was found to compile to the same program as none:
    XLA's CPU pipeline drops a barrier over several arrays before it fuses; docs/performance.md.)
    """
    dtype = jnp.result_type(*(block for row in blocks for block in row))
    rows = [
        jnp.concatenate([jnp.broadcast_to(block, (*block.shape[:2], n)).astype(dtype) for block in row], axis=1)
        for row in blocks
    ]
    return jnp.concatenate(rows, axis=0)


#: With ``last``, batches of at least this many configurations go through :func:`in_steps` (in at
#: least two steps): the configurations' axis is then moved to the front in a kernel of its own,
#: reading the buffer the loop wrote. In one call XLA fuses that move into the computation, which
#: then writes across the configurations and is not vectorised (world distances 2.5-4x slower;
#: docs/performance.md).
LAST_STEPPED = 64


def configurations_in_steps(
    fn: Callable, q, base, step: int, last: bool = False, halves: bool = False, extra=None, extra_batch=()
) -> jax.Array:
    """``fn(q, base)`` for a batch of configurations, ``step`` at a time when the batch is large (:func:`in_steps`).

    The batch axes of ``q (..., dof)``, ``base (..., 4, 4)`` (or ``None``) and ``extra_batch`` are
    broadcast and flattened to ``(N,)``; ``fn`` takes them so and returns one array with the
    configurations first, ``(N, ...)``, or last, ``(..., N)``, with ``last``. ``extra``: a pytree
    of arrays with leading axes ``extra_batch`` (per-problem data: a world of obstacles each), then
    broadcast and flattened with the configurations and passed as a third argument. Batches of at
    most ``2 step`` go in one call (with ``last``, only those below :data:`LAST_STEPPED`);
    ``halves``: as :func:`in_steps`. The memory then stays bounded whatever the batch, and a step's
    intermediates stay in cache (a whole robot's pass over 100,000 configurations is memory-bound).
    Values and derivatives are those of ``fn``.

    Returns:
        ``(*batch, ...)``.
    """
    q = jnp.asarray(q)
    batch = jnp.broadcast_shapes(q.shape[:-1], jnp.shape(base)[:-2] if base is not None else (), tuple(extra_batch))
    n = int(np.prod(batch, dtype=np.int64))
    inputs = [jnp.broadcast_to(q, (*batch, q.shape[-1])).reshape(n, q.shape[-1])]
    if base is not None:
        inputs.append(jnp.broadcast_to(jnp.asarray(base), (*batch, 4, 4)).reshape(n, 4, 4))
    leaves, tree = jax.tree.flatten(extra)
    for leaf in leaves:
        tail = jnp.shape(leaf)[len(extra_batch) :]
        inputs.append(jnp.broadcast_to(leaf, (*batch, *tail)).reshape(n, *tail))
    has_base = base is not None

    def call(q_, *rest):
        base_ = rest[0] if has_base else None
        if extra is None:
            return fn(q_, base_)
        return fn(q_, base_, jax.tree.unflatten(tree, rest[has_base:]))

    stepped = last and n >= LAST_STEPPED
    if stepped:
        step = min(step, 2 * -(-n // 4))  # at least two steps, of an even size (halves)
    if n <= 2 * step and not stepped:
        out = call(*inputs)
    else:
        (out,) = in_steps(lambda *x: (call(*x),), tuple(inputs), step, axis=-1 if last else 0, halves=halves)
    if last:
        out = jnp.moveaxis(out, -1, 0)
    return out.reshape(*batch, *out.shape[1:])


def problems_at_once(n: int) -> int:
    """How many of ``n`` independent problems, each with its own iteration loop (a trajectory's descent and
    certificate), one compiled step solves at once (:func:`in_steps`): on the CPU one, since one problem
    already vectorises hundreds of configurations and a batch's loop runs as long as its slowest problem;
    elsewhere all ``n`` (a GPU wants the width)."""
    return 1 if jax.default_backend() == "cpu" else n


def _cores() -> int:
    """The CPU cores this process may run on."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else os.cpu_count() or 1


#: the host threads of :func:`in_threads`, one per core
_THREADS = concurrent.futures.ThreadPoolExecutor(max_workers=_cores(), thread_name_prefix="diffkin-problems")
#: spans per core of :func:`spans`: the threads take them as they come free, so that they end together when the
#: problems' costs differ (one that fails every round of ``dk.traj`` costs many that succeed in the first)
SPANS_PER_CORE = 5


def spans(n: int, *args) -> list[tuple[int, int]]:
    """``(start, size)`` spans of ``n`` independent problems for :func:`in_threads`: :data:`SPANS_PER_CORE` per
    core (at most ``n``), of one size (the last overlaps the one before it where the count does not divide
    ``n``: one compiled program serves them all), when the call with ``args`` is at the top level on the CPU;
    else the one span ``(0, n)`` (a GPU wants the width, and inside a trace there is nothing to run)."""
    if n <= 1 or _default_backend() != "cpu" or not top_level(*args):
        return [(0, n)]
    size = -(-n // min(n, SPANS_PER_CORE * _cores()))
    return [(min(i * size, n - size), size) for i in range(-(-n // size))]


def in_threads(fn: Callable[[int, int], Any], parts: list[tuple[int, int]]) -> Any:
    """``fn(start, size)`` (a pytree of arrays with a leading axis of ``size``) for each span of ``parts``
    (:func:`spans`), where there are several on the host threads (one per core, each taking the next span as it
    comes free: XLA's CPU client runs programs called from different threads at once), joined along that axis:
    a pytree over all the spans' problems."""
    if len(parts) == 1:
        return fn(*parts[0])
    futures = [_THREADS.submit(lambda part: jax.block_until_ready(fn(*part)), part) for part in parts]
    pieces, done = [], 0
    for future, (start, size) in zip(futures, parts, strict=True):
        pieces.append(jax.tree.map(lambda x, skip=done - start: x[skip:], future.result()))
        done = start + size
    return jax.tree.map(lambda *xs: jnp.concatenate(xs), *pieces)


def in_steps(
    fn: Callable[..., tuple[jax.Array, ...]],
    inputs: tuple[jax.Array, ...],
    step: int,
    axis: int = 0,
    halves: bool = False,
    in_axis: int = 0,
):
    """``fn(*inputs)`` over the leading axis of ``inputs`` (``n >= step`` problems), ``step`` problems at a time
    (over their last axis with ``in_axis=-1``: problems last, as :mod:`diffkin.ik._qp` holds them).

    ``fn`` maps inputs with a leading axis of ``step`` to a tuple of outputs with that axis at
    ``axis`` (an output with the problems last is written by loops that run along them: XLA's CPU
    loops vectorise the innermost axis). The last step overlaps the one before it (every step has
    the same shape), so some problems are solved twice, with the same result. A step's
    intermediates then stay in cache, and XLA's temporary buffer stays small (a buffer above
    glibc's mmap threshold takes fresh, page-faulted memory on every call): ``dk.srs.ik`` in float64
    about 2x faster; in float32 the steps did not pay, and are kept for the memory bound. With
    ``halves`` (on the CPU, problems first), each step is two independent halves (:func:`_in_halves`).

    Returns:
        The outputs of ``fn``, each with an axis of ``n`` at ``axis``.
    """
    n = inputs[0].shape[in_axis]
    if halves and in_axis == 0 and step % 2 == 0 and jax.default_backend() == "cpu":
        fn = _in_halves(fn, axis)

    def sliced(x):  # the shape of x's step
        at = in_axis % x.ndim
        return x.shape[:at] + (step,) + x.shape[at + 1 :]

    shapes = jax.eval_shape(fn, *(jax.ShapeDtypeStruct(sliced(x), x.dtype) for x in inputs))

    def body(i, out):
        start = jnp.minimum(i * step, n - step)
        results = fn(*(jax.lax.dynamic_slice_in_dim(x, start, step, in_axis % x.ndim) for x in inputs))
        return tuple(jax.lax.dynamic_update_slice_in_dim(o, r, start, axis) for o, r in zip(out, results, strict=True))

    def full(shape):
        dims = list(shape)
        dims[axis] = n
        return tuple(dims)

    init = tuple(jnp.zeros(full(s.shape), s.dtype) for s in shapes)
    return jax.lax.fori_loop(0, -(-n // step), body, init)


def _in_halves(fn: Callable[..., tuple[jax.Array, ...]], axis: int) -> Callable[..., tuple[jax.Array, ...]]:
    """``fn`` over the two halves of its inputs' leading axis, computed independently and joined along ``axis``.

    XLA's CPU runtime runs independent kernels on separate threads, but the kernels of one step of
    a batched computation mostly wait for each other: two independent halves give every thread
    work (the halves are joined behind an optimization barrier, or XLA fuses the join back into
    one loop over both).
    """

    def halves(*inputs):
        h = inputs[0].shape[0] // 2
        first = fn(*(x[:h] for x in inputs))
        second = fn(*(x[h:] for x in inputs))
        first, second = jax.lax.optimization_barrier((first, second))
        return tuple(jnp.concatenate([a, b], axis=axis) for a, b in zip(first, second, strict=True))

    return halves


def summed_products(x: jax.Array, y: jax.Array, axis: int) -> jax.Array:
    """``sum(x * y, axis)`` of arrays of broadcastable shapes, written out term by term, ``x_0 y_0 + x_1 y_1 + ...``
    in that order, along ``axis`` of their broadcast shape.

    As an ``einsum`` of a short contraction per entry (GJK's support scores, the IK step's ``J^T J`` with
    the problems last), XLA's CPU backend makes a batched dot of one tiny product per entry; written out,
    every operation is elementwise, one fused loop that vectorises along the batch (measured with the IK
    step: docs/performance.md).

    Returns:
        The broadcast shape of ``x`` and ``y`` without ``axis`` (zeros when that axis is empty).
    """
    shape = jnp.broadcast_shapes(jnp.shape(x), jnp.shape(y))
    axis = axis % len(shape)
    x, y = (jnp.reshape(a, (1,) * (len(shape) - jnp.ndim(a)) + jnp.shape(a)) for a in (x, y))
    if not shape[axis]:
        return jnp.zeros(shape[:axis] + shape[axis + 1 :], jnp.result_type(x, y))
    terms = [
        jax.lax.index_in_dim(x, min(j, x.shape[axis] - 1), axis, keepdims=False)
        * jax.lax.index_in_dim(y, min(j, y.shape[axis] - 1), axis, keepdims=False)
        for j in range(shape[axis])
    ]
    return functools.reduce(jnp.add, terms)


def stable_partition(mask: jax.Array) -> jax.Array:
    """``(..., n, n)`` bool, ``[..., j, i]``: whether entry ``i`` of a row of ``mask`` ``(..., n)`` goes to slot
    ``j`` when the row's ``True`` entries come first, each group in its order (a stable sort of ``~mask``).

    Ranks from cumulative sums, without a sort: XLA's CPU sort of many short rows is slow (GJK's simplex
    reorder of 4 points cost as much as a GJK step's supports; commit 393961c).
    """
    n = mask.shape[-1]
    used = mask.astype(jnp.int32)
    before = jnp.cumsum(used, axis=-1) - used  # entries in use before each
    others = jnp.sum(used, axis=-1, keepdims=True) + jnp.arange(n) - before
    rank = jnp.where(mask, before, others)
    return rank[..., None, :] == jnp.arange(n)[:, None]
