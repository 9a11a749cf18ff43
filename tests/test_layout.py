"""The package's folders are its architecture (docs/architecture.md): data flows one way,
models -> engine -> data -> fitting -> analysis -> viz -> pipeline -> cli, and a module
imports only from its own layer or below (the top-level facade ``veil/__init__.py``, which
imports lazily, excepted). Outside ``models/`` no code names a model class."""

from __future__ import annotations

import ast
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "src" / "veil"
#: Layers, lowest first; a module's layer is its first package below veil.
LAYERS = [("_extras", "_jax", "_lazy", "errors", "io", "numbers"), ("models",), ("engine",), ("data",),
          ("fitting", "maps"), ("analysis", "interop"), ("viz",), ("pipeline",), ("cli",)]
RANK = {name: k for k, names in enumerate(LAYERS) for name in names}


def _modules():
    return sorted(p for p in ROOT.rglob("*.py") if p.name != "__init__.py" or p.parent != ROOT)


def _layer(parts) -> str:
    return parts[0].removesuffix(".py")


def _imports(path: pathlib.Path):
    """(line, imported module parts relative to veil) of every import of veil's own modules."""
    tree = ast.parse(path.read_text())
    package = list(path.relative_to(ROOT).parent.parts)
    for node in ast.walk(tree):
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
