"""JAX's persistent compilation cache is on by default for library users (diffkin._cache): a second process
reads back the programs the first compiled; ``DIFFKIN_CACHE_DIR=off`` and a cache the user configured for
JAX are respected; the folder is trimmed at exit."""

import json
import os
import subprocess
import sys

import pytest

from diffkin import _cache

# Counts JAX's cache hits and misses while it compiles the iiwa's jitted FK, after importing jax first or not.
SCRIPT = """
import json, sys
if sys.argv[1] == "jax-first":
    import jax
import diffkin as dk
import jax
from jax import monitoring

events = []
monitoring.register_event_listener(lambda name, **kw: events.append(name))
jax.jit(lambda q: dk.fk(dk.robots.iiwa14(), q))(jax.numpy.zeros(7)).block_until_ready()
print(json.dumps({
    "folder": jax.config.jax_compilation_cache_dir,
    "hits": events.count("/jax/compilation_cache/cache_hits"),
    "misses": events.count("/jax/compilation_cache/cache_misses"),
}))
"""


def _run(tmp_path, order="diffkin-first", **env):
    base = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "DIFFKIN_CACHE_DIR"}
    res = subprocess.run(
        [sys.executable, "-c", SCRIPT, order],
        capture_output=True,
        text=True,
        timeout=300,
        env={**base, "XDG_CACHE_HOME": str(tmp_path / "xdg"), **env},
    )
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def _files(folder):
    return [p for p in folder.rglob("*") if p.is_file()] if folder.exists() else []


@pytest.mark.parametrize("order", ["diffkin-first", "jax-first"])
def test_a_second_process_reads_the_first_ones_programs(tmp_path, order):
    first = _run(tmp_path, order)
    assert first["folder"] == str(tmp_path / "xdg" / "diffkin" / "jax")
    assert first["misses"] > 0 and first["hits"] == 0 and _files(tmp_path / "xdg")
    second = _run(tmp_path, order)
    assert second["hits"] >= first["misses"] and second["misses"] == 0


def test_the_cache_stays_off_or_where_the_user_put_it(tmp_path):
    off = _run(tmp_path, DIFFKIN_CACHE_DIR="off")
    assert off["folder"] is None and off["hits"] == off["misses"] == 0 and not _files(tmp_path / "xdg")
    mine = _run(tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "mine"))
    assert mine["folder"] == str(tmp_path / "mine") and not _files(tmp_path / "xdg")
    named = _run(tmp_path, DIFFKIN_CACHE_DIR=str(tmp_path / "named"))
    assert named["folder"] == str(tmp_path / "named") and _files(tmp_path / "named")


def test_trim_keeps_the_newest_files(tmp_path):
    for i in range(5):
        path = tmp_path / "sub" / f"{i}.bin"
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"x" * 100)
        os.utime(path, (1000 + i, 1000 + i))
    _cache.trim(tmp_path, 250)
    assert sorted(p.name for p in _files(tmp_path)) == ["3.bin", "4.bin"]
