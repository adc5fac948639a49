"""Each preset's detector: the centroid fidelity (calibrated error model) agrees with the pixel path (sparse
rendering and centroiding) in detection completeness and centroid error σ per magnitude bin, within the Monte
Carlo error of both (plus the theory's stated 10 % on σ), on that preset's own camera and exposure (the 3CMOS head: one channel's detector behind the
green channel's optics)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from startracker.centroid import simulate_detections
from startracker.centroid.fidelity import DEFAULT_ERROR_MODELS, grid_scene, predicted_centroid_sigma_px
from startracker.head import make_head
from startracker.imaging import KIND_STAR
from startracker.scene import ExposurePlan
from startracker.spec import PRESET_NAMES

N_FRAMES = 4


def bin_stats(det, sc, edges):
    """Per magnitude bin: (visible, found, squared per-axis errors of the finds), blends (> 3 px) left out."""
    m = sc.n_stars
    st = np.flatnonzero(det.truth_kind == KIND_STAR)
    key = det.truth_exposure[st] * m + det.truth_star[st]
    u, first = np.unique(key, return_index=True)
    found = np.zeros(m, dtype=bool)
    found[u] = True
    err = np.full((m, 2), np.nan)
    err[u] = det.xy[st[first]] - det.truth_xy[st[first]]
    vis = sc.visible.reshape(-1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = vis & (sc.vmag >= lo) & (sc.vmag < hi)
        e = err[s & found]
        e = e[np.all(np.abs(e) < 3.0, axis=1)]
        out.append((int(s.sum()), int((s & found).sum()), e.ravel() ** 2))
    return out


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_fidelities_agree_per_preset(name):
    head = make_head(name)
    model = replace(head.sensor_model, hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0)
    assert (name, "com") in DEFAULT_ERROR_MODELS  # calibrated for this detector, not borrowed from another
    cam, tau = head.camera, head.exposure_s
    # the magnitude of 50 % detection, from the theory; bins from certain to rare detection around it
    v = np.arange(0.0, 12.0, 0.01)
    _, p = predicted_centroid_sigma_px(model, cam, v, tau)
    v50 = float(v[np.argmin(np.abs(p - 0.5))])
    edges = v50 + np.array([-3.0, -1.5, -0.6, -0.2, 0.2, 0.6])
    plan = ExposurePlan(1, tau, frame_period_s=max(0.1, tau))
    speed = 1.0 / tau  # 1 px streaks: not the calibration's 0 and 2 px
    acc = {f: [[0, 0, []] for _ in edges[:-1]] for f in ("pixel", "centroid")}
    for i in range(N_FRAMES):
        sc = grid_scene(cam, plan, edges[0], edges[-1], speed, 40.0, np.random.default_rng([7, i]))
        for f in acc:
            det = simulate_detections(sc, model, np.random.default_rng([8, i, f == "pixel"]), f, include_false=False)
            for j, (n_vis, n_found, e2) in enumerate(bin_stats(det, sc, edges)):
                acc[f][j][0] += n_vis
                acc[f][j][1] += n_found
                acc[f][j][2].extend(e2)
    for j in range(len(edges) - 1):
        (nv_p, nf_p, e_p), (nv_c, nf_c, e_c) = acc["pixel"][j], acc["centroid"][j]
        assert nv_p == nv_c and nv_p > 150
        # completeness: the binomial standard error of the difference, 4σ
        pp, pc = nf_p / nv_p, nf_c / nv_c
        pbar = (nf_p + nf_c) / (nv_p + nv_c)
        se = np.sqrt(max(pbar * (1 - pbar), 1e-4) * 2.0 / nv_p)
        assert abs(pc - pp) <= 4.0 * se + 0.02, (name, j, pp, pc, se)
        if pp < 0.3 or pc < 0.3:
            # barely detected spots: the pixel path keeps those that noise lifted above the threshold, whose
            # centroids sit nearer the truth than the linearised theory's; their σ is not compared
            continue
        # centroid σ per axis: the standard error of a σ estimate from n squared errors is σ sd(e²)/(2 E[e²] √n)
        e_p, e_c = np.asarray(e_p), np.asarray(e_c)
        sp, sc_ = np.sqrt(e_p.mean()), np.sqrt(e_c.mean())
        se_p = sp * e_p.std() / (2 * e_p.mean() * np.sqrt(len(e_p)))
        se_c = sc_ * e_c.std() / (2 * e_c.mean() * np.sqrt(len(e_c)))
        # 4 Monte Carlo σ of the difference, plus the theory's 10 % (its linearisation of a thresholded centre of mass)
        assert abs(sc_ - sp) <= 4.0 * np.hypot(se_p, se_c) + 0.1 * sp, (name, j, sp, sc_)
