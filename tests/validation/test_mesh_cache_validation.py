"""The cache of mesh files' fits (``diffkin.collision._fitcache.cached_mesh``) with the real mesh reader
(trimesh): a second load of an STL file, and of the Panda's meshes, reads the cache and neither the files
nor trimesh, with the same geometry; a changed file refits. The cache's rules with a stand-in reader (the
unit tier has no trimesh): ``tests/unit/test_fit_cache.py``.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from _models import ERD

import diffkin as dk
from diffkin.collision import _sources

pytest.importorskip("trimesh")

# An L-shaped prism (concave: its hull reaches beyond it), as an ASCII STL
_L = np.array([[0, 0], [0.1, 0], [0.1, 0.03], [0.03, 0.03], [0.03, 0.08], [0, 0.08]])
_V = np.concatenate([np.c_[_L, np.zeros(6)], np.c_[_L, np.full(6, 0.05)]])
_F = [(0, 2, 1), (0, 3, 2), (0, 5, 3), (3, 5, 4), (6, 7, 8), (6, 8, 9), (6, 9, 11), (9, 10, 11)]
_F += [f for k in range(6) for f in ((k, (k + 1) % 6, (k + 1) % 6 + 6), (k, (k + 1) % 6 + 6, k + 6))]


def _stl(vertices=_V) -> str:
    facets = "".join(
        "facet normal 0 0 0\n outer loop\n"
        + "".join(f"  vertex {x!r} {y!r} {z!r}\n" for x, y, z in vertices[list(f)].tolist())
        + " endloop\nendfacet\n"
        for f in _F
    )
    return f"solid l\n{facets}endsolid l\n"


def _urdf(mesh) -> str:
    return f"""<robot name="m">
  <link name="base"/>
  <link name="a"><collision><origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/>
    <geometry><mesh filename="{mesh}" scale="1 1 1"/></geometry></collision></link>
  <joint name="j" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "fits"
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", str(folder))
    return folder


@pytest.fixture
def reads(monkeypatch):
    """The mesh files read (by trimesh), in order."""
    calls: list[str] = []
    read = _sources._read_mesh

    def spy(path):
        calls.append(path)
        return read(path)

    monkeypatch.setattr(_sources, "_read_mesh", spy)
    return calls


def _same(g, h) -> None:
    assert g.counts == h.counts and g.fits == h.fits and g.shape_overshoot == h.shape_overshoot
    for x, y in zip(jax.tree.leaves(g.shapes), jax.tree.leaves(h.shapes), strict=True):
        np.testing.assert_array_equal(x, y)


def _reload_without_reading(monkeypatch, load):
    def fail(*args):
        raise AssertionError("a mesh was read or fitted")

    with monkeypatch.context() as mp:
        mp.setattr(_sources, "_read_mesh", fail)
        mp.setattr(_sources, "fitted", fail)
        return load()


@pytest.mark.parametrize("meshes", ["hulls", "capsules"])
def test_an_stl_file_is_read_once(cache, tmp_path, monkeypatch, reads, meshes):
    path = tmp_path / "l.stl"
    path.write_text(_stl())
    urdf = _urdf(path)
    robot = dk.load_robot(urdf)
    first = dk.collision.load(urdf, robot, meshes=meshes)
    assert reads == [str(path)] and first.shape_overshoot[0] > 1e-3
    _same(first, _reload_without_reading(monkeypatch, lambda: dk.collision.load(urdf, robot, meshes=meshes)))
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", "off")
    _same(first, dk.collision.load(urdf, robot, meshes=meshes))  # the fit itself, as without the cache
    monkeypatch.setenv("DIFFKIN_FIT_CACHE", str(cache))
    path.write_text(_stl(_V * [1, 1, 1.5]))  # a changed file: fitted again, to the new mesh
    changed = dk.collision.load(urdf, robot, meshes=meshes)
    assert len(reads) == 3 and changed.fits[0][2] > first.fits[0][2]


def test_the_pandas_meshes_are_read_once(cache, monkeypatch, reads):
    path = f"{ERD}/panda_description/urdf/panda.urdf" if ERD else ""
    if not ERD:
        pytest.skip("no example-robot-data")
    robot = dk.load_robot(path)
    first = dk.collision.load(path, robot, meshes="hulls")
    assert len(reads) == 9 == first.counts[4]  # the link meshes, as polytopes
    _same(first, _reload_without_reading(monkeypatch, lambda: dk.collision.load(path, robot, meshes="hulls")))
