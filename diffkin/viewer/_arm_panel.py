"""The iiwa arm-angle panel of the viewer: the arm angle ``psi`` of the current flange pose on a
slider, its global configuration in a dropdown and the feasible arm-angle intervals (``dk.srs``);
moving the slider or the dropdown moves the arm along its self-motion."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import viser

import diffkin as dk
from diffkin.viewer._gui import Page, shown

GC_OPTIONS = tuple(" ".join(f"{s:+d}" for s in signs) for signs in itertools.product((1, -1), repeat=3))


def _signs(text: str) -> np.ndarray:
    """``(3,)`` global configuration of a dropdown entry ``"+1 -1 +1"``."""
    return np.array([float(s) for s in text.split()])


def _gc_text(gc) -> str:
    return " ".join(f"{int(s):+d}" for s in gc)


def _intervals_text(intervals: np.ndarray, mask: np.ndarray) -> str:
    used = [f"[{lo:+.3f}, {hi:+.3f}]" for (lo, hi), m in zip(np.asarray(intervals), np.asarray(mask), strict=True) if m]
    return " ∪ ".join(used) if used else "none (no arm angle keeps every joint within its limits)"


class ArmPanel:
    """The arm-angle controls of a :class:`~diffkin.viewer._viewer.Viewer` showing an iiwa, on its page.

    Attributes:
        psi_slider: the arm angle, radians.
        gc_dropdown: the global configuration (signs of joints 2, 4, 6).
        srs_status: the feasible arm-angle intervals of the flange pose and configuration.
    """

    def __init__(self, page: Page, arm) -> None:
        self.page = page
        chain = arm.chain()
        self._fk = jax.jit(lambda q: dk.fk(chain, q))
        self._ik = jax.jit(lambda T, psi, gc: dk.srs.ik(arm, T, psi, gc))
        self._angle = jax.jit(lambda q: dk.srs.arm_angle(arm, q))
        self._feasible = jax.jit(lambda T, gc: dk.srs.feasible_arm_angles(arm, T, gc))
        self._flange = None
        gui = page.gui
        with gui.add_folder("Arm angle (iiwa)") as self._folder:
            self.psi_slider = gui.add_slider("arm angle psi", min=-np.pi, max=np.pi, step=1e-3, initial_value=0.0)
            self.srs_status = gui.add_markdown("")
        self.gc_dropdown: viser.GuiDropdownHandle[str] | None = None
        self._show_gc(GC_OPTIONS[0])

        @self.psi_slider.on_update
        def _(_event) -> None:
            if not page.quiet:
                self.set_arm_angle(self.psi_slider.value)

    def _show_gc(self, text: str) -> None:
        """Show the global configuration ``text`` in its dropdown.

        The dropdown is rebuilt rather than updated: viser 1.1.1's page goes blank when a
        dropdown's value is changed from Python after the page has loaded other updates.
        """
        old = self.gc_dropdown
        if old is not None and old.value == text:
            return
        with self._folder:
            dropdown = self.page.gui.add_dropdown(
                "gc (signs q2 q4 q6)", GC_OPTIONS, initial_value=text, order=None if old is None else old.order
            )
        self.gc_dropdown = dropdown
        if old is not None:
            old.remove()

        @dropdown.on_update
        def _(_event) -> None:
            if not self.page.quiet:
                self.set_arm_angle(self.psi_slider.value, _signs(dropdown.value), nearest=True)

    def sync(self, q: np.ndarray) -> None:
        """Arm angle, global configuration and feasible intervals of the flange pose at ``q (7,)``."""
        q_now = jnp.asarray(q)
        self._flange = self._fk(q_now)
        psi, gc = (np.asarray(x) for x in self._angle(q_now))
        self.psi_slider.value = shown(float(psi)) if np.isfinite(psi) else 0.0  # type: ignore[misc]  # viser: read-only stub
        self._show_gc(_gc_text(gc))
        self._show_intervals(gc, "" if np.isfinite(psi) else "arm angle undefined here (elbow stretched)")

    def _show_intervals(self, gc, note: str = "") -> np.ndarray:
        gc = jnp.asarray(np.asarray(gc, dtype=np.float64))
        intervals, mask = (np.asarray(x) for x in self._feasible(self._flange, gc))
        self.srs_status.content = f"feasible psi for this flange pose and gc: {_intervals_text(intervals, mask)}" + (
            f"  \n{note}" if note else ""
        )
        return intervals[mask]

    def set_arm_angle(self, psi: float, gc=None, *, nearest: bool = False) -> bool:
        """:meth:`Viewer.set_arm_angle <diffkin.viewer._viewer.Viewer.set_arm_angle>`."""
        with self.page.lock:
            if gc is None and self.gc_dropdown is not None:  # (always built with the panel)
                gc = _signs(self.gc_dropdown.value)
            gc = np.asarray(gc, dtype=np.float64)
            q, valid = self._ik(self._flange, float(psi), jnp.asarray(gc))
            feasible = self._show_intervals(gc)
            if not bool(valid) and nearest and len(feasible):
                clipped = np.clip(psi, feasible[:, 0], feasible[:, 1])
                psi = float(clipped[np.argmin(np.abs(clipped - psi))])
                q, valid = self._ik(self._flange, psi, jnp.asarray(gc))
            with self.page.quietly():
                self.psi_slider.value = shown(psi)  # type: ignore[misc]  # viser's stub: read-only; its API sets it
                self._show_gc(_gc_text(gc))
            if not bool(valid):
                self.srs_status.content += "  \n**no solution within the joint limits at this arm angle**"
                return False
            self.page.show(np.asarray(q, dtype=np.float64), source="srs")
            return True
