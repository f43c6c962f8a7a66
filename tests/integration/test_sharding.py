"""FK and IK on inputs sharded over several devices give the results of one device (4 host CPU devices)."""

import json
import os
import subprocess
import sys
import textwrap

from _paths import DATA

FINGER = os.path.join(DATA, "example-robot-data", "robots", "finger_edu_description", "robots", "finger_edu.urdf")

SCRIPT = """
    import json, sys, jax, numpy as np
    from jax.sharding import AxisType, Mesh, NamedSharding, PartitionSpec as P
    jax.config.update("jax_enable_x64", True)
    import diffkin as dk

    chain = dk.robots.iiwa14()
    FINGER = sys.argv[1]  # a URDF path, from the test
    devices = jax.devices()
    sharded = NamedSharding(Mesh(np.array(devices), ("batch",)), P("batch"))  # automatic axes: jit partitions
    one = devices[0]
    rng = np.random.default_rng(3)
    q = rng.uniform(chain.lower, chain.upper, (64, 7))
    fk = jax.jit(lambda q: dk.fk(chain, q))
    T1, T4 = fk(jax.device_put(q, one)), fk(jax.device_put(q, sharded))

    targets = np.asarray(T1[:8])
    solve = jax.jit(lambda T, key: dk.ik.solve(chain, T, key=key))
    key = jax.random.key(5)
    r1, r4 = solve(jax.device_put(targets, one), key), solve(jax.device_put(targets, sharded), key)
    # A mesh with explicit axes (jax.make_mesh's default): the IK runs with them automatic.
    explicit = NamedSharding(jax.make_mesh((4,), ("batch",), axis_types=(AxisType.Explicit,)), P("batch"))
    Tx = jax.device_put(targets, explicit)
    rx = [dk.ik.solve(chain, Tx, key=key), solve(Tx, key)]  # a direct call and one inside a user's jit
    robot = dk.load_robot(FINGER)
    p = np.asarray(dk.fk(robot, rng.uniform(robot.lower, robot.upper, (8, 3)), "finger_tip_link"))[:, :3, 3]
    rr1 = dk.ik.solve(robot, {"finger_tip_link": p}, key=key)
    rrx = dk.ik.solve(robot, {"finger_tip_link": jax.device_put(p, explicit)}, key=key)
    print(json.dumps(dict(
        explicit_specs=[list(r.q.sharding.spec) for r in rx + [rrx]],
        explicit_devices=[len(r.q.sharding.device_set) for r in rx + [rrx]],
        explicit_q_diff=float(max(np.abs(np.asarray(r.q) - np.asarray(r1.q)).max() for r in rx)),
        explicit_robot_q_diff=float(np.abs(np.asarray(rrx.q) - np.asarray(rr1.q)).max()),
        explicit_success=[bool(np.all(r.success)) for r in rx + [rr1, rrx]],
        n_devices=len(devices),
        fk_devices=len(T4.sharding.device_set),
        ik_devices=len(r4.q.sharding.device_set),
        fk_diff=float(np.abs(np.asarray(T1) - np.asarray(T4)).max()),
        ik_q_diff=float(np.abs(np.asarray(r1.q) - np.asarray(r4.q)).max()),
        ik_err_diff=float(max(np.abs(np.asarray(r1.pos_err) - np.asarray(r4.pos_err)).max(),
                              np.abs(np.asarray(r1.rot_err) - np.asarray(r4.rot_err)).max())),
        success=[bool(np.all(r1.success)), bool(np.all(r4.success))],
    )))
"""


def test_fk_and_ik_sharded_over_4_devices_match_one_device():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(SCRIPT), FINGER],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert (r["n_devices"], r["fk_devices"], r["ik_devices"]) == (4, 4, 4)
    assert r["fk_diff"] < 1e-14
    assert r["success"] == [True, True]
    # The same solutions in float64: only the last bits may differ between the two compiled programs.
    assert r["ik_q_diff"] < 1e-10 and r["ik_err_diff"] < 1e-12, r
    # Explicit axes: sharded over the 4 devices like the targets, the same solutions as one device.
    assert r["explicit_specs"] == [["batch", None]] * 3 and r["explicit_devices"] == [4, 4, 4]
    assert r["explicit_success"] == [True] * 4
    assert r["explicit_q_diff"] < 1e-10 and r["explicit_robot_q_diff"] < 1e-10, r
