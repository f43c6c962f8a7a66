"""Scene files (``dk.collision.load_scene``) that break the JSON decoder or a float: deep nesting and huge
integers are the documented one-line ``ValueError``, and ``diffkin ik --avoid`` a one-line error, exit 2
(every field's own errors: ``tests/integration/test_cli.py``)."""

import pytest
from _shapes import CAPSULE_ARM

import diffkin as dk
from diffkin import cli

DEEP = 100_000

_HOSTILE = [
    ("[" * DEEP + "]" * DEEP, r"not valid JSON: nested too deeply"),
    ('{"spheres": ' + "[" * DEEP + "]" * DEEP + "}", r"not valid JSON: nested too deeply"),
    ('{"margin": 1' + "0" * 400 + "}", r"margin: expected a finite number, got an integer of 401 digits"),
    (
        '{"spheres": [{"center": [0, 0, -1' + "0" * 400 + '], "radius": 0.1}]}',
        r"spheres\[0\]\.center\[2\]: expected a finite number, got an integer of 401 digits",
    ),
    ('{"margin": 1' + "0" * 5000 + "}", r"not valid JSON: .*digits"),
]


@pytest.mark.parametrize("text, match", _HOSTILE, ids=["deep", "deep field", "big", "big entry", "huge"])
def test_hostile_scene_files_are_one_line_value_errors(tmp_path, text, match):
    path = tmp_path / "scene.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"^{path}: {match}") as info:
        dk.collision.load_scene(path)
    assert "\n" not in str(info.value) and len(str(info.value)) < 300


def test_deep_mappings_are_value_errors_too():
    nested: list = []
    for _ in range(DEEP):
        nested = [nested]
    with pytest.raises(ValueError, match=r"^spheres\[0\]: expected an object with center, radius, got a list"):
        dk.collision.load_scene({"spheres": nested})
    with pytest.raises(ValueError, match=r"^margin: expected a finite number, got an integer of 401 digits"):
        dk.collision.load_scene({"margin": 10**400})


def test_cli_avoid_with_a_hostile_scene_exits_2_with_one_line(tmp_path, capsys):
    urdf, scene = tmp_path / "arm.urdf", tmp_path / "scene.json"
    urdf.write_text(CAPSULE_ARM)
    scene.write_text("[" * DEEP + "]" * DEEP)
    assert cli.main(["ik", str(urdf), "--position", "0.3", "0.2", "0.4", "--avoid", str(scene)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"diffkin: error: --avoid: {scene}: not valid JSON"), err
