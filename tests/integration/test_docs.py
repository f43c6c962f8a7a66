"""Every ```python block of README.md and docs/*.md runs, so that the examples cannot rot.

The blocks of one page run in order in one fresh interpreter (a page reads as one session; a page
may start new sessions with the line :data:`SESSION`, run as tests of their own), with
the working directory and ``HOME`` in a temporary folder (files the examples write land there),
warnings as errors, and a persistent compilation cache shared by the pages (pages that solve the
same problem compile it once). A page whose examples need the validation install (example-robot-data, dm_control, viser)
or compile large solvers is marked slow.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]  # tests/integration/ -> the checkout
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```\s*$", re.MULTILINE | re.DOTALL)

#: Pages (relative to the repository root) whose examples need the validation install or compile big solvers.
SLOW = {"docs/models.md", "docs/ik.md", "docs/srs.md", "docs/workspace.md", "docs/viewer.md", "docs/traj.md"}


#: A line that starts a new session of a page: the blocks after it run in an interpreter of their own.
SESSION = "<!-- the examples below run on their own -->"


def blocks(page: Path) -> list[str]:
    """The ```python blocks of a markdown page, in order."""
    return BLOCK.findall(page.read_text())


def sessions(page: Path) -> list[list[str]]:
    """The ```python blocks of a page, per session (:data:`SESSION`)."""
    return [found for part in page.read_text().split(SESSION) if (found := BLOCK.findall(part))]


def _name(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


RUNNABLE = [p for p in PAGES if blocks(p)]


@pytest.fixture(scope="session")
def compilation_cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("jax-cache"))


def test_block_pattern_finds_the_examples():
    """The pattern finds every fenced block tagged python (and only those), so none is skipped silently."""
    for page in PAGES:
        fences = re.findall(r"^```python\s*$", page.read_text(), re.MULTILINE)
        assert len(fences) == len(blocks(page)), _name(page)
    assert {_name(p) for p in RUNNABLE} >= SLOW | {"README.md"}


@pytest.mark.parametrize(
    ("page", "session"),
    [
        pytest.param(
            p, k, id=_name(p) if len(sessions(p)) == 1 else f"{_name(p)}#{k + 1}",
            marks=[pytest.mark.slow] if _name(p) in SLOW else [],
        )
        for p in RUNNABLE
        for k in range(len(sessions(p)))
    ],
)  # fmt: skip
def test_examples_run(page: Path, session: int, tmp_path: Path, compilation_cache: str):
    code = "\n\n".join(sessions(page)[session])
    env = dict(
        os.environ,
        HOME=str(tmp_path),
        MPLBACKEND="Agg",
        PYTHONWARNINGS="error",  # as in the tests: an example that warns is a defect
        JAX_COMPILATION_CACHE_DIR=compilation_cache,
        PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900
    )
    assert res.returncode == 0, f"{_name(page)}:\n{res.stdout[-2000:]}\n{res.stderr[-4000:]}"
