"""A 1 kHz velocity-IK loop (``dk.ik.step``): the iiwa14 tracking a moving target, plotted to docs/velocity_ik.png.

The flange follows a circle of 10 cm radius at 0.75 turns a second (its orientation held) for two
seconds, one ``dk.ik.step`` a millisecond (gain 0.5, velocity limits of 0.5 rad/s on every joint) in a
``lax.scan``. The circle asks for 0.47 m/s: the velocity limits bind for much of it, and the flange
lags by up to a centimetre where they do (every step feasible, no velocity above its limit). The
figure: the target and the flange in the circle's plane, the tracking error, and the joint
velocities against their limits.

    python experiments/velocity_ik.py [--out docs/velocity_ik.png]
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import diffkin as dk

DT, SECONDS, RADIUS, TURNS_PER_S, VELOCITY = 1e-3, 2.0, 0.1, 0.75, 0.5


def run():
    arm = dk.robots.iiwa14()
    q0 = jnp.array([0.3, 0.7, -0.2, -1.2, 0.4, 0.9, 0.1])
    T0 = dk.fk(arm, q0)
    centre = T0[:3, 3] - jnp.array([0.0, RADIUS, 0.0])  # the flange starts on the circle

    def target(t):
        a = 2 * jnp.pi * TURNS_PER_S * t
        return T0.at[:3, 3].set(centre + RADIUS * jnp.array([0.0, jnp.cos(a), jnp.sin(a)]))

    @jax.jit
    def loop(q):
        def tick(q, t):
            T = target(t)
            step = dk.ik.step(arm, q, T, dt=DT, gain=0.5, velocity=VELOCITY)
            return step.q, (T[:3, 3], dk.fk(arm, step.q)[:3, 3], step.v, step.feasible)

        return jax.lax.scan(tick, q, jnp.arange(int(SECONDS / DT)) * DT)

    start = time.perf_counter()
    _, (goal, reached, v, feasible) = jax.block_until_ready(loop(q0))
    print(f"{int(SECONDS / DT)} steps, compiled and run in {time.perf_counter() - start:.1f} s")
    return np.asarray(goal), np.asarray(reached), np.asarray(v), np.asarray(feasible)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = os.path.dirname(os.path.abspath(__file__))
    parser.add_argument("--out", default=os.path.join(here, "..", "docs", "velocity_ik.png"))
    args = parser.parse_args()
    goal, reached, v, feasible = run()
    error = np.linalg.norm(goal - reached, axis=1)
    t = np.arange(len(error)) * DT
    print(f"every step feasible: {bool(feasible.all())}; largest |v| {np.abs(v).max():.3f} rad/s (limit {VELOCITY})")
    print(f"tracking error after 1 s: largest {error[t >= 1.0].max() * 1e3:.2f} mm")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    ax[0].plot(goal[:, 1], goal[:, 2], "k--", lw=1, label="target")
    ax[0].plot(reached[:, 1], reached[:, 2], lw=1.5, label="flange")
    ax[0].set(xlabel="y (m)", ylabel="z (m)", title="1 kHz steps, the circle's plane", aspect="equal")
    ax[0].legend(loc="lower right")
    ax[1].semilogy(t, np.maximum(error, 1e-7) * 1e3)
    ax[1].set(xlabel="time (s)", ylabel="position error (mm)", title="tracking error")
    ax[2].plot(t, v, lw=1)
    for s in (-1, 1):
        ax[2].axhline(s * VELOCITY, color="k", ls=":", lw=1)
    ax[2].set(xlabel="time (s)", ylabel="joint velocity (rad/s)", title="velocities within their limits")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"written: {os.path.normpath(args.out)}")


if __name__ == "__main__":
    main()
