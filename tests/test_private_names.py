"""A module keeps its underscore names to itself (docs/design.md, "Validation and kernels").

Two rules over every project package and script: no ``from <project module> import _name``, and no ``obj._name``
on an object other than ``self``/``cls`` unless ``_name`` is defined in the same module (a class may reach the
private state of another instance of itself, or a module its own helpers, never another module's); nor
``getattr``/``hasattr`` with such a name.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("startracker", "envs", "policies", "experiments")
SCANNED = PROJECT + ("benchmarks", "scripts")


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _defined_names(tree) -> set:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del)):
            names.add(node.attr)
        elif isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__slots__" for t in node.targets):
            names.update(c.value for c in ast.walk(node.value) if isinstance(c, ast.Constant) and isinstance(c.value, str))
        elif isinstance(node, ast.arg):
            names.add(node.arg)
    return names


def crossings(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    defined = _defined_names(tree)
    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PROJECT:
            out += [f"{where}:{node.lineno} imports {node.module}.{a.name}"
                    for a in node.names if _private(a.name)]
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            out += [f"{where}:{node.lineno} imports .{a.name}" for a in node.names if _private(a.name)]
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load) and _private(node.attr):
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                continue
            if node.attr not in defined:
                out.append(f"{where}:{node.lineno} reaches .{node.attr}")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr")
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
              and _private(node.args[1].value) and node.args[1].value not in defined):
            out.append(f"{where}:{node.lineno} reaches .{node.args[1].value} by name")
    return out


def all_files():
    for package in SCANNED:
        yield from sorted((ROOT / package).rglob("*.py"))


def test_no_underscore_name_crosses_a_module_boundary():
    bad = [c for f in all_files() for c in crossings(f)]
    assert bad == []


def test_the_rule_catches_a_reach_in(tmp_path):
    """The scanner itself: each kind of crossing is found, a module's own private names are not."""
    f = tmp_path / "scratch.py"
    f.write_text(
        "from startracker.rotations import _canonical_sign\n"
        "from startracker import track\n"
        "def _own():\n    return 1\n"
        "class A:\n    def __init__(self):\n        self._x = 1\n    def same(self, other):\n        return other._x + _own()\n"
        "def f(tracker, spacecraft):\n    return tracker._mode, spacecraft._step_recording, hasattr(tracker, '_state')\n"
    )
    found = crossings(f)
    assert len(found) == 4, found
    assert any("_canonical_sign" in c for c in found)
    assert any("._mode" in c for c in found) and any("._step_recording" in c for c in found)
