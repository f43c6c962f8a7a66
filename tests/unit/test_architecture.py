"""The layering rules that keep diffkin one-way: code outside ``diffkin/models/`` uses a model only
through its public fields and the forward interface (``model.forward(q, base) -> Pass``), no package
reaches into another's privates, and no module of ``diffkin/`` imports itself through others, not even
from inside a function."""

import ast
import functools
import pathlib

import diffkin as dk
from diffkin.models import _passes, forward

PACKAGE = pathlib.Path(dk.__file__).parent
MODEL_CLASSES = (dk.DHChain, dk.PoEChain, dk.Robot, forward.ChainPass, _passes.RobotPass, _passes.ScannedPass)
# diffkin._pytree's hooks, which the models define for it: validation (every model) and the defaults that
# depend on other fields (read with getattr, as a model need not define it)
HOOKS = {"_check", "_fill"}
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
    for path, tree in sorted(_trees().values()):
        if "models" not in path.relative_to(PACKAGE).parts:
            yield path, tree


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
                    if alias.name.startswith("_")
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


@functools.cache
def _trees() -> dict[str, tuple[pathlib.Path, ast.Module]]:
    """Every module of ``diffkin/``, parsed once: its path and syntax tree."""
    return {name: (path, ast.parse(path.read_text(), str(path))) for name, path in _modules().items()}


def _import_graph() -> dict[str, set[str]]:
    trees = _trees()
    return {name: _imported(name, path, tree, trees) for name, (path, tree) in trees.items()}


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


# -- no package reaches into another's privates
#
# The packages are the sub-packages of ``diffkin/`` (``diffkin.collision``, ``diffkin.ik``, ...) and each
# top-level module (``diffkin.kinematics``, ``diffkin.se3``, ``diffkin._xla``, ...). A package's interface
# to the others is its ``__init__`` and its modules without a leading underscore (some are internal, not in
# API.md: ``diffkin.collision.interface``, ``diffkin.models.ranges``), and their names without one. The
# top-level private modules (``_xla``, ``_pytree``, ``_static``, ``_rigid``, ``_trig``, ``_checks``,
# ``_validate``, ``_xml``, ``_cache``, ``_npz``, ``_sharding``, ``_meshfiles``) are the library's internal
# toolkit: every package may import them, and their names without an underscore; their underscore names
# stay theirs. Across packages these fail: importing a private module (``diffkin.collision._near`` from
# ``diffkin/ik/``), importing or reading an underscore name of another package's module (``from
# diffkin._xla import _x``, ``mjcf._Reader``), and reading an underscore attribute that only other
# packages define (``reader._get(...)`` on an object of another package's class; ``HOOKS`` aside).
# Imports inside functions count, and so do the same uses spelled with a string constant
# (``importlib.import_module("diffkin.collision._near")``, ``getattr(reader, "_get")``, ``hasattr``,
# ``setattr``, ``delattr``).


def _owner(module: str) -> str:
    """The package a module of ``diffkin`` belongs to: ``diffkin.<first part>`` (a sub-package or a top-level
    module), ``diffkin`` for the package's ``__init__``."""
    return ".".join(module.split(".")[:2])


def _underscore(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _private(module: str) -> bool:
    """Whether a module is private to its package: a part below the package starts with ``_``."""
    return any(_underscore(p) for p in module.split(".")[2:])


def _defined(tree: ast.AST) -> set[str]:
    """The underscore names a module defines: functions, classes, assigned names and attributes."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
    return {n for n in names if _underscore(n)}


def _reaches(name: str, path: pathlib.Path, tree: ast.AST, modules, defined: dict[str, set[str]]) -> set[str]:
    """The uses in module ``name`` (file ``path``) of other packages' private modules and underscore names,
    each as ``"path:line: what"`` (see above). ``modules``: every module's dotted name; ``defined``: per
    package, the underscore names it defines."""
    me = _owner(name)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found, bound = set(), {}  # bound: local name -> the module of diffkin it names

    def use(node, what: str) -> None:
        found.add(f"{path.relative_to(PACKAGE)}:{node.lineno}: {what}")

    def module(target: str, node) -> None:
        if _owner(target) != me and _private(target):
            use(node, f"imports {target}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "diffkin":
                    module(alias.name, node)
                    bound[alias.asname or "diffkin"] = alias.name if alias.asname else "diffkin"
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + [base]).strip(".")
            if base.split(".")[0] != "diffkin":
                continue
            for alias in node.names:
                full = f"{base}.{alias.name}"
                if full in modules:
                    module(full, node)
                    bound[alias.asname or alias.name] = full
                else:
                    module(base, node)
                    if _underscore(alias.name) and _owner(base) != me:
                        use(node, f"imports {full}")
        elif isinstance(node, ast.Call) and _named_import(node) and node.args[0].value.split(".")[0] == "diffkin":
            module(node.args[0].value, node)  # importlib.import_module("diffkin.pkg._private")
    own = defined.get(me, set()) | HOOKS
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            value, chain = _attributes(node)
        elif isinstance(node, ast.Call) and _named_attribute(node):  # getattr(x, "_name"): x._name
            value, chain = _attributes(node.args[0])
            chain.append(node.args[1].value)
        else:
            continue
        if isinstance(value, ast.Name) and value.id in bound:  # a module of diffkin: follow it down the attributes
            target = bound[value.id]
            for attr in chain:
                if f"{target}.{attr}" not in modules:
                    if _underscore(attr) and _owner(target) != me:
                        use(node, f"reads {target}.{attr}")
                    break
                target = f"{target}.{attr}"
                module(target, node)
        elif _underscore(chain[-1]) and chain[-1] not in own:
            others = sorted(p for p, names in defined.items() if chain[-1] in names)
            if others:
                use(node, f"reads .{chain[-1]} of {', '.join(others)}")
    return found


def _attributes(node: ast.expr) -> tuple[ast.expr, list[str]]:
    """The base of a chain of attributes and the attributes, innermost first: ``a.b.c`` is ``(a, [b, c])``."""
    chain = []
    while isinstance(node, ast.Attribute):
        chain.append(node.attr)
        node = node.value
    return node, chain[::-1]


def _constant_string(node: ast.Call, i: int) -> bool:
    return len(node.args) > i and isinstance(node.args[i], ast.Constant) and isinstance(node.args[i].value, str)


def _named_attribute(node: ast.Call) -> bool:
    """``getattr``/``hasattr``/``setattr``/``delattr`` of an attribute named by a string constant."""
    builtin = isinstance(node.func, ast.Name) and node.func.id in {"getattr", "hasattr", "setattr", "delattr"}
    return builtin and _constant_string(node, 1)


def _named_import(node: ast.Call) -> bool:
    """``importlib.import_module`` (or ``import_module``) of a module named by a string constant."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
    return name == "import_module" and _constant_string(node, 0)


def _all_reaches() -> set[str]:
    trees = _trees()
    defined: dict[str, set[str]] = {}
    for name, (_, tree) in trees.items():
        defined.setdefault(_owner(name), set()).update(_defined(tree))
    return {r for name, (path, tree) in trees.items() for r in _reaches(name, path, tree, trees.keys(), defined)}


def test_no_package_reaches_into_another():
    """Across packages: no private module, no underscore name, no underscore attribute of another's class."""
    found = sorted(_all_reaches())
    assert not found, "private uses across packages (give the package an interface):\n" + "\n".join(found)


def test_the_reach_check_sees_a_violation():
    """Planted uses of each kind are found (top level, in a function, relative, through an alias, down a
    chain of attributes, named by a string constant), and a package's own privates, the toolkit's modules,
    public names of other packages and their interface modules are not."""
    modules = {
        "diffkin": PACKAGE / "__init__.py",
        "diffkin._xla": PACKAGE / "_xla.py",
        "diffkin.collision": PACKAGE / "collision/__init__.py",
        "diffkin.collision._near": PACKAGE / "collision/_near.py",
        "diffkin.collision.interface": PACKAGE / "collision/interface.py",
        "diffkin.ik": PACKAGE / "ik/__init__.py",
        "diffkin.ik._solve": PACKAGE / "ik/_solve.py",
        "diffkin.ik._terms": PACKAGE / "ik/_terms/__init__.py",
        "diffkin.ik._terms.avoid": PACKAGE / "ik/_terms/avoid.py",
    }
    code = """
from diffkin._xla import SOLVER_COMPILE, _in_halves
from diffkin.collision import interface, _private_name
from diffkin.collision.interface import near_motions
from ..import _solve
import diffkin as dk

def f(reader, self):
    from diffkin.collision._near import near_motions
    from diffkin import _xla
    _xla._in_halves(interface.moved, dk.collision._near.near_motions, dk.ik._solve._plan)
    self._check(True)
    return reader._get(_solve._own, reader._fields, interface._hidden)

def g(reader, name):
    import importlib
    importlib.import_module("diffkin.collision._near"), importlib.import_module("diffkin.collision.interface")
    getattr(reader, "_get"), hasattr(interface, "_hidden"), setattr(dk.collision, "_near", None)
    getattr(reader, "_own", None), getattr(reader, "_fields"), getattr(reader, name), getattr(dk, "_xla").solver_jit
"""
    defined = {"diffkin.models": {"_get", "_check"}, "diffkin.ik": {"_own"}, "diffkin.collision": {"_hidden"}}
    found = _reaches("diffkin.ik._terms.avoid", modules["diffkin.ik._terms.avoid"], ast.parse(code), modules, defined)
    assert sorted(found) == [
        "ik/_terms/avoid.py:11: imports diffkin.collision._near",
        "ik/_terms/avoid.py:11: reads diffkin._xla._in_halves",
        "ik/_terms/avoid.py:13: reads ._get of diffkin.models",
        "ik/_terms/avoid.py:13: reads diffkin.collision.interface._hidden",
        "ik/_terms/avoid.py:17: imports diffkin.collision._near",
        "ik/_terms/avoid.py:18: imports diffkin.collision._near",
        "ik/_terms/avoid.py:18: reads ._get of diffkin.models",
        "ik/_terms/avoid.py:18: reads diffkin.collision.interface._hidden",
        "ik/_terms/avoid.py:2: imports diffkin._xla._in_halves",
        "ik/_terms/avoid.py:3: imports diffkin.collision._private_name",
        "ik/_terms/avoid.py:9: imports diffkin.collision._near",
    ]


def _compiler_options_outside_xla() -> list[str]:
    """``module:line`` of every ``compiler_options=`` keyword outside :mod:`diffkin._xla`."""
    return [
        f"{name}:{node.lineno}"
        for name, (path, tree) in _trees().items()
        if name != "diffkin._xla"
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and any(k.arg == "compiler_options" for k in node.keywords)
    ]


def test_compiler_options_only_through_xla():
    """XLA's compiler options are backend-specific (a GPU's compiler rejects the CPU emitter's): code compiles
    with options through ``diffkin._xla.solver_jit``, which gives them to CPU compiles only."""
    assert _compiler_options_outside_xla() == []
