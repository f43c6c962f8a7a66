"""dk.ik in a fresh interpreter without optax."""

import subprocess
import sys


def test_import_and_lm_without_optax_subprocess():
    """A fresh interpreter without optax imports diffkin.ik and solves with LM."""
    code = (
        "import sys; sys.modules['optax'] = None\n"
        "import jax.numpy as jnp, diffkin as dk\n"
        "chain = dk.robots.planar([1.0, 1.0])\n"
        "T = dk.fk(chain, jnp.array([0.3, 0.5]))\n"
        "print(bool(dk.ik.solve(chain, T, num_seeds=4).success))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.strip() == "True", res.stderr[-2000:]
