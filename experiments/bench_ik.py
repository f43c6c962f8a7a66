"""Batched IK speed and success: diffkin (LM, optax) vs pytorch-kinematics PseudoInverseIK.

Same 1,000 iiwa14 targets (poses of uniform in-limit configurations, shipped URDF), float32, CPU.
pytorch-kinematics: 30 iterations x 10 retries at its default 1 mm / 0.01 rad, seeded, eager and
compiled (``use_compile=True``: ``torch.compile`` of its kernels, in an empty on-disk cache), median
of 3 warm runs. diffkin: jitted, warm, median of 5 runs; every reported success is re-checked with
pytorch-kinematics' float64 FK. Each solver's first call (compile included) is timed apart. Then
diffkin's success and time against ``num_seeds`` and ``max_iters``, and the optax solver against LM.

Run: ``python experiments/bench_ik.py``
"""

import jax
import jax.numpy as jnp
import numpy as np
import torch
from _bench import PK_IK_TOL, first_call_seconds, machine_line, median_seconds, pk, pk_ik_timed, table

import diffkin as dk
import diffkin.ik as ik
from diffkin import se3

N = 1000
TIGHT_TOL = (1e-5, 1e-4)


def _rotation_angle(M):
    """Angle of rotations (float64), accurate near 0 and pi (``arccos`` of the trace is not)."""
    with jax.enable_x64(True):
        return np.asarray(se3.rotation_angle(np.asarray(M, np.float64)))


def main():
    path = dk.robots.urdf_path("iiwa14")
    chain = dk.load_urdf(path, "iiwa14_link_ee")
    with open(path, "rb") as f:
        xml = f.read()
    pk32 = pk.build_serial_chain_from_urdf(xml, "iiwa14_link_ee")
    pk64 = pk.build_serial_chain_from_urdf(xml, "iiwa14_link_ee").to(dtype=torch.float64)
    q_true = np.random.default_rng(0).uniform(chain.lower, chain.upper, (N, 7))
    target64 = pk64.forward_kinematics(torch.as_tensor(q_true)).get_matrix().numpy()
    T32, key = jnp.asarray(target64.astype(np.float32)), jax.random.key(1)

    def verified(q, tol):
        """Reported successes re-checked with float64 FK (float32 rounding allowed)."""
        T = pk64.forward_kinematics(torch.as_tensor(np.asarray(q, np.float64))).get_matrix().numpy()
        pos = np.linalg.norm(T[:, :3, 3] - target64[:, :3, 3], axis=-1)
        rot = _rotation_angle(target64[:, :3, :3] @ np.swapaxes(T[:, :3, :3], -1, -2))
        return (pos <= tol[0] + 1e-6) & (rot <= tol[1] + 1e-5)

    def run(repeats=5, first=False, **kw):
        fn = jax.jit(lambda T, k: ik.solve(chain, T, key=k, **kw))
        first_s = first_call_seconds(fn, T32, key) if first else None
        seconds = median_seconds(fn, T32, key, repeats=repeats, warmup=1, min_time=0.0)
        return seconds, fn(T32, key), first_s

    print(f"# IK benchmark: iiwa14, {N} targets, float32. {machine_line()}\n")
    goal = pk.Transform3d(matrix=torch.as_tensor(target64, dtype=torch.float32))
    pk_times: dict[bool, float | None] = {}

    def ratios(seconds: float, bold: bool = False) -> list[str]:
        """``pk eager / this`` and ``pk compiled / this`` (n/a where pk's solver raised)."""
        fmt = "**{:.1f}x**" if bold else "{:.2f}x"
        return [fmt.format(pk_times[c] / seconds) if pk_times[c] else "n/a" for c in (False, True)]

    rows, pk_notes = [], []
    for label, compiled in (("eager", False), ("compiled (`use_compile=True`)", True)):
        name = f"pytorch-kinematics PseudoInverseIK {label}, 30 x 10, 1 mm / 0.01 rad"
        r = pk_ik_timed(pk32, chain.lower, chain.upper, goal, compiled=compiled, warmup=0, min_time=0.0)
        pk_times[compiled] = r.seconds
        if r.seconds is None:
            rows.append([name, "raised (below)", "", "", ""])
        else:
            first = f"{r.first:.2f}" + (" (caches warm: below)" if compiled and r.failures else "")
            rows.append([name, f"{r.success:.1%}", first, f"{r.seconds * 1e3:.1f}", f"{N / r.seconds:,.0f}"])
        if r.failures:
            pk_notes.append(f"pytorch-kinematics {label}: {r.note()}.")
    for row, compiled in zip(rows, (False, True), strict=True):
        row += ratios(pk_times[compiled]) if pk_times[compiled] else ["n/a", "n/a"]
    for label, tol in (
        ("diffkin LM, defaults, 1e-5 m / 1e-4 rad", TIGHT_TOL),
        ("diffkin LM, defaults, pk's 1 mm / 0.01 rad", PK_IK_TOL),
    ):
        dt, res, first = run(first=True, pos_tol=tol[0], rot_tol=tol[1])
        ok = np.asarray(res.success)
        assert np.all(verified(res.q, tol)[ok]), "a reported success fails float64 FK"
        rows.append([label, f"{ok.mean():.1%}", f"{first:.2f}", f"{dt * 1e3:.1f}", f"{N / dt:,.0f}", *ratios(dt, True)])
    header = ["solver", "success", "first call (s)", "warm (ms)", "solves/s", "pk eager / this", "pk compiled / this"]
    print(table(header, rows))
    print(
        "\nFirst call: compile and one solve (diffkin: `jax.jit`, no persistent cache; pk compiled: `torch.compile` "
        "with an empty on-disk cache). Warm: median of 5 (diffkin) or 3 (pk) calls after it. pk's 10 retries are "
        "drawn once per solver from torch's RNG, seeded with 0."
    )
    for note in pk_notes:
        print("\n" + note)

    print("\n## diffkin LM vs num_seeds and max_iters (1e-5 m / 1e-4 rad)\n")
    rows = []
    for seeds in (4, 16, 32, 64):
        for iters in (6, 10, 20):
            dt, res, _ = run(repeats=3, num_seeds=seeds, max_iters=iters)
            rows.append([seeds, iters, f"{float(res.success.mean()):.1%}", f"{dt * 1e3:.1f}", f"{N / dt:,.0f}"])
    print(table(["num_seeds", "max_iters", "success", "time (ms)", "solves/s"], rows))

    print("\n## optax (Adam 1e-2) vs LM, 4 seeds, no early stop\n")
    rows = []
    for method, iters in (("lm", 10), ("lm", 40), ("optax", 300), ("optax", 1000)):
        dt, res, _ = run(repeats=1, method=method, num_seeds=4, max_iters=iters, pos_tol=0.0, rot_tol=0.0)
        pos, rot = np.asarray(res.pos_err), np.asarray(res.rot_err)
        tight = np.mean((pos <= TIGHT_TOL[0]) & (rot <= TIGHT_TOL[1]))
        loose = np.mean((pos <= PK_IK_TOL[0]) & (rot <= PK_IK_TOL[1]))
        rows.append([method, iters, f"{tight:.1%}", f"{loose:.1%}", f"{np.median(pos):.2e}", f"{dt * 1e3:.0f}"])
    print(
        table(
            [
                "method",
                "iters",
                "success 1e-5 m / 1e-4 rad",
                "success 1 mm / 0.01 rad",
                "median pos err (m)",
                "time (ms)",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    main()
