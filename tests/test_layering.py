"""startracker must not depend on envs or policies; envs must not depend on policies (DESIGN.md §1)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imported_top_modules(package: str):
    for path in (ROOT / package).rglob("*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    yield path, a.name.split(".")[0]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                yield path, node.module.split(".")[0]


@pytest.mark.parametrize(
    "package,forbidden",
    [("startracker", {"envs", "policies", "experiments"}), ("envs", {"policies", "experiments"}), ("policies", {"experiments"})],
)
def test_import_direction(package, forbidden):
    if not (ROOT / package).exists():
        pytest.fail(f"{package} missing")
    bad = [(str(p.relative_to(ROOT)), m) for p, m in imported_top_modules(package) if m in forbidden]
    assert bad == []
