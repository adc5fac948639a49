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


# Rooms of startracker (a room is a top-level module or subpackage: ``startracker/<room>.py`` or
# ``startracker/<room>/``) and the rooms each must NOT import. Read off the code's import graph, low to high:
#
#   base      rotations, validation, kernels, cache
#   data      catalog, optics, photometry, kvector, imu, attitude, filter
#   truth     scene
#   pixels    imaging (detector, background, spots, render) -> centroid (extraction, fidelity)
#   solving   identify, track (siblings: neither imports the other, nor pixels)
#   tracker   sensor (identify + track), head (camera heads: pixels, centroid, color)
#   subsystems  color (3CMOS, paper 004), multifov (distributed FoVs, paper 001): they use the rooms
#             below; only sensor-level code (head, sensor) may import them, and neither imports the other
#   helpers   simulation (synthetic frames for tests and benchmarks): no room imports it
ABOVE_DATA = {"scene", "imaging", "centroid", "identify", "track", "sensor", "head", "color", "multifov", "simulation"}
SUBSYSTEMS = {"color", "multifov"}
SENSOR_LEVEL = {"head", "sensor"}
FORBIDDEN = {
    **{room: ABOVE_DATA for room in ("rotations", "validation", "kernels", "cache", "catalog", "optics",
                                     "photometry", "kvector", "imu", "attitude", "filter")},
    "scene": ABOVE_DATA - {"scene"},
    "imaging": {"centroid", "identify", "track", "sensor", "head", "simulation"} | SUBSYSTEMS,
    "centroid": {"identify", "track", "sensor", "head", "simulation"} | SUBSYSTEMS,
    "identify": {"imaging", "centroid", "track", "sensor", "head", "simulation"} | SUBSYSTEMS,
    "track": {"imaging", "centroid", "identify", "sensor", "head", "simulation"} | SUBSYSTEMS,
    "sensor": {"head", "simulation"},
    "head": {"sensor", "simulation"},
    "color": {"multifov", "sensor", "head", "simulation"},
    "multifov": {"color", "sensor", "head", "simulation"},
    "simulation": {"sensor", "head"} | SUBSYSTEMS,
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
