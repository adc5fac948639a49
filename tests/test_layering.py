"""startracker must not depend on envs or policies; envs must not depend on policies (DESIGN.md §1)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imported_top_modules(package: str):
    for path in (ROOT / package).rglob("*.py"):
        if path.name == "__main__.py":
            continue  # the command-line shim (`python -m envs`) may start the experiments package
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


# What envs/ may import from startracker: the entry points of the sensor (heads, the onboard unit, the tracker
# state machine, the filter), rotations (the env computes attitude errors and the first frame's truth), the
# catalog and gyro presets, and the input-check module (the spacecraft validates its arguments with it). The
# camera simulation (scene, imaging, centroid, colour, optics) and the tracker's internals stay behind these.
ENVS_ALLOWED_STARTRACKER = {
    "startracker.head",
    "startracker.onboard",
    "startracker.sensor",
    "startracker.filter",
    "startracker.rotations",
    "startracker.kernels.rotations",
    "startracker.catalog",
    "startracker.imu",
    "startracker.validation",
}
ENVS_ALLOWED_OTHER = {"envs", "numpy", "gymnasium", "mujoco"}


def envs_import_violations(sources):
    """(file, imported name) pairs of ``sources`` ({name: python source}) breaking the envs import rule."""
    import sys

    bad = []
    for name, text in sources.items():
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Import):
                targets = [(a.name, None) for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [(node.module, a.name) for a in node.names]
            else:
                continue
            for module, member in targets:
                top = module.split(".")[0]
                if member is not None and member.startswith("_") and module != "__future__":
                    bad.append((name, f"{module}.{member}"))  # a private name
                elif top == "startracker":
                    full = module if member is None else f"{module}.{member}"
                    if module not in ENVS_ALLOWED_STARTRACKER and full not in ENVS_ALLOWED_STARTRACKER:
                        bad.append((name, full))
                elif top not in ENVS_ALLOWED_OTHER and top not in sys.stdlib_module_names:
                    bad.append((name, module))
    return bad


def test_envs_imports_only_entry_points():
    sources = {str(p.relative_to(ROOT)): p.read_text() for p in (ROOT / "envs").rglob("*.py") if p.name != "__main__.py"}
    assert len(sources) >= 4
    assert envs_import_violations(sources) == []
    # the rule bites: the camera simulation, a private name, or a module outside the entry points
    assert envs_import_violations({"x.py": "from startracker.scene import compute_scene"}) == [
        ("x.py", "startracker.scene.compute_scene")]
    assert envs_import_violations({"x.py": "from startracker.onboard import _empty_stats"}) != []
    assert envs_import_violations({"x.py": "import startracker.centroid"}) != []
    assert envs_import_violations({"x.py": "from startracker import imaging"}) != []
    assert envs_import_violations({"x.py": "from startracker.kernels import rotations as rk"}) == []
