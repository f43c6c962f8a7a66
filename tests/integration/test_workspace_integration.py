"""Workspace maps saved, loaded and plotted (matplotlib: the plot extra); in subprocesses, identical
across device counts (4 host devices), and memory that does not grow with the number of samples."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffkin as dk
from diffkin import workspace as ws

KEY = jax.random.key(7)


def test_save_load_and_plot_slice(tmp_path):
    m = ws.reachability(dk.robots.planar([1.0, 0.5]), 4000, key=KEY, voxel_size=0.25, chunk=1000)
    m.save(tmp_path / "map.npz")
    back = ws.ReachabilityMap.load(tmp_path / "map.npz")
    for name in ("counts", "manipulability", "dexterity", "origin"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    assert (back.voxel_size, back.n_samples, back.n_outside, back.orientation_bins, back.chain_name) == (
        m.voxel_size,
        m.n_samples,
        m.n_outside,
        m.orientation_bins,
        "planar2R",
    )
    labels = {"count": "samples per voxel", "manipulability": "Yoshikawa", "dexterity": "(of 48)"}
    for quantity in ("count", "manipulability", "dexterity"):
        path = tmp_path / f"{quantity}.png"
        ax = ws.plot_slice(m, axis="z", value=0.0, quantity=quantity, path=path)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 5000
        # the plot says what it shows: the slab, the samples, the Jacobian, the dexterity scale
        title, image = ax.get_title(), ax.images[0]
        assert "slab z in [-0.125, 0.125) m" in title and "4,000 samples uniform in joint space" in title, title
        assert labels[quantity] in image.colorbar.ax.get_ylabel()
        if quantity == "manipulability":
            assert "world Jacobian of the end effector" in title
        if quantity == "dexterity":
            assert image.get_clim() == (0, 48)
    ws.plot_slice(reach_map=m, axis="z")  # the parameter no longer shadows the builtin map
    with pytest.raises(ValueError, match="quantity"):
        ws.plot_slice(m, quantity="volume")
    with pytest.raises(ValueError, match="axis"):
        ws.plot_slice(m, axis="w")
    with pytest.raises(ValueError, match="value"):
        ws.plot_slice(m, axis="z", value=5.0)


def _run(script: str, env: dict) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=240,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_identical_maps_on_1_3_and_4_devices(tmp_path):
    script = f"""
        import json, jax, numpy as np
        import diffkin as dk
        from diffkin import workspace as ws
        chain, devices = dk.robots.panda(), jax.devices()
        maps = [ws.reachability(chain, 10_123, key=jax.random.key(7), voxel_size=0.15, chunk=1000,
                                devices=devices[:k], dtype="float32") for k in (1, 3, 4)]
        maps[2].save({str(tmp_path / "four.npz")!r})
        same = [all(np.array_equal(getattr(a, f), getattr(maps[0], f)) for f in ("counts", "manipulability",
                "dexterity")) for a in maps]
        print(json.dumps(dict(n_devices=len(devices), same=same, total=[int(a.counts.sum()) for a in maps])))
    """
    result = _run(script, {"XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"})
    assert result == dict(n_devices=4, same=[True, True, True], total=[10_123] * 3)
    four = ws.ReachabilityMap.load(tmp_path / "four.npz")
    here = ws.reachability(dk.robots.panda(), 10_123, key=KEY, voxel_size=0.15, chunk=1000, dtype=jnp.float32)
    # This process (x64 mode, float32 computation) draws the same samples: the same voxels and
    # bins; the float32 manipulability may differ in the last bits as XLA compiles it differently.
    np.testing.assert_array_equal(here.counts, four.counts)
    np.testing.assert_array_equal(here.dexterity, four.dexterity)
    np.testing.assert_allclose(here.manipulability, four.manipulability, rtol=1e-5, atol=0)


def test_memory_does_not_grow_with_the_number_of_samples():
    script = """
        import json, resource, jax
        import diffkin as dk
        from diffkin import workspace as ws
        chain, chunk = dk.robots.planar([1.0, 0.5]), 1 << 17
        run = lambda n: ws.reachability(chain, n, key=jax.random.key(0), voxel_size=0.05, chunk=chunk)
        run(2 * chunk)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        m = run(50 * chunk)
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(json.dumps(dict(growth_kib=after - before, total=int(m.counts.sum()))))
    """
    result = _run(script, {"JAX_PLATFORMS": "cpu"})
    # Holding the 50 chunks' joint values and positions at once would take 50 * 2**17 * 5 * 4 B = 125 MiB.
    assert result["total"] == 50 * (1 << 17) and result["growth_kib"] < 12 * 1024


UR10_URDF = os.path.join(
    sys.prefix,
    "lib",
    f"python{sys.version_info[0]}.{sys.version_info[1]}",
    "site-packages",
    "cmeel.prefix",
    "share",
    "example-robot-data",
    "robots",
    "ur_description",
    "urdf",
    "ur10_robot.urdf",
)


@pytest.mark.skipif(not os.path.exists(UR10_URDF), reason="example-robot-data's UR10 URDF is not installed")
def test_identical_maps_on_1_2_and_4_devices_ur10():
    """The case of issue 18: 1 sample in 400,000 changed voxels between 1 and 2 or 4 devices (UR10, 10 cm)."""
    script = f"""
        import json, jax, numpy as np
        import diffkin as dk
        from diffkin import workspace as ws
        chain, devices = dk.load_urdf({UR10_URDF!r}, "tool0"), jax.devices()
        maps = [ws.reachability(chain, 400_000, key=jax.random.key(7), voxel_size=0.1, devices=devices[:k])
                for k in (1, 2, 4)]
        same = [all(np.array_equal(getattr(a, f), getattr(maps[0], f)) for f in ("counts", "manipulability",
                "dexterity")) for a in maps]
        print(json.dumps(dict(n_devices=len(devices), same=same)))
    """
    result = _run(script, {"XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"})
    assert result == dict(n_devices=4, same=[True, True, True])
