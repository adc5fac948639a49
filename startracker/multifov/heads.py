"""A star sensor with distributed multiple fields of view (paper 001 §2): K optical heads, one body.

Paper 001 ("A Novel Inertial-aided Star Pattern Matching Method for Distributed Multiple FoVs") mounts
several small, non-overlapping optical heads at large installation angles on a fast vehicle. No head alone
sees enough stars, so the stars of the auxiliary heads are transferred into the *extended image plane* of
the main head and the whole set is matched as one picture. The extraction of the paper lost its symbols;
the equations below are rebuilt from the words and the geometry (our reading):

* **eq. 1-2 (one head, perspective projection).** A star with head-frame coordinates ``(X, Y, Z)`` images
  at ``x = f X / Z``, ``y = f Y / Z`` on the image plane (origin at the image-plane centre, axes along the
  detector sides). The paper's pinhole has the optical-centre-behind-the-plane sign flip; the project's
  convention (docs/design.md, Conventions: +z toward the sky, positive image) drops it, which changes no angle. Eq. 2 is
  the same for the main head (focal ``f_m``) and the auxiliary head (``f_a``).
* **eq. 3 (transfer matrix).** With installation matrices ``C_m`` and ``C_a`` (head -> body, i.e. each
  head's ``Camera.r_cam_to_body``) the auxiliary-to-main transfer is ``C_am = C_mᵀ C_a``.
* **eq. 4 (rebuild and transform).** The auxiliary image point is rebuilt into a head-frame direction with
  its focal length, ``s_a = (x_a, y_a, f_a)``, and rotated into the main head: ``s_m = C_am s_a``.
* **eq. 5 (projection into the extended main plane).** ``x' = f_m s_m,x / s_m,z``,
  ``y' = f_m s_m,y / s_m,z``: the auxiliary stars land outside the main detector on the main image plane
  extended to infinity; starlight is parallel, so this is the image the main head would take with an
  unbounded detector. It needs ``s_m,z > 0``: an auxiliary head whose FoV reaches 90° from the main
  boresight cannot be fused into a plane (``MultiFovSensor.fusable``).

Rebuilding a fused point ``(x', y', f_m)`` gives the same direction as ``C_am s_a``, so inter-star angles
measured on the fused image equal the angles between the stars' body-frame directions; the matcher
(:mod:`startracker.multifov.matcher`) uses those directions (:meth:`MultiFovSensor.body_vectors`).

Image coordinates are measured, i.e. distorted; the rebuild of eq. 4 first removes each head's radial
distortion (:meth:`Camera.undistort_px_to_mm`), and the extended plane is an ideal (distortion-free)
pinhole plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from startracker.catalog import StarCatalog
from startracker.optics import Camera
from startracker.rotations import quat_from_matrix, quat_from_rotvec, quat_to_matrix
from startracker.validation import as_float_array

__all__ = [
    "MultiFovSensor",
    "FusedImage",
    "SkyView",
    "installation_quaternions",
    "PAPER001_HEAD",
    "paper001_head",
]

# Paper 001's Table 1 (the head's parameters) was lost in extraction. §4.3 states 3.0 visible stars on
# average in the main FoV and 50-52 % single-head against 90 % fused successes; a 5° x 5° head on the
# V <= 6.0 sky reproduces both (3.07 stars on average, P(N >= 3) = 0.53 single, 0.91 fused at 45°), so
# the head used here is a small 5° x 5° camera: 1024 x 1024 pixels of 5.5 µm, f = 64.5 mm (17.4"/px).
PAPER001_HEAD = dict(
    resolution=(1024, 1024),
    pixel_size_um=5.5,
    focal_length_mm=0.5 * 1024 * 5.5e-3 / np.tan(np.radians(2.5)),
)

_ORTHO_TOL = 1e-6


def paper001_head(q_cam_to_body=(1.0, 0.0, 0.0, 0.0)) -> Camera:
    """The small 5°×5° head assumed for paper 001 (see ``PAPER001_HEAD``), mounted by ``q_cam_to_body``."""
    return Camera(**PAPER001_HEAD, q_cam_to_body=q_cam_to_body, name="paper001")


def installation_quaternions(matrices) -> np.ndarray:
    """Validate installation matrices (head -> body) and convert them to quaternions.

    Parameters
    ----------
    matrices : array_like, shape (K, 3, 3)
        ``C_k`` with ``v_body = C_k @ v_head``: proper rotation matrices.

    Returns
    -------
    ndarray, shape (K, 4)
        ``q_cam_to_body`` (w, x, y, z) per head.

    Raises
    ------
    ValueError
        A matrix that is singular, not orthonormal, or a reflection (det = −1), naming its index.
    """
    m = as_float_array(matrices, "installation_matrices")
    if m.ndim != 3 or m.shape[1:] != (3, 3):
        raise ValueError(f"installation_matrices must have shape (K, 3, 3), got {m.shape}")
    for k, mk in enumerate(m):
        det = float(np.linalg.det(mk))
        if abs(det) < 1e-9 or np.linalg.matrix_rank(mk, tol=1e-9) < 3:
            raise ValueError(f"installation_matrices[{k}] is singular (det = {det:.3g}): not a rotation")
        err = np.abs(mk.T @ mk - np.eye(3)).max()
        if err > _ORTHO_TOL:
            raise ValueError(
                f"installation_matrices[{k}] is not orthonormal (max |CᵀC − I| = {err:.3g} > {_ORTHO_TOL})"
            )
        if det < 0:
            raise ValueError(f"installation_matrices[{k}] is a reflection (det = {det:.6f}), not a rotation")
    return quat_from_matrix(m)


@dataclass(frozen=True)
class FusedImage:
    """Stars of all heads on the main head's extended image plane (paper 001 eqs. 2-5).

    Attributes
    ----------
    xy_mm : ndarray, shape (n, 2)
        Ideal (undistorted) extended-plane coordinates in mm, origin at the main principal point.
    xy_px : ndarray, shape (n, 2)
        The same in main-head pixel units (column, row) continuing the main pixel grid beyond the detector.
    v_main : ndarray, shape (n, 3)
        Unit directions in the main head frame rebuilt from the plane, ``(x', y', f_m) / |·|``.
    head : ndarray of int, shape (n,)
        Head that observed each star (0 = main).
    index_in_head : ndarray of int, shape (n,)
        Row of the star in that head's detection list.
    """

    xy_mm: np.ndarray
    xy_px: np.ndarray
    v_main: np.ndarray
    head: np.ndarray
    index_in_head: np.ndarray


@dataclass(frozen=True)
class SkyView:
    """Which catalog stars each head sees at one attitude (truth).

    Attributes
    ----------
    star_index : tuple of ndarray of int
        Per head, catalog rows of the stars landing on the detector, brightest first.
    xy : tuple of ndarray, shape (n_k, 2)
        Their pixel coordinates (column, row), distorted as the head measures them.
    """

    star_index: tuple
    xy: tuple

    @property
    def counts(self) -> np.ndarray:
        """Number of visible stars per head, shape (K,)."""
        return np.array([len(s) for s in self.star_index], dtype=np.int64)

    @property
    def n_fused(self) -> int:
        """Stars in the fused FoV (heads do not overlap, so the sum)."""
        return int(self.counts.sum())


@dataclass(frozen=True, eq=False)
class MultiFovSensor:
    """K optical heads strapped to one body; head 0 is the main head (paper 001 §2.3).

    Parameters
    ----------
    heads : sequence of Camera
        Each with its installation ``q_cam_to_body`` (build them with :meth:`Camera.with_mounting`).
    allow_overlap : bool
        Paper 001's heads never overlap; by default two heads whose circumscribed FoV cones intersect
        raise ``ValueError`` (a star seen twice would be matched as two stars).

    Raises
    ------
    TypeError
        ``heads`` is not a non-empty sequence of ``Camera``.
    ValueError
        Two heads point the same way (boresights within 1e-6 rad), or their FoVs overlap.
    """

    heads: tuple
    allow_overlap: bool = False

    def __post_init__(self):
        if isinstance(self.heads, Camera) or not hasattr(self.heads, "__len__") or len(self.heads) == 0:
            raise TypeError("heads must be a non-empty sequence of startracker.optics.Camera")
        for k, h in enumerate(self.heads):
            if not isinstance(h, Camera):
                raise TypeError(f"heads[{k}] must be a Camera, got {type(h).__name__}")
        object.__setattr__(self, "heads", tuple(self.heads))
        ang = self.installation_angles_rad
        hd = self.half_diagonal_fov_rad
        for i in range(self.n_heads):
            for j in range(i + 1, self.n_heads):
                if ang[i, j] < 1e-6:
                    raise ValueError(f"heads[{i}] and heads[{j}] point the same way (boresights {ang[i, j]:.2e} rad apart)")
                if not self.allow_overlap and ang[i, j] < hd[i] + hd[j]:
                    raise ValueError(
                        f"the FoVs of heads[{i}] and heads[{j}] overlap: boresights {np.degrees(ang[i, j]):.2f}° apart, "
                        f"half-diagonals {np.degrees(hd[i]):.2f}° + {np.degrees(hd[j]):.2f}° "
                        "(pass allow_overlap=True to accept)"
                    )

    # ------------------------------------------------------------------ construction
    @classmethod
    def two_heads(cls, camera: Camera, installation_angle_deg: float, **kw) -> "MultiFovSensor":
        """Main and auxiliary head, boresights ``installation_angle_deg`` apart, symmetric about body +z.

        The main head is rotated by +θ/2 about body +x (boresight ``(0, −sin θ/2, cos θ/2)``), the
        auxiliary head by −θ/2 (boresight ``(0, sin θ/2, cos θ/2)``). ``camera``'s own mounting is ignored.
        """
        if not np.isfinite(installation_angle_deg) or not (0.0 < installation_angle_deg <= 180.0):
            raise ValueError(f"installation_angle_deg must be in (0, 180], got {installation_angle_deg}")
        half = np.radians(installation_angle_deg) / 2
        main = camera.with_mounting(quat_from_rotvec([half, 0.0, 0.0]), name=f"{camera.name}-main")
        aux = camera.with_mounting(quat_from_rotvec([-half, 0.0, 0.0]), name=f"{camera.name}-aux")
        return cls((main, aux), **kw)

    @classmethod
    def from_installation_matrices(cls, camera: Camera, installation_matrices, **kw) -> "MultiFovSensor":
        """K copies of ``camera`` with installation matrices ``C_k`` (head -> body), shape (K, 3, 3).

        Singular, non-orthonormal or reflecting matrices raise ``ValueError`` naming the index.
        """
        q = installation_quaternions(installation_matrices)
        return cls(tuple(camera.with_mounting(qk, name=f"{camera.name}-{k}") for k, qk in enumerate(q)), **kw)

    # ------------------------------------------------------------------ geometry
    @property
    def n_heads(self) -> int:
        return len(self.heads)

    @property
    def r_cam_to_body(self) -> np.ndarray:
        """Installation matrices ``C_k`` (K, 3, 3), ``v_body = C_k @ v_head``."""
        return np.stack([h.r_cam_to_body for h in self.heads])

    @property
    def boresights_body(self) -> np.ndarray:
        """Boresights (head +z) in the body frame, shape (K, 3)."""
        return self.r_cam_to_body[:, :, 2]

    @property
    def half_diagonal_fov_rad(self) -> np.ndarray:
        """FoV radius of each head: boresight to the farthest detector corner, rad, shape (K,)."""
        return np.array([h.half_diagonal_fov_rad for h in self.heads])

    @property
    def installation_angles_rad(self) -> np.ndarray:
        """Angles between every two boresights, rad, shape (K, K)."""
        b = self.boresights_body
        c = np.clip(b @ b.T, -1.0, 1.0)
        s = np.linalg.norm(np.cross(b[:, None, :], b[None, :, :]), axis=-1)
        return np.arctan2(s, c)

    def transfer_matrix(self, k: int) -> np.ndarray:
        """Paper 001 eq. 3: ``C_km = C_mᵀ C_k`` mapping head-``k`` coordinates to main-head coordinates, (3, 3)."""
        k = self._check_head(k)
        r = self.r_cam_to_body
        return r[0].T @ r[k]

    @property
    def fusable(self) -> np.ndarray:
        """Per head, bool (K,): its whole FoV lies in front of the main head, so eq. 5 can project it."""
        ang = self.installation_angles_rad[0]
        return ang + self.half_diagonal_fov_rad < np.pi / 2 - 1e-9

    def _check_head(self, k) -> int:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not (0 <= k < self.n_heads):
            raise ValueError(f"head index must be an integer in [0, {self.n_heads - 1}], got {k!r}")
        return int(k)

    def _check_xy_per_head(self, xy_per_head) -> list:
        if not hasattr(xy_per_head, "__len__") or len(xy_per_head) != self.n_heads:
            raise ValueError(f"xy_per_head must hold one (n_k, 2) array per head ({self.n_heads} heads)")
        out = []
        for k, xy in enumerate(xy_per_head):
            a = np.asarray(xy, dtype=np.float64) if len(np.asarray(xy)) else np.empty((0, 2))
            out.append(as_float_array(a.reshape(-1, 2) if a.size == 0 else a, f"xy_per_head[{k}]", last_dim=2, ndim=2))
        return out

    # ------------------------------------------------------------------ fusion (eqs. 2-5)
    def fuse(self, xy_per_head) -> FusedImage:
        """Transfer every head's stars into the main head's extended image plane (paper 001 eqs. 2-5).

        Parameters
        ----------
        xy_per_head : sequence of K array_like, shape (n_k, 2)
            Measured pixel coordinates (column, row) per head.

        Returns
        -------
        FusedImage
            Stars in head order (all of head 0, then head 1, ...).

        Raises
        ------
        ValueError
            A head with stars is not :attr:`fusable` (its FoV reaches 90° from the main boresight, where the
            extended plane does not exist).
        """
        xy_list = self._check_xy_per_head(xy_per_head)
        main = self.heads[0]
        fus = self.fusable
        pts, vs, heads, idx = [], [], [], []
        for k, (cam, xy) in enumerate(zip(self.heads, xy_list)):
            if len(xy) == 0:
                continue
            if not fus[k]:
                raise ValueError(
                    f"heads[{k}] cannot be fused into the main image plane: its FoV reaches "
                    f"{np.degrees(self.installation_angles_rad[0, k] + self.half_diagonal_fov_rad[k]):.1f}° from the main boresight"
                )
            ideal = cam.undistort_px_to_mm(xy)  # eq. 2 (with distortion removed)
            s = np.column_stack([ideal, np.full(len(ideal), cam.focal_length_mm)])  # eq. 4: rebuild
            s_m = s @ self.transfer_matrix(k).T  # eq. 4: C_km s
            xp = main.focal_length_mm * s_m[:, :2] / s_m[:, 2:3]  # eq. 5
            pts.append(xp)
            v = np.column_stack([xp, np.full(len(xp), main.focal_length_mm)])
            vs.append(v / np.linalg.norm(v, axis=1, keepdims=True))
            heads.append(np.full(len(xy), k, dtype=np.int64))
            idx.append(np.arange(len(xy), dtype=np.int64))
        if not pts:
            e = np.empty((0, 2))
            return FusedImage(e, e.copy(), np.empty((0, 3)), np.empty(0, np.int64), np.empty(0, np.int64))
        xy_mm = np.concatenate(pts)
        xy_px = xy_mm / main.pixel_size_mm + np.asarray(main.principal_point)
        return FusedImage(xy_mm, xy_px, np.concatenate(vs), np.concatenate(heads), np.concatenate(idx))

    def body_vectors(self, xy_per_head) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame unit directions of every head's stars (equal to rebuilding the fused image).

        Parameters
        ----------
        xy_per_head : sequence of K array_like, shape (n_k, 2)

        Returns
        -------
        v_body : ndarray, shape (n, 3)
            In head order.
        head : ndarray of int, shape (n,)
        """
        xy_list = self._check_xy_per_head(xy_per_head)
        vs, hs = [np.empty((0, 3))], [np.empty(0, np.int64)]
        for k, (cam, xy) in enumerate(zip(self.heads, xy_list)):
            if len(xy):
                vs.append(cam.unproject(xy) @ cam.r_cam_to_body.T)
                hs.append(np.full(len(xy), k, dtype=np.int64))
        return np.concatenate(vs), np.concatenate(hs)

    # ------------------------------------------------------------------ visibility (truth)
    def view(self, q_body_to_icrs, catalog: StarCatalog, mag_limit: float | None = None) -> SkyView:
        """Catalog stars each head sees at one attitude (truth, no noise).

        Parameters
        ----------
        q_body_to_icrs : array_like, shape (4,)
        catalog : StarCatalog
        mag_limit : float, optional
            Only stars with ``vmag <= mag_limit``.

        Returns
        -------
        SkyView
        """
        if not isinstance(catalog, StarCatalog):
            raise TypeError("catalog must be a StarCatalog")
        q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=1)
        r_body_to_icrs = quat_to_matrix(q)
        idx_all, xy_all = [], []
        for cam in self.heads:
            r_cam_to_icrs = r_body_to_icrs @ cam.r_cam_to_body
            cand = catalog.cone_search(r_cam_to_icrs[:, 2], min(np.pi, cam.half_diagonal_fov_rad * 1.001 + 1e-9))
            if mag_limit is not None:
                cand = cand[catalog.vmag[cand] <= mag_limit]
            if len(cand) == 0:
                idx_all.append(np.empty(0, np.int64))
                xy_all.append(np.empty((0, 2)))
                continue
            xy, inf = cam.project(catalog.vectors[cand] @ r_cam_to_icrs)
            cand, xy = cand[inf], xy[inf]
            order = np.argsort(catalog.vmag[cand], kind="stable")
            idx_all.append(cand[order])
            xy_all.append(xy[order])
        return SkyView(tuple(idx_all), tuple(xy_all))

    def count_visible(self, q_body_to_icrs, catalog: StarCatalog, mag_limits) -> np.ndarray:
        """Visible-star counts per attitude, limiting magnitude and head, vectorised (paper 001 Fig. 8).

        Parameters
        ----------
        q_body_to_icrs : array_like, shape (N, 4)
        catalog : StarCatalog
        mag_limits : array_like, shape (M,)
            Limiting V magnitudes.

        Returns
        -------
        ndarray of int, shape (N, M, K)
        """
        q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=2)
        mags = as_float_array(mag_limits, "mag_limits", ndim=1)
        sel = np.flatnonzero(catalog.vmag <= mags.max())
        vec, vmag = catalog.vectors[sel], catalog.vmag[sel]
        tree = cKDTree(vec)
        r_b2i = quat_to_matrix(q)
        out = np.zeros((len(q), len(mags), self.n_heads), dtype=np.int64)
        for k, cam in enumerate(self.heads):
            r_c2i = r_b2i @ cam.r_cam_to_body  # (N, 3, 3)
            chord = 2 * np.sin(min(np.pi, cam.half_diagonal_fov_rad * 1.001) / 2)
            lists = tree.query_ball_point(r_c2i[:, :, 2], r=chord)
            lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
            if lens.sum() == 0:
                continue
            att = np.repeat(np.arange(len(q)), lens)
            star = np.fromiter((s for x in lists for s in x), dtype=np.int64, count=int(lens.sum()))
            v_cam = np.einsum("nji,nj->ni", r_c2i[att], vec[star])  # R^T v
            _, inf = cam.project(v_cam)
            ok_mag = vmag[star][:, None] <= mags[None, :]  # (P, M)
            w = inf[:, None] & ok_mag
            for m in range(len(mags)):
                out[:, m, k] = np.bincount(att[w[:, m]], minlength=len(q))
        return out

    def observe(
        self,
        q_body_to_icrs,
        catalog: StarCatalog,
        rng: np.random.Generator | None = None,
        sigma_px: float = 0.0,
        mag_limit: float | None = None,
        *,
        mag_sigma: float = 0.0,
        n_false: int = 0,
        missing: int = 0,
    ) -> tuple[list, list]:
        """Synthetic detections: the visible stars' pixel coordinates with Gaussian centroid noise, and, as the
        single head's identification frames have them (:func:`startracker.simulation.simulate_identification_frame`),
        missing stars, false stars and magnitude noise, per head.

        Per head, in this order: ``missing`` of its visible stars are removed at random; centroid noise of
        ``sigma_px`` per axis; ``n_false`` false stars uniform over its detector, with magnitudes uniform over
        the range of that head's true detections (V 3 to 6 when it has none); every magnitude gets Gaussian noise
        of ``mag_sigma``; the list is sorted brightest first by *measured* magnitude (the order the matcher sees).
        With all three at 0 no random number is drawn for them (the same frames as before they existed).

        Parameters
        ----------
        q_body_to_icrs : array_like, shape (4,)
        catalog : StarCatalog
        rng : numpy.random.Generator, optional
            Required when any noise, false or missing star is asked for.
        sigma_px : float
            1σ centroid noise per axis, px.
        mag_limit : float, optional
        mag_sigma : float
            1σ magnitude noise (>= 0).
        n_false : int
            False stars per head (>= 0).
        missing : int
            Visible stars removed at random per head (>= 0; at most all of them).

        Returns
        -------
        xy_per_head : list of K ndarray, shape (n_k, 2)
            Brightest first (measured magnitude).
        star_index_per_head : list of K ndarray of int, shape (n_k,)
            Catalog rows (truth), -1 for a false star.
        """
        if not np.isfinite(sigma_px) or sigma_px < 0:
            raise ValueError(f"sigma_px must be >= 0, got {sigma_px}")
        if not np.isfinite(mag_sigma) or mag_sigma < 0:
            raise ValueError(f"mag_sigma must be >= 0, got {mag_sigma}")
        for name, val in (("n_false", n_false), ("missing", missing)):
            if isinstance(val, bool) or int(val) != val or val < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {val!r}")
        n_false, missing = int(n_false), int(missing)
        noisy = sigma_px > 0 or mag_sigma > 0 or n_false > 0 or missing > 0
        if noisy and not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator when noise, false or missing stars are asked for")
        v = self.view(q_body_to_icrs, catalog, mag_limit)
        xy_out, idx_out = [], []
        for cam, x, idx in zip(self.heads, v.xy, v.star_index):
            idx = idx.copy()
            if missing > 0 and len(idx):
                keep = np.ones(len(idx), dtype=bool)
                keep[rng.choice(len(idx), size=min(missing, len(idx)), replace=False)] = False
                x, idx = x[keep], idx[keep]
            x = x + (rng.normal(0.0, sigma_px, x.shape) if sigma_px > 0 else 0.0)
            mag = catalog.vmag[idx].astype(np.float64)
            if n_false > 0:
                w, h = cam.resolution
                fxy = np.column_stack([rng.uniform(-0.5, w - 0.5, n_false), rng.uniform(-0.5, h - 0.5, n_false)])
                lo, hi = (mag.min(), mag.max()) if len(mag) else (3.0, 6.0)
                x = np.vstack([x, fxy])
                mag = np.concatenate([mag, rng.uniform(lo, hi, n_false)])
                idx = np.concatenate([idx, np.full(n_false, -1, dtype=idx.dtype)])
            if mag_sigma > 0:
                mag = mag + rng.normal(0.0, mag_sigma, len(mag))
            if n_false > 0 or mag_sigma > 0:
                order = np.argsort(mag, kind="stable")
                x, idx = x[order], idx[order]
            xy_out.append(x)
            idx_out.append(idx)
        return xy_out, idx_out
