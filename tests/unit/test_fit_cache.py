"""The mesh fits' cache on disk (``diffkin.collision._fitcache``): a second load reads it, a changed mesh,
placement or fit refits, a corrupt entry is ignored with a warning and replaced, and it can be turned off.

MJCF inline meshes (``<mesh vertex=...>``): no mesh files, no trimesh. Each test gets its own folder
(``DIFFKIN_FIT_CACHE``); the session's own is set by ``tests/conftest.py``.
"""

from __future__ import annotations

import io
import re

import numpy as np
import pytest

import diffkin as dk
from diffkin.collision import _fit, _fitcache

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
