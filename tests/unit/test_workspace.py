"""Workspace maps against the textbook 2R annulus, a plain-numpy recomputation on the same samples and
direct forward kinematics (saved maps and their plots with matplotlib, and across device counts and
memory in subprocesses: ``tests/integration/test_workspace_integration.py``)."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _paths import DATA

import diffkin as dk
from diffkin import workspace as ws
from diffkin._static import partition
from diffkin.workspace import _bins

KEY = jax.random.key(7)


def _planar_reference(lengths, q, origin, voxel_size, shape, n_roll):
    """Counts, best manipulability and dexterity of a planar 2R arm by closed forms in numpy."""
    (a1, a2), (t1, t2) = lengths, (q[:, 0], q[:, 1])
    x, y = a1 * np.cos(t1) + a2 * np.cos(t1 + t2), a1 * np.sin(t1) + a2 * np.sin(t1 + t2)
    p = np.stack([x, y, np.zeros_like(x)], axis=1)
    # J = [[dx/dt1, dx/dt2], [dy/dt1, dy/dt2], 0, 0, 0, [1, 1]]: det(J^T J) of the 6x2 world Jacobian.
    j1, j2 = np.stack([-y, x], 1), np.stack([-a2 * np.sin(t1 + t2), a2 * np.cos(t1 + t2)], 1)
    gram = np.stack([[(j1 * j1).sum(1) + 1, (j1 * j2).sum(1) + 1], [(j1 * j2).sum(1) + 1, (j2 * j2).sum(1) + 1]])
    manip = np.sqrt(np.maximum(gram[0, 0] * gram[1, 1] - gram[0, 1] ** 2, 0))
    phi = np.arctan2(np.sin(t1 + t2), np.cos(t1 + t2))  # tool z = base z: cube face 4 (+z), roll = phi
    bins = 4 * n_roll + np.minimum(np.floor((phi + np.pi) / (2 * np.pi / n_roll)), n_roll - 1).astype(int)
    cell = np.floor((p - origin) / voxel_size).astype(int)
    inside = np.all((cell >= 0) & (cell < shape), axis=1)
    flat = np.ravel_multi_index(cell[inside].T, shape)
    counts, best = np.zeros(np.prod(shape), int), np.zeros(np.prod(shape))
    np.add.at(counts, flat, 1)
    np.maximum.at(best, flat, manip[inside])
    dexterity = np.bincount(np.unique(flat * 6 * n_roll + bins[inside]) // (6 * n_roll), minlength=np.prod(shape))
    return counts.reshape(shape), best.reshape(shape), dexterity.reshape(shape), int((~inside).sum())


def test_sample_configs_within_limits_and_uniform():
    chain = dk.robots.panda()
    q = np.asarray(ws.sample_configs(chain, 40_000, KEY))
    lo, hi = np.asarray(chain.lower), np.asarray(chain.upper)
    assert q.shape == (40_000, 7) and np.all(q >= lo) and np.all(q <= hi)
    u = (q - lo) / (hi - lo)  # uniform on [0, 1]: each decile holds 10 % (binomial sd 0.15 %)
    deciles = np.stack([np.histogram(u[:, i], bins=10, range=(0, 1))[0] for i in range(7)]) / 40_000
    np.testing.assert_allclose(deciles, 0.1, atol=0.008)
    planar = np.asarray(ws.sample_configs(dk.robots.planar([1.0, 1.0]), 1000, KEY))
    assert np.all(planar >= -np.pi) and np.all(planar < np.pi) and planar.std() > 1.5  # one turn


def test_manipulability_matches_core():
    """The maps' division-free manipulability (one forward pass, Cauchy-Binet) equals the core's
    ``dk.manipulability`` on 500 sampled configurations: both in one compiled program per chain."""
    for chain in (dk.robots.iiwa14(), dk.robots.ur5(), dk.robots.planar([1.0, 0.5, 0.3])):  # 7, 6 and 3 joints

        def both(key, chain=chain):
            q = ws.sample_configs(chain, 500, key)
            return _bins._manipulability(chain.forward(list(q.T)), chain.dof), dk.manipulability(chain, q)

        ours, core = jax.jit(both)(KEY)
        np.testing.assert_allclose(ours, core, rtol=1e-9, atol=1e-12)


def test_orientation_bins_partition_so3_evenly():
    n = 96_000
    quat = np.random.default_rng(0).normal(size=(n, 4))  # Haar-uniform rotations
    w, x, y, z = (quat / np.linalg.norm(quat, axis=1, keepdims=True)).T
    R = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    # Followed by rotations about z by each sector's centre: one compiled call for both sets.
    phi = -np.pi + (np.arange(8) + 0.5) * np.pi / 4
    c, s, zero, one = np.cos(phi), np.sin(phi), np.zeros(8), np.ones(8)
    planar = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    both = [
        [jnp.asarray(np.concatenate(pair)) for pair in zip(*rows, strict=True)] for rows in zip(R, planar, strict=True)
    ]
    bins = np.asarray(jax.jit(_bins._orientation_bin, static_argnums=1)(both, 8))
    counts = np.bincount(bins[:n], minlength=48)
    assert counts.size == 48  # every bin in [0, 48)
    assert np.all(np.abs(counts - n / 48) < 5.5 * np.sqrt(n / 48))  # equal measure (binomial, 5.5 sd)
    np.testing.assert_array_equal(bins[n:], 32 + np.arange(8))  # distinct planar angles, distinct bins


def test_map_matches_numpy_on_the_same_samples():
    lengths, chunk, n = (1.0, 0.5), 3000, 20_000  # 7 chunks, the last one partial
    chain = dk.robots.planar(list(lengths))
    bounds = [[-1.0, -1.6, -0.05], [1.6, 1.6, 0.05]]  # cuts the annulus: some samples outside
    m = ws.reachability(chain, n, key=KEY, voxel_size=0.1, bounds=bounds, chunk=chunk)
    q = np.concatenate([np.asarray(ws.sample_configs(chain, chunk, jax.random.fold_in(KEY, c))) for c in range(7)])[:n]
    counts, best, dexterity, outside = _planar_reference(lengths, q, m.origin, 0.1, m.counts.shape, 8)
    assert m.counts.shape == (26, 32, 1) and m.n_samples == n
    np.testing.assert_array_equal(m.counts, counts)
    assert m.n_outside == outside > 0 and m.counts.sum() + m.n_outside == n
    np.testing.assert_allclose(m.manipulability, best, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(m.dexterity, dexterity)


def _radii(m):
    """Nearest and farthest distance from the base z axis of each voxel column of a map, (nx, ny)."""
    edges = [m.origin[i] + m.voxel_size * np.arange(m.counts.shape[i] + 1) for i in range(2)]
    lo, hi = (
        np.meshgrid(edges[0][:-1], edges[1][:-1], indexing="ij"),
        np.meshgrid(edges[0][1:], edges[1][1:], indexing="ij"),
    )
    near = [np.where(a > 0, a, np.where(b < 0, -b, 0.0)) for a, b in zip(lo, hi, strict=True)]
    far = [np.maximum(np.abs(a), np.abs(b)) for a, b in zip(lo, hi, strict=True)]
    return np.hypot(*near), np.hypot(*far)


def test_planar_2r_fills_the_textbook_annulus():
    a1, a2, h = 1.0, 0.4, 0.1
    m = ws.reachability(
        dk.robots.planar([a1, a2]),
        200_000,
        key=KEY,
        voxel_size=h,
        bounds=[[-1.5, -1.5, -h / 2], [1.5, 1.5, h / 2]],
        chunk=1 << 14,
    )
    occupied = m.counts[:, :, 0] > 0
    near, far = _radii(m)
    eps = 1e-9  # rounding of the FK only
    meets = (far >= a1 - a2 - eps) & (near <= a1 + a2 + eps)  # voxel meets |a1 - a2| <= r <= a1 + a2
    within = (near >= a1 - a2) & (far <= a1 + a2)  # voxel inside the annulus: >= 40 samples expected
    assert np.all(meets[occupied]) and np.all(occupied[within])
    assert within.sum() > 300 and m.n_outside == 0


def test_folded_arm_reaches_every_planar_orientation_at_the_origin():
    m = ws.reachability(dk.robots.planar([0.5, 0.5]), 100_000, key=KEY, voxel_size=0.1, chunk=1 << 14)
    assert m.counts.shape == (21, 21, 21)  # default bounds: reach 1 m, the base origin at voxel (10, 10, 10)
    near, _ = _radii(m)
    rim = (near >= 0.9) & (m.counts[:, :, 10] > 0)
    assert m.dexterity[10, 10, 10] == 8  # every planar bin (6 faces x 8 roll sectors; planar: face +z only)
    assert rim.sum() > 20 and m.dexterity[:, :, 10][rim].max() <= 3  # elbow within 52 degrees of straight


def test_samples_from_an_independent_stream_land_in_occupied_voxels():
    chain = dk.robots.iiwa14()
    m = ws.reachability(chain, 300_000, key=KEY, voxel_size=0.2, chunk=1 << 15)
    assert m.counts.sum() == 300_000 and m.n_outside == 0  # the default box holds the whole reach
    positions = jax.jit(lambda key: dk.fk(chain, ws.sample_configs(chain, 20_000, key))[:, :3, 3])
    p = np.asarray(positions(jax.random.key(123)))
    cell = np.floor((p - m.origin) / m.voxel_size).astype(int)
    hit = m.counts[tuple(cell.T)] > 0
    assert hit.mean() >= 0.999  # only voxels of tiny reachable volume can be missed by 300k samples
    assert np.all(m.manipulability[m.counts > 0] > 0) and m.dexterity.max() > 24


def test_compiled_once_per_chain_grid_and_chunk():
    ws._compiled.cache_clear()
    kwargs = dict(voxel_size=0.25, chunk=512)
    ws.reachability(dk.robots.planar([1.0, 0.5]), 1000, key=KEY, **kwargs)
    ws.reachability(dk.robots.planar([1.0, 0.5]), 5000, key=jax.random.key(1), **kwargs)  # equal chain, new n
    assert (ws._compiled.cache_info().hits, ws._compiled.cache_info().misses) == (1, 1)
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("devices",))
    _, step, _ = ws._compiled(
        partition(dk.robots.planar([1.0, 0.5]))[0], (13, 13, 13), 48, 512, jnp.dtype(jnp.float64), mesh, None
    )
    assert step._cache_size() == 1  # 2 + 10 steps, one compilation


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(n_samples=0), ValueError, "n_samples"),
        (dict(n_samples=1.5), TypeError, "n_samples"),
        (dict(voxel_size=0.0), ValueError, "voxel_size"),
        (dict(voxel_size=float("nan")), ValueError, "voxel_size"),
        (dict(voxel_size="1"), TypeError, "voxel_size"),
        (dict(bounds=[[0, 0, 0], [1, 1]]), ValueError, "bounds"),
        (dict(bounds=[[0, 0, 0], [1, -1, 1]]), ValueError, "bounds"),
        (dict(chunk=0), ValueError, "chunk"),
        (dict(orientation_bins=50), ValueError, "orientation_bins"),
        (dict(devices=[]), TypeError, "devices"),
        (dict(voxel_size=1e-4), ValueError, "voxel_size"),
    ],
)
def test_bad_arguments_raise(kwargs, error, match):
    args = dict(n_samples=100, key=KEY, voxel_size=0.1) | kwargs
    with pytest.raises(error, match=match):
        ws.reachability(dk.robots.planar([1.0, 0.5]), args.pop("n_samples"), **args)


def test_bad_chain_and_unbounded_prismatic_joint():
    with pytest.raises(TypeError, match="chain"):
        ws.sample_configs("iiwa", 10, KEY)
    slider = dk.DHChain.from_table([[0.0, 0.0, 0.0, 0.0]], "P")
    with pytest.raises(ValueError, match=r"lower/upper\[0\]"):
        ws.sample_configs(slider, 10, KEY)


# ----- issue 18: resource limits, load errors, device-count determinism -----


def test_chunk_is_capped_and_fine_grids_are_refused(monkeypatch):
    chain = dk.robots.planar([1.0, 0.5])
    # chunk=10**8 for 512 samples: the chunk is capped (it would take ~12 GB and minutes otherwise), to
    # 512: the program of test_compiled_once_per_chain_grid_and_chunk, compiled once for the file.
    m = ws.reachability(chain, 512, key=KEY, voxel_size=0.25, chunk=10**8)
    assert m.counts.sum() + m.n_outside == 512
    with pytest.raises(ValueError, match=r"^voxel_size: 0.008 m gives a grid .* GiB of maps"):
        ws.reachability(dk.robots.ur5(), 1000, key=KEY, voxel_size=0.008)
    monkeypatch.setattr(ws, "MAX_GRID_BYTES", 1000)
    with pytest.raises(ValueError, match=r"^voxel_size: "):
        ws.reachability(chain, 1000, key=KEY, voxel_size=0.25)
    with pytest.raises(ValueError, match=r"^n_samples: expected at most"):
        ws.reachability(chain, 10**20, key=KEY, voxel_size=0.25)


def test_load_errors_name_the_file_and_the_problem(tmp_path):
    m = ws.reachability(dk.robots.planar([1.0, 0.5]), 512, key=KEY, voxel_size=0.25, chunk=512)  # compiled above
    m.save(tmp_path / "map")  # numpy writes map.npz ...
    back = ws.ReachabilityMap.load(tmp_path / "map")  # ... and load finds it by the same name
    np.testing.assert_array_equal(back.counts, m.counts)
    (tmp_path / "empty.npz").write_bytes(b"")
    whole = (tmp_path / "map.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(whole[: len(whole) // 2])
    np.savez(tmp_path / "partial.npz", counts=m.counts, origin=m.origin)
    np.save(tmp_path / "array.npy", m.counts)
    cases = [
        ("empty.npz", "could not read it"),
        ("cut.npz", "could not read it"),
        ("partial.npz", "missing field.*manipulability"),
        ("array.npy", "got a single array"),
    ]
    for name, what in cases:
        with pytest.raises(ValueError, match=rf"{name}: .*{what}"):
            ws.ReachabilityMap.load(tmp_path / name)
    with pytest.raises(FileNotFoundError):
        ws.ReachabilityMap.load(tmp_path / "nothing.npz")


def test_voxel_and_sector_indices_do_not_depend_on_the_compilation():
    """Positions on and next to voxel faces, roll angles next to sector edges: the same bins whether the
    binning is compiled alone or fused after other arithmetic (the cause of maps that differed with the
    number of devices: XLA's CPU division rounds differently in different compilations), and the voxel
    cell is IEEE ``floor((p - origin) * (1 / voxel_size))``, as numpy computes it."""
    dtype = np.float32
    origin, inv, shape = np.array([-1.75, -1.75, -1.75], dtype), dtype(1 / 0.1), (35, 35, 35)
    faces = (origin[0] + np.arange(36) * 0.1).astype(dtype)
    x = np.concatenate(
        [
            faces,
            np.nextafter(faces, np.inf),
            np.nextafter(faces, -np.inf),
            [0.85, 0.85000004],
            [np.nan, np.inf, -np.inf],
        ]
    ).astype(dtype)
    P = [jnp.asarray(x), jnp.zeros_like(x), jnp.zeros_like(x)]
    alone = jax.jit(lambda P: _bins._flat_index(P, origin, inv, shape))
    fused = jax.jit(lambda P, s: _bins._flat_index([P[0] * s + 0.0 * P[1], P[1], P[2]], origin, inv, shape))
    (flat_a, in_a), (flat_f, in_f) = alone(P), fused(P, jnp.ones(x.shape, dtype))
    np.testing.assert_array_equal(np.asarray(flat_a), np.asarray(flat_f))
    np.testing.assert_array_equal(np.asarray(in_a), np.asarray(in_f))
    with np.errstate(invalid="ignore"):
        cell = np.floor((x - origin[0]) * inv)  # float32 IEEE, no division
    ok = (cell >= 0) & (cell < 35)
    np.testing.assert_array_equal(np.asarray(in_a), ok)
    np.testing.assert_array_equal(np.asarray(flat_a)[ok] // (35 * 35), cell[ok].astype(int))
    # Roll sectors next to their edges: the same alone and fused; away from the edges, the exact sector.
    n_roll = 8
    edges = -np.pi + 2 * np.pi * np.arange(n_roll + 1) / n_roll
    phi = np.concatenate([edges + d for d in (-1e-7, -3e-8, 0.0, 3e-8, 1e-7, 0.2, -0.2)])
    phi = phi[(phi > -np.pi) & (phi < np.pi)]
    c, s = np.cos(phi).astype(dtype), np.sin(phi).astype(dtype)
    z, one = np.zeros_like(c), np.ones_like(c)
    R = tuple(tuple(jnp.asarray(v) for v in row) for row in ((c, -s, z), (s, c, z), (z, z, one)))
    bins_a = np.asarray(jax.jit(lambda R: _bins._orientation_bin(R, n_roll))(R))
    bins_f = np.asarray(
        jax.jit(lambda R, k: _bins._orientation_bin(tuple(tuple(v * k for v in row) for row in R), n_roll))(
            R, jnp.ones_like(R[0][0])
        )
    )
    np.testing.assert_array_equal(bins_a, bins_f)
    far = np.abs(phi[:, None] - edges[None, :]).min(axis=1) > 1e-3
    expected = np.floor((np.arctan2(s, c).astype(np.float64) + np.pi) / (2 * np.pi / n_roll)).astype(int)
    np.testing.assert_array_equal(bins_a[far] - 4 * n_roll, expected[far])


def test_voxel_size_defaults_to_the_clis():
    m = ws.reachability(dk.robots.planar([0.3, 0.2]), 1000, key=KEY, chunk=1000)
    assert m.voxel_size == 0.05


def test_a_frame_of_a_whole_robot():
    """``(robot, frame_name)``: the map of the path's chain; ``sample_configs`` of a robot samples its q."""
    robot = dk.load_robot(os.path.join(DATA, "panda.urdf"))
    chain = robot.chain("panda_hand_tcp")
    of_robot = ws.reachability((robot, "panda_hand_tcp"), 2000, key=KEY, voxel_size=0.2, chunk=1000)
    of_chain = ws.reachability(chain, 2000, key=KEY, voxel_size=0.2, chunk=1000)
    np.testing.assert_array_equal(of_robot.counts, of_chain.counts)
    assert of_robot.counts.sum() == 2000
    q = ws.sample_configs(robot, 100, KEY)
    assert q.shape == (100, robot.dof)
    assert np.all((q >= robot.lower) & (q <= robot.upper))
    with pytest.raises(TypeError, match=r"chain: expected a DHChain, PoEChain or \(Robot, frame_name\)"):
        ws.reachability(robot, 10, key=KEY)
