"""Why float32 FK was slow on a GPU: the trigonometry, how the outputs are written, and the kernels.

    python experiments/probe_gpu_trig.py [--sizes 10000000,100000000] [--dump DIR]

Times the jitted iiwa14 FK (warm, outputs blocked on; median of at least 10 calls) for each
variant below, float32 and float64, and counts the kernels of the compiled program (the
``fusion``/``custom-call``/``conditional``/``while``/``copy``/``reduce``/``sort`` instructions of
the optimized HLO's entry computation); then the world Jacobian (analytic and autodiff) with the
library's default outputs and with the CPU's, at batch 1 to 10^7. Each variant's FK is first
checked against float64 FK on the CPU. ``--dump`` writes the optimized HLO of every program there.

Trigonometry (:mod:`diffkin._trig`): ``fused+cond`` the CPU version (a ``lax.cond`` on any angle
beyond the fast range, one reduction over the array first); ``fused`` its polynomial alone (exact
only for ``|x| <~ 1.3e4`` in float32: a probe); ``xla`` ``jnp.sin``/``jnp.cos`` (the library's
choice off the CPU). Outputs (:func:`diffkin._xla.gpu_outputs`): ``stack`` (the entries stacked
on the last axis as they are, the CPU's), ``entries|`` (the computed entries materialised behind
an optimization barrier first: the library's choice off the CPU). An earlier run of this probe
(2026-11-23, H100) also tried reading ``q`` through a transpose to rows and writing the outputs
as rows then transposed (with and without barriers): no variant moved FK or Jacobian times by
more than 1 %, so they are gone.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _bench import duration, median_seconds, rate, table

import diffkin as dk
from diffkin import _trig, _xla

TRIG = {"fused+cond": _trig._sincos_any, "fused": _trig._sincos_fast, "xla": _trig._sincos_xla}
OUTPUTS = {"stack": _xla._as_is, "entries|": _xla._materialized}
DEFAULT = ("xla", "entries|")


def kernels(compiled_text: str) -> int:
    """Kernel-launching instructions of the entry computation of an optimized HLO module."""
    entry = compiled_text[compiled_text.index("\nENTRY") :]
    entry = entry[: entry.index("\n}")]
    return len(re.findall(r"\b(fusion|custom-call|conditional|while|copy|reduce|sort)\(%", entry))


@contextlib.contextmanager
def variant(trig: str, outputs: str):
    """The library with this trigonometry and these outputs off the CPU (patched in while tracing)."""
    saved = _trig.sincos, _xla._materialized
    _trig.sincos, _xla._materialized = TRIG[trig], OUTPUTS[outputs]
    try:
        yield
    finally:
        _trig.sincos, _xla._materialized = saved


def compiled(fn, v, x):
    """``fn`` compiled for ``x`` with variant ``v`` (a fresh function each time: jit caches traces per function)."""
    with variant(*v):
        return jax.jit(lambda x: fn(x)).lower(x).compile()


def configs(n: int, dtype, seed: int = 0) -> jax.Array:
    """``(n, 7)`` iiwa14 configurations within its limits, drawn on the device."""
    chain = dk.robots.iiwa14()
    lo, hi = (jnp.asarray(x, dtype) for x in (chain.lower, chain.upper))
    return jax.random.uniform(jax.random.key(seed), (n, 7), dtype, lo, hi)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1000,10000000,100000000")
    parser.add_argument("--dump", default=None)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    sizes = [int(s) for s in args.sizes.split(",")]
    dump = Path(args.dump) if args.dump else None
    if dump:
        dump.mkdir(parents=True, exist_ok=True)
    print(f"jax {jax.__version__}, devices {jax.devices()}, backend {jax.default_backend()}", flush=True)
    chain = dk.robots.iiwa14()

    def fk(q):
        return dk.fk(chain, q)

    variants = [("xla", "stack"), DEFAULT, ("fused", "stack"), ("fused", "entries|"), ("fused+cond", "entries|")]
    q64 = np.asarray(configs(100_000, jnp.float64, seed=1))
    with jax.default_device(jax.devices("cpu")[0]):
        ref = np.asarray(dk.fk(chain, q64))
    for v in variants:
        for dtype in (jnp.float32, jnp.float64):
            out = np.asarray(compiled(fk, v, jnp.asarray(q64, dtype))(jnp.asarray(q64, dtype)), np.float64)
            err = np.abs(out - ref).max()
            print(f"check {'/'.join(v)} {jnp.dtype(dtype).name}: max |FK - FK float64 (CPU)| = {err:.2e}", flush=True)
            assert err < (2e-6 if dtype == jnp.float32 else 1e-12), err

    rows = []
    for dtype in (jnp.float32, jnp.float64):
        for n in sizes:
            q = configs(n, dtype)
            for v in variants:
                c = compiled(fk, v, q)
                text = c.as_text()
                if dump:
                    (dump / f"fk-{'_'.join(v)}-{jnp.dtype(dtype).name}-{n}.txt".replace("|", "B")).write_text(text)
                seconds = median_seconds(c, q, repeats=10)
                rows.append(
                    ["FK", *v, jnp.dtype(dtype).name, f"{n:,}", duration(seconds), rate(n, seconds), kernels(text)]
                )
                print(" | ".join(map(str, rows[-1])), flush=True)
            del q

    for n, dtype in (
        (1, jnp.float32),
        (1000, jnp.float32),
        (1_000_000, jnp.float32),
        (10_000_000, jnp.float32),
        (10_000_000, jnp.float64),
    ):
        q = configs(n, dtype)
        for method in ("analytic", "autodiff"):
            for v in (DEFAULT, ("xla", "stack")):
                c = compiled(lambda q, method=method: dk.jacobian(chain, q, "world", method=method), v, q)
                if dump:
                    name = f"jac-{method}-{'_'.join(v)}-{jnp.dtype(dtype).name}-{n}.txt".replace("|", "B")
                    (dump / name).write_text(c.as_text())
                s = median_seconds(c, q, repeats=10)
                rows.append(
                    [
                        f"Jacobian ({method})",
                        *v,
                        jnp.dtype(dtype).name,
                        f"{n:,}",
                        duration(s),
                        rate(n, s),
                        kernels(c.as_text()),
                    ]
                )
                print(" | ".join(map(str, rows[-1])), flush=True)
        del q

    print()
    print(table(["work", "trig", "outputs", "dtype", "batch", "median", "rate", "kernels"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
