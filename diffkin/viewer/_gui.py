"""Small helpers of the page's controls."""

from __future__ import annotations


def shown(x: float) -> float:
    """A value as a slider shows it: 6 decimals (the browser breaks on values such as ``1e-17``)."""
    return round(float(x), 6) + 0.0
