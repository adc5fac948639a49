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
  persistent index buffer (no sort), so overlapping windows share one noisy value. Both paths draw the
  same random numbers (:func:`_draw_pixel_noise`) and run the same per-pixel arithmetic (the full frame in
  :func:`startracker.kernels.imaging.pixels_to_dn`; the sparse set in
  :func:`startracker.kernels.imaging.sparse_pixels_to_dn`, which also evaluates the background there in the same
  pass), so their statistics agree (tests/test_imaging.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from startracker.imaging.background import BackgroundField, FalseObjects, background_field, draw_false_objects
from startracker.imaging.detector import SensorModel, fixed_pattern
from startracker.kernels.imaging import (
    false_pixel_cells,
    lookup_pixels,
    pixels_to_dn,
    place_false_pixels,
    sparse_pixel_set,
    sparse_pixels_to_dn,
    sparse_source_table,
)
from startracker.validation import check_real, check_rng
from startracker.imaging.spots import (
    KIND_HOT_PIXEL,
    KIND_NOISE,
    SourceTable,
    frame_spots,
    randomize_intensified,
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
_NO_PRNU = np.zeros(0, dtype=np.float32)


def _draw_pixel_noise(spot, model: SensorModel, rng, n_hot: int):
    """The random numbers of :func:`_pixels_to_dn`, in its order: one normal per pixel, (CMOS) the star
    photoelectrons and their gain, one normal per hot pixel. Returns ``z`` (U,), ``charge`` (U,) e⁻ (the spot
    itself for an intensified detector, unused), ``hot_z`` (H,)."""
    u = spot.shape[0]
    z = rng.standard_normal(u)
    g = model.intensifier_gain
    if model.intensified:
        charge = spot  # unused by the kernel
    else:
        charge = np.zeros(u)
        nz = np.flatnonzero(spot > 0)
        if len(nz):
            n_pe = rng.poisson(spot[nz])
            k = model.gamma_shape_per_pe
            if math.isinf(k):
                charge[nz] = g * n_pe.astype(np.float64)
            else:
                charge[nz] = rng.gamma(np.maximum(k * n_pe, 1e-300), g / k) * (n_pe > 0)
    hot_z = rng.standard_normal(n_hot)
    return z, charge, hot_z


def _pixels_to_dn(spot, bg: BackgroundField, opt_bg, prnu, lin, model: SensorModel, rng, *, hot_u=None, hot_e=None,
                  direct=None):
    """Random DN of pixels given their expected signals (the full-frame path; the sparse path runs the same
    arithmetic in :func:`startracker.kernels.imaging.sparse_pixels_to_dn`).

    Draws the numbers of :func:`_draw_pixel_noise`, then :func:`startracker.kernels.imaging.pixels_to_dn`.

    Parameters
    ----------
    spot : ndarray, shape (U,)
        Intensified: the randomised spot charge, e⁻; CMOS: the expected star photoelectrons.
    opt_bg : ndarray, shape (U,)
        Optical background photoelectrons (``bg.optical_pe`` at the pixels).
    prnu : ndarray of float32, shape (n_rows * n_cols,) or None
        The detector's PRNU pattern (:func:`fixed_pattern`).
    lin : ndarray of int64, shape (U,)
        Linear indices of the pixels.
    hot_u, hot_e : compact ids of the hot pixels among the U and their extra dark charge, e⁻.
    direct : ndarray, shape (U,) or None
        Charge deposited directly (cosmic rays), e⁻.
    """
    u = spot.shape[0]
    if hot_u is None:
        hot_u = np.zeros(0, dtype=np.int64)
        hot_e = np.zeros(0)
    z, charge, hot_z = _draw_pixel_noise(spot, model, rng, len(hot_u))
    g = model.intensifier_gain
    return pixels_to_dn(bool(model.intensified), spot, opt_bg, _NO_PRNU if prnu is None else prnu, lin, z, charge,
                        np.zeros(u) if direct is None else direct, hot_u, np.asarray(hot_e, dtype=np.float64), hot_z,
                        float(g), float(bg.enf2_c), float(bg.dark_e), float(bg.read_var_e2), float(model.full_well_e),
                        float(model.gain_e_per_dn), float(model.bias_dn), float(model.adc_max_dn))


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


def _optical_at(bg: BackgroundField, lin: np.ndarray, n_cols: int) -> np.ndarray:
    """Optical background photoelectrons at linear pixel indices, shape (U,)."""
    if bg.flat:
        return np.full(len(lin), max(bg.opt0, 0.0))
    rows, cols = np.divmod(lin, n_cols)
    return bg.optical_pe(cols, rows)


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
    spot = np.zeros(n_px)
    direct = None
    if optical is not None:
        hw = window_half_widths(optical, bg, model.intensifier_gain, _FULL_FLOOR)
        if model.intensified:
            randomize_intensified(optical, model, rng)
        lin, val, _ = render_windows(optical, hw, n_cols, n_rows)
        spot = np.bincount(lin, val, minlength=n_px)
    if cosmic is not None:
        lin, val, _ = render_windows(cosmic, 3, n_cols, n_rows)
        direct = np.bincount(lin, val, minlength=n_px)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    lin_all = np.arange(n_px)
    opt = _optical_at(bg, lin_all, n_cols)
    dn = _pixels_to_dn(spot, bg, opt, prnu, lin_all, model, rng,
                       hot_u=np.asarray(hot_idx, dtype=np.int64), hot_e=hot_rate * scene.plan.integration_window_s,
                       direct=direct)
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
        lin, val, _ = render_windows(optical, hw, n_cols, n_rows)
        light += np.bincount(lin, val * model.intensifier_gain, minlength=n_px)
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
        img += np.bincount(lin, val, minlength=n_px)
    return img.reshape(n_rows, n_cols)


# ----------------------------------------------------------------------------------- sparse frame
class _PixelIndex:
    """Sort-free deduplication of linear pixel indices with a persistent int32 buffer, interleaved with the
    detector's PRNU map.

    The buffer is never cleared: a lookup is valid only if the stored compact id points back to the same
    pixel (the 'sparse set' trick). One buffer per detector (size and PRNU map) is shared by all frames of the
    process (not thread-safe); a frame that finds the buffer taken over by a later frame rewrites its own ids
    (O(U)) before looking up. The buffer and the PRNU are the two int32/float32 columns of one (n_px, 2) array
    (built once per detector): a window row's lookup fetches its PRNU in the same cache line, where two separate
    16 MB maps cost two misses per row (:func:`startracker.kernels.imaging.sparse_pixel_set`).
    """

    _buffers: dict = {}
    _owner: dict = {}

    def __init__(self, n_px: int, prnu: np.ndarray | None = None):
        key = (n_px, None if prnu is None else id(prnu))
        hit = self._buffers.get(key)
        if hit is None or hit[0] is not prnu:
            pair = np.zeros((n_px, 2), dtype=np.int32)
            if prnu is not None:
                pair.view(np.float32)[:, 1] = prnu
            if len(self._buffers) > 8:  # stale detectors (their PRNU maps dropped from the fixed-pattern cache)
                self._buffers.clear()
                self._owner.clear()
            hit = (prnu, pair[:, 0], _NO_PRNU if prnu is None else pair.view(np.float32)[:, 1])
            self._buffers[key] = hit
        self.key = key
        self.n_px = n_px
        self.buf = hit[1]
        self.prnu = hit[2]
        self.uniq = np.zeros(0, dtype=np.int64)

    def adopt(self, uniq: np.ndarray) -> None:
        """Record ``uniq`` as this frame's pixels (the caller has just written ``buf[uniq] = arange``)."""
        self.uniq = uniq
        self._owner[self.key] = self

    def claimed(self) -> np.ndarray:
        """The buffer, holding this frame's compact ids (rewritten if a later frame took it over)."""
        if self._owner.get(self.key) is not self:
            self.buf[self.uniq] = np.arange(len(self.uniq), dtype=np.int32)
            self._owner[self.key] = self
        return self.buf

    def contains(self, lin: np.ndarray) -> np.ndarray:
        """Compact id of each pixel in ``lin`` among this frame's pixels, −1 if absent."""
        return lookup_pixels(np.asarray(lin, dtype=np.int64), self.claimed(), self.uniq)


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

    def buffer(self) -> np.ndarray:
        """The index buffer of the detector, int32 (n_rows * n_cols,) (a strided view: its other column holds the
        PRNU), holding ``buffer()[lin[i]] == i`` for this frame's pixels (other entries are stale): for kernels that
        look pixels up."""
        return self._index.claimed()

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


_CELL_CACHE: dict = {}


def _false_pixel_cells(bg: BackgroundField, k_sigma: float, n_cols: int, n_rows: int, model: SensorModel):
    """The grid of :func:`draw_false_pixels` and the per-cell statistics of its threshold crossings
    (:func:`startracker.kernels.imaging.false_pixel_cells`), with the model's DN constants: computed once per
    (background object, threshold, detector size, model), since a quiet sky's background is the same object
    frame after frame (:func:`startracker.imaging.background_field`)."""
    key = (id(bg), float(k_sigma), n_cols, n_rows, id(model))
    hit = _CELL_CACHE.get(key)
    if hit is not None and hit[0] is bg and hit[1] is model:
        return hit[2]
    if bg.flat:  # one cell: the crossing probability is the same everywhere
        gx = gy = 1
    else:
        # cells fine enough that the background changes by < 0.25 DN across one (the crossing probability of
        # quantised pixels depends on where the threshold falls between two DN levels)
        dn_per_pe = bg.gain / model.gain_e_per_dn
        gx = int(min(_FALSE_GRID, n_cols, max(1, math.ceil(4 * abs(bg.opt_dx) * n_cols * dn_per_pe))))
        gy = int(min(_FALSE_GRID, n_rows, max(1, math.ceil(4 * abs(bg.opt_dy) * n_rows * dn_per_pe))))
    ce = np.linspace(-0.5, n_cols - 0.5, gx + 1)
    re = np.linspace(-0.5, n_rows - 0.5, gy + 1)
    cells = false_pixel_cells(ce, re, float(bg.opt0), float(bg.opt_dx), float(bg.opt_dy), float(bg.cx), float(bg.cy),
                              float(bg.gain), float(bg.enf2_c), float(bg.dark_e), float(bg.read_var_e2),
                              float(bg.prnu_sigma), float(model.gain_e_per_dn), float(model.bias_dn),
                              float(model.saturation_dn), float(k_sigma))
    value = (float(cells[0][-1]), ce, re, cells, (float(model.full_well_e), float(model.gain_e_per_dn),
                                                   float(model.bias_dn), float(model.adc_max_dn)))
    if len(_CELL_CACHE) > 64:
        _CELL_CACHE.clear()
    _CELL_CACHE[key] = (bg, model, value)
    return value


# shared empty results (nothing can be written into them; writable, like the kernel's outputs: one signature)
_NO_FALSE_LIN = np.zeros(0, dtype=np.int64)
_NO_FALSE_DN = np.zeros(0)


def draw_false_pixels(bg: BackgroundField, k_sigma: float, n_cols: int, n_rows: int, model: SensorModel, rng):
    """Background pixels above the threshold, drawn from the noise statistics (module docstring).

    Draws one Poisson total, then four uniforms per pixel.

    Returns linear indices (F,) (they may repeat) and their DN values (F,) (shared empty arrays when F = 0).
    """
    lam, ce, re, cells, dn_consts = _false_pixel_cells(bg, k_sigma, n_cols, n_rows, model)
    # a Poisson process over the cells: Poisson total, cells in proportion to their expected counts
    tot = int(rng.poisson(lam)) if lam > 0 else 0
    if tot == 0:
        return _NO_FALSE_LIN, _NO_FALSE_DN
    u = rng.random((4, tot))
    return place_false_pixels(u[0], u[1], u[2], u[3], cells[0], ce, re, *cells[1:], *dn_consts)


def render_sparse(scene: Scene, model: SensorModel, rng: np.random.Generator, k_sigma: float = 5.0, *,
                  false_objects: FalseObjects | None = None, draw_crossings: bool = True,
                  validate: bool = True) -> SparseFrame:
    """Draw only the pixels that can be detected: the fast path of the pixel fidelity.

    Parameters
    ----------
    scene, model, rng
    k_sigma : float
        Detection threshold in background σ (the background's threshold crossings are drawn for it).
    false_objects : FalseObjects, optional
    draw_crossings : bool
        Draw the background's threshold crossings away from the windows (False: a noise-free sky).
    validate : bool
        Check the arguments (False: the caller has checked them, as the per-frame path does).

    Returns
    -------
    SparseFrame
    """
    if validate:
        _check_inputs(scene, model, rng)
        check_rng(rng)
        k_sigma = check_real(k_sigma, "k_sigma", 0.0, lo_open=True)
    fo, optical, cosmic, table = _prepare(scene, model, rng, false_objects)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    bg = background_field(scene, model)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    hot_idx = np.asarray(hot_idx, dtype=np.int64)
    hot_e_all = hot_rate * scene.plan.integration_window_s
    q0 = len(table["kind"])
    n_hot = len(hot_idx)
    q1 = q0 + n_hot
    g = model.intensifier_gain

    empty_i, empty_f = np.zeros(0, dtype=np.int64), np.zeros(0)
    o_lin, o_val, o_src = empty_i, empty_f, empty_i
    if optical is not None:
        hw = window_half_widths(optical, bg, g, _SPARSE_FLOOR)
        if model.intensified:
            randomize_intensified(optical, model, rng)
        # drop window pixels whose expected light is below _SPARSE_FLOOR of the background noise (units of val)
        floor_e = _SPARSE_FLOOR * math.sqrt(bg.var_e_centre)
        o_lin, o_val, o_src = render_windows(optical, hw, n_cols, n_rows, floor_e if model.intensified else floor_e / g)
    d_lin, d_val, d_src = empty_i, empty_f, empty_i
    if cosmic is not None:
        d_lin, d_val, d_src = render_windows(cosmic, 3, n_cols, n_rows)
    # background threshold crossings outside the windows (kept only where no window pixel lies)
    if draw_crossings:
        f_lin, f_dn = draw_false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
        if len(f_lin) > 1:
            f_lin, first = np.unique(f_lin, return_index=True)
            f_dn = f_dn[first]
    else:
        f_lin, f_dn = empty_i, empty_f

    index = _PixelIndex(n_px, prnu)
    uniq, inv, all_src, all_exp, spot_u, dir_u, hot_u, false_u, prnu_u = sparse_pixel_set(
        o_lin, o_val, o_src, 1.0 if model.intensified else g, d_lin, d_val, d_src, hot_idx,
        np.asarray(hot_e_all, dtype=np.float64), q0, f_lin, q1, n_cols, n_rows, index.buf, index.prnu)
    index.adopt(uniq)
    # background, DN and the crossings' values in one compiled pass over the pixels
    z, charge, hot_z = _draw_pixel_noise(spot_u, model, rng, len(hot_u))
    dn, mean_dn_u, thr_dn_u = sparse_pixels_to_dn(
        bool(model.intensified), spot_u, prnu_u, uniq, z, charge, dir_u, hot_u,
        np.asarray(hot_e_all, dtype=np.float64), hot_z, false_u, f_dn, n_cols, float(bg.opt0), float(bg.opt_dx),
        float(bg.opt_dy), float(bg.cx), float(bg.cy), float(bg.gain), float(bg.enf2_c), float(bg.dark_e),
        float(bg.read_var_e2), float(bg.prnu_sigma), float(model.full_well_e), float(model.gain_e_per_dn),
        float(model.bias_dn), float(model.adc_max_dn), float(k_sigma))

    # source table: stars, debris, cosmic rays (from frame_spots), hot pixels, background crossings
    kind, star, expo, xy, exp_e = sparse_source_table(
        table["kind"], table["star"], table["exposure"], table["xy"], table["expected_e"], hot_idx,
        np.asarray(hot_e_all, dtype=np.float64), f_lin, f_dn, n_cols, KIND_HOT_PIXEL, KIND_NOISE,
        float(model.bias_dn), float(model.gain_e_per_dn), float(bg.opt0), float(bg.opt_dx), float(bg.opt_dy),
        float(bg.cx), float(bg.cy), float(bg.gain), float(bg.dark_e))
    sources = SourceTable(kind=kind, star=star, exposure=expo, xy=xy, expected_e=exp_e)
    return SparseFrame(
        shape=(n_rows, n_cols),
        lin=uniq,
        dn=dn,
        background_dn=mean_dn_u,
        threshold_dn=thr_dn_u,
        saturation_dn=model.saturation_dn,
        sources=sources,
        entry_pixel=inv,
        entry_source=all_src,
        entry_e=all_exp,
        k_sigma=k_sigma,
        _index=index,
        background_dn_centre=bg.mean_dn_centre,
        noise_dn_centre=bg.sigma_dn_centre,
    )
