"""Pixels to DN and the two rendering paths of :mod:`startracker.imaging`: full frame and sparse windows.

Rendering paths
---------------
* :func:`render_frame` draws the full frame (for ``render()`` and tests).
* :func:`render_sparse` draws only windows around the spots (the pixels where a spot's expected light
  exceeds 0.3 σ of the background noise: a dropped pixel's chance of crossing a 5σ threshold rises
  from 2.9e-7 to at most 1.3e-6, about 0.02 missed crossings per frame of 450 spots), hot pixels and
  cosmic rays, and draws the rest of the background's threshold crossings from its statistics: per
  cell of a grid fine enough that the background changes by < 0.25 DN across a cell (at most 64×64,
  one cell when the background is flat), a Poisson number of crossing pixels
  with mean ``n_px · P(DN > threshold)``, uniform positions, values from the Gaussian tail above the
  threshold, each with its 3×3 neighbourhood drawn as plain background. Pixels are deduplicated with a
  persistent index buffer (no sort), so overlapping windows share one noisy value. Both paths use
  :func:`_pixels_to_dn`, so their statistics agree (tests/test_imaging.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.special import ndtr, ndtri

from startracker.imaging.background import BackgroundField, FalseObjects, background_field, draw_false_objects
from startracker.imaging.detector import SensorModel, fixed_pattern
from startracker.validation import check_real, check_rng
from startracker.imaging.spots import (
    KIND_HOT_PIXEL,
    KIND_NOISE,
    SourceTable,
    frame_spots,
    randomize_intensified,
    render_bucketed,
    render_windows,
    window_half_widths,
)
from startracker.scene import Scene

__all__ = [
    "SparseFrame",
    "render_frame",
    "render_expected",
    "render_sparse",
    "draw_false_pixels",
]


_SPARSE_FLOOR = 0.3  # sparse windows keep pixels whose expected light exceeds this fraction of the noise σ
_FULL_FLOOR = 0.02  # the full frame draws spots out to where they fall to this fraction of the noise σ
_FALSE_GRID = 64  # cells per axis for drawing the background's threshold crossings


# ----------------------------------------------------------------------------------- pixel values
def _pixels_to_dn(spot_opt, bg: BackgroundField, opt_bg, prnu, model: SensorModel, rng, *,
                  hot_at=None, hot_e=None, direct_at=None, direct_e=None, dtype=np.float64):
    """Random DN of pixels given their expected signals (shared by the full-frame and sparse paths).

    Parameters
    ----------
    spot_opt : ndarray, shape (U,)
        Intensified: the randomised spot charge, e⁻; CMOS: the expected star photoelectrons.
    opt_bg : float or ndarray, shape (U,)
        Optical background photoelectrons (``bg.optical_pe`` at the pixels).
    prnu : ndarray, shape (U,) or None
    hot_at, hot_e : indices into the U pixels and their extra dark charge (hot pixels), e⁻.
    direct_at, direct_e : indices and charge deposited directly (cosmic rays), e⁻.
    """
    g = model.intensifier_gain
    u = spot_opt.shape[0]
    base_var = bg.dark_e + bg.read_var_e2
    z = rng.standard_normal(u, dtype=dtype)
    if model.intensified:
        q = spot_opt + g * opt_bg if np.ndim(opt_bg) or opt_bg != 0 else spot_opt.copy()
        sd = np.sqrt(bg.enf2_c * q + base_var)
        if prnu is not None:
            q *= 1.0 + prnu
        e = q
        e += bg.dark_e
        e += sd * z
    else:
        b = g * opt_bg
        sd = np.sqrt(bg.enf2_c * b + base_var)
        e = sd * z
        e += (b * (1.0 + prnu) if prnu is not None else b) + bg.dark_e
        nz = np.flatnonzero(spot_opt > 0)
        if len(nz):
            n_pe = rng.poisson(spot_opt[nz])
            k = model.gamma_shape_per_pe
            if math.isinf(k):
                charge = g * n_pe.astype(np.float64)
            else:
                charge = rng.gamma(np.maximum(k * n_pe, 1e-300), g / k) * (n_pe > 0)
            e[nz] += (1.0 + prnu[nz]) * charge if prnu is not None else charge
    if hot_at is not None and len(hot_at):
        e[hot_at] += hot_e + np.sqrt(hot_e) * rng.standard_normal(len(hot_at))
    if direct_at is not None and len(direct_at):
        e[direct_at] += direct_e
    np.minimum(e, model.full_well_e, out=e)
    e *= 1.0 / model.gain_e_per_dn
    e += model.bias_dn
    np.rint(e, out=e)
    np.clip(e, 0.0, model.adc_max_dn, out=e)
    return e


def _check_inputs(scene, model, rng):
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a startracker.scene.Scene, got {type(scene).__name__}")
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    if rng is not None:
        check_rng(rng)


def _prepare(scene, model, rng, false_objects):
    fo = draw_false_objects(scene, model, rng) if false_objects is None else false_objects
    if not isinstance(fo, FalseObjects):
        raise TypeError("false_objects must be a FalseObjects (or None to draw them)")
    optical, cosmic, table = frame_spots(scene, model, fo)
    return fo, optical, cosmic, table


def _hot_expected(model, scene):
    _, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    return hot_idx, hot_rate * scene.plan.integration_window_s


# ----------------------------------------------------------------------------------- full frame
def render_frame(scene: Scene, model: SensorModel, rng: np.random.Generator, *, false_objects: FalseObjects | None = None) -> np.ndarray:
    """Draw the full detector frame (for display and tests; the fast path is :func:`render_sparse`).

    Parameters
    ----------
    scene : Scene
    model : SensorModel
    rng : numpy.random.Generator
    false_objects : FalseObjects, optional
        Debris and cosmic rays; drawn from ``rng`` when None (``FalseObjects.none()`` for none).

    Returns
    -------
    image : ndarray of float32, shape (n_rows, n_cols)
        DN, indexed ``image[row, col]``.
    """
    _check_inputs(scene, model, rng)
    check_rng(rng)
    fo, optical, cosmic, _ = _prepare(scene, model, rng, false_objects)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    bg = background_field(scene, model)
    spot = np.zeros(n_px, dtype=np.float32)
    direct = np.zeros(n_px, dtype=np.float32) if cosmic is not None else None
    if optical is not None:
        hw = window_half_widths(optical, bg, model.intensifier_gain, _FULL_FLOOR)
        if model.intensified:
            randomize_intensified(optical, model, rng)
        lin, val, _ = render_bucketed(optical, hw, n_cols, n_rows)
        np.add.at(spot, lin, val)
    if cosmic is not None:
        lin, val, _ = render_windows(cosmic, 3, n_cols, n_rows)
        np.add.at(direct, lin, val)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    if bg.flat:
        opt = max(bg.opt0, 0.0)
    else:
        opt = bg.optical_pe(np.arange(n_cols, dtype=np.float32)[None, :], np.arange(n_rows, dtype=np.float32)[:, None]).astype(np.float32).ravel()
    d_at = np.flatnonzero(direct) if cosmic is not None else None
    dn = _pixels_to_dn(spot, bg, opt, prnu, model, rng, hot_at=hot_idx, hot_e=hot_rate * scene.plan.integration_window_s,
                       direct_at=d_at, direct_e=None if d_at is None else direct[d_at], dtype=np.float32)
    return dn.reshape(n_rows, n_cols).astype(np.float32, copy=False)


def render_expected(scene: Scene, model: SensorModel, *, include_background: bool = True,
                    false_objects: FalseObjects | None = None) -> np.ndarray:
    """Expected charge of every pixel without noise, clipping or quantisation, e⁻.

    ``(1 + PRNU) × G × (star light + sky + stray light) [+ dark + hot pixels] + cosmic-ray charge``;
    the background terms only with ``include_background``; no false objects unless given.

    Returns
    -------
    ndarray of float64, shape (n_rows, n_cols)
    """
    _check_inputs(scene, model, None)
    fo = FalseObjects.none() if false_objects is None else false_objects
    optical, cosmic, _ = frame_spots(scene, model, fo)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    light = np.zeros(n_px)
    bg = background_field(scene, model)
    if optical is not None:
        hw = np.maximum(window_half_widths(optical, bg, model.intensifier_gain, _FULL_FLOOR),
                        int(math.ceil(6 * model.sigma_px)) + 1)
        lin, val, _ = render_bucketed(optical, hw, n_cols, n_rows)
        np.add.at(light, lin, val * model.intensifier_gain)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    if include_background:
        rows, cols = np.divmod(np.arange(n_px), n_cols)
        light += bg.gain * bg.optical_pe(cols, rows)
    img = light if prnu is None else light * (1.0 + prnu)
    if include_background:
        img += bg.dark_e
        img[hot_idx] += hot_rate * scene.plan.integration_window_s
    if cosmic is not None:
        lin, val, _ = render_windows(cosmic, 3, n_cols, n_rows)
        np.add.at(img, lin, val)
    return img.reshape(n_rows, n_cols)


# ----------------------------------------------------------------------------------- sparse frame
class _PixelIndex:
    """Sort-free deduplication of linear pixel indices with a persistent int32 buffer.

    The buffer is never cleared: a lookup is valid only if the stored compact id points back to the same
    pixel (the 'sparse set' trick). One buffer per detector size is shared by all frames of the process
    (not thread-safe); a frame that finds the buffer taken over by a later frame rewrites its own ids
    (O(U)) before looking up.
    """

    _buffers: dict = {}
    _owner: dict = {}

    def __init__(self, n_px: int):
        buf = self._buffers.get(n_px)
        if buf is None:
            buf = np.zeros(n_px, dtype=np.int32)
            self._buffers[n_px] = buf
        self.n_px = n_px
        self.buf = buf
        self.uniq = np.zeros(0, dtype=np.int64)

    def unique(self, lin: np.ndarray):
        """Unique pixels of ``lin`` (E,) and, for each entry, its compact id. Returns (uniq (U,), inv (E,))."""
        e = np.arange(len(lin), dtype=np.int32)
        self.buf[lin] = e
        rep = self.buf[lin]
        first = np.flatnonzero(rep == e)
        compact = np.empty(len(lin), dtype=np.int32)
        compact[first] = np.arange(len(first), dtype=np.int32)
        inv = compact[rep]
        self.uniq = lin[first]
        self.buf[self.uniq] = np.arange(len(first), dtype=np.int32)
        self._owner[self.n_px] = self
        return self.uniq, inv

    def contains(self, lin: np.ndarray) -> np.ndarray:
        """Compact id of each pixel in ``lin`` among the last ``unique`` call's pixels, −1 if absent."""
        u = self.uniq
        if len(u) == 0:
            return np.full(len(lin), -1, dtype=np.int64)
        if self._owner.get(self.n_px) is not self:
            self.buf[u] = np.arange(len(u), dtype=np.int32)
            self._owner[self.n_px] = self
        cand = self.buf[lin].astype(np.int64)
        ok = (cand >= 0) & (cand < len(u))
        cand_c = np.where(ok, cand, 0)
        ok &= u[cand_c] == lin
        return np.where(ok, cand_c, -1)


@dataclass(frozen=True, eq=False)
class SparseFrame:
    """The pixels of a frame that matter: windows around the light sources and the background's
    threshold crossings (with their 3×3 neighbourhoods).

    Attributes
    ----------
    shape : (int, int)
        (n_rows, n_cols).
    lin : ndarray of int64, shape (U,)
        Linear pixel indices ``row * n_cols + col``.
    rows, cols : ndarray of int64, shape (U,)
    dn : ndarray of float32, shape (U,)
        Pixel values, DN.
    background_dn : ndarray, shape (U,)
        Expected background there, DN.
    threshold_dn : ndarray, shape (U,)
        Detection threshold ``background + k σ``, DN.
    saturation_dn : float
    sources : SourceTable
    entry_pixel, entry_source : ndarray of int, shape (E,)
        Per rendered entry: compact pixel id and source id.
    entry_e : ndarray, shape (E,)
        Expected charge that source puts in that pixel, e⁻ (for truth labels).
    k_sigma : float
    background_dn_centre, noise_dn_centre : float
        Background level and σ at the principal point, DN.
    """

    shape: tuple
    lin: np.ndarray
    dn: np.ndarray
    background_dn: np.ndarray
    threshold_dn: np.ndarray
    saturation_dn: float
    sources: SourceTable
    entry_pixel: np.ndarray
    entry_source: np.ndarray
    entry_e: np.ndarray
    k_sigma: float
    _index: _PixelIndex
    background_dn_centre: float = float("nan")
    noise_dn_centre: float = float("nan")

    @cached_property
    def _rows_cols(self):
        return np.divmod(self.lin, self.shape[1])

    @property
    def rows(self) -> np.ndarray:
        return self._rows_cols[0]

    @property
    def cols(self) -> np.ndarray:
        return self._rows_cols[1]

    def linear_ids(self, lin: np.ndarray) -> np.ndarray:
        """Compact ids of pixels given as int64 linear indices ``row * n_cols + col`` on the detector (−1 where not
        in the sparse set)."""
        return self._index.contains(lin)

    def pixel_ids(self, rows, cols) -> np.ndarray:
        """Compact ids of pixels (−1 where not in the sparse set or off the detector)."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        n_rows, n_cols = self.shape
        inside = (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)
        lin = np.where(inside, rows * n_cols + cols, 0)
        ids = self._index.contains(lin)
        return np.where(inside, ids, -1)

    def to_image(self, fill: float | None = None) -> np.ndarray:
        """A full frame with the sparse pixels set and the rest at ``fill`` (default the mean background)."""
        n_rows, n_cols = self.shape
        f = float(np.median(self.background_dn)) if fill is None and len(self.lin) else (fill or 0.0)
        img = np.full(n_rows * n_cols, f, dtype=np.float32)
        img[self.lin] = self.dn
        return img.reshape(n_rows, n_cols)


def draw_false_pixels(bg: BackgroundField, k_sigma: float, n_cols: int, n_rows: int, model: SensorModel, rng):
    """Background pixels above the threshold, drawn from the noise statistics (module docstring).

    Returns linear indices (F,) and their DN values (F,).
    """
    if bg.flat:  # one cell: the crossing probability is the same everywhere
        mu_e = float(bg.mean_e(bg.cx, bg.cy))
        sd_e = math.sqrt(float(bg.var_e(bg.cx, bg.cy)))
        thr = float(bg.threshold_dn(bg.cx, bg.cy, k_sigma))
        z0 = ((math.floor(thr) + 0.5 - model.bias_dn) * model.gain_e_per_dn - mu_e) / sd_e
        p = float(ndtr(-z0)) if math.floor(thr) + 1 <= model.saturation_dn else 0.0  # a clipped pixel cannot cross
        tot = int(rng.poisson(p * n_cols * n_rows))
        if tot == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        lin = rng.integers(0, n_cols * n_rows, tot)
        z = np.maximum(-ndtri(np.clip(rng.random(tot) * p, 1e-300, None)), z0)
        e = np.minimum(mu_e + sd_e * z, model.full_well_e)
        dn = np.clip(np.rint(e / model.gain_e_per_dn + model.bias_dn), math.floor(thr) + 1, model.adc_max_dn)
        return lin, dn
    # cells fine enough that the background changes by < 0.25 DN across one (the crossing probability of
    # quantised pixels depends on where the threshold falls between two DN levels)
    dn_per_pe = bg.gain / model.gain_e_per_dn
    gx = int(min(_FALSE_GRID, n_cols, max(1, math.ceil(4 * abs(bg.opt_dx) * n_cols * dn_per_pe))))
    gy = int(min(_FALSE_GRID, n_rows, max(1, math.ceil(4 * abs(bg.opt_dy) * n_rows * dn_per_pe))))
    ce = np.linspace(-0.5, n_cols - 0.5, gx + 1)
    re = np.linspace(-0.5, n_rows - 0.5, gy + 1)
    xc = 0.5 * (ce[:-1] + ce[1:])[None, :]
    yc = 0.5 * (re[:-1] + re[1:])[:, None]
    mu_e = bg.mean_e(xc, yc)
    var_e = bg.var_e(xc, yc)
    sd_e = np.sqrt(var_e)
    thr = mu_e / model.gain_e_per_dn + model.bias_dn + k_sigma * np.sqrt(var_e / model.gain_e_per_dn**2 + 1.0 / 12.0)
    cut_e = (np.floor(thr) + 0.5 - model.bias_dn) * model.gain_e_per_dn  # DN > thr  <=>  e >= cut_e
    z0 = (cut_e - mu_e) / sd_e
    p = np.where(np.floor(thr) + 1 <= model.saturation_dn, ndtr(-z0), 0.0)  # a clipped pixel cannot cross
    n_in_cell = np.outer(np.diff(np.floor(re + 0.5)), np.diff(np.floor(ce + 0.5)))
    lam = np.cumsum((p * n_in_cell).ravel())
    # a Poisson process over the cells: Poisson total, cells in proportion to their expected counts
    tot = int(rng.poisson(lam[-1])) if lam[-1] > 0 else 0
    if tot == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    cell = np.minimum(np.searchsorted(lam, rng.random(tot) * lam[-1], side="right"), lam.size - 1)
    cy, cx = np.divmod(cell, gx)
    c0 = np.floor(ce[cx] + 0.5).astype(np.int64)
    c1 = np.floor(ce[cx + 1] + 0.5).astype(np.int64)
    r0 = np.floor(re[cy] + 0.5).astype(np.int64)
    r1 = np.floor(re[cy + 1] + 0.5).astype(np.int64)
    col = c0 + np.floor(rng.random(tot) * (c1 - c0)).astype(np.int64)
    row = r0 + np.floor(rng.random(tot) * (r1 - r0)).astype(np.int64)
    pc = p.ravel()[cell]
    u = rng.random(tot)
    z = -ndtri(np.clip(u * pc, 1e-300, None))  # Gaussian tail above z0
    z = np.maximum(z, z0.ravel()[cell])
    e = mu_e.ravel()[cell] + sd_e.ravel()[cell] * z
    e = np.minimum(e, model.full_well_e)
    dn = np.clip(np.rint(e / model.gain_e_per_dn + model.bias_dn), np.floor(thr.ravel()[cell]) + 1, model.adc_max_dn)
    return row * n_cols + col, dn


_NEIGHBOURS_3x3 = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


def render_sparse(scene: Scene, model: SensorModel, rng: np.random.Generator, k_sigma: float = 5.0, *,
                  false_objects: FalseObjects | None = None, draw_crossings: bool = True) -> SparseFrame:
    """Draw only the pixels that can be detected: the fast path of the pixel fidelity.

    Parameters
    ----------
    scene, model, rng
    k_sigma : float
        Detection threshold in background σ (the background's threshold crossings are drawn for it).
    false_objects : FalseObjects, optional
    draw_crossings : bool
        Draw the background's threshold crossings away from the windows (False: a noise-free sky).

    Returns
    -------
    SparseFrame
    """
    _check_inputs(scene, model, rng)
    check_rng(rng)
    k_sigma = check_real(k_sigma, "k_sigma", 0.0, lo_open=True)
    fo, optical, cosmic, table = _prepare(scene, model, rng, false_objects)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    bg = background_field(scene, model)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    hot_e_all = hot_rate * scene.plan.integration_window_s
    q0 = len(table["kind"])

    lins, srcs, exp_e = [], [], []
    opt_val = dir_val = None
    if optical is not None:
        hw = window_half_widths(optical, bg, model.intensifier_gain, _SPARSE_FLOOR)
        if model.intensified:
            randomize_intensified(optical, model, rng)
        # drop window pixels whose expected light is below _SPARSE_FLOOR of the background noise (units of val)
        floor_e = _SPARSE_FLOOR * math.sqrt(float(bg.var_e(bg.cx, bg.cy)))
        lin, opt_val, src = render_bucketed(optical, hw, n_cols, n_rows,
                                             floor_e if model.intensified else floor_e / model.intensifier_gain)
        lins.append(lin)
        srcs.append(src)
        exp_e.append(opt_val if model.intensified else opt_val * model.intensifier_gain)
    n_opt = len(opt_val) if opt_val is not None else 0
    if cosmic is not None:
        lin, dir_val, src = render_windows(cosmic, 3, n_cols, n_rows)
        lins.append(lin)
        srcs.append(src)
        exp_e.append(dir_val)
    n_dir = len(dir_val) if dir_val is not None else 0
    # hot pixels with their 3x3 neighbourhoods
    n_hot = len(hot_idx)
    if n_hot:
        hr, hc = np.divmod(hot_idx, n_cols)
        nr = (hr[:, None] + _NEIGHBOURS_3x3[None, :, 0]).ravel()
        nc = (hc[:, None] + _NEIGHBOURS_3x3[None, :, 1]).ravel()
        ok = (nr >= 0) & (nr < n_rows) & (nc >= 0) & (nc < n_cols)
        centre = np.tile(np.arange(9) == 4, n_hot)
        lins.append((nr * n_cols + nc)[ok])
        srcs.append(np.repeat(q0 + np.arange(n_hot), 9)[ok])
        exp_e.append(np.where(centre, np.repeat(hot_e_all, 9), 0.0)[ok])
    q1 = q0 + n_hot

    # background threshold crossings outside the windows (kept only where no window pixel lies)
    if draw_crossings:
        f_lin, f_dn = draw_false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
    else:
        f_lin, f_dn = np.zeros(0, dtype=np.int64), np.zeros(0)
    n_base = int(sum(len(v) for v in lins))
    if len(f_lin) > 1:
        f_lin, first = np.unique(f_lin, return_index=True)
        f_dn = f_dn[first]
    n_false = len(f_lin)
    if n_false:
        fr, fc = np.divmod(f_lin, n_cols)
        nr = (fr[:, None] + _NEIGHBOURS_3x3[None, :, 0]).ravel()
        nc = (fc[:, None] + _NEIGHBOURS_3x3[None, :, 1]).ravel()
        ok = (nr >= 0) & (nr < n_rows) & (nc >= 0) & (nc < n_cols)
        lins.append((nr * n_cols + nc)[ok])
        srcs.append(np.repeat(q1 + np.arange(n_false), 9)[ok])
        exp_e.append(np.where(np.tile(np.arange(9) == 4, n_false), 1.0, 0.0)[ok])

    if lins:
        all_lin = np.concatenate(lins) if len(lins) > 1 else lins[0]
        all_src = np.concatenate(srcs) if len(srcs) > 1 else srcs[0]
        all_exp = np.concatenate(exp_e) if len(exp_e) > 1 else exp_e[0].copy()
    else:
        all_lin = np.zeros(0, dtype=np.int64)
        all_exp = np.zeros(0)
        all_src = np.zeros(0, dtype=np.int64)
    index = _PixelIndex(n_px)
    uniq, inv = index.unique(all_lin)
    u = len(uniq)
    spot_u = np.bincount(inv[:n_opt], opt_val, minlength=u) if n_opt else np.zeros(u)
    hot_pos = index.contains(hot_idx) if n_hot else np.zeros(0, dtype=np.int64)
    prnu_u = None if prnu is None else prnu[uniq].astype(np.float64)
    if bg.flat:
        opt_u = max(bg.opt0, 0.0)
    else:
        rows_u, cols_u = np.divmod(uniq, n_cols)
        opt_u = bg.optical_pe(cols_u, rows_u)
    if n_dir:
        dir_u = np.bincount(inv[n_opt:n_opt + n_dir], dir_val, minlength=u)
        d_at = np.flatnonzero(dir_u)
        d_e = dir_u[d_at]
    else:
        d_at = d_e = None
    dn = _pixels_to_dn(spot_u, bg, opt_u, prnu_u, model, rng, hot_at=hot_pos[hot_pos >= 0],
                       hot_e=hot_e_all[hot_pos >= 0], direct_at=d_at, direct_e=d_e)
    if n_false:
        f_uid = index.contains(f_lin)
        in_window = np.zeros(u, dtype=bool)
        in_window[inv[:n_base]] = True
        keep_f = ~in_window[f_uid]
        dn[f_uid[keep_f]] = f_dn[keep_f]
        # a crossing that fell on a window pixel is not a separate event: its 3x3 stays plain background
        drop_src = q1 + np.flatnonzero(~keep_f)
        if len(drop_src):
            all_exp[np.isin(all_src, drop_src)] = 0.0

    # source table: stars, debris, cosmic rays (from frame_spots), hot pixels, background crossings
    hr, hc = np.divmod(hot_idx, n_cols)
    fr, fc = np.divmod(f_lin, n_cols)
    f_e = (f_dn - model.bias_dn) * model.gain_e_per_dn - (bg.mean_e(fc, fr) if n_false else 0.0)
    sources = SourceTable(
        kind=np.concatenate([table["kind"], np.full(n_hot, KIND_HOT_PIXEL), np.full(n_false, KIND_NOISE)]).astype(np.int64),
        star=np.concatenate([table["star"], np.full(n_hot + n_false, -1)]).astype(np.int64),
        exposure=np.concatenate([table["exposure"], np.full(n_hot + n_false, -1)]).astype(np.int64),
        xy=np.concatenate([table["xy"], np.stack([hc, hr], 1).astype(float), np.stack([fc, fr], 1).astype(float)]),
        expected_e=np.concatenate([table["expected_e"], hot_e_all, np.atleast_1d(f_e)[:n_false]]),
    )
    mean_dn_u = np.broadcast_to((bg.gain * opt_u + bg.dark_e) / model.gain_e_per_dn + model.bias_dn, (u,))
    q_u = bg.gain * opt_u
    sigma_dn_u = np.broadcast_to(np.sqrt((bg.enf2_c * q_u + bg.dark_e + bg.read_var_e2 + (bg.prnu_sigma * q_u) ** 2)
                                         / model.gain_e_per_dn**2 + 1.0 / 12.0), (u,))
    return SparseFrame(
        shape=(n_rows, n_cols),
        lin=uniq,
        dn=dn.astype(np.float32),
        background_dn=mean_dn_u,
        threshold_dn=np.broadcast_to(mean_dn_u + k_sigma * sigma_dn_u, (u,)),
        saturation_dn=model.saturation_dn,
        sources=sources,
        entry_pixel=inv.astype(np.int64),
        entry_source=all_src.astype(np.int64),
        entry_e=all_exp,
        k_sigma=k_sigma,
        _index=index,
        background_dn_centre=float(bg.mean_dn(bg.cx, bg.cy)),
        noise_dn_centre=float(bg.sigma_dn(bg.cx, bg.cy)),
    )
