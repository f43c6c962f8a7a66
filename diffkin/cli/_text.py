"""Numbers and poses as the commands print them."""

from __future__ import annotations

import numpy as np


def clean(x) -> np.ndarray:
    """float64 copy with rounding noise below 1e-12 (and negative zeros) set to 0, for printing."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.abs(x) < 1e-12, 0.0, x)


def indent(text: str, pad: str = "  ") -> str:
    return "\n".join(pad + line for line in text.splitlines())


def fmt(x, digits: int = 6) -> str:
    """Numbers as ``[a b c]`` with ``digits`` significant digits."""
    return "[" + " ".join(f"{v: .{digits}g}" for v in np.atleast_1d(clean(x))) + "]"


def quaternions(T) -> np.ndarray:
    """``(..., 4)`` unit quaternions ``(w, x, y, z)``, ``w >= 0``, of the rotations of ``(..., 4, 4)`` poses."""
    from diffkin import se3

    return np.asarray(se3.quaternion_from_rotation(np.asarray(T, dtype=np.float64)[..., :3, :3]))


def collision_word(clearance: float, margin: float) -> str:
    """``collision-free`` (clearance at least the margin), ``within the margin`` or ``in collision`` (< 0)."""
    if clearance >= margin:
        return "collision-free"
    return "within the margin" if clearance >= 0 else "in collision"
