"""Reachability map over every device of several hosts: the same ``reachability`` call as on one host.

Start one process per host (or per GPU group); each calls ``jax.distributed.initialize`` and then
``dk.workspace.reachability`` over ``jax.devices()`` (all devices of all processes). Chunk ``c``
is drawn from ``fold_in(key, c)`` wherever it runs, and the partial maps are reduced with sums,
maxima and ors, so the map equals the single-host one. Process 0 writes it.

    # host 0 (coordinator), host 1, ... each with the same arguments except the process id:
    python experiments/workspace_multihost.py --coordinator host0:1234 --num-processes 2 --process-id 0
    python experiments/workspace_multihost.py --coordinator host0:1234 --num-processes 2 --process-id 1
    # or from the environment (JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID; SLURM and
    # Open MPI are detected by jax.distributed.initialize when no option is given):
    srun -N 2 python experiments/workspace_multihost.py --n 10000000000 --voxel 0.01

Tested here on one host only (two local processes on CPU:
``--coordinator localhost:1234 --num-processes 2 --process-id 0|1`` with ``JAX_PLATFORMS=cpu``).
"""

from __future__ import annotations

import argparse
import os

import jax

import diffkin as dk
from diffkin import workspace as ws


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coordinator", default=os.environ.get("JAX_COORDINATOR_ADDRESS"), help="host:port")
    parser.add_argument("--num-processes", type=int, default=os.environ.get("JAX_NUM_PROCESSES"))
    parser.add_argument("--process-id", type=int, default=os.environ.get("JAX_PROCESS_ID"))
    parser.add_argument("--robot", default="iiwa14", help="a dk.robots model name")
    parser.add_argument("--n", type=int, default=100_000_000, help="samples")
    parser.add_argument("--voxel", type=float, default=0.02, help="voxel edge, metres")
    parser.add_argument("--chunk", type=int, default=1 << 16, help="samples per device per step")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "out", "workspace_multihost.npz"))
    args = parser.parse_args()
    jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    chain = getattr(dk.robots, args.robot)()
    m = ws.reachability(
        chain,
        args.n,
        key=jax.random.key(args.seed),
        voxel_size=args.voxel,
        chunk=args.chunk,
        devices=jax.devices(),
        dtype="float32",
    )
    if jax.process_index() == 0:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        m.save(args.out)
        print(
            f"{args.robot}: {m.counts.sum()} of {m.n_samples} samples in {int((m.counts > 0).sum())} voxels over "
            f"{jax.device_count()} devices of {jax.process_count()} processes; map in {args.out}"
        )


if __name__ == "__main__":
    main()
