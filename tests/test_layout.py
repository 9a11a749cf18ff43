"""The package's folders are its architecture (docs/architecture.md): data flows one way,
models -> engine -> data -> fitting (and maps) -> analysis -> viz -> pipeline -> cli, and a
module imports only from its own layer or below (the top-level facade ``veil/__init__.py``,
which imports lazily, excepted); no two modules import each other, directly or round a loop.
Outside ``models/`` no code names a model class, a parameter or an option (not even a
one-letter parameter where code looks one up), the public API says what it returns, and
no module or function outgrows the sizes docs/architecture.md promises.

Each rule is a function of a source tree, and a test plants a violation in a small tree to
show that the rule catches it."""

from __future__ import annotations

import ast
import inspect
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "src" / "veil"
#: Layers, lowest first; a module's layer is its first package below veil.
LAYERS = [("_extras", "_jax", "_lazy", "errors", "io", "numbers"), ("models",), ("engine",), ("data",),
          ("fitting", "maps"), ("analysis", "interop"), ("viz",), ("pipeline",), ("cli",)]
RANK = {name: k for k, names in enumerate(LAYERS) for name in names}


def _modules(root: pathlib.Path = ROOT):
    return sorted(p for p in root.rglob("*.py") if p.name != "__init__.py" or p.parent != root)


def _layer(parts) -> str:
    return parts[0].removesuffix(".py")


def _type_checking_only(tree) -> set:
    """The ids of the nodes under ``if TYPE_CHECKING:`` (imports for annotations only)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return out


def _imports(path: pathlib.Path, root: pathlib.Path = ROOT, runtime: bool = False):
    """(line, imported module parts relative to veil) of every import of veil's own modules;
    ``runtime``: without those under ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text())
    package = list(path.relative_to(root).parent.parts)
    skip = _type_checking_only(tree) if runtime else set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = base + (node.module.split(".") if node.module else [])
                if not target:  # from . import name (the veil package itself)
                    yield node.lineno, [a.name for a in node.names][:1]
                    continue
                if not node.module:  # from . import sibling
                    for a in node.names:
                        yield node.lineno, target + [a.name]
                    continue
                yield node.lineno, target
            elif node.module and node.module.split(".")[0] == "veil":
                yield node.lineno, node.module.split(".")[1:]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "veil":
                    yield node.lineno, a.name.split(".")[1:]


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_only_go_down(path):
    rel = path.relative_to(ROOT).parts
    own = RANK[_layer(rel)]
    for line, target in _imports(path):
        if not target or target[0] == "__version__":
            continue
        assert RANK[_layer(target)] <= own, (
            f"{'/'.join(rel)}:{line} imports veil.{'.'.join(target)}, a layer above "
            f"{_layer(rel)} ({' -> '.join(n[0] for n in LAYERS)})")


def test_no_model_class_named_outside_models():
    from veil.models import REGISTRY

    names = {c.__name__ for c in REGISTRY.values()}
    pattern = re.compile(r"\b(" + "|".join(sorted(names)) + r")\b")
    found = []
    for path in _modules():
        if path.relative_to(ROOT).parts[0] == "models":
            continue
        code = ast.parse(path.read_text())
        for node in ast.walk(code):
            if isinstance(node, ast.Name) and pattern.fullmatch(node.id):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.id}")
            if isinstance(node, ast.Attribute) and pattern.fullmatch(node.attr):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} .{node.attr}")
            if isinstance(node, ast.alias) and pattern.fullmatch(node.name.split(".")[-1]):
                found.append(f"{path.relative_to(ROOT)}: import {node.name}")
    assert not found, found


def _names_and_literals():
    """Parameter names and option values of veil's own families. Left out: single letters
    (g is also a colour channel and a loop variable) and the measurement tables' own
    vocabulary (rho is the goniometer's rotation as well as an albedo)."""
    from veil.data.measurements import KNOWN_COLUMNS
    from veil.models.registry import FAMILIES

    params = {p.name for c in FAMILIES for p in c.PARAMS if len(p.name) > 1}
    params |= {p.alias for c in FAMILIES for p in c.PARAMS if p.alias}
    params -= set(KNOWN_COLUMNS)
    choices = {str(v) for c in FAMILIES for o in c.OPTIONS for v in o.choices}
    return params, choices


def _docstring_nodes(tree):
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def test_no_parameter_name_or_option_value_outside_models():
    """Code outside models/ reads parameters and options from the declarations: no string
    constant equal to a parameter's name or an option's value, no attribute access by a
    parameter's name (help texts and messages may mention them inside longer strings)."""
    params, choices = _names_and_literals()
    found = []
    for path in _modules():
        if path.relative_to(ROOT).parts[0] == "models":
            continue
        tree = ast.parse(path.read_text())
        docs = _docstring_nodes(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docs and node.value in params | choices:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.value!r}")
            if isinstance(node, ast.Attribute) and node.attr in params:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} .{node.attr}")
    assert not found, found


# --------------------------------------------------------------------------------------
# no import loops between the modules of a layer
# --------------------------------------------------------------------------------------
def _module_of(parts: list, root: pathlib.Path) -> str | None:
    """The module (dotted, relative to veil) that ``parts`` names, or whose attribute it
    names: the longest prefix that is a module file or a package."""
    for k in range(len(parts), 0, -1):
        head = parts[:k]
        if (root.joinpath(*head[:-1]) / f"{head[-1]}.py").is_file():
            return ".".join(head)
        if (root.joinpath(*head) / "__init__.py").is_file():
            return ".".join(head)
    return None


def import_graph(root: pathlib.Path = ROOT) -> dict:
    """{module: the modules it imports when it runs} over the tree ``root`` (a package's
    ``__init__`` is the package; imports under ``if TYPE_CHECKING:`` do not run)."""
    graph = {}
    for path in _modules(root):
        rel = path.relative_to(root).with_suffix("").parts
        name = ".".join(rel[:-1] if rel[-1] == "__init__" else rel)
        tree = ast.parse(path.read_text())
        skip = _type_checking_only(tree)
        targets = set()
        for node in ast.walk(tree):
            if id(node) in skip or not isinstance(node, ast.ImportFrom | ast.Import):
                continue
            for _, parts in _imports_of(node, path, root):
                found = _module_of(parts, root)
                if found and found != name:
                    targets.add(found)
        graph[name] = targets
    return graph


def _imports_of(node, path: pathlib.Path, root: pathlib.Path):
    """The veil modules (parts) one import statement names, a ``from X import name`` also as
    X.name (which may be a submodule)."""
    package = list(path.relative_to(root).parent.parts)
    if isinstance(node, ast.Import):
        for a in node.names:
            if a.name.split(".")[0] == "veil":
                yield node.lineno, a.name.split(".")[1:]
        return
    if node.level:
        base = package[: len(package) - (node.level - 1)]
    elif node.module and node.module.split(".")[0] == "veil":
        base = []
    else:
        return
    module = (node.module or "").split(".") if node.module else []
    if not node.level:
        module = module[1:]
    for a in node.names:
        yield node.lineno, base + module + [a.name]


def _rank(module: str):
    """The layer of a dotted module name: its rank in LAYERS (a planted tree's unknown
    package is a layer of its own)."""
    layer = _layer(module.split("."))
    return RANK.get(layer, layer)


def import_loops(root: pathlib.Path = ROOT) -> list[list[str]]:
    """The loops of the import graph whose modules are all of one layer - one package, or
    packages of the same rank such as fitting/ and maps/ (each loop once, as the modules
    round it); a loop across layers is an upward import, caught above."""
    graph = import_graph(root)
    loops, seen = [], set()
    for start in sorted(graph):
        # a trail through a module of another layer closes no loop of one layer: the
        # search stays in the start's layer (the same loops, in the same order, without
        # walking every path of the whole graph)
        rank = _rank(start)
        stack = [(start, [start])]
        while stack:
            node, trail = stack.pop()
            for nxt in sorted(graph.get(node, ())):
                if nxt == start:
                    key = frozenset(trail)
                    if key not in seen and len({_rank(m) for m in trail}) == 1:
                        seen.add(key)
                        loops.append(trail)
                elif nxt not in trail and nxt > start and _rank(nxt) == rank:
                    stack.append((nxt, trail + [nxt]))
    return loops


def test_no_import_loops_within_a_layer():
    loops = import_loops()
    assert not loops, [" -> ".join(loop + loop[:1]) for loop in loops]


def _tree(tmp_path, files: dict) -> pathlib.Path:
    """A planted source tree ``veil/`` of ``files`` {relative path: source}."""
    root = tmp_path / "veil"
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in {p.parent for p in root.rglob("*.py")}:
        (folder / "__init__.py").touch()
    return root


def test_an_import_loop_within_a_layer_is_caught(tmp_path):
    """result imports report (inside a method), report imports result (at its top): a loop;
    the same import of report under TYPE_CHECKING is none."""
    root = _tree(tmp_path, {
        "fitting/result.py": "def report():\n    from .report import text\n    return text\n",
        "fitting/report.py": "from .result import report\ntext = 'x'\n",
        "fitting/other.py": "from veil.fitting import result\n",
    })
    assert import_loops(root) == [["fitting.report", "fitting.result"]]
    (root / "fitting/report.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .result import report\n"
        "text = 'x'\n")
    assert import_loops(root) == []


def test_an_import_loop_between_packages_of_one_layer_is_caught(tmp_path):
    """fitting/ and maps/ are one layer: neither import goes up, but the two make a loop;
    so do two modules of the lowest layer (io and numbers)."""
    root = _tree(tmp_path, {
        "fitting/solver.py": "from ..maps.solve import step\n",
        "maps/solve.py": "from veil.fitting import solver\nstep = 1\n",
        "io.py": "from .numbers import json_float\n",
        "numbers.py": "def json_float(x):\n    from .io import write\n    return x\n",
    })
    assert sorted(import_loops(root)) == [["fitting.solver", "maps.solve"], ["io", "numbers"]]


# --------------------------------------------------------------------------------------
# option names and one-letter parameter names outside models/
# --------------------------------------------------------------------------------------
def option_name_literals(root: pathlib.Path = ROOT, names=None) -> list[str]:
    """String constants (docstrings aside) equal to an option's name (``variant``,
    ``orders``, ...) outside models/: code reads options from the declarations (their
    ``Option.name``, or a constant of models/ such as ``VARIANT_OPTION``)."""
    if names is None:
        from veil.models.registry import FAMILIES
        names = {o.name for c in FAMILIES for o in c.OPTIONS}
    found = []
    for path in _modules(root):
        if path.relative_to(root).parts[0] == "models":
            continue
        tree = ast.parse(path.read_text())
        docs = _docstring_nodes(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docs and node.value in names:
                found.append(f"{path.relative_to(root)}:{node.lineno} {node.value!r}")
    return found


def test_no_option_name_outside_models():
    assert not option_name_literals()


def test_an_option_name_outside_models_is_caught(tmp_path):
    root = _tree(tmp_path, {
        "fitting/result.py": '"""The variant of a result."""\n'
                             'def variant_of(data):\n    return data["variant"]\n',
        "models/base.py": 'VARIANT_OPTION = "variant"\n',
    })
    assert option_name_literals(root, {"variant"}) == ["fitting/result.py:3 'variant'"]


#: Names of what holds or looks up a model's parameters: a one-letter parameter name as a
#: key or an argument of these is a parameter looked up by name.
PARAM_HOLDERS = re.compile(r"(^|_)(params?|names|values|fixed|free|stderr|vector|start|"
                           r"bounds|grid)($|_)")
PARAM_LOOKUPS = {"index", "param", "scale_index", "param_index"}


def _holder_name(node) -> str:
    while isinstance(node, ast.Call | ast.Subscript):
        node = node.func if isinstance(node, ast.Call) else node.value
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def one_letter_parameter_uses(root: pathlib.Path = ROOT, names=None) -> list[str]:
    """One-letter parameter names (``g``, ``n``, ``k``, ``s``) where code looks a parameter up
    outside models/: a key of something holding parameters (``params["g"]``,
    ``fixed.get("g")``, ``{"g": ...}`` passed as ``fixed=``), an argument of ``.index``,
    ``.param``, ``.scale_index``, or compared with a parameter's ``name``. (The same letters
    elsewhere - a colour channel, a number format, a plural - are not parameters.)"""
    if names is None:
        from veil.models.registry import FAMILIES
        names = {p.name for c in FAMILIES for p in c.PARAMS if len(p.name) == 1}
    found = []
    for path in _modules(root):
        if path.relative_to(root).parts[0] == "models":
            continue
        tree = ast.parse(path.read_text())

        def hit(node, why):
            found.append(f"{path.relative_to(root)}:{node.lineno} {node.value!r} ({why})")

        def letter(node):
            return isinstance(node, ast.Constant) and node.value in names

        for node in ast.walk(tree):
            if isinstance(node, ast.Subscript) and letter(node.slice) \
                    and PARAM_HOLDERS.search(_holder_name(node.value)):
                hit(node.slice, "a key of " + _holder_name(node.value))
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                holder = _holder_name(node.func.value)
                for arg in node.args[:1]:
                    if letter(arg) and (node.func.attr in PARAM_LOOKUPS or (
                            node.func.attr in ("get", "pop") and PARAM_HOLDERS.search(holder))):
                        hit(arg, f".{node.func.attr}()")
            if isinstance(node, ast.keyword) and node.arg and PARAM_HOLDERS.search(node.arg) \
                    and isinstance(node.value, ast.Dict):
                for key in node.value.keys:
                    if key is not None and letter(key):
                        hit(key, f"a key of {node.arg}=")
            if isinstance(node, ast.Compare):
                sides = [node.left, *node.comparators]
                if any(letter(s) for s in sides) and any(
                        _holder_name(s) in ("name", "pname", "param_name") for s in sides):
                    hit(next(s for s in sides if letter(s)), "compared with a name")
    return found


def test_no_one_letter_parameter_name_in_code_paths():
    assert not one_letter_parameter_uses()


def test_a_one_letter_parameter_name_in_a_code_path_is_caught(tmp_path):
    root = _tree(tmp_path, {
        "analysis/ok.py": 'CHANNELS = ("r", "g", "b")\ndef f(x, counts):\n'
                          '    return format(x, "g"), counts["n"]\n',
        "analysis/bad.py": 'def f(result, cls, p):\n'
                           '    a = result.params["g"]\n'
                           '    b = cls.param_names().index("n")\n'
                           '    c = fit(fixed={"g": 0.9})\n'
                           '    return a, b, c, p.name == "k"\n',
    })
    found = one_letter_parameter_uses(root, {"g", "n", "k"})
    assert [f.split(" (")[0] for f in found] == [
        "analysis/bad.py:2 'g'", "analysis/bad.py:3 'n'", "analysis/bad.py:4 'g'",
        "analysis/bad.py:5 'k'"], found


# --------------------------------------------------------------------------------------
# the public API says what it returns
# --------------------------------------------------------------------------------------
def _public_functions(module, names) -> list:
    """(label, function) of the functions among ``names`` of ``module`` and the public
    methods (static and class methods too) of its classes defined in veil."""
    out = []
    for name in names:
        obj = getattr(module, name)
        if inspect.isfunction(obj):
            out.append((name, obj))
        elif inspect.isclass(obj) and obj.__module__.startswith("veil."):
            for m, f in vars(obj).items():
                f = f.__func__ if isinstance(f, staticmethod | classmethod) else f
                if not m.startswith("_") and inspect.isfunction(f):
                    out.append((f"{name}.{m}", f))
    return out


def public_modules(root: pathlib.Path = ROOT) -> list[str]:
    """veil and every package and module below it that declares ``__all__`` (veil.fitting,
    veil.fitting.solver, veil.viz.render, ...): their ``__all__`` is their public API."""
    found = ["veil"]
    for path in _modules(root):
        if re.search(r"^__all__\b", path.read_text(), re.M):
            rel = path.relative_to(root).with_suffix("").parts
            found.append(".".join(("veil",) + (rel[:-1] if rel[-1] == "__init__" else rel)))
    return found


def missing_return_annotations(names=None, package: str = "veil") -> list[str]:
    """The functions of ``package.__all__`` (default veil's; ``package`` may be any module),
    and the public methods of its classes defined in veil, without a return annotation:
    their labels, a subpackage's or module's prefixed by its name below veil."""
    import importlib

    module = importlib.import_module(package)
    prefix = "" if package == "veil" else package.removeprefix("veil.") + "."
    return [prefix + label
            for label, f in _public_functions(module, names if names is not None
                                              else module.__all__)
            if "return" not in f.__annotations__]


def test_public_api_has_return_annotations():
    modules = public_modules()
    assert {"veil", "veil.fitting", "veil.models", "veil.fitting.solver",
            "veil.viz.render"} <= set(modules), modules
    missing = [m for module in modules for m in missing_return_annotations(package=module)]
    assert not missing, missing


def test_a_module_all_is_public_api(tmp_path):
    """A module's own ``__all__`` makes it public API, as a package's does; a module without
    one is not."""
    root = _tree(tmp_path, {
        "fitting/__init__.py": '__all__ = ["solve"]\n',
        "fitting/solver.py": 'def solve(x):\n    return x\n\n\n__all__ = ["solve"]\n',
        "fitting/helpers.py": "def helper(x):\n    return x\n",
        "io.py": "__all__ = []\n",
    })
    assert public_modules(root) == ["veil", "veil.fitting", "veil.fitting.solver", "veil.io"]


def test_a_public_function_without_a_return_annotation_is_caught(monkeypatch):
    import veil
    import veil.fitting

    def unannotated(x):
        return x

    class Solver:
        def run(self) -> None: ...

        @classmethod
        def load(cls, path): ...

    Solver.__module__ = "veil.fitting.solver"
    monkeypatch.setattr(veil, "unannotated", unannotated, raising=False)
    monkeypatch.setattr(veil.fitting, "Solver", Solver, raising=False)
    assert missing_return_annotations(["apparent", "unannotated"]) == ["unannotated"]
    assert missing_return_annotations(["fit_target", "Solver"], "veil.fitting") == [
        "fitting.Solver.load"]
    import veil.fitting.solver

    monkeypatch.setattr(veil.fitting.solver, "unannotated", unannotated, raising=False)
    assert missing_return_annotations(["solve", "unannotated"], "veil.fitting.solver") == [
        "fitting.solver.unannotated"]


#: The sizes docs/architecture.md promises: lines per module, lines per function.
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80


def oversized(root: pathlib.Path = ROOT) -> list[str]:
    """Modules over MAX_MODULE_LINES lines and functions (methods, nested ones) over
    MAX_FUNCTION_LINES, from the first line of the definition to its last."""
    found = []
    for path in _modules(root):
        text = path.read_text()
        name = str(path.relative_to(root))
        if text.count("\n") > MAX_MODULE_LINES:
            found.append(f"{name}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    found.append(f"{name}:{node.lineno}: {node.name} has {lines} lines")
    return found


def test_modules_and_functions_within_their_size():
    assert not oversized(), "\n".join(oversized())


def test_an_oversized_module_and_function_are_caught(tmp_path):
    pkg = tmp_path / "fitting"
    pkg.mkdir()
    body = "\n".join(f"    x{k} = {k}" for k in range(MAX_FUNCTION_LINES))
    (pkg / "long.py").write_text(f"def fine():\n    return 1\n\n\ndef long():\n{body}\n")
    (pkg / "big.py").write_text("\n" * (MAX_MODULE_LINES + 1))
    found = oversized(tmp_path)
    assert any("long.py:5: long has 81 lines" in f for f in found), found
    assert any(f.startswith("fitting/big.py: 601 lines") for f in found), found
    assert not any("fine" in f for f in found)
