"""The mesh fits' cache on disk (``diffkin.collision._fitcache``): a second load reads it, a changed mesh,
placement or fit refits, a corrupt entry is ignored with a warning and replaced, and it can be turned off.

Capsule fits of points: MJCF inline meshes (``<mesh vertex=...>``). Fits of mesh files: a URDF naming an
OBJ file, read here by a stand-in for trimesh (``_sources._read_mesh``: the unit tier has no trimesh; the
real reader: ``tests/validation/test_mesh_cache_validation.py``). Each test gets its own folder
(``DIFFKIN_FIT_CACHE``); the session's own is set by ``tests/conftest.py``.
"""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

import diffkin as dk
from diffkin.collision import _fit, _fitcache, _sources

_VERTICES = np.random.default_rng(5).normal(size=(40, 3)) * [0.03, 0.04, 0.12]
MJCF = f"""<mujoco>
  <asset><mesh name="m" scale="1 1 1" vertex="{" ".join(map(repr, _VERTICES.ravel().tolist()))}"/></asset>
  <worldbody>
    <body name="a"><joint name="ja" type="hinge" axis="0 1 0"/>
      <geom name="g" type="mesh" mesh="m" pos="0 0 0.1"/>
    </body>
  </worldbody>
</mujoco>"""
ROBOT = dk.load_robot(MJCF)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """This test's cache folder (not created yet)."""
    folder = tmp_path / "fits"
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", str(folder))
    return folder


@pytest.fixture
def fits(monkeypatch):
    """The fits computed (not read from the cache): the number of points of each. A short search (the
    cache does not depend on how good the fit is): the tests are fast."""
    monkeypatch.setattr(_fit, "SEARCH", tuple({**dict(_fit.SEARCH), "maxiter": 30}.items()))
    calls: list[int] = []
    search = _fit._search

    def spy(P):
        calls.append(len(P))
        return search(P)

    monkeypatch.setattr(_fit, "_search", spy)
    return calls


def _capsule(source: str = MJCF):
    geom = dk.collision.load(source, ROBOT)
    return tuple(np.asarray(x)[0] for x in (geom.capsules.a, geom.capsules.b, geom.capsules.radius)), geom.fits


def _entries(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_second_load_reads_the_cache(cache, fits):
    first, volumes = _capsule()
    assert len(fits) == 1
    (name,) = _entries(cache)  # one entry, no temporary file left
    assert re.fullmatch(r"[0-9a-f]{64}\.npz", name)
    second, again = _capsule()
    assert len(fits) == 1  # read back, not fitted
    for x, y in zip(first, second, strict=True):
        np.testing.assert_array_equal(x, y)
    assert again == volumes
    # what was cached is the fit itself: the same as without the cache
    a, b, r = _fit._search(_VERTICES + [0, 0, 0.1])
    np.testing.assert_array_equal(first[0], a)
    np.testing.assert_array_equal(first[1], b)
    assert first[2] == r


@pytest.mark.parametrize(
    "change",
    [
        lambda s, mp: s.replace(repr(float(_VERTICES[7, 2])), repr(float(_VERTICES[7, 2]) + 1e-9)),  # one vertex
        lambda s, mp: s.replace('scale="1 1 1"', 'scale="1 1 1.0000001"'),
        lambda s, mp: s.replace('pos="0 0 0.1"', 'pos="0 0 0.1000001"'),  # the placement
        lambda s, mp: mp.setattr(_fit, "FIT_VERSION", _fit.FIT_VERSION + "-next") or s,  # the algorithm
        lambda s, mp: mp.setattr(_fit, "GRID", 33) or s,  # a setting
    ],
    ids=["vertex", "scale", "placement", "version", "setting"],
)
def test_a_change_refits(cache, fits, monkeypatch, change):
    _capsule()
    source = change(MJCF, monkeypatch)
    _capsule(source)
    assert len(fits) == 2 and len(_entries(cache)) == 2
    _capsule(source)
    assert len(fits) == 2  # the new entry is read back


def _npz(**arrays) -> bytes:
    f = io.BytesIO()
    np.savez(f, **arrays)
    return f.getvalue()


@pytest.mark.parametrize(
    "content, reason",
    [
        (b"not a cache entry", "cannot be read"),
        (b"", "cannot be read"),
        (_npz(a=np.zeros(3), b=np.zeros(3), radius=np.float64(1e-3)), "outside"),  # well formed, too small
        (_npz(a=np.zeros(3), b=np.zeros(3)), "cannot be read"),  # no radius
        (_npz(a=np.zeros(2), b=np.zeros(3), radius=np.float64(1.0)), "shapes"),
        (_npz(a=np.zeros(3), b=np.full(3, np.nan), radius=np.float64(1.0)), "not finite"),
        (_npz(a=np.zeros(3), b=np.zeros(3), radius=np.array(["big"])), "cannot be read"),
    ],
    ids=["garbage", "empty", "too-small", "missing", "shapes", "nan", "strings"],
)
def test_a_corrupt_entry_is_ignored_and_replaced(cache, fits, content, reason):
    first, _ = _capsule()
    (name,) = _entries(cache)
    (cache / name).write_bytes(content)
    with pytest.warns(UserWarning, match=rf"{re.escape(name)}.*{reason}"):
        again, _ = _capsule()
    assert len(fits) == 2  # fitted again
    for x, y in zip(first, again, strict=True):
        np.testing.assert_array_equal(x, y)
    _capsule()  # overwritten: read back without a warning (warnings are errors)
    assert len(fits) == 2 and _entries(cache) == [name]


@pytest.mark.parametrize("value", ["off", "0", "false", "no", "none", "", " OFF "])
def test_off_writes_nothing(tmp_path, monkeypatch, fits, value):
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", value)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _fitcache.folder() is None
    _capsule()
    _capsule()
    assert len(fits) == 2 and list(tmp_path.iterdir()) == []


def test_default_folder(tmp_path, monkeypatch, fits):
    monkeypatch.delenv("DIFFKIN_FIT_CACHE")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert _fitcache.folder() == tmp_path / "home" / ".cache" / "diffkin" / "fits"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    _capsule()
    assert len(_entries(tmp_path / "xdg" / "diffkin" / "fits")) == 1
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", "~/fits")
    assert _fitcache.folder() == tmp_path / "home" / "fits"


def test_an_unwritable_folder_is_no_cache(tmp_path, monkeypatch, fits):
    (tmp_path / "file").write_text("in the way")
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", str(tmp_path / "file" / "fits"))
    first, _ = _capsule()
    second, _ = _capsule()  # no error, no warning: fitted each time
    assert len(fits) == 2
    for x, y in zip(first, second, strict=True):
        np.testing.assert_array_equal(x, y)


# ------------------------------------------------------------------------------------- mesh files

# A concave mesh (an L-shaped prism: its hull reaches beyond it) as an OBJ file.
_L = np.array([[0, 0], [0.1, 0], [0.1, 0.03], [0.03, 0.03], [0.03, 0.08], [0, 0.08]])
_OBJ_VERTICES = np.concatenate([np.c_[_L, np.zeros(6)], np.c_[_L, np.full(6, 0.05)]])
_OBJ_FACES = [(0, 2, 1), (0, 3, 2), (0, 5, 3), (3, 5, 4), (6, 7, 8), (6, 8, 9), (6, 9, 11), (9, 10, 11)]
_OBJ_FACES += [f for k in range(6) for f in ((k, (k + 1) % 6, (k + 1) % 6 + 6), (k, (k + 1) % 6 + 6, k + 6))]
OBJ = "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in _OBJ_VERTICES.tolist())
OBJ += "".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in _OBJ_FACES)
RPY = (0.1, 0.2, 0.3)


def _urdf(mesh, xyz="0 0 0.1", scale="1 1 1") -> str:
    return f"""<robot name="m">
  <link name="base"/>
  <link name="a"><collision><origin xyz="{xyz}" rpy="{" ".join(map(str, RPY))}"/>
    <geometry><mesh filename="{mesh}" scale="{scale}"/></geometry></collision></link>
  <joint name="j" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """A stand-in for trimesh: the ``v`` and ``f`` lines of an OBJ file."""
    rows = [line.split() for line in Path(path).read_text().splitlines()]
    vertices = np.array([[float(x) for x in r[1:]] for r in rows if r and r[0] == "v"])
    faces = np.array([[int(i) - 1 for i in r[1:]] for r in rows if r and r[0] == "f"], dtype=np.int64)
    return vertices, faces


@pytest.fixture
def mesh_file(tmp_path):
    path = tmp_path / "l.obj"
    path.write_text(OBJ)
    return path


@pytest.fixture
def reads(monkeypatch, fits):
    """The mesh files read (by :func:`_read_obj`), in order; the fits' short search (``fits``)."""
    calls: list[str] = []

    def read(path):
        calls.append(path)
        return _read_obj(path)

    monkeypatch.setattr(_sources, "_read_mesh", read)
    return calls


def _load(mesh_file, meshes, **kw):
    urdf = _urdf(mesh_file, **kw)
    return dk.collision.load(urdf, dk.load_robot(urdf), meshes=meshes)


def _same(g, h) -> None:
    """Identical geometries: shapes, fits and overshoot."""
    assert g.counts == h.counts and g.fits == h.fits and g.shape_overshoot == h.shape_overshoot
    for x, y in zip(jax.tree.leaves(g.shapes), jax.tree.leaves(h.shapes), strict=True):
        np.testing.assert_array_equal(x, y)


def _mesh_entry(mesh_file, meshes) -> str:
    """The entry's name of the fit of ``mesh_file`` as :func:`_load` places it by default."""
    from diffkin.models.urdf import rpy_matrix

    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rpy_matrix(np.array(RPY)), (0, 0, 0.1)
    key = _fitcache.mesh_key(mesh_file.read_bytes(), np.ones(3), T, meshes, _sources.mesh_settings())
    return f"{key}.npz"


@pytest.mark.parametrize("meshes", ["hulls", "capsules"])
def test_a_second_load_of_a_mesh_file_neither_reads_it_nor_fits(cache, mesh_file, reads, fits, monkeypatch, meshes):
    first = _load(mesh_file, meshes)
    assert reads == [str(mesh_file)]
    # the key: the file's bytes, scale, placement, fit and settings; for a capsule, the fit of the points too
    assert _mesh_entry(mesh_file, meshes) in _entries(cache)
    assert len(_entries(cache)) == (1 if meshes == "hulls" else 2)
    assert first.fits[0][1] == "mesh" and first.shape_overshoot[0] > 1e-3  # the concave mesh: a real overshoot

    def fail(*args):
        raise AssertionError("read or fitted again")

    with monkeypatch.context() as mp:
        mp.setattr(_sources, "_read_mesh", fail)
        mp.setattr(_sources, "fitted", fail)
        second = _load(mesh_file, meshes)
    _same(first, second)
    # what was cached is the fit itself: the same as without the cache
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", "off")
    _same(first, _load(mesh_file, meshes))
    assert len(reads) == 2


def _append(path, text: str) -> dict:
    path.write_text(path.read_text() + text)
    return {}


@pytest.mark.parametrize(
    "change",
    [
        lambda f, mp: _append(f, "# one more line\n"),  # the file's bytes (the same mesh)
        lambda f, mp: {"scale": "1 1 1.0000001"},
        lambda f, mp: {"xyz": "0 0 0.1000001"},  # the placement
        lambda f, mp: mp.setattr(_sources, "MESH_VERSION", _sources.MESH_VERSION + "-next") or {},  # the code
        lambda f, mp: mp.setattr(_sources._overshoot, "FACE_STEPS", 3) or {},  # a setting
    ],
    ids=["file", "scale", "placement", "version", "setting"],
)
@pytest.mark.parametrize("meshes", ["hulls", "capsules"])
def test_a_change_to_a_mesh_file_or_its_fit_refits(cache, mesh_file, reads, monkeypatch, meshes, change):
    _load(mesh_file, meshes)
    kw = change(mesh_file, monkeypatch)
    _load(mesh_file, meshes, **kw)
    assert len(reads) == 2
    _load(mesh_file, meshes, **kw)
    assert len(reads) == 2  # the new entry is read back


def test_the_mode_is_part_of_the_key(cache, mesh_file, reads):
    hulls = _load(mesh_file, "hulls")
    capsules = _load(mesh_file, "capsules")
    assert len(reads) == 2 and hulls.counts != capsules.counts
    _same(hulls, _load(mesh_file, "hulls"))
    _same(capsules, _load(mesh_file, "capsules"))
    assert len(reads) == 2


_HULL = {"kind": np.str_("convex"), "params": np.zeros(3), "volume": 0.0, "fitted_volume": 0.0, "overshoot": 0.0}
_CAPSULE = {**_HULL, "kind": np.str_("capsule"), "params": np.r_[np.zeros(6), 0.1]}


@pytest.mark.parametrize(
    "meshes, content, reason",
    [
        ("hulls", b"not a cache entry", "cannot be read"),
        ("hulls", _npz(**{**_HULL, "volume": np.array(["big"])}), "cannot be read"),
        ("hulls", _npz(**{k: v for k, v in _HULL.items() if k != "overshoot"}), "cannot be read"),
        ("hulls", _npz(**{**_HULL, "kind": np.str_("capsule")}), "kind"),
        ("hulls", _npz(**{**_HULL, "params": np.zeros(0)}), "parameters"),
        ("hulls", _npz(**{**_HULL, "params": np.zeros(4)}), "parameters"),
        ("hulls", _npz(**{**_HULL, "params": np.full(3, np.inf)}), "not finite"),
        ("hulls", _npz(**{**_HULL, "overshoot": -1.0}), "negative overshoot"),
        ("hulls", _npz(**{**_HULL, "volume": np.zeros(2)}), "not scalars"),
        ("hulls", _npz(**{**_HULL, "fitted_volume": -np.inf}), "volume"),
        ("capsules", _npz(**_HULL), "kind"),
        ("capsules", _npz(**{**_CAPSULE, "params": np.zeros(6)}), "parameters"),
        ("capsules", _npz(**{**_CAPSULE, "params": np.r_[np.zeros(6), -0.1]}), "negative radius"),
    ],
    ids=[
        "garbage",
        "strings",
        "missing",
        "kind",
        "no-vertex",
        "not-points",
        "inf",
        "overshoot",
        "shape",
        "volume",
        "capsule-kind",
        "capsule-shape",
        "capsule-radius",
    ],
)
def test_a_corrupt_mesh_entry_is_ignored_and_replaced(cache, mesh_file, reads, meshes, content, reason):
    first = _load(mesh_file, meshes)
    entry = cache / _mesh_entry(mesh_file, meshes)
    entry.write_bytes(content)
    with pytest.warns(UserWarning, match=rf"{re.escape(str(mesh_file))}.*{re.escape(entry.name)}.*{reason}"):
        again = _load(mesh_file, meshes)
    assert len(reads) == 2  # read and fitted again
    _same(first, again)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _same(first, _load(mesh_file, meshes))  # overwritten: read back without a warning
    assert len(reads) == 2


def test_off_writes_no_mesh_entry(tmp_path, monkeypatch, mesh_file, reads):
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for meshes in ("hulls", "capsules", "hulls"):
        _load(mesh_file, meshes)
    assert len(reads) == 3 and sorted(p.name for p in tmp_path.iterdir()) == ["l.obj"]
