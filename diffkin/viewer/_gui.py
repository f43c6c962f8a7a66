"""What the viewer's panels work with: the page (its GUI, lock, quiet flag and a way to show a
configuration), names as the page shows them, and the slider rounding."""

from __future__ import annotations

import contextlib
import string
import threading
from collections.abc import Callable, Iterator

import numpy as np

_MARKDOWN_ESCAPES = {
    **{c: "\\" + c for c in string.punctuation},  # CommonMark: any ASCII punctuation escapes with a backslash
    "&": "&amp;",
    "<": "&lt;",
    ">": "&gt;",
    **{c: " " for c in "\n\r\t\f\v"},  # one line: no block structure
}


class Page:
    """The part of a :class:`~diffkin.viewer._viewer.Viewer` that a panel uses (a panel gets it, not the viewer).

    Attributes:
        gui: the server's GUI (``viser.GuiApi``), to add the panel's controls to.
        lock: held (re-entrant) while the configuration shown changes.
        quiet: ``True`` while the viewer sets controls itself: a control's callback then does nothing.
    """

    def __init__(self, gui, show: Callable[[np.ndarray, object], None]):
        """``show(q, source)`` shows the configuration ``q (dof,)``; ``source`` names the control that moved
        it (the viewer leaves that one as it is)."""
        self.gui, self._show = gui, show
        self.lock = threading.RLock()
        self.quiet = False

    @contextlib.contextmanager
    def quietly(self) -> Iterator[None]:
        """Set controls from Python without their callbacks acting."""
        before, self.quiet = self.quiet, True
        try:
            yield
        finally:
            self.quiet = before

    def show(self, q: np.ndarray, source: object) -> None:
        """Show the configuration ``q (dof,)``, moved by the control ``source``."""
        self._show(q, source)


def shown(x: float) -> float:
    """A value as a slider shows it: 6 decimals (the browser breaks on values such as ``1e-17``)."""
    return round(float(x), 6) + 0.0


def plain(text: str) -> str:
    """``text`` (a name or path from a file or the command line) as Markdown that shows it verbatim.

    viser renders Markdown with raw HTML and its server reads the file of an image ``![x](path)``
    into the page: every ASCII punctuation character is escaped (``<``, ``>``, ``&`` as HTML
    entities), so the text forms no tag, link, image, code span or emphasis.
    """
    return "".join(_MARKDOWN_ESCAPES.get(c, c) for c in str(text))


def node(name: str) -> str:
    """A frame name as one scene-tree path component, one-to-one: ``%`` and ``/`` percent-encoded
    (``arm/base`` is ``arm%2Fbase``, apart from ``arm_base``), the empty name ``%``."""
    return name.replace("%", "%25").replace("/", "%2F") or "%"
