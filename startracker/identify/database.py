"""The identification database: navigation stars, star-pair catalog, pattern strings; built once, cached.

``build_database(catalog, camera)`` selects the navigation stars (the catalog, with stars closer than a
couple of pixels resolved as one, as the detector would see them), builds the star-pair catalog of
paper 002 on the k-vector (pairs closer than the FOV diagonal), the reference-star pair catalog, the
main-star pattern strings of paper 003 and a k-d tree for verification, and measures the catalog's
clumping for the false-alarm rule. The result is cached per (catalog object, camera, build options), so
``identify()`` without ``database=`` builds it on the first call only.

Disk cache. The arrays of a database are also stored on disk with :mod:`startracker.cache` (one ``.npz``
per catalog content, camera and build options, atomic, checksummed, no pickle), so a later process
loads them instead of rebuilding: the k-d tree and the sky grid are rebuilt from the stored navigation
stars at load (about a millisecond). A corrupt or stale file is rebuilt, never trusted.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import time
import weakref
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from startracker import cache as disk_cache
from startracker.catalog import StarCatalog, select_navigation_stars
from startracker.kernels.identify import GRID_CELLS, build_sky_grid, pair_count_table
from startracker.identify.pairs import StarPairCatalog, build_pair_catalog
from startracker.kvector import KVector
from startracker.identify.pattern_string import PatternCatalog, build_pattern_catalog
from startracker.optics import Camera

__all__ = ["StarDatabase", "build_database", "clear_database_cache", "default_database", "database_key",
           "database_arrays", "database_from_arrays", "catalog_digest", "DISK_FORMAT"]

_CACHE: "weakref.WeakKeyDictionary[StarCatalog, dict]" = weakref.WeakKeyDictionary()
_LAST: list = []  # [weakref(catalog), camera, database] of the last default look-up


@dataclass(frozen=True, eq=False)
class StarDatabase:
    """Everything identification needs for one (catalog, camera).

    Attributes
    ----------
    camera : Camera
    nav : StarCatalog
        Navigation stars, brightest first; all indices below point into it.
    tree : scipy.spatial.cKDTree
        Over ``nav.vectors`` (verification).
    pairs : StarPairCatalog
        All pairs closer than the FOV diagonal (paper 002 §4.2.1).
    ref_pairs : StarPairCatalog or None
        Pairs whose brighter star is brighter than ``ref_mag_limit`` (reference stars).
    ref_mag_limit : float
    patterns : PatternCatalog
        Main-star pattern strings (paper 003).
    clumping3 : float
        ``⟨ρ³⟩ / ⟨ρ⟩³`` of the star density over FOV-sized cones (1 for a uniform sky).
    density_eff_per_sr : float
        Star density a wrong attitude meets, ``⟨ρ⁴⟩ / ⟨ρ³⟩``, stars per steradian.
    build_time_s : float
        Wall-clock build time.
    options : dict
        The build options.
    grid_start, grid_stars : ndarray of int32
        Sky grid of the navigation stars (:func:`startracker.kernels.identify.build_sky_grid`), the
        compiled kernels' nearest-star index.
    grid_cells : int
        Cells per axis of the sky grid.
    source : str
        ``"built"`` in this process or ``"disk"`` (loaded from the disk cache).
    load_time_s : float
        Wall-clock time of the disk load (0 when built).
    """

    camera: Camera
    nav: StarCatalog
    tree: cKDTree
    pairs: StarPairCatalog
    ref_pairs: StarPairCatalog | None
    ref_mag_limit: float
    patterns: PatternCatalog
    clumping3: float
    density_eff_per_sr: float
    build_time_s: float
    options: dict
    grid_start: np.ndarray
    grid_stars: np.ndarray
    grid_cells: int = GRID_CELLS
    source: str = "built"
    load_time_s: float = 0.0

    @property
    def n_stars(self) -> int:
        return len(self.nav)

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the database's arrays (navigation stars, pairs, reference pairs, strings, tree)."""
        nav = self.nav
        total = nav.hip.nbytes + nav.vectors.nbytes + nav.vmag.nbytes + nav.bv.nbytes
        total += self.pairs.nbytes + (self.ref_pairs.nbytes if self.ref_pairs is not None else 0)
        total += self.patterns.nbytes
        total += self.tree.data.nbytes + self.tree.indices.nbytes
        total += self.grid_start.nbytes + self.grid_stars.nbytes
        return int(total)

    @property
    def pattern_catalog_bytes(self) -> int:
        """Size of the pattern-string catalog with paper 003's storage layout, bytes."""
        return self.patterns.paper_bytes

    @functools.cached_property
    def mean_stars_per_fov(self) -> float:
        """Mean number of navigation stars on the detector (uniform sky)."""
        hx, hy = self.camera.half_fov_rad
        omega = 4.0 * math.asin(math.sin(hx) * math.sin(hy))  # solid angle of the rectangular field
        return self.n_stars * omega / (4.0 * math.pi)

    @functools.cached_property
    def search_arrays(self) -> tuple:
        """The database as the compiled pyramid takes it, gathered once: ``(nav, sorted pair angles, k-vector,
        a1, b1, first, second, grid_start, grid_stars, grid_cells, count_cdf, count_bin_rad)`` (see
        :func:`startracker.kernels.identify.pyramid_search`; the count table is
        :func:`startracker.kernels.identify.pair_count_table`)."""
        kv = self.pairs.kvector
        cdf, bin_rad = pair_count_table(kv.sorted_values)
        # read-only views, whether the database was built here or loaded (memory-mapped): one compiled signature
        ro = _read_only_view
        return (ro(self.nav.vectors), ro(kv.sorted_values), ro(kv.k), float(kv.a1), float(kv.b1), ro(self.pairs.first),
                ro(self.pairs.second), ro(self.grid_start), ro(self.grid_stars), int(self.grid_cells), ro(cdf),
                float(bin_rad))

    @functools.cached_property
    def usable(self) -> bool:
        """Whether the catalog is dense enough for lost-in-space (some pairs, at least a star per frame)."""
        return len(self.pairs) > 0 and self.mean_stars_per_fov >= 1.0

    def p_random(self, tol_rad: float) -> float:
        """Probability that a direction falls within ``tol_rad`` of some navigation star by chance."""
        return min(1.0, self.density_eff_per_sr * math.pi * tol_rad * tol_rad)

    def summary(self) -> str:
        return (
            f"{self.n_stars} navigation stars, {len(self.pairs)} pairs "
            f"(< {np.degrees(self.pairs.max_angle_rad):.2f} deg), "
            f"{0 if self.ref_pairs is None else len(self.ref_pairs)} reference pairs, "
            f"{len(self.patterns.guide)} pattern strings ({self.pattern_catalog_bytes / 1000:.1f} kB paper layout); "
            f"{self.memory_bytes / 1e6:.1f} MB, built in {self.build_time_s:.2f} s"
        )


def _fibonacci_sphere(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _density_moments(tree: cKDTree, n_stars: int, radius_rad: float) -> tuple[float, float]:
    """Clumping ⟨ρ³⟩/⟨ρ⟩³ and the effective density ⟨ρ⁴⟩/⟨ρ³⟩ (per sr) over cones of ``radius_rad``."""
    dirs = _fibonacci_sphere(3000)
    counts = tree.query_ball_point(dirs, r=2 * math.sin(radius_rad / 2), return_length=True).astype(float)
    omega = 2 * math.pi * (1 - math.cos(radius_rad))
    rho = counts / omega
    m1 = rho.mean()
    m3 = (rho**3).mean()
    if m3 <= 0:
        return 1.0, float(n_stars / (4 * math.pi))
    return float(m3 / m1**3), float((rho**4).mean() / m3)


def build_database(
    catalog: StarCatalog,
    camera: Camera,
    *,
    mag_limit: float | None = None,
    min_separation_px: float = 2.0,
    ref_mag_limit: float = 3.6,
    guide_mag_limit: float | None = None,
    guide_min_separation_deg: float = 0.0,
    cache: bool = True,
    disk_folder=None,
) -> StarDatabase:
    """Build (or fetch from the cache) the identification database for a catalog and a camera.

    Parameters
    ----------
    catalog : StarCatalog
        The stars the tracker can see (e.g. ``load_catalog(6.0)``).
    camera : Camera
    mag_limit : float, optional
        Extra V cut on the navigation stars.
    min_separation_px : float
        Stars closer than this (pixels at the boresight) blend into one spot: the fainter is dropped.
    ref_mag_limit : float
        Reference-star pair catalog: pairs whose brighter star has V <= this (paper 002 uses 3.0; the
        default leaves 3σ room for 0.2 mag intensity errors).
    guide_mag_limit : float, optional
        V limit of the main (guide) stars of the pattern strings (default: all navigation stars).
    guide_min_separation_deg : float
        Paper 003 keeps only guide stars more than 3° from a brighter one; 0 (default) keeps all, which
        suits images that contain every star down to the catalog limit.
    cache : bool
        Reuse a database built earlier for the same catalog object, camera and options (in memory).
    disk_folder : path-like or False, optional
        Folder of the disk cache (default :func:`startracker.cache.cache_dir`: ``$STARTRACKER_CACHE_DIR``,
        else ``$XDG_CACHE_HOME/startracker-gym``, else ``~/.cache/startracker-gym``); False: no disk cache.

    Returns
    -------
    StarDatabase
        ``build_time_s``, ``memory_bytes`` and ``pattern_catalog_bytes`` report its cost.
    """
    if not isinstance(catalog, StarCatalog):
        raise TypeError(f"catalog must be a StarCatalog, got {type(catalog).__name__}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    for name, v in (("min_separation_px", min_separation_px), ("ref_mag_limit", ref_mag_limit),
                    ("guide_min_separation_deg", guide_min_separation_deg)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
            raise ValueError(f"{name} must be a finite number, got {v!r}")
    if min_separation_px < 0 or guide_min_separation_deg < 0:
        raise ValueError("min_separation_px and guide_min_separation_deg must be >= 0")
    options = dict(
        mag_limit=None if mag_limit is None else float(mag_limit),
        min_separation_px=float(min_separation_px),
        ref_mag_limit=float(ref_mag_limit),
        guide_mag_limit=None if guide_mag_limit is None else float(guide_mag_limit),
        guide_min_separation_deg=float(guide_min_separation_deg),
    )
    key = (camera, tuple(sorted(options.items())))
    if cache:
        hit = _CACHE.get(catalog, {}).get(key)
        if hit is not None:
            return hit

    t0 = time.perf_counter()
    disk = disk_cache.cache_dir() if disk_folder is None else disk_folder
    if disk_folder is False:
        disk = None
    if disk is None:
        db = _freeze(_build(catalog, camera, options))
    else:
        built: list = []

        def build_arrays():
            built.append(_build(catalog, camera, options))
            return database_arrays(built[0])

        arrays = disk_cache.load_or_build(database_key(catalog, camera, options), build_arrays, folder=disk)
        if built:
            db = built[0]
        else:
            db = database_from_arrays(arrays, camera, options)
            db = dataclasses.replace(db, load_time_s=time.perf_counter() - t0)
        db = _freeze(db)
    if cache:
        _CACHE.setdefault(catalog, {})[key] = db
    return db


def _read_only_view(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def _freeze(obj, depth: int = 0):
    """``obj`` with every array of it and of its dataclass fields (two levels down; not the camera, which is the
    caller's) read-only, in place: the database's own arrays (its catalogs are subsets, copies of the caller's).

    Built or loaded from the disk cache (memory-mapped, read-only), a database then hands the identification
    kernels the same kind of arrays: numba compiles a kernel once per kind (writable or read-only) of each argument,
    so a mix would compile the identification kernels twice (~15 s on a fresh machine)."""
    for f in dataclasses.fields(obj):
        if f.name == "camera":
            continue
        v = getattr(obj, f.name)
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
        elif depth < 2 and dataclasses.is_dataclass(v) and not isinstance(v, type):
            _freeze(v, depth + 1)
    return obj


def _build(catalog: StarCatalog, camera: Camera, options: dict) -> StarDatabase:
    mag_limit = options["mag_limit"]
    min_separation_px = options["min_separation_px"]
    ref_mag_limit = options["ref_mag_limit"]
    guide_mag_limit = options["guide_mag_limit"]
    guide_min_separation_deg = options["guide_min_separation_deg"]
    t0 = time.perf_counter()
    pix_rad = camera.pixel_size_mm / camera.focal_length_mm
    nav = select_navigation_stars(catalog, mag_limit=mag_limit, min_separation_rad=min_separation_px * pix_rad)
    # Corner to corner, with room for distortion and the aberration widening of windows.
    max_angle = min(2.0 * camera.half_diagonal_fov_rad * 1.02, np.pi * 0.999)
    pairs = build_pair_catalog(nav.vectors, nav.vmag, max_angle)
    ref_mask = pairs.first_mag <= ref_mag_limit
    ref_pairs = pairs.subset(ref_mask) if ref_mask.any() else None
    tree = cKDTree(nav.vectors.reshape(-1, 3))
    theta_max = min(camera.half_fov_rad)
    guide_mask = np.ones(len(nav), dtype=bool) if guide_mag_limit is None else nav.vmag <= guide_mag_limit
    if guide_min_separation_deg > 0:
        kept = select_navigation_stars(nav.subset(guide_mask), min_separation_rad=np.radians(guide_min_separation_deg))
        guide_mask = np.isin(nav.hip, kept.hip)
    patterns = build_pattern_catalog(pairs, guide_mask, theta_max)
    clumping, dens = _density_moments(tree, len(nav), max(camera.half_fov_rad))
    grid_start, grid_stars = build_sky_grid(nav.vectors)
    db = StarDatabase(
        camera=camera,
        nav=nav,
        tree=tree,
        pairs=pairs,
        ref_pairs=ref_pairs,
        ref_mag_limit=float(ref_mag_limit),
        patterns=patterns,
        clumping3=clumping,
        density_eff_per_sr=dens,
        build_time_s=time.perf_counter() - t0,
        options=options,
        grid_start=grid_start,
        grid_stars=grid_stars,
    )
    return db


DISK_FORMAT = 2  # version of the stored arrays; bump when their layout or the build changes


def catalog_digest(catalog: StarCatalog) -> str:
    """SHA-256 of a catalog's content (HIP numbers, directions, magnitudes, colours, epoch)."""
    h = hashlib.sha256()
    for a in (catalog.hip, catalog.vectors, catalog.vmag, catalog.bv):
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    h.update(repr(float(getattr(catalog, "epoch", 0.0))).encode())
    return h.hexdigest()


def database_key(catalog: StarCatalog, camera: Camera, options: dict) -> dict:
    """Disk-cache key of a database: everything it depends on, with the format version."""
    cam = {f.name: getattr(camera, f.name) for f in dataclasses.fields(camera) if f.init and f.name != "name"}
    return {
        "kind": "identify-database",
        "format": DISK_FORMAT,
        "grid_cells": GRID_CELLS,
        "catalog": catalog_digest(catalog),
        "camera": {k: (list(v) if isinstance(v, tuple) else v) for k, v in cam.items()},
        "options": options,
    }


def _pairs_arrays(prefix: str, p: StarPairCatalog | None, out: dict) -> None:
    if p is None or p.kvector is None:
        return
    kv = p.kvector
    out[prefix + "first"] = p.first
    out[prefix + "second"] = p.second
    out[prefix + "angle"] = kv.sorted_values
    out[prefix + "k"] = kv.k.astype(np.int64, copy=False)
    out[prefix + "line"] = np.array([kv.a1, kv.b1, p.max_angle_rad])


def _pairs_from(prefix: str, arrays: dict, vmag: np.ndarray, max_angle: float) -> StarPairCatalog | None:
    if prefix + "first" not in arrays:
        if prefix == "pairs_":
            e = np.empty(0, dtype=np.int32)
            f = np.empty(0, dtype=np.float32)
            return StarPairCatalog(first=e, second=e.copy(), first_mag=f, second_mag=f.copy(), kvector=None,
                                   max_angle_rad=max_angle)
        return None
    first, second = arrays[prefix + "first"], arrays[prefix + "second"]
    a1, b1, max_angle_rad = arrays[prefix + "line"].tolist()
    kv = KVector.from_arrays(arrays[prefix + "angle"], None, arrays[prefix + "k"], a1, b1)
    vmag32 = vmag.astype(np.float32)
    return StarPairCatalog(first=first, second=second, first_mag=vmag32[first], second_mag=vmag32[second],
                           kvector=kv, max_angle_rad=max_angle_rad)


def database_arrays(db: StarDatabase) -> dict:
    """The arrays that define a database (what the disk cache stores)."""
    nav = db.nav
    pc = db.patterns
    out = {
        "nav_hip": nav.hip,
        "nav_vectors": nav.vectors,
        "nav_vmag": nav.vmag,
        "nav_bv": nav.bv,
        "nav_epoch": np.array(float(getattr(nav, "epoch", 0.0))),
        "stats": np.array([db.clumping3, db.density_eff_per_sr, db.build_time_s, db.pairs.max_angle_rad,
                           db.ref_mag_limit]),
        "pat_guide": pc.guide,
        "pat_length": pc.length,
        "pat_codes": pc.codes,
        "pat_neighbour": pc.neighbour,
        "pat_below": pc.below,
        "pat_theta_max": np.array(pc.theta_max_rad),
    }
    _pairs_arrays("pairs_", db.pairs, out)
    _pairs_arrays("ref_", db.ref_pairs, out)
    return out


def database_from_arrays(arrays: dict, camera: Camera, options: dict, load_time_s: float = 0.0) -> StarDatabase:
    """A database from :func:`database_arrays` (the k-d tree and the sky grid are rebuilt)."""
    nav = StarCatalog(hip=arrays["nav_hip"], vectors=arrays["nav_vectors"], vmag=arrays["nav_vmag"],
                      bv=arrays["nav_bv"], epoch=float(arrays["nav_epoch"]))
    clumping, dens, build_s, max_angle, ref_lim = arrays["stats"].tolist()
    pairs = _pairs_from("pairs_", arrays, nav.vmag, max_angle)
    ref_pairs = _pairs_from("ref_", arrays, nav.vmag, max_angle)
    patterns = PatternCatalog(guide=arrays["pat_guide"], length=arrays["pat_length"], codes=arrays["pat_codes"],
                              neighbour=arrays["pat_neighbour"], below=arrays["pat_below"],
                              theta_max_rad=float(arrays["pat_theta_max"]))
    grid_start, grid_stars = build_sky_grid(nav.vectors)
    return StarDatabase(
        camera=camera, nav=nav, tree=cKDTree(nav.vectors.reshape(-1, 3)), pairs=pairs, ref_pairs=ref_pairs,
        ref_mag_limit=float(ref_lim), patterns=patterns, clumping3=float(clumping), density_eff_per_sr=float(dens),
        build_time_s=float(build_s), options=dict(options), grid_start=grid_start, grid_stars=grid_stars,
        source="disk", load_time_s=float(load_time_s))


def default_database(catalog: StarCatalog, camera: Camera) -> StarDatabase:
    """The cached default database of (catalog, camera), remembering the last look-up by identity."""
    last = _LAST
    if last and last[0]() is catalog and last[1] is camera:
        return last[2]
    db = build_database(catalog, camera)
    _LAST[:] = [weakref.ref(catalog), camera, db]
    return db


def clear_database_cache() -> None:
    """Forget every cached database."""
    _CACHE.clear()
    _LAST.clear()
