"""Capability maps and base placement against brute force: a planar 3R arm (links 0.4, 0.3, 0.2 m,
unlimited joints), whose poses ``(x, y, phi)`` are reachable exactly when the wrist point ``p - 0.2 (cos
phi, sin phi)`` lies 0.1 to 0.7 m from the base, and IK (``dk.ik.solve``) from every base of a small grid
(across device counts, the CLI and a Panda: ``tests/integration/test_capability_integration.py``)."""

import jax
import numpy as np
import pytest

import diffkin as dk
from diffkin import workspace as ws
from diffkin.workspace import _placement
from diffkin.workspace._cells import STEPS, neighbour_bins, pose_halves, split_bin
from diffkin.workspace._placement import planar_poses

KEY = jax.random.key(3)
LINKS = [0.4, 0.3, 0.2]
VOXEL, BINS = 0.05, 5184  # 5 cm voxels, 15 degree orientation cells (d = 6)
BOUNDS = [[-1.0, -1.0, -VOXEL / 2], [1.0, 1.0, VOXEL / 2]]  # the arm's plane: one layer


@pytest.fixture(scope="module")
def chain():
    return dk.robots.planar(LINKS)


@pytest.fixture(scope="module")
def cap(chain):
    return ws.capability(chain, 200_000, key=KEY, voxel_size=VOXEL, orientation_bins=BINS, bounds=BOUNDS)


def _exact(T):
    """Whether the planar 3R arm reaches planar poses ``T (..., 4, 4)`` (base frame): its closed form."""
    phi = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    wrist = T[..., :2, 3] - LINKS[2] * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    r = np.linalg.norm(wrist, axis=-1)
    return (r >= LINKS[0] - LINKS[1]) & (r <= LINKS[0] + LINKS[1])


def _precision_recall(said, truth):
    hit = (said & truth).sum()
    return hit / said.sum(), hit / truth.sum()


def _random_rotations(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    ).transpose(2, 0, 1)


def test_orientation_bins_are_even_and_within_the_stated_error():
    """``24 d^3`` bins of equal-angle direction cells x roll sectors: every bin hit, each bin's centre in
    its own bin, and every rotation within the docstring's worst error (16.1 degrees for d = 6) of its
    bin's centre."""
    n = 60_000
    R = _random_rotations(n)
    T = np.zeros((n, 4, 4))
    T[:, :3, :3], T[:, 3, 3] = R, 1.0
    centres = ws.bin_rotations(BINS)
    C = np.zeros((BINS, 4, 4))
    C[:, :3, :3], C[:, 3, 3] = centres, 1.0
    _, b, _, _ = pose_halves(np.concatenate([T, C]), 6, 24, np.zeros(3), 1.0, np.full(3, 1e9))
    b = np.asarray(b)
    np.testing.assert_array_equal(b[n:], np.arange(BINS))
    counts = np.bincount(b[:n], minlength=BINS)  # 11.6 a bin on average, the corners' cells smaller
    assert counts.size == BINS and np.count_nonzero(counts) > 0.99 * BINS and counts.max() < 40
    rel = np.einsum("nji,njk->nik", centres[b[:n]], R)
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert 13.0 < angle.max() <= 16.1


def test_cells_are_the_samples_cells_and_counts_match_reachability(chain, cap):
    """The map's sparse cells are its samples' cells (looked up on the host from their FK), and its voxel
    counts and manipulability are the reachability map's of the same samples."""
    chunk = 1 << 16
    q = np.concatenate([np.asarray(ws.sample_configs(chain, chunk, jax.random.fold_in(KEY, c))) for c in range(4)])
    T = np.asarray(dk.fk(chain, q[:200_000]))
    cell, b, inside, _ = (np.asarray(a) for a in pose_halves(T, 6, 24, cap.origin, 1 / VOXEL, np.asarray(cap.shape)))
    flat = np.ravel_multi_index(tuple(cell[inside].T), cap.shape) * BINS + b[inside]
    cells, counts = np.unique(flat, return_counts=True)
    np.testing.assert_array_equal(cap.cells, cells)
    np.testing.assert_array_equal(cap.cell_counts, counts)
    reach = ws.reachability(chain, 200_000, key=KEY, voxel_size=VOXEL, bounds=BOUNDS, orientation_bins=48)
    np.testing.assert_array_equal(cap.counts, reach.counts)
    np.testing.assert_array_equal(cap.manipulability, reach.manipulability)
    assert cap.n_outside == reach.n_outside == 0 and cap.cell_counts.sum() == 200_000
    assert np.all(cap.count(T[:500]) >= 1) and cap.dexterity().max() == 24  # every planar roll sector


def test_precision_and_recall_against_the_closed_form(cap):
    """Uniform planar poses over the 2 m square: at 5 cm / 15 degrees the map's look-up, judged at the pose
    (its edge in the middle of the outermost cells), has precision 0.97 and recall 0.985; its cells alone
    (``count >= 1``, the edge on their outer faces) precision 0.89, recall 1."""
    rng = np.random.default_rng(1)
    n = 40_000
    xy, phi = rng.uniform(-1, 1, (n, 2)), rng.uniform(-np.pi, np.pi, n)
    T = planar_poses(xy[:, 0], xy[:, 1], phi, 0.0)
    precision, recall = _precision_recall(cap.reaches(T), _exact(T))
    assert precision >= 0.96 and recall >= 0.98, (precision, recall)
    cells, _ = _precision_recall(cap.count(T) >= 1, _exact(T))
    assert cells < 0.9 < precision
    strict, _ = _precision_recall(cap.reaches(T, min_count=8), _exact(T))
    assert strict > precision  # a higher count trades recall for precision


def _line_map(held_x, bins=24):
    """A map of one orientation bin (bin 0) held at voxels ``(x, 1, 1)`` for ``x`` in ``held_x`` of a
    ``12 x 3 x 3`` grid of 1 m voxels from the origin (4 samples each)."""
    cells = np.sort(np.ravel_multi_index((np.asarray(held_x), 1, 1), (12, 3, 3)) * bins)
    return ws.CapabilityMap(
        cells=cells,
        cell_counts=np.full(cells.size, 4),
        counts=np.zeros((12, 3, 3), np.int64),
        manipulability=np.zeros((12, 3, 3)),
        origin=np.zeros(3),
        voxel_size=1.0,
        n_samples=4 * cells.size,
        n_outside=0,
        orientation_bins=bins,
    )


def test_reaches_moves_the_edge_to_the_middle_of_the_outermost_cells():
    """Along a line of held voxels (one cell thin along y, z and the orientation: not cut there) a pose of
    an end voxel is reached in the half toward the line, not in the other; a voxel between two held ones
    (unsampled) is reached; a line two voxels long is not cut; ``at_pose=False`` is the cell alone."""
    cap = _line_map([1, 2, 3, 5, 6, 7, 10, 11])
    x = np.array([1.25, 1.75, 3.75, 4.5, 6.25, 7.75, 8.5, 10.25, 11.75])
    T = np.tile(np.eye(4), (x.size, 1, 1))
    T[:, :3, :3], T[:, 0, 3], T[:, 1:3, 3] = ws.bin_rotations(24)[0], x, 1.5
    # 1.25, 7.75: the line's ends; 3.75: a hole (4) and 5 held beyond; 4.5: the hole; 8.5: 9 is empty too.
    np.testing.assert_array_equal(cap.reaches(T), [False, True, True, True, True, False, False, True, True])
    held = [True, True, True, False, True, True, False, True, True]
    np.testing.assert_array_equal(cap.count(T) > 0, held)
    np.testing.assert_array_equal(cap.reaches(T, at_pose=False), held)


def test_neighbour_bins_step_along_the_face_and_across_its_edges():
    """Within a cube face the neighbours are the index steps (the roll's wrap around); across a face's
    edge a step is a bin of another face whose centre is about a cell (12-20 degrees) away."""
    n_dir, n_roll = 6, 24
    near = neighbour_bins(n_dir, n_roll)
    face, i_u, i_v, sector = split_bin(np.arange(BINS), n_dir, n_roll)
    for k, step in enumerate(STEPS):
        inside = (i_u + step >= 0) & (i_u + step < n_dir)
        expected = ((face * n_dir + i_u + step) * n_dir + i_v) * n_roll + sector
        np.testing.assert_array_equal(near[inside, 0, k], expected[inside])
        rolled = ((face * n_dir + i_u) * n_dir + i_v) * n_roll + (sector + step) % n_roll
        np.testing.assert_array_equal(near[:, 2, k], rolled)
    centres = ws.bin_rotations(BINS)
    for axis, index in ((0, i_u), (1, i_v)):
        for k, end in ((1, 0), (2, n_dir - 1)):  # one step down from the first cell, up from the last
            edge = index == end
            across = near[edge, axis, k]
            assert np.all(split_bin(across, n_dir, n_roll)[0] != face[edge])
            rel = np.einsum("nji,njk->nik", centres[edge], centres[across])
            angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
            assert 12.0 < angle.min() and angle.max() < 20.0


def test_base_placement_against_ik_from_every_base(chain, cap):
    """For a 4 x 4 x 4 grid of bases and 8 tasks, IK (``verify`` over every base) decides which tasks each
    base reaches: the map's precision and recall against it, the scores as the map's look-ups, and IK
    agreeing with the closed form."""
    rng = np.random.default_rng(0)
    xy, phi = rng.uniform(-0.3, 0.3, (8, 2)), rng.uniform(-np.pi, np.pi, 8)
    tasks = planar_poses(xy[:, 0], xy[:, 1], phi, 0.0)
    placement = ws.base_placement(cap, tasks, region=[[-0.8, -0.8], [0.8, 0.8]], yaw_bins=4, cell=0.4)
    assert placement.score.shape == (4, 4, 4)
    np.testing.assert_allclose(placement.x, [-0.6, -0.2, 0.2, 0.6])
    np.testing.assert_allclose(placement.yaw, [0, np.pi / 2, np.pi, 3 * np.pi / 2])
    check = placement.verify(chain, k=64, key=KEY, num_seeds=8)  # every base: the brute force
    in_base = np.linalg.inv(check.bases)[:, None] @ tasks
    said = cap.reaches(in_base)
    np.testing.assert_allclose(check.score, said.mean(axis=1), atol=1e-6)  # the placement is the look-up
    np.testing.assert_array_equal(check.success, _exact(in_base))  # IK is exact here
    precision, recall = _precision_recall(said, check.success)
    assert precision >= 0.95 and recall >= 0.95, (precision, recall)
    assert np.all(np.diff(check.score) <= 0) and check.score[0] == placement.score.max()
    np.testing.assert_allclose(placement.best(3), check.bases[:3])
    assert check.verified[0] >= 0.95 * check.success.mean(axis=1).max()  # the top base is (nearly) the best


@pytest.mark.parametrize("min_count, at_pose", [(1, True), (3, True), (3, False)])
def test_placement_scores_are_reaches_averaged_in_any_task_groups(cap, monkeypatch, min_count, at_pose):
    """Every base's score is the mean of ``reaches`` over the tasks in its frame (with ``min_count`` and
    ``at_pose``), whether the look-ups take the tasks all at once or in groups of 3 (the last padded)."""
    rng = np.random.default_rng(1)
    xy, phi = rng.uniform(-0.4, 0.4, (8, 2)), rng.uniform(-np.pi, np.pi, 8)
    tasks = planar_poses(xy[:, 0], xy[:, 1], phi, 0.0)
    kwargs = dict(region=[[-0.6, -0.6], [0.6, 0.6]], yaw_bins=3, cell=0.3, min_count=min_count, at_pose=at_pose)
    whole = ws.base_placement(cap, tasks, **kwargs)
    assert _placement._task_groups(8, 16) == (1, 8)
    monkeypatch.setattr(_placement, "LOOK_UPS_PER_GROUP", 3 * 16)  # 16 bases: 3 groups of 3 tasks
    assert _placement._task_groups(8, 16) == (3, 3)
    np.testing.assert_array_equal(ws.base_placement(cap, tasks, **kwargs).score, whole.score)
    i, j, k = np.meshgrid(*map(np.arange, whole.score.shape), indexing="ij")
    in_base = np.linalg.inv(whole.base(i, j, k))[..., None, :, :] @ tasks
    said = cap.reaches(in_base, min_count=min_count, at_pose=at_pose)
    np.testing.assert_allclose(whole.score, said.mean(axis=-1), atol=1e-6)
    assert 0 < whole.score.max() and whole.score.min() < 1


def test_save_load_round_trip_and_errors(cap, tmp_path):
    cap.save(tmp_path / "cap")
    back = ws.CapabilityMap.load(tmp_path / "cap")
    for field in ("cells", "cell_counts", "counts", "manipulability", "origin"):
        np.testing.assert_array_equal(getattr(back, field), getattr(cap, field))
    assert (back.voxel_size, back.n_samples, back.orientation_bins) == (VOXEL, 200_000, BINS)
    np.savez(tmp_path / "partial.npz", counts=cap.counts)
    with pytest.raises(ValueError, match=r"partial.npz: not a complete capability map, missing field.*cells"):
        ws.CapabilityMap.load(tmp_path / "partial.npz")
    with pytest.raises(ValueError, match="could not read it"):
        (tmp_path / "empty.npz").write_bytes(b"")
        ws.CapabilityMap.load(tmp_path / "empty.npz")


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(orientation_bins=48), ValueError, "orientation_bins: expected 24 d"),
        (dict(orientation_bins=24.0), TypeError, "orientation_bins"),
        (dict(voxel_size=-1.0), ValueError, "voxel_size"),
        (dict(n_samples=0), ValueError, "n_samples"),
        (dict(bounds=[[0, 0, 0], [1, 1]]), ValueError, "bounds"),
    ],
)
def test_bad_capability_arguments_raise(chain, kwargs, error, match):
    args = dict(n_samples=100, key=KEY, voxel_size=0.1) | kwargs
    with pytest.raises(error, match=match):
        ws.capability(chain, args.pop("n_samples"), **args)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(tasks=np.eye(4)), ValueError, r"tasks: expected \(N, 4, 4\)"),
        (dict(tasks=np.full((1, 4, 4), np.nan)), ValueError, "tasks: expected finite"),
        (dict(region=[[0, 0], [-1, 1]]), ValueError, "region"),
        (dict(region=[0, 1]), ValueError, "region"),
        (dict(yaw_bins=0), ValueError, "yaw_bins"),
        (dict(cell=0.0), ValueError, "cell"),
        (dict(base_height="0"), TypeError, "base_height"),
        (dict(min_count=0), ValueError, "min_count"),
        (dict(at_pose=1), TypeError, "at_pose"),
        (dict(cap="map"), TypeError, "cap: expected a CapabilityMap"),
    ],
)
def test_bad_placement_arguments_raise(cap, kwargs, error, match):
    args = dict(cap=cap, tasks=np.eye(4)[None], region=[[-1, -1], [1, 1]]) | kwargs
    with pytest.raises(error, match=match):
        ws.base_placement(args.pop("cap"), args.pop("tasks"), **args)


def test_look_ups_of_bad_poses_and_outside_the_grid(cap):
    with pytest.raises(ValueError, match=r"T: expected poses of shape \(\.\.\., 4, 4\)"):
        cap.reaches(np.eye(3))
    far = planar_poses([5.0, 0.5], [0.0, 0.0], [0.0, 0.0], 0.0)
    np.testing.assert_array_equal(cap.reaches(far), [False, True])
    with pytest.raises(TypeError, match="at_pose: expected a bool"):
        cap.reaches(far, at_pose="no")
    with pytest.raises(ValueError, match="min_count"):
        cap.reaches(far, min_count=0)
    assert cap.reaches(np.zeros((0, 4, 4))).shape == (0,)


def test_cell_counter_merges_batches_into_sorted_counts():
    """The host's counting of a capability map's cells: batches merged (into cells already held and new
    ones, the sentinel of uncounted samples dropped) give ``np.unique``'s cells and counts."""
    from diffkin.workspace._driver import _CellCounter

    rng = np.random.default_rng(0)
    counter, batches = _CellCounter(sentinel=1000), []
    for i in range(6):
        batch = rng.integers(0, 1001 if i % 2 else 300, 500).astype(np.int32)  # overlapping and new cells
        batches.append(batch[batch != 1000])
        counter.add(batch)
        counter.merge()
    cells, counts = np.unique(np.concatenate(batches), return_counts=True)
    np.testing.assert_array_equal(counter.cells, cells)
    np.testing.assert_array_equal(counter.counts, counts)


@pytest.mark.parametrize("huge_counts", [False, True])
def test_layers_are_the_cells_ordered_by_bin_and_layer(cap, huge_counts):
    """``CapabilityMap.layers`` (one packed sort; counts too large to pack: a stable argsort) against the
    stable argsort of the cells by ``(bin, z layer)``."""
    import dataclasses

    counts = cap.cell_counts << 40 if huge_counts else cap.cell_counts
    m = dataclasses.replace(cap, cell_counts=counts)
    voxel, b = np.divmod(m.cells, BINS)
    ij, k = np.divmod(voxel, m.shape[2])
    layer = b * m.shape[2] + k
    order = np.argsort(layer, kind="stable")
    for got, expected in zip(m.layers, (layer[order], ij[order], counts[order]), strict=True):
        np.testing.assert_array_equal(got, expected)
