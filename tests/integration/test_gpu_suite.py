"""``experiments/gpu_suite.py --cpu-check`` (issue 57): the GPU rows at a tiny size, here, so that the script
the GPU sessions run never breaks unseen.

Its cost is compilation (the figures are tiny), so the test runs the rows that compile in seconds (FK,
Jacobians, the arms' IK, centre of mass, collision distances); the whole-robot, path, collision-aware
IK and MotionBenchMaker rows compile for minutes each on two cores and are left to
``gpu_suite.py --cpu-check`` by hand (their code is their benchmarks', which other tests run). The
subprocess keeps its programs in a persistent cache of its own beside the tests' (``DIFFKIN_TEST_CACHE_DIR``,
``off`` for none), so a rerun reads most of them back."""

import os
import subprocess
import sys

from _paths import EXPERIMENTS, ROOT

ROWS = "fk,jacobian,ik,com,collision"
SECTIONS = (
    "FK (flange pose) throughput",
    "Jacobian (default) throughput",
    "IK of the arms",
    "Centre of mass of Talos",
    "Collision distances",
)


def _cache_env() -> dict[str, str]:
    """JAX's persistent cache for the subprocess (every program kept), where the tests keep one."""
    env = os.environ.get("DIFFKIN_TEST_CACHE_DIR")
    if env is not None and env.strip().lower() in ("", "0", "off", "false", "no", "none"):
        return {"DIFFKIN_CACHE_DIR": "off"}
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = os.path.join(env or os.path.join(base, "diffkin", "jax-tests"), "gpu-suite")
    return {
        "JAX_COMPILATION_CACHE_DIR": folder,
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
    }


def test_cpu_check_writes_every_row(tmp_path):
    out = tmp_path / "suite.md"
    out.write_text("# a results file\n\nearlier text\n")
    env = dict(os.environ, JAX_PLATFORMS="cpu", **_cache_env())
    res = subprocess.run(
        [sys.executable, os.path.join(EXPERIMENTS, "gpu_suite.py"), "--cpu-check", "--only", ROWS, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=3600,
        env=env,
        cwd=ROOT,
    )
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-4000:]
    text = out.read_text()
    # the suite's section goes after the file's title, the rest kept
    assert text.startswith("# a results file\n\n<!-- gpu_suite.py: begin -->"), text[:300]
    assert text.rstrip().endswith("<!-- gpu_suite.py: end -->\n\nearlier text"), text[-300:]
    assert "Rows that raised" not in text
    for title in SECTIONS:
        parts = text.split(f"### {title}", 1)
        assert len(parts) == 2, f"no section {title!r}"
        body = parts[1].split("\n### ", 1)[0]
        assert "_no row ran_" not in body, f"{title}: no row\n{body}"
    for target in ("FK float32 at 1e8", "default Jacobian float32 at 1e7", "IK 1,000 Panda targets"):
        assert f"| {target}" in text
