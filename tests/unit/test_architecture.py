"""The layering rules that keep diffkin one-way: code outside ``diffkin/models/`` uses a model only
through its public fields and the forward interface (``model.forward(q, base) -> Pass``), and no module
of ``diffkin/`` imports itself through others, not even from inside a function."""

import ast
import pathlib

import diffkin as dk
from diffkin.models import _passes, forward

PACKAGE = pathlib.Path(dk.__file__).parent
MODEL_CLASSES = (dk.DHChain, dk.PoEChain, dk.Robot, forward.ChainPass, _passes.RobotPass, _passes.ScannedPass)
HOOKS = {"_check"}  # diffkin._pytree's validation hook, which every model defines for it
# Helper modules of diffkin/models/ that other readers share, not model members: the field checks of
# every pytree model (also dk.srs.SRSArm's) and the hardened XML reader (also dk.collision.load's).
SHARED = {"_validate", "_xml"}
# Import cycles known and not yet untied, each as its sorted modules: none (a new one fails the test, and so
# does an entry here that is no longer a cycle).
KNOWN_CYCLES: set[tuple[str, ...]] = set()


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


def _modules() -> dict[str, pathlib.Path]:
    """Every module of ``diffkin/`` by dotted name (a package by its ``__init__.py``)."""
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _imported(name: str, path: pathlib.Path, tree: ast.AST, modules) -> set[str]:
    """The modules of ``modules`` that module ``name`` imports anywhere (top level, functions, ``TYPE_CHECKING``):
    ``from a import b`` is ``a.b`` when that is a module, else ``a``; relative imports resolved."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
            base = ".".join(package[: len(package) - node.level + 1] + [node.module or ""]).strip(".")
            base = base if node.level else (node.module or "")
            found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names}
    return (found & modules.keys()) - {name}


def _cycles(graph: dict[str, set[str]]) -> list[tuple[str, ...]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(tuple(sorted(component)))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _import_graph() -> dict[str, set[str]]:
    modules = _modules()
    return {
        name: _imported(name, path, ast.parse(path.read_text(), str(path)), modules) for name, path in modules.items()
    }


def test_no_module_imports_itself_through_others():
    """The import graph of ``diffkin/``, function-level imports included, has no cycle but the known ones."""
    cycles = set(_cycles(_import_graph()))
    assert cycles <= KNOWN_CYCLES, f"import cycles: {sorted(cycles - KNOWN_CYCLES)}"
    assert not KNOWN_CYCLES - cycles, f"cycles untied: remove them from KNOWN_CYCLES: {KNOWN_CYCLES - cycles}"


def test_the_cycle_check_sees_a_cycle():
    """Function-level and relative imports count: a planted circle through both is found."""
    modules = {"pkg.a": pathlib.Path("pkg/a.py"), "pkg.b": pathlib.Path("pkg/b.py"), "pkg.c": pathlib.Path("pkg/c.py")}
    a = ast.parse("from pkg import b\n")
    b = ast.parse("def f():\n    from .c import thing\n")
    c = ast.parse("import pkg.a\n")
    graph = {name: _imported(name, modules[name], tree, modules) for name, tree in zip(modules, (a, b, c), strict=True)}
    assert graph == {"pkg.a": {"pkg.b"}, "pkg.b": {"pkg.c"}, "pkg.c": {"pkg.a"}}
    assert _cycles(graph) == [("pkg.a", "pkg.b", "pkg.c")]
    assert _cycles({"pkg.a": {"pkg.b"}, "pkg.b": set()}) == []
