"""The test settings of ``tests/conftest.py``: each xdist worker compiles into a persistent cache folder of its
own (two workers sharing one read each other's half-written entries: issue 56), bounded as a whole."""

import os

import conftest
import jax


def test_each_xdist_worker_has_a_compilation_cache_folder_of_its_own(monkeypatch):
    live, worker = jax.config.jax_compilation_cache_dir, os.environ.get("PYTEST_XDIST_WORKER")
    if live is not None and worker is not None:
        assert os.path.basename(live) == worker
    monkeypatch.setenv("DIFFKIN_TEST_CACHE_DIR", os.path.join("somewhere", "jax-tests"))
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    assert conftest._compilation_cache() == os.path.join("somewhere", "jax-tests")
    for name in ("gw0", "gw1"):
        monkeypatch.setenv("PYTEST_XDIST_WORKER", name)
        assert conftest._compilation_cache() == os.path.join("somewhere", "jax-tests", name)
    monkeypatch.setenv("DIFFKIN_TEST_CACHE_DIR", "off")
    assert conftest._compilation_cache() is None


def test_the_cache_is_bounded_over_every_worker_folder(tmp_path):
    for age, (folder, name) in enumerate([("gw0", "a"), ("gw1", "b"), (".", "c"), ("gw0", "d")]):
        path = tmp_path / folder / name
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"x" * 100)
        os.utime(path, (age, age))
    conftest._bound(tmp_path, 250)
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == ["c", "d"]
