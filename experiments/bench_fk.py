"""Forward kinematics and world Jacobian: diffkin vs pytorch-kinematics, float32, CPU, iiwa14.

    python experiments/bench_fk.py [--batches 1 1000 100000] [--repeats 7]

Both libraries evaluate the same robot (diffkin's built-in DH ``iiwa14`` and pytorch-kinematics
on the shipped ``iiwa14.urdf``, the same kinematics), on the same random configurations, warm
(JIT compiled / first call done), median of ``--repeats`` runs. Prints a markdown table.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
import pytorch_kinematics as pk
import torch
from _bench import machine_line, median_seconds, rate, table

import diffkin as dk


def _pk_chain(dtype=torch.float32):
    with open(dk.robots.urdf_path("iiwa14"), "rb") as fh:
        return pk.build_serial_chain_from_urdf(fh.read(), "iiwa14_link_ee").to(dtype=dtype)


def run(batches=(1, 1000, 100_000), repeats=7) -> str:
    chain = dk.robots.iiwa14()
    ref = _pk_chain()
    fk = jax.jit(lambda q: dk.fk(chain, q))
    jac = jax.jit(lambda q: dk.jacobian(chain, q, "world", method="analytic"))
    jac_ad = jax.jit(lambda q: dk.jacobian(chain, q, "world"))
    rows = []
    for n in batches:
        q = np.random.default_rng(0).uniform(chain.lower, chain.upper, (n, 7)).astype(np.float32)
        qj, qt = jnp.asarray(q), torch.tensor(q)
        t_fk = median_seconds(fk, qj, repeats=repeats)
        t_pk = median_seconds(lambda x: ref.forward_kinematics(x).get_matrix(), qt, repeats=repeats)
        t_j = median_seconds(jac, qj, repeats=repeats)
        t_jad = median_seconds(jac_ad, qj, repeats=repeats)
        t_pkj = median_seconds(ref.jacobian, qt, repeats=repeats)
        rows.append(["FK", f"{n:,}", f"{t_fk * 1e3:.3f} ms ({rate(n, t_fk)})", f"{t_pk * 1e3:.3f} ms ({rate(n, t_pk)})",
                     f"**{t_pk / t_fk:.1f}x**"])
        rows.append(["Jacobian (world, analytic)", f"{n:,}", f"{t_j * 1e3:.3f} ms ({rate(n, t_j)})",
                     f"{t_pkj * 1e3:.3f} ms ({rate(n, t_pkj)})", f"**{t_pkj / t_j:.1f}x**"])
        rows.append(["Jacobian (world, autodiff)", f"{n:,}", f"{t_jad * 1e3:.3f} ms ({rate(n, t_jad)})",
                     f"{t_pkj * 1e3:.3f} ms ({rate(n, t_pkj)})", f"**{t_pkj / t_jad:.1f}x**"])
    head = ["work", "batch", "diffkin", "pytorch-kinematics", "speed-up"]
    return (f"iiwa14, float32, median of {repeats} warm runs. {machine_line()}\n\n"
            + table(head, rows))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 1000, 100_000])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    print(run(args.batches, args.repeats))


if __name__ == "__main__":
    main()
