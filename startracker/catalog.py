"""The star catalog: Hipparcos new reduction, offline, with V magnitudes, navigation-star selection and cone search.

Source: ESA Hipparcos new reduction (I/311, van Leeuwen 2007), converted once by
``scripts/convert_hipparcos.py`` into ``startracker/data/hip2_hp8.npz`` (all stars with Hp <= 8.0).
No download ever happens at run time.

Magnitudes. Hipparcos measured Hp, a broad band; star trackers are specified in Johnson V. V is derived
from Hp and B−V with Bessell (2000, PASP 112, 961) Table 2, which gives V − Hp and B − V as functions of
BT − VT for B–G main-sequence stars and K–M giants; it is interpolated here as a function of B − V.
Accuracy: about 0.01–0.02 mag for −0.25 < B − V < 1.05 (Bessell's own scatter), the range of almost all
navigation stars; outside the table V − Hp is held at the edge value, which for M stars (B − V > 1.4)
can be off by 0.1–0.3 mag. Stars without B − V (stored as 0 with a zero error) get the B − V = 0 value.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from startracker.kernels import catalog as catalog_kernels
from startracker.validation import as_float_array

__all__ = [
    "StarCatalog",
    "load_catalog",
    "radec_to_vector",
    "vector_to_radec",
    "v_from_hp",
    "select_navigation_stars",
    "HIPPARCOS_EPOCH",
    "MAG_LIMIT_RANGE",
]

DATA_FILE = Path(__file__).resolve().parent / "data" / "hip2_hp8.npz"
HIPPARCOS_EPOCH = 1991.25  # Julian year of the I/311 positions
MAG_LIMIT_RANGE = (-1.0, 7.9)  # V; the shipped file is complete to Hp 8.0, i.e. V ~ 7.93
MAS_TO_RAD = np.pi / (180.0 * 3600.0 * 1000.0)

# Bessell (2000) Table 2: BT-VT, del(B-V) where B-V = (BT-VT) + del, and V - Hp.
_BESSELL = np.array(
    [
        [-0.25, 0.031, 0.066], [-0.20, 0.021, 0.051], [-0.15, 0.011, 0.036], [-0.10, 0.005, 0.021],
        [-0.05, 0.002, 0.006], [0.00, -0.005, -0.011], [0.05, -0.010, -0.025], [0.10, -0.017, -0.038],
        [0.15, -0.020, -0.048], [0.20, -0.021, -0.058], [0.25, -0.023, -0.069], [0.30, -0.025, -0.079],
        [0.35, -0.025, -0.087], [0.40, -0.026, -0.094], [0.45, -0.030, -0.101], [0.50, -0.035, -0.108],
        [0.55, -0.045, -0.114], [0.60, -0.051, -0.120], [0.65, -0.060, -0.127], [0.70, -0.068, -0.131],
        [0.75, -0.076, -0.134], [0.80, -0.085, -0.137], [0.85, -0.094, -0.142], [0.90, -0.104, -0.147],
        [0.95, -0.113, -0.151], [1.00, -0.122, -0.155], [1.05, -0.131, -0.158], [1.10, -0.142, -0.157],
        [1.15, -0.154, -0.160], [1.20, -0.166, -0.162],
    ]
)
_BV_TABLE = _BESSELL[:, 0] + _BESSELL[:, 1]
# Hipparcos Hp is biased for the two brightest stars (detector saturation: Sirius Hp = -1.09 against
# V = -1.46); their Johnson V from the Yale Bright Star Catalogue (5th ed.) replaces the derived value.
_V_OVERRIDES = {32349: -1.46, 30438: -0.74}
_V_MINUS_HP_TABLE = _BESSELL[:, 2]


def v_from_hp(hp_mag, bv) -> np.ndarray:
    """Johnson V from Hipparcos Hp and B−V (Bessell 2000 Table 2, see the module docstring).

    Parameters
    ----------
    hp_mag : array_like, shape (K,)
        Hipparcos magnitude.
    bv : array_like, shape (K,)
        Johnson B−V colour index.

    Returns
    -------
    ndarray, shape (K,)
        V magnitude.
    """
    hp = as_float_array(hp_mag, "hp_mag")
    bv = as_float_array(bv, "bv")
    return hp + np.interp(bv, _BV_TABLE, _V_MINUS_HP_TABLE)


def radec_to_vector(ra_rad, dec_rad) -> np.ndarray:
    """ICRS unit vectors (K, 3) from right ascension and declination in rad."""
    ra = np.asarray(ra_rad, dtype=np.float64)
    dec = np.asarray(dec_rad, dtype=np.float64)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def vector_to_radec(v) -> tuple[np.ndarray, np.ndarray]:
    """Right ascension in [0, 2π) and declination in [−π/2, π/2], rad, from vectors (..., 3)."""
    v = as_float_array(v, "v", last_dim=3)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2 * np.pi)
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


@dataclass(frozen=True, eq=False)
class StarCatalog:
    """Stars as a struct of arrays, all of length N.

    Attributes
    ----------
    hip : ndarray of int, shape (N,)
        Hipparcos numbers.
    vectors : ndarray, shape (N, 3)
        ICRS unit vectors at ``epoch``.
    vmag : ndarray, shape (N,)
        Johnson V magnitude.
    bv : ndarray, shape (N,)
        B−V colour index (0 where unknown).
    epoch : float
        Julian year of the positions.
    """

    hip: np.ndarray
    vectors: np.ndarray
    vmag: np.ndarray
    bv: np.ndarray
    epoch: float = 2025.0
    _z_index: tuple = field(init=False, repr=False)

    def __post_init__(self):
        n = len(self.hip)
        v = as_float_array(self.vectors, "vectors", last_dim=3, ndim=2)
        if v.shape[0] != n or len(self.vmag) != n or len(self.bv) != n:
            raise ValueError("hip, vectors, vmag and bv must have the same length")
        norms = np.linalg.norm(v, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-9):
            raise ValueError("vectors must be unit vectors")
        object.__setattr__(self, "hip", np.asarray(self.hip, dtype=np.int64))
        object.__setattr__(self, "vectors", v)
        object.__setattr__(self, "vmag", as_float_array(self.vmag, "vmag"))
        object.__setattr__(self, "bv", as_float_array(self.bv, "bv"))
        # Cone-search structure: stars sorted by z (declination bands), see startracker.kernels.catalog.
        z_order = np.argsort(v[:, 2], kind="stable").astype(np.int64)
        v_by_z = np.ascontiguousarray(v[z_order])
        object.__setattr__(self, "_z_index", (v_by_z, np.ascontiguousarray(v_by_z[:, 2]), z_order))

    def __len__(self) -> int:
        return len(self.hip)

    @property
    def z_index(self) -> tuple:
        """The cone search's index: ``(vectors_by_z (S, 3), z_sorted (S,), order (S,) int64)``, the unit
        vectors sorted by their ICRS z component, those z values (ascending) and the catalog row of each (for a
        compiled caller of :func:`startracker.kernels.catalog.cone_search_angle`)."""
        return self._z_index

    def __repr__(self) -> str:
        return f"StarCatalog({len(self)} stars, V <= {self.vmag.max() if len(self) else float('nan'):.2f}, epoch {self.epoch})"

    def index_of(self, hip) -> np.ndarray:
        """Row indices of the given HIP numbers (array), −1 where absent."""
        hip = np.atleast_1d(np.asarray(hip, dtype=np.int64))
        order = np.argsort(self.hip)
        pos = np.searchsorted(self.hip, hip, sorter=order)
        pos = np.clip(pos, 0, len(self.hip) - 1)
        idx = order[pos]
        return np.where(self.hip[idx] == hip, idx, -1)

    def subset(self, mask_or_index) -> "StarCatalog":
        """A catalog of the selected rows (boolean mask or index array)."""
        sel = np.asarray(mask_or_index)
        return StarCatalog(self.hip[sel], self.vectors[sel], self.vmag[sel], self.bv[sel], self.epoch)

    def cone_search(self, direction, radius_rad: float, *, validate: bool = True) -> np.ndarray:
        """Indices of all stars within ``radius_rad`` of ``direction``.

        A compiled scan of the declination band that can hold the cone (stars sorted by their z component),
        each star tested by its chord ``|v - d| <= 2 sin(radius_rad / 2)`` (relative tolerance 1e-12).

        Parameters
        ----------
        direction : array_like, shape (3,) or (Q, 3)
            Direction(s) in ICRS (normalised here).
        radius_rad : float
            Cone half-angle in rad, in (0, π].
        validate : bool
            False skips the checks and the normalisation: for a caller passing one unit (3,) float64 direction
            and a float radius in (0, π] (the tracker's per-frame prediction).

        Returns
        -------
        ndarray of int (sorted) for one direction, or a list of such arrays for Q directions.
        """
        if not validate:
            return self._cone(direction, float(radius_rad))
        d = as_float_array(direction, "direction", last_dim=3)
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        if np.any(n == 0):
            raise ValueError("direction must be non-zero")
        if not (0 < radius_rad <= np.pi):
            raise ValueError(f"radius_rad must be in (0, pi], got {radius_rad}")
        d = d / n
        if d.ndim == 1:
            return self._cone(np.ascontiguousarray(d), float(radius_rad))
        return [self._cone(np.ascontiguousarray(di), float(radius_rad)) for di in d.reshape(-1, 3)]

    def _cone(self, d: np.ndarray, radius_rad: float) -> np.ndarray:
        return catalog_kernels.cone_search_angle(*self._z_index, d, radius_rad)


def _propagate(ra, dec, pmra_mas_yr, pmdec_mas_yr, years) -> np.ndarray:
    """Linear space motion on the tangent plane (radial velocity and parallax neglected)."""
    u0 = radec_to_vector(ra, dec)
    p = np.stack([-np.sin(ra), np.cos(ra), np.zeros_like(ra)], axis=-1)
    q = np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)], axis=-1)
    du = (p * pmra_mas_yr[:, None] + q * pmdec_mas_yr[:, None]) * (MAS_TO_RAD * years)
    u = u0 + du
    return u / np.linalg.norm(u, axis=1, keepdims=True)


@lru_cache(maxsize=1)
def _raw():
    with np.load(DATA_FILE, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


@lru_cache(maxsize=16)
def _load_cached(mag_limit: float, epoch: float) -> StarCatalog:
    raw = _raw()
    bv = raw["bv"].astype(np.float64)
    vmag = v_from_hp(raw["hp_mag"].astype(np.float64), bv)
    for hip, v in _V_OVERRIDES.items():
        vmag[raw["hip"] == hip] = v
    keep = vmag <= mag_limit
    vec = _propagate(
        raw["ra_rad"][keep],
        raw["dec_rad"][keep],
        raw["pmra_mas_yr"][keep].astype(np.float64),
        raw["pmdec_mas_yr"][keep].astype(np.float64),
        epoch - HIPPARCOS_EPOCH,
    )
    order = np.argsort(vmag[keep], kind="stable")  # brightest first
    return StarCatalog(
        hip=raw["hip"][keep][order].astype(np.int64),
        vectors=vec[order],
        vmag=vmag[keep][order],
        bv=bv[keep][order],
        epoch=float(epoch),
    )


def load_catalog(mag_limit: float = 6.0, epoch: float = 2025.0) -> StarCatalog:
    """Load the Hipparcos catalog, offline.

    Parameters
    ----------
    mag_limit : float
        Keep stars with V <= mag_limit; in ``MAG_LIMIT_RANGE`` (−1 to 7.9).
    epoch : float
        Julian year (e.g. 2025.0) at which positions are given, by proper motion from J1991.25;
        1900 to 2100.

    Returns
    -------
    StarCatalog
        Sorted brightest first. About 5,000 stars for ``mag_limit=6.0``. The object is cached and
        shared: treat it as read-only.
    """
    if not isinstance(mag_limit, (int, float, np.floating, np.integer)) or isinstance(mag_limit, bool):
        raise TypeError(f"mag_limit must be a number, got {type(mag_limit).__name__}")
    if not (MAG_LIMIT_RANGE[0] <= mag_limit <= MAG_LIMIT_RANGE[1]):
        raise ValueError(f"mag_limit must be in [{MAG_LIMIT_RANGE[0]}, {MAG_LIMIT_RANGE[1]}] (V), got {mag_limit}")
    if not isinstance(epoch, (int, float, np.floating, np.integer)) or not (1900.0 <= epoch <= 2100.0):
        raise ValueError(f"epoch must be a Julian year in [1900, 2100], got {epoch!r}")
    return _load_cached(float(mag_limit), float(epoch))


def select_navigation_stars(
    catalog: StarCatalog,
    mag_limit: float | None = None,
    min_separation_rad: float = 0.0,
    mode: str = "drop",
) -> StarCatalog:
    """Navigation stars: a magnitude cut, then close pairs resolved as papers 001 and 003 do.

    Two stars closer than ``min_separation_rad`` would blend into one spot on the detector. With
    ``mode="drop"`` the fainter is removed (the brighter is kept); with ``mode="merge"`` the pair
    becomes one entry at the flux-weighted direction with the summed flux, under the brighter's HIP.
    Pairs are resolved brightest first, so a chain of close stars keeps its brightest member.

    Parameters
    ----------
    catalog : StarCatalog
    mag_limit : float, optional
        V limit applied first.
    min_separation_rad : float
        Separation below which stars are treated as one (rad); 0 keeps all.
    mode : {"drop", "merge"}

    Returns
    -------
    StarCatalog
        Brightest first.
    """
    if mode not in ("drop", "merge"):
        raise ValueError(f"mode must be 'drop' or 'merge', got {mode!r}")
    if not np.isfinite(min_separation_rad) or min_separation_rad < 0:
        raise ValueError(f"min_separation_rad must be >= 0, got {min_separation_rad}")
    cat = catalog if mag_limit is None else catalog.subset(catalog.vmag <= mag_limit)
    order = np.argsort(cat.vmag, kind="stable")
    cat = cat.subset(order)
    if min_separation_rad == 0 or len(cat) < 2:
        return cat
    chord = 2 * np.sin(min_separation_rad / 2)
    pairs = cKDTree(cat.vectors).query_pairs(chord, output_type="ndarray")
    if len(pairs) == 0:
        return cat
    pairs = np.sort(pairs, axis=1)  # column 0 is the brighter (lower index after sorting by vmag)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    alive = np.ones(len(cat), dtype=bool)
    vec = cat.vectors.copy()
    flux = 10 ** (-0.4 * cat.vmag)
    for i, j in pairs:  # a handful of close pairs per catalog: a loop is fine here
        if alive[i] and alive[j]:
            alive[j] = False
            if mode == "merge":
                v = vec[i] * flux[i] + vec[j] * flux[j]
                vec[i] = v / np.linalg.norm(v)
                flux[i] += flux[j]
    vmag = -2.5 * np.log10(flux)
    out = StarCatalog(cat.hip[alive], vec[alive], vmag[alive], cat.bv[alive], cat.epoch)
    return out.subset(np.argsort(out.vmag, kind="stable"))
