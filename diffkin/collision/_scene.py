"""Obstacle scenes as JSON files (:func:`load_scene`): spheres, capsules, boxes, cylinders and half-spaces,
checked on the host with errors that name the field (``boxes[1].half_extents``); the format is in
:func:`load_scene` and ``docs/collision.md`` ("Scene files").
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.collision._robot import World
from diffkin.collision._shapes import Box, Capsule, Cylinder, Plane, Sphere

#: per kind, its fields: name -> number of values (0: one number), and whether the field may be left out
_KINDS: dict[str, dict[str, tuple[int, bool]]] = {
    "spheres": {"center": (3, True), "radius": (0, True)},
    "capsules": {"a": (3, True), "b": (3, True), "radius": (0, True)},
    "boxes": {"position": (3, True), "quaternion": (4, False), "half_extents": (3, True)},
    "cylinders": {"position": (3, True), "quaternion": (4, False), "radius": (0, True), "half_length": (0, True)},
    "planes": {"normal": (3, True), "offset": (0, True)},
}
_TOP = ("margin", "self_collision", *_KINDS)
_QUATERNION_TOL = 1e-3  # the norm of a box's quaternion may be off 1 by this much (rounded decimals)


@dataclasses.dataclass(frozen=True)
class Scene:
    """The obstacles of a scene file, and how far to keep from them.

    Attributes:
        world: the obstacles (:class:`World`), in the world frame.
        margin: metres, ``>= 0``: the clearance asked for (``dk.ik.Avoid(..., margin=)``).
        self_collision: also keep the robot's own shapes apart (``dk.ik.Avoid(..., self_collision=)``).
    """

    world: World
    margin: float
    self_collision: bool


def _show(value: Any, limit: int = 60) -> str:
    """``value`` as JSON for a one-line message: cut at ``limit`` characters; what JSON cannot write (nested
    too deeply, an integer too long for a string) by its type."""
    try:
        text = json.dumps(value)
    except (RecursionError, ValueError):
        return f"a {type(value).__name__}"
    return text if len(text) <= limit else f"{text[:limit]}..."


def _number(value: Any, where: str) -> float:
    """A finite JSON number (not a boolean) as a float, else a ValueError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {_show(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond float64
        try:
            digits = f"{len(str(abs(value)))} digits"
        except ValueError:  # beyond Python's integer string conversion limit
            digits = "thousands of digits"
        raise ValueError(f"{where}: expected a finite number, got an integer of {digits}") from None
    if not math.isfinite(number):
        raise ValueError(f"{where}: expected a finite number, got {value}")
    return number


def _vector(value: Any, where: str, n: int) -> np.ndarray:
    """A list of ``n`` finite numbers as a float64 array ``(n,)``, else a ValueError naming ``where``."""
    if not isinstance(value, list) or len(value) != n:
        got = f"{len(value)} values" if isinstance(value, list) else _show(value)
        raise ValueError(f"{where}: expected a list of {n} numbers, got {got}")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(value)])


def _entries(kind: str, items: Any) -> list[dict[str, Any]]:
    """The checked fields of every obstacle of one kind: numbers as floats, vectors as arrays."""
    if not isinstance(items, list):
        raise ValueError(f"{kind}: expected a list of objects, got {_show(items)}")
    fields = _KINDS[kind]
    out = []
    for i, item in enumerate(items):
        where = f"{kind}[{i}]"
        if not isinstance(item, dict):
            raise ValueError(f"{where}: expected an object with {', '.join(fields)}, got {_show(item)}")
        unknown = sorted(set(item) - set(fields))
        if unknown:
            raise ValueError(f"{where}: unknown key {unknown[0]!r}: expected {', '.join(fields)}")
        entry: dict[str, Any] = {}
        for name, (n, required) in fields.items():
            if name not in item:
                if required:
                    raise ValueError(f"{where}: missing key {name!r}")
                continue
            entry[name] = _vector(item[name], f"{where}.{name}", n) if n else _number(item[name], f"{where}.{name}")
        for name in ("radius", "half_extents", "half_length"):
            if name in entry and np.any(entry[name] < 0):
                raise ValueError(f"{where}.{name}: expected values >= 0, got {json.dumps(item[name])}")
        out.append(entry)
    return out


def _rotation(quat: np.ndarray, where: str) -> np.ndarray:
    """``(3, 3)`` rotation of a quaternion ``(w, x, y, z)`` of norm within ``1e-3`` of 1 (normalised)."""
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) > _QUATERNION_TOL:
        raise ValueError(f"{where}: expected a unit quaternion [w, x, y, z] (norm 1 within 1e-3), got norm {norm:.6g}")
    w, x, y, z = quat / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _world(kinds: dict[str, list[dict[str, Any]]]) -> World:
    """The :class:`World` of the checked obstacles, in JAX's default float type."""

    def array(values) -> jax.Array:
        return jnp.asarray(np.asarray(values), jnp.result_type(float))

    def poses(kind: str, items: list[dict[str, Any]]) -> jax.Array:
        """``(n, 4, 4)`` of each item's ``position`` and ``quaternion`` (default: no rotation)."""
        T = np.tile(np.eye(4), (len(items), 1, 1))
        for i, item in enumerate(items):
            if "quaternion" in item:
                T[i, :3, :3] = _rotation(item["quaternion"], f"{kind}[{i}].quaternion")
            T[i, :3, 3] = item["position"]
        return array(T)

    shapes: list[Sphere | Capsule | Box | Cylinder | Plane] = []
    spheres, capsules, boxes, cylinders, planes = (kinds[k] for k in _KINDS)
    if spheres:
        shapes.append(Sphere(array([s["center"] for s in spheres]), array([s["radius"] for s in spheres])))
    if capsules:
        shapes.append(
            Capsule(
                array([c["a"] for c in capsules]),
                array([c["b"] for c in capsules]),
                array([c["radius"] for c in capsules]),
            )
        )
    if boxes:
        shapes.append(Box(poses("boxes", boxes), array([b["half_extents"] for b in boxes])))
    if cylinders:
        radii, halves = (array([c[k] for c in cylinders]) for k in ("radius", "half_length"))
        shapes.append(Cylinder(poses("cylinders", cylinders), radii, halves))
    if planes:
        norms = np.array([float(np.linalg.norm(p["normal"])) for p in planes])
        if np.any(norms < 1e-12):
            i = int(np.argmax(norms < 1e-12))
            raise ValueError(f"planes[{i}].normal: expected a non-zero vector, got {planes[i]['normal'].tolist()}")
        normals = np.stack([p["normal"] for p in planes]) / norms[:, None]
        shapes.append(Plane(array(normals), array(np.array([p["offset"] for p in planes]) / norms)))
    return World(*shapes)


def _parse(data: Any) -> Scene:
    """The :class:`Scene` of a decoded JSON document (ValueErrors name the field)."""
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object with keys {', '.join(_TOP)}, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise ValueError(f"unknown key {unknown[0]!r}: expected {', '.join(_TOP)}")
    margin = _number(data.get("margin", 0.0), "margin")
    if margin < 0:
        raise ValueError(f"margin: expected a distance >= 0 (metres), got {margin}")
    self_collision = data.get("self_collision", True)
    if not isinstance(self_collision, bool):
        raise ValueError(f"self_collision: expected true or false, got {_show(self_collision)}")
    kinds = {kind: _entries(kind, data.get(kind, [])) for kind in _KINDS}
    return Scene(_world(kinds), margin, self_collision)


def load_scene(source) -> Scene:
    """The obstacles of a scene: a JSON file of spheres, capsules, boxes, cylinders and half-spaces.

    The format (lengths in metres, world frame; every key optional)::

        {"margin": 0.01, "self_collision": true,
         "spheres": [{"center": [x, y, z], "radius": r}],
         "capsules": [{"a": [x, y, z], "b": [x, y, z], "radius": r}],
         "boxes": [{"position": [x, y, z], "quaternion": [w, x, y, z], "half_extents": [hx, hy, hz]}],
         "cylinders": [{"position": [x, y, z], "quaternion": [w, x, y, z], "radius": r, "half_length": h}],
         "planes": [{"normal": [nx, ny, nz], "offset": d}]}

    A cylinder's axis is the z axis of its ``quaternion``'s rotation. A box's or cylinder's
    ``quaternion`` (default ``[1, 0, 0, 0]``) is normalised (its norm must be within
    ``1e-3`` of 1); a plane is the half-space ``normal . x <= offset`` (the normal of any non-zero
    length). Use it as ``dk.ik.Avoid(geom, scene.world, scene.margin, scene.self_collision)``.

    Args:
        source: a path of a JSON file, JSON text (starting with ``{``), or the decoded mapping.

    Returns:
        The :class:`Scene`: ``world`` (a :class:`World`), ``margin``, ``self_collision``.

    Raises:
        ValueError: invalid JSON (or nested too deeply), an unknown or missing key, a list of the wrong length, a value
            that is not a finite number, a negative radius, half extent, half length or margin, a quaternion
            whose norm is not 1, a zero plane normal; the message names the field (``boxes[1].
            half_extents``) and, for a file, starts with its path. A number beyond float64 is not finite.
        OSError: a file that cannot be read.
    """
    where = ""
    if isinstance(source, Mapping):
        data: Any = dict(source)
    else:
        text = os.fspath(source)
        if isinstance(text, str) and text.lstrip().startswith("{"):
            raw = text
        else:
            where = f"{os.fsdecode(text)}: "
            with open(text, encoding="utf-8") as fh:
                raw = fh.read()
        try:
            data = json.loads(raw)  # NaN and Infinity decode as floats: the field check names them
        except RecursionError:
            raise ValueError(f"{where}not valid JSON: nested too deeply") from None
        except ValueError as err:  # JSONDecodeError, or an integer beyond Python's string conversion limit
            raise ValueError(f"{where}not valid JSON: {err}") from None
    try:
        return _parse(data)
    except ValueError as err:
        raise ValueError(f"{where}{err}") from None
