"""The demo's figure of an iiwa's self-motion (matplotlib, the ``plot`` extra)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from diffkin.cli._compiled import srs_fns


def plot_self_motion(name: str, q: np.ndarray, path: Path) -> None:
    """Plot the self-motion through ``q`` of the iiwa ``name``: its joints along the arm angle.

    One panel for the global configuration of ``q`` (the branch ``q`` itself lies on): each joint
    angle divided by its limit (rad / rad; -1 lower, +1 upper limit, drawn) against the arm angle
    ``psi`` (rad), the arm angles whose solution is within every limit shaded, ``q``'s own arm
    angle dotted. The title gives ``q`` and the signs of joints 2, 4 and 6.

    Args:
        name: ``iiwa7`` or ``iiwa14``.
        q: ``(7,)`` configuration (rad) whose flange pose and global configuration are shown.
        path: the PNG to write.
    """
    from matplotlib.figure import Figure

    import diffkin as dk

    arm, _, srs_ik, arm_angle = srs_fns(name)
    psi0, gc = (np.asarray(x) for x in arm_angle(q))
    psi = np.linspace(-np.pi, np.pi, 721)
    T_base_flange = dk.fk(arm.chain(), q)
    qs, valid = (np.asarray(x) for x in srs_ik(T_base_flange, psi, gc))
    lower, upper = np.asarray(arm.lower), np.asarray(arm.upper)
    frac = (2 * qs - (lower + upper)) / (upper - lower)
    frac[1:][np.abs(np.diff(frac, axis=0)) > 1] = np.nan  # do not draw the +-pi wraps of a joint
    fig = Figure(figsize=(10, 6), layout="constrained")
    ax = fig.add_subplot()
    ax.fill_between(psi, -1, 1, where=valid, color="tab:green", alpha=0.15, lw=0, label="within all limits")
    for j in range(7):
        ax.plot(psi, frac[:, j], lw=1.5, label=f"joint {j + 1} (limits ±{upper[j]:.2f} rad)")
    for limit in (-1, 1):
        ax.axhline(limit, color="k", ls="--", lw=1)
    ax.axvline(float(psi0), color="k", ls=":", lw=1, label=f"arm angle of q ({float(psi0):+.2f} rad)")
    signs = " ".join(f"{int(g):+d}" for g in gc)
    ax.set(
        xlim=(-np.pi, np.pi),
        ylim=(-1.6, 1.6),
        xlabel="arm angle psi (rad)",
        ylabel="joint angle / its limit (rad / rad; -1 lower, +1 upper limit)",
    )
    ax.set_title(
        f"{name} self-motion: every configuration with the flange pose of q, along the arm angle psi\n"
        f"q = {' '.join(f'{v:+.2f}' for v in q)} rad (a random in-limit configuration: IK target 0 "
        f"of the demo)\nshown: q's own global configuration (signs of joints 2, 4, 6 = {signs});\neach of "
        f"the other 7 has a self-motion of its own; {valid.mean():.0%} of arm angles within all limits",
        fontsize="medium",
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize="small")
    fig.savefig(path, dpi=120)
