"""Reading robot description files (URDF, MJCF): a path or the XML text itself, parsed with the errors
named (the model readers' and :func:`diffkin.collision.load`'s)."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np


def read(source, what: str = "robot description") -> tuple[ET.Element, str | None]:
    """Parse ``source`` (a path or an XML string); returns the root element and the file's path.

    Files are parsed as bytes, so an XML declaration's encoding (e.g. ISO-8859-1) is honoured.

    Raises:
        TypeError: ``source`` is not a string or path.
        ValueError: a missing file or malformed XML.
    """
    if not isinstance(source, (str, os.PathLike)):
        raise TypeError(f"source: expected a {what} path or XML string, got {type(source).__name__}")
    text = os.fspath(source)
    path = None
    if text.lstrip().startswith("<"):
        data: str | bytes = text
    else:
        if not os.path.isfile(text):
            raise ValueError(f"source: {what} file not found: {text!r}")
        path = os.path.abspath(text)
        with open(text, "rb") as fh:
            data = fh.read()
    try:
        return ET.fromstring(data), path
    except ET.ParseError as err:
        raise ValueError(f"source: malformed {what} XML ({err})") from err


def numbers(element: ET.Element | None, attribute: str, count: int, default: str | None, where: str) -> np.ndarray:
    """``count`` finite numbers from a whitespace-separated attribute (``default`` if absent)."""
    text = element.get(attribute) if element is not None else None
    if text is None:
        if default is None:
            raise ValueError(f"{where}: missing attribute {attribute!r}")
        text = default
    try:
        values = np.array([float(x) for x in text.split()], dtype=np.float64)
    except ValueError:
        values = np.array([])
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{where} {attribute}: expected {count} finite numbers, got {text!r}")
    return values
