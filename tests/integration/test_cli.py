"""The ``diffkin`` command line, run in-process through ``diffkin.cli.main`` (and once as ``python -m diffkin``).

The IK, self-motion and reachability tests reuse the shapes of the quick demo, so each jitted
function compiles once per session.
"""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from _paths import DATA, INTERRUPTIBLE
from _reference import dh_fk, pose, pose_errors
from _shapes import BOX_CENTER, SCENE, SCENE_FILE
from _shapes import CAPSULE_ARM as ARM

import diffkin as dk
from diffkin import cli
from diffkin._cache import cache_dir

FINGER = os.path.join(DATA, "example-robot-data", "robots", "finger_edu_description", "robots", "finger_edu.urdf")
TARGET = pose(np.diag([1.0, -1.0, -1.0]), [0.5, 0.1, 0.6])  # --pose 0.5 0.1 0.6 0 1 0 0: a half-turn about x


def run(capsys, *argv):
    """``(exit status, stdout, stderr)`` of ``diffkin ARGV``."""
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_user_error(capsys, *argv, match=""):
    code, out, err = run(capsys, *argv)
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("diffkin: error: "), err
    assert "Traceback" not in err
    assert match in lines[0], lines[0]
    return lines[0]


@pytest.mark.slow
def test_help_subprocess():
    res = subprocess.run([sys.executable, "-m", "diffkin", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    for command in ("demo", "info", "fk", "ik", "workspace", "view"):
        assert command in res.stdout


def test_the_cli_names_the_built_in_robots():
    """The CLI keeps its own list (its --help imports no JAX): the same as dk.robots.BUILTIN."""
    from diffkin.cli import _robots

    assert _robots.ROBOTS == dk.robots.BUILTIN


def test_version_has_one_source(capsys):
    """pyproject.toml reads the version from ``diffkin.__version__``, and ``diffkin --version`` prints it."""
    import tomllib

    with open(os.path.join(os.path.dirname(DATA), "..", "pyproject.toml"), "rb") as fh:
        meta = tomllib.load(fh)
    assert "version" not in meta["project"] and meta["project"]["dynamic"] == ["version"]
    assert meta["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "diffkin.__version__"}
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.strip() == f"diffkin {dk.__version__}" and re.fullmatch(r"\d+\.\d+\.\d+", dk.__version__)


@pytest.mark.parametrize("command", ["demo", "info", "fk", "ik", "workspace", "view"])
def test_subcommand_help(capsys, command):
    code, out, _ = run(capsys, command, "--help")
    assert code == 0 and "usage: diffkin " + command in out


@pytest.mark.slow
def test_demo_quick(capsys, tmp_path):
    code, out, err = run(capsys, "demo", "--quick", "--out", tmp_path / "demo")
    assert code == 0, err
    assert "FK check" in out and ": OK" in out
    assert re.search(r"IK .* success \d+\.\d% \(\d+/50\)", out)
    assert "valid samples" in out and "psi in [" in out
    # warm timings say what they are: medians of several calls (a single call read 60 ms where the median is 3 ms)
    assert len(re.findall(r"ms warm, median of 7 calls", out)) == 2, out
    assert "s (one run: " in out and "reached in" in out and ", one run (compile" in out
    for name in ("reachability_count_y0.png", "reachability_manipulability_y0.png", "self_motion.png"):
        path = tmp_path / "demo" / name
        assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str((tmp_path / "demo").resolve()) in out.strip().splitlines()[-1]


def test_info(capsys):
    code, out, _ = run(capsys, "info", "iiwa14")
    assert code == 0
    assert "DHChain, standard DH, 7 joints" in out and "iiwa14_joint_7" in out and "-170.0 .. +170.0 deg" in out
    assert "home pose (q = 0): position [ 0  0  1.306]" in out
    code, out, _ = run(capsys, "info", os.path.join(DATA, "ur5.urdf"), "--end-link", "tool0")
    assert code == 0 and "PoEChain" in out and "screw table" in out and "6 joints" in out


def test_fk_text_json_npy(capsys, tmp_path):
    chain = dk.robots.iiwa14()
    q = [0.1, -0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    T = np.asarray(dk.fk(chain, np.asarray(q)))
    code, out, _ = run(capsys, "fk", "iiwa14", *q)
    assert code == 0 and f"{T[0, 3]:.6f}"[:7] in out and "quaternion" in out
    code, out, _ = run(capsys, "fk", "iiwa14", *q, "--format", "json")
    doc = json.loads(out)
    np.testing.assert_allclose(doc["poses"][0]["T"], T, atol=1e-12)
    qs = np.random.default_rng(0).uniform(chain.lower, chain.upper, (4, 7))
    np.save(tmp_path / "q.npy", qs)
    code, out, _ = run(
        capsys, "fk", "iiwa14", "--q-file", tmp_path / "q.npy", "--format", "npy", "--output", tmp_path / "T.npy"
    )
    assert code == 0
    np.testing.assert_allclose(np.load(tmp_path / "T.npy"), dh_fk(chain, qs), atol=1e-12)


def test_ik_pose(capsys):
    chain = dk.robots.iiwa14()
    code, out, _ = run(capsys, "ik", "iiwa14", "--pose", 0.5, 0.1, 0.6, 0, 1, 0, 0)
    assert code == 0 and "success  True" in out
    q = np.array([float(v) for v in out.split("q", 1)[1].split("[")[1].split("]")[0].split()])
    pos, rot = pose_errors(dh_fk(chain, q), TARGET)
    assert pos < 2e-5 and rot < 2e-4
    code, out, _ = run(capsys, "ik", "iiwa14", "--pose", 5, 0, 0, 1, 0, 0, 0)  # out of reach
    assert code == 1 and "success  False" in out


def test_ik_all(capsys):
    code, out, _ = run(capsys, "ik", "iiwa14", "--pose", 0.5, 0.1, 0.6, 0, 1, 0, 0, "--all", "--samples", 200)
    assert code == 0 and "200 of 200 valid" in out
    rows = [line for line in out.splitlines() if " yes " in line]
    q = np.array([[float(v) for v in r.split("[")[1].split("]")[0].split()] for r in rows])
    assert pose_errors(dh_fk(dk.robots.iiwa14(), q), TARGET)[0].max() < 1e-5  # printed to 6 digits
    code, out, _ = run(
        capsys, "ik", "iiwa14", "--pose", 0.5, 0.1, 0.6, 0, 1, 0, 0, "--all", "--psi", 0.3, "--gc", 1, -1, 1
    )
    assert code == 0 and "1 of 1 valid" in out and "+1 -1 +1" in out


def test_workspace(capsys, tmp_path):
    code, out, err = run(
        capsys,
        "workspace",
        "iiwa14",
        "--samples",
        20_000,
        "--voxel",
        0.2,
        "--out",
        tmp_path / "map.npz",
        "--plot",
        tmp_path / "slice.png",
    )
    assert code == 0, err
    wmap = dk.workspace.ReachabilityMap.load(tmp_path / "map.npz")
    assert wmap.n_samples == 20_000 and wmap.counts.sum() + wmap.n_outside == 20_000
    assert (tmp_path / "slice.png").is_file() and "reached" in out


@pytest.mark.slow
def test_cli_does_not_import_jax():
    """``diffkin --help`` and usage errors stay fast: the package and the CLI import JAX only when used."""
    code = "import sys, diffkin.cli; assert 'jax' not in sys.modules, 'jax imported'; print(diffkin.fk.__name__)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.strip() == "fk", res.stderr


@pytest.mark.parametrize(
    "argv, match",
    [
        (["info", "nosuchrobot"], "unknown robot 'nosuchrobot': expected one of iiwa7, iiwa14"),
        (["info", "robots/missing.urdf"], "robot file 'robots/missing.urdf' does not exist"),
        (["fk", "missing.xml", "0"], "robot file 'missing.xml' does not exist"),
        (["ik", "/", "--position", "0.5", "0", "0.5"], "'/' is a directory"),
        (["info", "iiwa14", "--end-link", "x"], "apply to URDF and MJCF files"),
        (["fk", "iiwa14", "0.1", "0.2"], "7 joint values"),
        (["fk", "iiwa14", "0.1", "zero", "0", "0", "0", "0", "0"], "invalid number: 'zero'"),
        (["fk", "iiwa14", "nan", "0", "0", "0", "0", "0", "0"], "finite"),
        (["fk", "iiwa14"], "either on the command line or with --q-file"),
        (["fk", "iiwa14", "--q-file", "/nonexistent/q.npy"], "no such file"),
        (["fk", "iiwa14", "0", "0", "0", "0", "0", "0", "0", "--format", "npy"], "--output"),
        (["ik", "iiwa14"], "one of the arguments --pose --position is required"),
        (["ik", "iiwa14", "--pose", "0", "0", "0.5", "0", "0", "0", "0"], "must not be zero, got 0 0 0 0"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--seeds", "0"], "positive integer"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--q0", "0", "0"], "--q0"),
        (["ik", "panda", "--pose", "0.5", "0", "0.5", "1", "0", "0", "0", "--all"], "iiwa7 or iiwa14"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--all"], "full --pose"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--psi", "0.1"], "go with --all"),
        (["ik", "iiwa14", "--pose", "0.5", "0", "0.5", "1", "0", "0", "0", "--all", "--gc", "1", "0", "1"], "+1 or -1"),
        (["workspace", "iiwa14", "--samples", "10", "--voxel", "-1", "--out", "m.npz"], "positive number"),
        (["workspace", "iiwa14", "--out", "/nonexistent/dir/m.npz"], "no such directory"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--seed", str(2**80)], "--seed: expected a seed"),
        (["workspace", "iiwa14", "--samples", "1e20", "--out", "m.npz"], "--samples: expected at most"),
        (["workspace", "iiwa14", "--samples", "2.5", "--out", "m.npz"], "invalid integer: '2.5'"),
        (["ik", "iiwa14", "--position", "0.5", "0", "0.5", "--pos-tol", "-1"], "non-negative"),
        (["ik", "iiwa14", "--pose", "0.5", "0", "0.5", "1", "0", "0", "0", "--all", "--rot-tol", "0.1"], "--all"),
        (["frobnicate"], "invalid choice"),
        ([], "required"),
    ],
)
def test_user_errors(capsys, argv, match):
    assert_user_error(capsys, *argv, match=match)


def test_user_errors_from_files_and_diffkin(capsys, tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'/>")  # malformed XML: a ValueError of load_urdf
    assert_user_error(capsys, "info", bad)
    assert_user_error(capsys, "info", os.path.join(DATA, "ur5.urdf"), "--end-link", "nolink", match="nolink")
    (tmp_path / "q.npy").write_bytes(b"not an npy file")
    assert_user_error(capsys, "fk", "iiwa14", "--q-file", tmp_path / "q.npy", match="cannot read")
    np.save(tmp_path / "q6.npy", np.zeros((3, 6)))
    assert_user_error(capsys, "fk", "iiwa14", "--q-file", tmp_path / "q6.npy", match="7 joint values")
    # a ValueError raised by diffkin itself: the slice plane outside the grid
    assert_user_error(
        capsys,
        "workspace",
        "iiwa14",
        "--samples",
        100,
        "--voxel",
        0.2,
        "--out",
        tmp_path / "m.npz",
        "--plot",
        tmp_path / "s.png",
        "--value",
        9,
        "--no-progress",
        match="value",
    )


# --------------------------------------------------------------------------------------------- issue 14


def test_options_between_positionals_and_negative_scientific_numbers(capsys):
    path = os.path.join(DATA, "ur5.urdf")
    q = [0.0, -1e-3, 0.0, -1.5, 0.0, -2.5e-1]
    code, out, err = run(
        capsys, "fk", path, "--end-link", "tool0", "0", "-1e-3", "0", "-1.5", "0", "-2.5E-1", "--format", "json"
    )
    assert code == 0, err
    pose = json.loads(out)["poses"][0]
    assert pose["q"] == q
    np.testing.assert_allclose(pose["T"], dk.fk(dk.load_urdf(path, "tool0"), np.asarray(q)), atol=1e-12)


def test_quaternion_not_of_unit_norm_is_normalised_and_said(capsys):
    code, out, err = run(capsys, "ik", "iiwa14", "--pose", 0.5, 0.1, 0.6, 0, 2, 0, 0)  # the pose of test_ik_pose
    assert code == 0 and "success  True" in out
    assert "norm is 2, not 1: normalised" in err


def test_ik_tolerances(capsys):
    code, out, _ = run(
        capsys, "ik", "iiwa14", "--pose", 0.5, 0.1, 0.6, 0, 1, 0, 0, "--pos-tol", "1e-3", "--rot-tol", "1e-2"
    )
    assert code == 0 and "tolerances 0.001 m / 0.01 rad" in out
    assert float(out.split("pos_err")[1].split()[0]) <= 1e-3


def test_errors_name_flags_not_parameters(capsys):
    line = assert_user_error(capsys, "info", os.path.join(DATA, "ur5.urdf"), "--end-link", "nolink")
    assert line.startswith("diffkin: error: --end-link: unknown frame 'nolink': the robot has 11 frames"), line
    assert "closest names are 'ee_link'" in line and "`diffkin info` lists them all" in line


def test_unknown_frames_are_named_with_the_closest_ones(capsys):
    """An unknown frame gets the closest names and the count, not every frame name on one line."""
    panda = os.path.join(DATA, "panda.urdf")
    line = assert_user_error(capsys, "fk", panda, "--frame", "hand", *["0"] * 8)
    assert line == (
        "diffkin: error: --frame: unknown frame 'hand': the robot has 13 frames, the closest names are "
        "'panda_hand', 'panda_hand_tcp' (`diffkin info` lists them all)"
    )
    line = assert_user_error(capsys, "info", panda, "--base-link", "zzz")
    assert "13 frames, none named like it (the first: 'panda_link0', 'panda_link1', 'panda_link2', ...)" in line
    assert len(line) < 200


def test_bad_slice_is_reported_before_the_map_is_computed(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(dk.workspace, "reachability", lambda *a, **k: pytest.fail("map computed"))
    line = assert_user_error(
        capsys,
        "workspace",
        "iiwa14",
        "--samples",
        10**9,
        "--out",
        tmp_path / "m.npz",
        "--plot",
        tmp_path / "s.png",
        "--value",
        9,
    )
    assert "--value" in line and "outside the grid" in line
    assert not (tmp_path / "m.npz").exists()


def test_output_paths(capsys, tmp_path):
    assert_user_error(capsys, "workspace", "iiwa14", "--samples", 100, "--out", tmp_path, match="is a directory")
    assert not tmp_path.with_name(tmp_path.name + ".npz").exists()
    code, out, _ = run(capsys, "fk", "iiwa14", *[0.0] * 7, "--format", "npy", "--output", tmp_path / "poses")
    assert code == 0 and out.strip().endswith(str(tmp_path / "poses.npy")) and (tmp_path / "poses.npy").is_file()


def test_q_file_csv_with_header(capsys, tmp_path):
    (tmp_path / "q.csv").write_text("q1,q2,q3,q4,q5,q6,q7\n0,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n")
    code, out, err = run(capsys, "fk", "iiwa14", "--q-file", tmp_path / "q.csv")
    assert code == 0, err
    assert "config 0" in out and "config 1" in out and "config 2" not in out


def test_info_says_home_is_outside_the_limits(capsys):
    code, out, _ = run(capsys, "info", "panda")
    assert code == 0 and "q = 0 is outside the limits of joint 4 (panda_joint4" in out
    code, out, _ = run(capsys, "info", "iiwa14")
    assert code == 0 and "outside the limits" not in out


@pytest.mark.parametrize(
    "argv, module, extra",
    [
        (["demo", "--quick"], "matplotlib", "demo"),
        (["workspace", "iiwa14", "--samples", "100", "--out", "m.npz", "--plot", "s.png"], "matplotlib", "plot"),
        (
            ["ik", FINGER, "--position", "0", "0", "0.3", "--avoid", SCENE_FILE],
            "trimesh",
            "collision",
        ),
    ],
)
def test_missing_optional_dependency_is_one_line(capsys, monkeypatch, tmp_path, argv, module, extra):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, module, None)  # import raises ImportError
    line = assert_user_error(capsys, *argv, match=f"pip install 'diffkin[{extra}]'")
    assert module in line and not (tmp_path / "m.npz").exists()


def test_cache_dir_choice(monkeypatch, tmp_path):
    monkeypatch.delenv("DIFFKIN_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "diffkin" / "jax"
    assert cache_dir(str(tmp_path / "opt")) == tmp_path / "opt"
    assert cache_dir(str(tmp_path / "opt"), disabled=True) is None
    for off in ("", "0", "off", "OFF"):
        monkeypatch.setenv("DIFFKIN_CACHE_DIR", off)
        assert cache_dir() is None
    monkeypatch.setenv("DIFFKIN_CACHE_DIR", str(tmp_path / "env"))
    assert cache_dir() == tmp_path / "env" and cache_dir(str(tmp_path / "opt")) == tmp_path / "opt"


def _diffkin(*argv, env=None, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "diffkin", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.slow
def test_cli_writes_the_persistent_cache(tmp_path):
    res = _diffkin("fk", "iiwa14", *[0.1] * 7, "--cache-dir", tmp_path / "cache")
    assert res.returncode == 0, res.stderr
    assert any((tmp_path / "cache").iterdir()), "no cache files written"
    res = _diffkin("fk", "iiwa14", *[0.1] * 7, env={"DIFFKIN_CACHE_DIR": str(tmp_path / "env")})
    assert res.returncode == 0 and any((tmp_path / "env").iterdir()), res.stderr
    res = _diffkin("fk", "iiwa14", *[0.1] * 7, "--no-cache", env={"DIFFKIN_CACHE_DIR": str(tmp_path / "no")})
    assert res.returncode == 0 and not any(p.is_file() for p in (tmp_path / "no").rglob("*")), res.stderr


@pytest.mark.slow
def test_without_optional_dependencies_subprocess(tmp_path):
    """As after ``pip install -e .`` alone: each command runs or says in one line which extra to install."""
    hide = (
        "import sys\nfor m in ('optax', 'matplotlib', 'tqdm', 'torch', 'pytorch_kinematics', 'pinocchio'):\n"
        "    sys.modules[m] = None\nfrom diffkin.cli import main\nsys.exit(main())\n"
    )
    script = tmp_path / "bare.py"
    script.write_text(hide)

    def bare(*argv):
        return subprocess.run(
            [sys.executable, str(script), *map(str, argv)], capture_output=True, text=True, timeout=300, cwd=tmp_path
        )

    for argv, extra in (
        (["demo", "--quick"], "demo"),
        (["workspace", "iiwa14", "--samples", 100, "--out", "m.npz", "--plot", "s.png"], "plot"),
    ):
        res = bare(*argv)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and f"diffkin[{extra}]" in res.stderr, res.stderr
    res = bare("workspace", "iiwa14", "--samples", 1000, "--voxel", 0.2, "--out", "m.npz")
    assert res.returncode == 0 and (tmp_path / "m.npz").is_file(), res.stderr


@pytest.mark.slow
def test_ctrl_c_exits_130(tmp_path):
    import signal
    import time

    proc = subprocess.Popen(
        [*INTERRUPTIBLE, "demo", "--quick", "--out", tmp_path / "demo"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(4)
    # Ctrl-C until it stops: a SIGINT that lands in a callback CPython runs with its exceptions ignored (jax's
    # garbage-collection callback) is lost, as a user's first Ctrl-C would be
    for _ in range(60):
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=2)
            break
        except subprocess.TimeoutExpired:
            continue
    else:
        proc.kill()
        raise AssertionError("the demo did not stop on Ctrl-C")
    assert proc.returncode == 130, (proc.returncode, err[-2000:])
    assert err.strip().splitlines()[-1] == "diffkin: interrupted" and "Traceback" not in err


def test_info_and_fk_of_whole_robots(capsys):
    """A file's tree: ``info`` lists joints, mimic couplings and frames; ``fk --frame`` poses any frame."""
    panda = os.path.join(DATA, "panda.urdf")
    code, out, _ = run(capsys, "info", panda)
    assert code == 0 and "Robot (tree), 8 actuated joints, 1 mimic, 13 frames" in out
    assert "mimic: 1 * panda_finger_joint1 + 0" in out and "choose --end-link" in out
    code, out, _ = run(capsys, "info", os.path.join(DATA, "iiwa14.xml"))  # MJCF, one branch: the chain too
    assert code == 0 and "Robot (tree), 7 actuated joints" in out and "PoEChain" in out
    q = ["0.1", "-0.2", "0.3", "-1.2", "0.4", "1.1", "0.2", "0.03"]
    code, out, _ = run(capsys, "fk", panda, "--frame", "panda_rightfinger", *q, "--format", "json")
    robot = dk.load_robot(panda)
    T = np.asarray(dk.fk(robot, np.array(q, float), "panda_rightfinger"))
    assert code == 0 and np.allclose(json.loads(out)["poses"][0]["T"], T, atol=1e-12)
    code, _, err = run(capsys, "fk", panda, "--frame", "hand", *q)
    assert code == 2 and "unknown frame 'hand'" in err
    code, _, err = run(capsys, "fk", "iiwa14", "--frame", "x", *q[:7])
    assert code == 2 and "applies to URDF and MJCF files" in err


# ------------------------------------------------------------------------------------ scenes and ik --avoid


@pytest.fixture(scope="module")
def arm_scene(tmp_path_factory):
    """The arm's URDF and the scene's JSON, written once per module (the IK compiles once for both)."""
    folder = tmp_path_factory.mktemp("avoid")
    (folder / "arm.urdf").write_text(ARM)
    (folder / "scene.json").write_text(json.dumps(SCENE))
    return str(folder / "arm.urdf"), str(folder / "scene.json")


def test_scene_file_of_every_kind():
    """docs/scene.json: every kind, in the world as written (the box turned by its quaternion)."""
    scene = dk.collision.load_scene(SCENE_FILE)
    world = scene.world
    assert scene.margin == 0.01 and scene.self_collision is True
    assert [int(k.radius.shape[0]) if hasattr(k, "radius") else None for k in world.kinds()[:2]] == [2, 1]
    assert world.boxes.pose.shape == (4, 4, 4) and world.planes.normal.shape == (1, 3) and world.size == 8
    np.testing.assert_allclose(world.spheres.center[0], [0.3, -0.45, 0.45])
    np.testing.assert_allclose(world.capsules.b[0], [-0.4, -0.4, 1.2])
    turned = np.asarray(world.boxes.pose[3])
    np.testing.assert_allclose(turned[:3, 3], [-0.5, 0.4, 0.0])
    np.testing.assert_allclose(turned[:3, 0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0.0], atol=1e-6)  # yaw 30 deg
    np.testing.assert_allclose(world.boxes.pose[0, :3, :3], np.eye(3))  # no quaternion: not turned
    np.testing.assert_allclose(world.boxes.half_extents[2], [0.2, 0.02, 0.37])
    np.testing.assert_allclose(world.planes.normal[0], [0, 0, 1]) and float(world.planes.offset[0]) == -0.15
    # the same scene from JSON text and from a mapping; a plane normal's length is divided out with its offset
    again = dk.collision.load_scene(json.dumps(SCENE))
    np.testing.assert_allclose(again.world.planes.normal[0], [0, 0, 1])
    assert float(again.world.planes.offset[0]) == pytest.approx(-0.1)
    assert dk.collision.load_scene({"self_collision": False}).world.size == 0


_BAD_SCENES = [
    ({"obstacles": []}, "unknown key 'obstacles'"),
    ({"margin": -0.1}, "margin: expected a distance >= 0"),
    ({"margin": float("nan")}, "margin: expected a finite number, got nan"),
    ({"self_collision": 1}, "self_collision: expected true or false, got 1"),
    ({"spheres": {"center": [0, 0, 0]}}, "spheres: expected a list of objects"),
    ({"spheres": [[0, 0, 0, 0.1]]}, "spheres[0]: expected an object with center, radius"),
    ({"spheres": [{"center": [0, 0, 0]}]}, "spheres[0]: missing key 'radius'"),
    ({"spheres": [{"center": [0, 0], "radius": 0.1}]}, "spheres[0].center: expected a list of 3 numbers, got 2 values"),
    ({"spheres": [{"center": [0, 0, 0], "radius": -0.1}]}, "spheres[0].radius: expected values >= 0, got -0.1"),
    ({"spheres": [{"center": [0, 0, "1"], "radius": 0.1}]}, 'spheres[0].center[2]: expected a number, got "1"'),
    ({"spheres": [{"center": [0, 0, True], "radius": 0.1}]}, "spheres[0].center[2]: expected a number, got true"),
    ({"spheres": [{"center": [0, float("inf"), 0], "radius": 0.1}]}, "spheres[0].center[1]: expected a finite"),
    (
        {"capsules": [{"a": [0, 0, 0], "b": [0, 0, 1], "radius": 0.1, "name": "pole"}]},
        "capsules[0]: unknown key 'name'",
    ),
    ({"capsules": [{"a": [0, 0, 0], "b": [0, 0, 1, 2], "radius": 0.1}]}, "capsules[0].b: expected a list of 3"),
    ({"boxes": [{"position": [0, 0, 0], "half_extents": [0.1, -0.1, 0.1]}]}, "boxes[0].half_extents: expected values"),
    ({"boxes": [{"position": [0, 0, 0], "rpy": [0, 0, 1], "half_extents": [0.1] * 3}]}, "boxes[0]: unknown key 'rpy'"),
    ({"boxes": [{"position": [0, 0, 0], "quaternion": [0, 0, 0, 0], "half_extents": [0.1] * 3}]}, "norm 0"),
    ({"boxes": [{"position": [0, 0, 0], "quaternion": [1, 0, 0], "half_extents": [0.1] * 3}]}, "list of 4 numbers"),
    ({"boxes": [{"quaternion": [1, 0, 0, 0], "half_extents": [0.1] * 3}]}, "boxes[0]: missing key 'position'"),
    ({"planes": [{"normal": [0, 0, 0], "offset": 0}]}, "planes[0].normal: expected a non-zero vector"),
    ({"planes": [{"normal": [0, 0, 1]}]}, "planes[0]: missing key 'offset'"),
]


@pytest.mark.parametrize("data, match", _BAD_SCENES, ids=[m for _, m in _BAD_SCENES])
def test_bad_scenes_name_the_field(data, match):
    with pytest.raises(ValueError) as info:
        dk.collision.load_scene(data)
    assert match in str(info.value)


def test_bad_scene_files(tmp_path):
    """A file's errors start with its path; NaN, Infinity and broken JSON are named too."""
    path = tmp_path / "scene.json"
    path.write_text('{"spheres": [{"center": [0, NaN, 0], "radius": 0.1}]}')
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: spheres\[0\]\.center\[1\]: expected a finite"):
        dk.collision.load_scene(path)
    path.write_text("[1, 2]")
    with pytest.raises(
        ValueError, match="scene.json: expected a JSON object with keys margin, self_collision, spheres"
    ):
        dk.collision.load_scene(path)
    path.write_text('{"spheres": [')
    with pytest.raises(ValueError, match="scene.json: not valid JSON"):
        dk.collision.load_scene(str(path))
    with pytest.raises(OSError):
        dk.collision.load_scene(tmp_path / "missing.json")


def _printed_q(out: str) -> np.ndarray:
    return np.array(out.split("q          [")[1].split("]")[0].split(), dtype=np.float64)


def test_ik_avoid_solves_clear_of_a_box(capsys, arm_scene):
    """A hand target beside the box: solved, and the printed q clears the scene by the margin (checked
    here by dk.collision.clearance and fk)."""
    urdf, scene = arm_scene
    code, out, err = run(capsys, "ik", urdf, "--position", 0.3, 0.2, 0.4, "--avoid", scene, "--seeds", 8)
    assert code == 0, err
    assert "arm: IK of a position (orientation free) of hand, LM, 8 seeds" in out
    robot_line = "self-collision on (4 shapes on the robot, 2 self pairs)"
    assert f"avoiding 2 obstacles of {scene}, margin 0.02 m, {robot_line}" in out
    assert "success    True" in out and "m: collision-free" in out
    robot = dk.load_robot(ARM)
    geom = dk.collision.load(ARM, robot)
    world = dk.collision.load_scene(SCENE).world
    q = _printed_q(out)
    clearance = float(dk.collision.clearance(robot, geom, q, world))
    assert clearance >= 0.02 - 1e-8
    assert float(out.split("clearance  ")[1].split()[0]) == pytest.approx(clearance, abs=1e-6)
    np.testing.assert_allclose(np.asarray(dk.fk(robot, q, "hand"))[:3, 3], [0.3, 0.2, 0.4], atol=2e-5)


def test_ik_avoid_target_inside_the_box_is_no_success(capsys, arm_scene):
    """The box's centre (reachable without obstacles): not a success, exit status 1; the --margin flag
    replaces the scene's."""
    urdf, scene = arm_scene
    code, out, err = run(capsys, "ik", urdf, "--position", *BOX_CENTER, "--avoid", scene, "--seeds", 8, "--margin", 0)
    assert code == 1, err
    assert "margin 0 m" in out and "success    False" in out
    missed = float(out.split("pos_err")[1].split()[0]) > 1e-5
    assert missed or "m: in collision" in out  # the best found either misses the centre or is in the box


def test_ik_avoid_user_errors(capsys, arm_scene, tmp_path):
    urdf, scene = arm_scene
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"boxes": [{"position": [0, 0, 0], "half_extents": [0.1, 0.1]}]}))
    target = ("--position", 0.3, 0.2, 0.4)
    line = assert_user_error(
        capsys, "ik", urdf, *target, "--avoid", bad, match="boxes[0].half_extents: expected a list"
    )
    assert line.startswith(f"diffkin: error: --avoid: {bad}: ")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", tmp_path / "no.json", match="--avoid: [Errno 2]")
    assert_user_error(capsys, "ik", "panda", *target, "--avoid", scene, match="built-in robot 'panda' has no collision")
    bare = tmp_path / "bare.urdf"
    bare.write_text(re.sub(r"<collision>.*?</collision>", "", ARM, flags=re.DOTALL))
    assert_user_error(capsys, "ik", bare, *target, "--avoid", scene, match="has no collision geometry")
    assert_user_error(capsys, "ik", urdf, *target, "--margin", 0.1, match="--margin goes with --avoid")
    assert_user_error(capsys, "ik", urdf, *target, "--srdf", scene, match="--srdf goes with --avoid")
    missing = tmp_path / "no.srdf"
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--srdf", missing, match="--srdf: no such")
    assert_user_error(
        capsys,
        "ik",
        urdf,
        *target,
        "--avoid",
        scene,
        "--srdf",
        scene,
        match="scene.json': not well-formed XML",
    )
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--margin", -1, match="non-negative")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--q0", 0, 0, match="--q0: arm has 3 joints")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--end-link", "hnd", match="--end-link")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--base-link", "l1", match="--base-link does not")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--all", match="--avoid does not apply to --all")
    assert_user_error(capsys, "ik", urdf, *target, "--avoid", scene, "--psi", 0.1, match="go with --all")


def test_srdf_files_disable_self_pairs(arm_scene, tmp_path):
    """``--srdf`` (repeatable): the robot's geometry without the link pairs the files disable (what ``ik`` and
    ``view`` solve with), read again when a file changes."""
    from diffkin.cli._robots import robot_with_geometry

    urdf, _ = arm_scene
    srdf = tmp_path / "arm.srdf"
    srdf.write_text('<robot name="arm"><disable_collisions link1="l1" link2="hand" reason="Never"/></robot>')
    robot, geom = robot_with_geometry(urdf)
    _, fewer = robot_with_geometry(urdf, [str(srdf)])
    assert geom.pair_bodies == (("l3", "l1"), ("l1", "l3")) and fewer.pair_bodies == (("l1", "l3"),)
    expected = dk.collision.load(urdf, robot, srdf=str(srdf)).pair_list
    assert fewer.pair_list == expected
    srdf.write_text('<robot name="arm"></robot>')
    os.utime(srdf, ns=(0, 10**18))  # a new modification time, whatever the clock's resolution
    assert robot_with_geometry(urdf, [str(srdf)])[1].pair_list == geom.pair_list
