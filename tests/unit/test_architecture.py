"""The layering rules that keep diffkin one-way: code outside ``diffkin/models/`` uses a model only
through its public fields and the forward interface (``model.forward(q, base) -> Pass``)."""

import ast
import pathlib

import diffkin as dk
from diffkin.models import forward, robot

PACKAGE = pathlib.Path(dk.__file__).parent
MODEL_CLASSES = (dk.DHChain, dk.PoEChain, dk.Robot, forward.ChainPass, robot.RobotPass)
HOOKS = {"_check"}  # diffkin._pytree's validation hook, which every model defines for it
# Helper modules of diffkin/models/ that other readers share, not model members: the field checks of
# every pytree model (also dk.srs.SRSArm's) and the hardened XML reader (also dk.collision.load's).
SHARED = {"_validate", "_xml"}


def _private_members() -> set[str]:
    names = set()
    for cls in MODEL_CLASSES:
        for klass in cls.__mro__[:-1]:
            names |= {n for n in vars(klass) if n.startswith("_") and not n.startswith("__")}
    return names - HOOKS


def _outside_models():
    for path in sorted(PACKAGE.rglob("*.py")):
        if "models" not in path.relative_to(PACKAGE).parts:
            yield path, ast.parse(path.read_text(), filename=str(path))


def test_no_code_outside_models_reaches_into_a_model():
    private = _private_members()
    assert "_frames" not in private and "forward" not in private  # the interface is public
    found = []
    for path, tree in _outside_models():
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr in private:
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno}: .{node.attr}")
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("diffkin.models"):
                found += [
                    f"{path.relative_to(PACKAGE)}:{node.lineno}: imports {node.module}.{alias.name}"
                    for alias in node.names
                    if alias.name.startswith("_") and alias.name not in SHARED
                ]
    assert not found, "model privates used outside diffkin/models/:\n" + "\n".join(found)


def test_the_check_sees_a_violation(tmp_path):
    """The scan above finds what it looks for (a planted attribute access and a private import)."""
    tree = ast.parse("from diffkin.models.poe import _screw_types\nchain._frames(q)\n")
    private = _private_members() | {"_frames"}
    attrs = [n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr in private]
    imports = [a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names]
    assert attrs == ["_frames"] and imports == ["_screw_types"]
