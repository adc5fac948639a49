"""The import direction of docs/design.md ("Layout"): startracker never imports envs, policies or experiments;
envs never imports policies or experiments; inside startracker, each room imports only the rooms below it."""

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


# Rooms of startracker (a room is a top-level module or subpackage: ``startracker/<room>.py`` or
# ``startracker/<room>/``) and the rooms each must NOT import. Read off the code's import graph, low to high:
#
#   base      rotations, validation, kernels, cache
#   data      catalog, optics, photometry, kvector, imu, attitude, filter, processor
#   truth     scene
#   pixels    imaging (detector, background, spots, render) -> centroid (extraction, fidelity)
#   solving   identify, track (siblings: neither imports the other, nor pixels)
#   spec      spec (a star tracker described as data: optics, detector, exposure; reads the centroid theory)
#   tracker   sensor (identify + track), head (camera heads: pixels, centroid, color)
#   subsystems  color (3CMOS, paper 004), multifov (distributed FoVs, paper 001): they use the rooms
#             below; only sensor-level code (head, sensor) may import them, and neither imports the other
#   unit      onboard (heads + trackers + gyro + EKF observing a truth history: what the env runs)
#   helpers   simulation (synthetic frames for tests and benchmarks): no room imports it
ABOVE_DATA = {"scene", "imaging", "centroid", "identify", "track", "sensor", "head", "color", "multifov", "simulation",
              "onboard", "spec"}
SUBSYSTEMS = {"color", "multifov"}
SENSOR_LEVEL = {"head", "sensor", "onboard"}
FORBIDDEN = {
    **{room: ABOVE_DATA for room in ("rotations", "validation", "kernels", "compilation", "cache", "catalog", "optics",
                                     "photometry", "kvector", "imu", "attitude", "filter", "processor")},
    "scene": ABOVE_DATA - {"scene"},
    "imaging": {"centroid", "identify", "track", "sensor", "head", "simulation", "onboard"} | SUBSYSTEMS,
    "centroid": {"identify", "track", "sensor", "head", "simulation", "onboard"} | SUBSYSTEMS,
    "identify": {"imaging", "centroid", "track", "sensor", "head", "simulation", "onboard"} | SUBSYSTEMS,
    "track": {"imaging", "centroid", "identify", "sensor", "head", "simulation", "onboard"} | SUBSYSTEMS,
    "spec": {"identify", "track", "sensor", "head", "simulation", "onboard"} | SUBSYSTEMS,
    "sensor": {"head", "simulation", "onboard"},
    "head": {"sensor", "simulation", "onboard"},
    "color": {"multifov", "sensor", "head", "simulation", "onboard"},
    "multifov": {"color", "sensor", "head", "simulation", "onboard"},
    "simulation": {"sensor", "head", "onboard"} | SUBSYSTEMS,
    "onboard": {"simulation"},
}
# Modules of a subsystem or split room must not reach into each other's private names either.
SPLIT_ROOMS = ("imaging", "centroid", "color", "multifov", "simulation")


def room_of(path: Path) -> str:
    rel = path.relative_to(ROOT / "startracker")
    return rel.parts[0].removesuffix(".py")


def imported_rooms(path: Path):
    """(room, imported names) for every absolute ``startracker.<room>`` import in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] == "startracker" and len(parts) > 1:
                    yield parts[1], ()
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            parts = node.module.split(".")
            if parts[0] != "startracker":
                continue
            if len(parts) == 1:  # from startracker import rotations as rot
                for a in node.names:
                    yield a.name, ()
            else:
                yield parts[1], tuple(a.name for a in node.names)


def startracker_modules():
    return [p for p in (ROOT / "startracker").rglob("*.py") if p.name != "__init__.py" or p.parent.name != "startracker"]


def test_rooms_in_table_exist():
    """The table names real rooms, and every room of the package has a row (so a new room gets a rule)."""
    rooms = {room_of(p) for p in startracker_modules()}
    for room in ("imaging", "centroid", "color", "multifov", "simulation"):
        assert room in rooms, f"startracker/{room} missing"
    for sub in ("imaging", "centroid", "color", "multifov"):
        assert (ROOT / "startracker" / sub / "__init__.py").is_file(), f"startracker/{sub} is not a subpackage"
    assert rooms - set(FORBIDDEN) == set(), "rooms without a row in FORBIDDEN"


def test_room_import_direction():
    bad = []
    for path in startracker_modules():
        room = room_of(path)
        for target, _ in imported_rooms(path):
            if target != room and target in FORBIDDEN.get(room, set()):
                bad.append((str(path.relative_to(ROOT)), target))
    assert bad == []


def test_subsystems_only_imported_by_sensor_level_code():
    """Inside startracker, color and multifov are imported only by themselves and head/sensor."""
    bad = []
    for path in startracker_modules():
        room = room_of(path)
        for target, _ in imported_rooms(path):
            if target in SUBSYSTEMS and target != room and room not in SENSOR_LEVEL:
                bad.append((str(path.relative_to(ROOT)), target))
    assert bad == []


def test_split_rooms_share_only_public_names():
    """No file imports an underscore name from imaging, centroid, color, multifov or simulation."""
    bad = []
    for package in ("startracker", "envs", "policies", "experiments", "benchmarks", "scripts", "tests"):
        for path in (ROOT / package).rglob("*.py"):
            for target, names in imported_rooms(path):
                if target in SPLIT_ROOMS:
                    bad += [(str(path.relative_to(ROOT)), target, n) for n in names if n.startswith("_")]
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


def test_big_modules_say_why():
    """A room over ~600 lines is split along its own concepts, or its docstring says why it stays whole."""
    packages = ("startracker", "envs", "policies", "experiments")
    big = []
    for package in packages:
        for path in (ROOT / package).rglob("*.py"):
            text = path.read_text()
            if text.count("\n") > 620:
                doc = ast.get_docstring(ast.parse(text)) or ""
                if "over 600 lines because" not in doc and "about 600 lines" not in doc:
                    big.append(str(path.relative_to(ROOT)))
    assert big == []
