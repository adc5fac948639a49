"""Star-tracker bookkeeping kernels: the lock's innovation test, the instants' smoothness test, the accepted
instants of a tracked frame, the motion state's rate arithmetic and the consistency verdict, no checks.

The callers are :class:`startracker.sensor.StarTracker` (the innovation χ² of a tracked frame) and the verdicts of
:mod:`startracker.onboard` (:func:`~startracker.onboard.judge_samples`, :func:`~startracker.onboard.judge_estimate`:
an attitude against the truth on its own covariance); both hand over float64 arrays they built themselves. Quaternions are (w, x, y, z), covariances body-frame rad².
"""

from __future__ import annotations

import numpy as np
from numba import njit

from startracker.kernels.algebra import mahalanobis3
from startracker.kernels.rotations import interpolate_rows, normalize_rows, relative_rotvec_rows

__all__ = ["innovation_chi2_mean", "consistency_nis", "instant_deleted_chi2", "smooth_instants", "accept_instants",
           "wrong_sample_flags", "rate_difference", "rate_at", "rate_difference_at", "any_nonpositive", "true_indices",
           "gather_instants"]


@njit(cache=True, no_cfunc_wrapper=True)
def rate_difference(omega1, cov1, omega0, cov0, dt_s, dt2_s2):
    """Angular acceleration from two rate measurements ``dt_s`` apart, and its covariance: ``(ω₁ − ω₀) / dt`` and
    ``(C₁ + C₀) / dt²`` (the numpy expressions' operations, element by element; the tracker's motion state).

    Parameters
    ----------
    omega1, omega0 : ndarray, shape (3,)
        The later and the earlier rate, rad/s.
    cov1, cov0 : ndarray, shape (3, 3)
        Their covariances, (rad/s)².
    dt_s : float
        Time from the earlier to the later, s (> 0).
    dt2_s2 : float
        ``dt_s ** 2`` as the caller computes it, s².

    Returns
    -------
    alpha : ndarray, shape (3,)
        rad/s².
    cov_alpha : ndarray, shape (3, 3)
        (rad/s²)².
    """
    alpha = np.empty(3)
    for i in range(3):
        alpha[i] = (omega1[i] - omega0[i]) / dt_s
    cov = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            cov[i, j] = (cov1[i, j] + cov0[i, j]) / dt2_s2
    return alpha, cov


@njit(cache=True, no_cfunc_wrapper=True)
def rate_at(omega, cov_omega, alpha, cov_alpha, lever_s, lever2_s2):
    """A rate carried ``lever_s`` along by an acceleration, and its covariance: ``ω + α lever`` and
    ``C_ω + C_α lever²`` (the numpy expressions' operations, element by element; the tracker's propagation and
    motion state).

    Parameters
    ----------
    omega : ndarray, shape (3,)
        Rate, rad/s.
    cov_omega : ndarray, shape (3, 3)
        Its covariance, (rad/s)².
    alpha : ndarray, shape (3,)
        Angular acceleration, rad/s².
    cov_alpha : ndarray, shape (3, 3)
        Its covariance, (rad/s²)².
    lever_s : float
        Time carried over, s.
    lever2_s2 : float
        ``lever_s ** 2`` as the caller computes it, s².

    Returns
    -------
    omega_at : ndarray, shape (3,)
        rad/s.
    cov_at : ndarray, shape (3, 3)
        (rad/s)².
    """
    w = np.empty(3)
    for i in range(3):
        w[i] = omega[i] + alpha[i] * lever_s
    cov = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            cov[i, j] = cov_omega[i, j] + cov_alpha[i, j] * lever2_s2
    return w, cov


@njit(cache=True, no_cfunc_wrapper=True)
def rate_difference_at(omega1, cov1, omega0, cov0, dt_s, dt2_s2, cov_extra, lever_s, lever2_s2):
    """:func:`rate_difference` of two rate measurements, then :func:`rate_at` carrying the later one ``lever_s`` along
    by that acceleration, whose covariance grows by ``cov_extra`` there: the motion state's rate update in one call,
    the same floats as the two kernels and the numpy sum ``cov_alpha + cov_extra`` in between.

    Parameters
    ----------
    omega1, cov1, omega0, cov0, dt_s, dt2_s2
        As :func:`rate_difference`: the later and the earlier rate (3,), rad/s, their covariances (3, 3), (rad/s)²,
        the time between them and its square, s and s².
    cov_extra : ndarray, shape (3, 3)
        Added to the acceleration's covariance for the carry (the unmodelled change), (rad/s²)².
    lever_s : float
        Time the later rate is carried over, s.
    lever2_s2 : float
        ``lever_s ** 2`` as the caller computes it, s².

    Returns
    -------
    alpha : ndarray, shape (3,)
        ``(ω₁ − ω₀) / dt``, rad/s².
    cov_alpha : ndarray, shape (3, 3)
        ``(C₁ + C₀) / dt²``, (rad/s²)².
    omega_at : ndarray, shape (3,)
        ``ω₁ + α lever``, rad/s.
    cov_at : ndarray, shape (3, 3)
        ``C₁ + (C_α + C_extra) lever²``, (rad/s)².
    """
    alpha, cov_alpha = rate_difference(omega1, cov1, omega0, cov0, dt_s, dt2_s2)
    cov_total = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            cov_total[i, j] = cov_alpha[i, j] + cov_extra[i, j]
    w, cov = rate_at(omega1, cov1, alpha, cov_total, lever_s, lever2_s2)
    return alpha, cov_alpha, w, cov


@njit(cache=True, no_cfunc_wrapper=True)
def innovation_chi2_mean(q_pred, q_sol, cov_sol, tau_s, cov_theta, cov_omega, cov_alpha):
    """Mean over instants of the innovation χ² ``δᵀ S⁻¹ δ`` of solved against predicted attitudes.

    ``δ`` is the rotation vector of ``conj(q_pred) ⊗ q_sol`` (angle in [0, π]) and
    ``S = P_θ + P_ω τ² + P_α τ⁴ / 4 + C_sol``: the prediction's covariance after ``τ`` plus the solution's.

    Parameters
    ----------
    q_pred, q_sol : ndarray, shape (n, 4)
        Predicted and solved attitudes at each instant (non-zero; normalised here).
    cov_sol : ndarray, shape (n, 3, 3)
        Covariance of each solved attitude, rad².
    tau_s : ndarray, shape (n,)
        Time from the motion state's reference instant to each instant, s.
    cov_theta : ndarray, shape (3, 3)
        Attitude covariance of the motion state, rad².
    cov_omega : ndarray, shape (3, 3)
        Rate covariance, (rad/s)².
    cov_alpha : ndarray, shape (3, 3)
        Acceleration covariance, (rad/s²)².

    Returns
    -------
    float
        Mean χ² (3 degrees of freedom per instant); 0.0 for n = 0.
    """
    n = q_pred.shape[0]
    if n == 0:
        return 0.0
    d = relative_rotvec_rows(q_pred, q_sol)
    total = 0.0
    s = np.empty((3, 3))
    for k in range(n):
        t2 = tau_s[k] * tau_s[k]
        t4 = t2 * t2 / 4.0
        for i in range(3):
            for j in range(3):
                s[i, j] = cov_theta[i, j] + cov_omega[i, j] * t2 + cov_alpha[i, j] * t4 + cov_sol[k, i, j]
        total += mahalanobis3(s, d[k, 0], d[k, 1], d[k, 2])
    return total / n


@njit(cache=True, no_cfunc_wrapper=True)
def consistency_nis(q_true, q_est, cov):
    """Normalised error squared of each attitude against the truth, on its own covariance (3 dof).

    The error is the body-frame rotation vector ``δθ = log(q_est* ⊗ q_true)`` (``q_true = q_est ⊗ exp(δθ)``, the
    convention of the tracker's and the filter's covariances; angle in [0, π]) and the result ``δθᵀ C⁻¹ δθ``:
    χ²(3)-distributed when the covariance tells the truth. A covariance that is not positive definite gives ``inf``
    (an attitude that claims no uncertainty is consistent with no error at all).

    Parameters
    ----------
    q_true, q_est : ndarray, shape (n, 4)
        True and reported attitudes (w, x, y, z), unit, body -> ICRS; signs do not matter.
    cov : ndarray, shape (n, 3, 3)
        Reported covariance of each attitude's error, body frame, rad², symmetric.

    Returns
    -------
    ndarray, shape (n,)
        ``δθᵀ C⁻¹ δθ`` of each attitude (dimensionless).
    """
    n = q_true.shape[0]
    d = relative_rotvec_rows(q_est, q_true)
    out = np.empty(n)
    for k in range(n):
        out[k] = mahalanobis3(cov[k], d[k, 0], d[k, 1], d[k, 2])
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def wrong_sample_flags(t_true, q_meas, cov, times_s, q_hist, chi2_max):
    """Which samples are wrong against a truth history: their :func:`consistency_nis` against the true attitude at
    their true instant exceeds ``chi2_max``; samples outside the history are not judged (False).

    One call for :func:`startracker.onboard.judge_samples`' selection, slerp and test: the truth history is
    normalised (:func:`~startracker.kernels.rotations.normalize_rows`), interpolated at the instants inside it
    (:func:`~startracker.kernels.rotations.interpolate_rows`) and the selected samples tested, the same loops in the
    same order as the numpy formulation, so the flags are its own.

    Parameters
    ----------
    t_true : ndarray, shape (n,)
        True exposure instant of each sample, s.
    q_meas : ndarray, shape (n, 4)
        Reported attitudes (w, x, y, z), unit.
    cov : ndarray, shape (n, 3, 3)
        Reported covariances, body frame, rad².
    times_s : ndarray, shape (S,)
        Truth history instants, s, increasing.
    q_hist : ndarray, shape (S, 4)
        True attitudes at ``times_s`` (non-zero).
    chi2_max : float
        The test's threshold.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    n = t_true.shape[0]
    wrong = np.zeros(n, dtype=np.bool_)
    t_first, t_last = times_s[0], times_s[times_s.shape[0] - 1]
    idx = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if t_true[i] >= t_first and t_true[i] <= t_last:
            idx[m] = i
            m += 1
    if m == 0:
        return wrong
    tq = np.empty(m)
    qm = np.empty((m, 4))
    cm = np.empty((m, 3, 3))
    for j in range(m):
        i = idx[j]
        tq[j] = t_true[i]
        for c in range(4):
            qm[j, c] = q_meas[i, c]
        for r in range(3):
            for c in range(3):
                cm[j, r, c] = cov[i, r, c]
    q_true = interpolate_rows(times_s, normalize_rows(q_hist), tq)
    nis = consistency_nis(q_true, qm, cm)
    for j in range(m):
        wrong[idx[j]] = nis[j] > chi2_max
    return wrong


@njit(cache=True, no_cfunc_wrapper=True)
def instant_deleted_chi2(q_ref, q_sol, cov_sol, tau_s, degree):
    """Leave-one-out χ² of each instant's attitude against a polynomial in time through the other instants.

    The rotation vectors ``θ_k`` of the instants relative to their references ``q_ref`` (the predicted attitudes:
    then ``θ`` is the prediction's error, a low-order polynomial in time whatever the motion; or one attitude for all)
    are fitted, axis by axis, by ordinary
    least squares with a polynomial of ``degree`` in time. Instant k's deleted residual is ``d_k = r_k / (1 − h_k)``
    (``r_k`` its residual, ``h_k`` its leverage): its attitude minus the fit through all the others at its time,
    with covariance ``S_k = C_k + C̄ h_k / (1 − h_k)`` (``C̄`` the mean covariance of the other instants: the fit's
    own error at ``τ_k``). The result ``d_kᵀ S_k⁻¹ d_k`` is χ²(3) when the motion is that polynomial over the frame
    and the covariances tell the truth. An instant matched one exposure off sits on the trajectory at its
    neighbour's time: its deleted residual is one exposure's rotation, hundreds of σ.

    Parameters
    ----------
    q_ref : ndarray, shape (n, 4)
        Reference attitude of each instant (non-zero).
    q_sol : ndarray, shape (n, 4)
        Solved attitudes of the instants (non-zero), n > degree + 1.
    cov_sol : ndarray, shape (n, 3, 3)
        Their covariances, body frame, rad².
    tau_s : ndarray, shape (n,)
        Their times, s (any origin), not all equal.
    degree : int
        Polynomial degree (>= 0).

    Returns
    -------
    ndarray, shape (n,)
        The leave-one-out χ² of each instant (3 degrees of freedom).
    """
    n = q_sol.shape[0]
    p = degree + 1
    theta = relative_rotvec_rows(q_ref, q_sol)
    # mean, max and min by loops (the same values as numba's in-order ones): its reductions compile for seconds
    acc, hi, lo = 0.0, tau_s[0], tau_s[0]
    for k in range(n):
        acc += tau_s[k]
        hi = max(hi, tau_s[k])
        lo = min(lo, tau_s[k])
    t0 = acc / n
    span = max(hi - lo, 1e-12)
    x = np.empty((n, p))
    for k in range(n):
        u = (tau_s[k] - t0) / span
        v = 1.0
        for j in range(p):
            x[k, j] = v
            v *= u
    a_inv = np.linalg.inv(x.T @ x)
    beta = a_inv @ (x.T @ theta)
    resid = x @ beta
    c_sum = np.zeros((3, 3))
    for k in range(n):  # element loops, not array expressions (each compiles a ufunc kernel)
        for i in range(3):
            resid[k, i] = theta[k, i] - resid[k, i]
            for j in range(3):
                c_sum[i, j] += cov_sol[k, i, j]
    out = np.empty(n)
    s = np.empty((3, 3))
    for k in range(n):
        h = 0.0
        for i in range(p):
            for j in range(p):
                h += x[k, i] * a_inv[i, j] * x[k, j]
        h = min(h, 1.0 - 1e-9)
        g = h / (1.0 - h) / (n - 1)
        for i in range(3):
            for j in range(3):
                s[i, j] = cov_sol[k, i, j] + (c_sum[i, j] - cov_sol[k, i, j]) * g
        f = 1.0 / (1.0 - h)
        out[k] = mahalanobis3(s, resid[k, 0] * f, resid[k, 1] * f, resid[k, 2] * f)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _argmax_first(v):
    """``numpy.argmax`` of a non-empty 1-D array: the first NaN, else the first largest value."""
    worst = 0
    for i in range(v.shape[0]):
        if v[i] != v[i]:
            return i
        if v[i] > v[worst]:
            worst = i
    return worst


@njit(cache=True, no_cfunc_wrapper=True)
def true_indices(mask):
    """``numpy.flatnonzero(mask)`` of a 1-D bool array, int64 (m,) (numba's compiles one more function).

    Parameters
    ----------
    mask : ndarray of bool, shape (n,)

    Returns
    -------
    ndarray of int64, shape (m,)
        Indices of the true entries, ascending.
    """
    m = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            m += 1
    out = np.empty(m, dtype=np.int64)
    m = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            out[m] = i
            m += 1
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def gather_instants(idx, t, q_pred, q_sol, cov):
    """The rows ``idx`` of an instants' times, predicted and solved attitudes and covariances, as fresh contiguous
    arrays (``t[idx]``, ...: numba's fancy indexing compiles far more code).

    Parameters
    ----------
    idx : ndarray of int64, shape (m,)
        Rows.
    t : ndarray, shape (N,)
        Times, s.
    q_pred, q_sol : ndarray, shape (N, 4)
        Quaternions.
    cov : ndarray, shape (N, 3, 3)
        Covariances, rad².

    Returns
    -------
    t_s : ndarray, shape (m,)
    q_pred_rows, q_sol_rows : ndarray, shape (m, 4)
    cov_rows : ndarray, shape (m, 3, 3)
    """
    m = idx.shape[0]
    ts = np.empty(m)
    qp = np.empty((m, 4))
    qs = np.empty((m, 4))
    cs = np.empty((m, 3, 3))
    for k in range(m):  # element loops: a row assignment compiles numba's shape check and its message
        j = idx[k]
        ts[k] = t[j]
        for a in range(4):
            qp[k, a] = q_pred[j, a]
            qs[k, a] = q_sol[j, a]
        for a in range(3):
            for b in range(3):
                cs[k, a, b] = cov[j, a, b]
    return ts, qp, qs, cs


@njit(cache=True, no_cfunc_wrapper=True)
def smooth_instants(q_pred, q_sol, cov_sol, tau_s, gate):
    """The instants of a tracked frame that lie on a smooth motion (the tracker's smoothness test).

    The rotations from the predicted to the solved attitudes (the prediction's error: smooth in time, whatever the
    motion) are fitted: with more than three instants, the one with the largest leave-one-out χ²
    (:func:`instant_deleted_chi2`: a quadratic in time from 6 instants, a line from 4) is removed while that χ²
    exceeds ``gate`` and at least 4 remain. With three, a line through two checks the third (one degree of freedom,
    the same χ² for all three): above the gate, none is kept. Fewer than three cannot be tested.

    Parameters
    ----------
    q_pred, q_sol : ndarray, shape (n, 4)
        Predicted and solved attitudes of the solved instants (non-zero).
    cov_sol : ndarray, shape (n, 3, 3)
        Covariances of the solved attitudes, body frame, rad².
    tau_s : ndarray, shape (n,)
        Times of the instants, s, increasing.
    gate : float
        χ² (3 degrees of freedom) above which an instant is off the smooth motion; ``inf`` disables the test.

    Returns
    -------
    ndarray of int64, shape (m,)
        Rows kept (ascending); all ``n`` rows when every instant passes or the test cannot tell.
    """
    n = tau_s.shape[0]
    idx = np.empty(n, dtype=np.int64)
    for k in range(n):
        idx[k] = k
    if n < 3 or gate == np.inf:
        return idx
    if n == 3:
        # degree n - 2 = 1, an int64 as the loop's below, not a literal: one compiled signature of the callee
        chi2 = instant_deleted_chi2(q_pred, q_sol, cov_sol, tau_s, n - 2)
        return idx if not chi2[0] > gate else idx[:0]
    m = n
    while m >= 4:
        degree = 2 if m >= 6 else 1
        ts, qp, qs, cs = gather_instants(idx[:m], tau_s, q_pred, q_sol, cov_sol)
        chi2 = instant_deleted_chi2(qp, qs, cs, ts, degree)
        worst = _argmax_first(chi2)
        if not chi2[worst] > gate:
            break
        for k in range(worst, m - 1):
            idx[k] = idx[k + 1]
        m -= 1
    return idx[:m].copy()


@njit(cache=True, no_cfunc_wrapper=True)
def accept_instants(sel, t_exp, q_pred, q_all, cov_all, rms_arcsec, n_stars, gate, residual_expected_arcsec, scale):
    """The samples of a tracked frame that passed the lock tests: the smoothness test, then the covariance scaling.

    The solved instants ``sel`` go through :func:`smooth_instants`; with ``scale``, each kept instant's covariance
    grows by its a-posteriori variance factor ``max((rms / rms_expected)² / max(1 − 1.5 / n, 0.25), 1)`` (``n`` its
    stars) when any instant's factor exceeds 1 (never shrinks).

    Parameters
    ----------
    sel : ndarray of int64, shape (s,)
        The solved instants (ascending).
    t_exp : ndarray, shape (N,)
        Exposure instants, s.
    q_pred, q_all : ndarray, shape (N, 4)
        Predicted and solved attitudes of all instants.
    cov_all : ndarray, shape (N, 3, 3)
        Covariances of the solutions, rad².
    rms_arcsec : ndarray, shape (N,)
        RMS residual of each instant, arcsec.
    n_stars : ndarray of int64, shape (N,)
        Stars of each instant's solution.
    gate : float
        :func:`smooth_instants`' χ² gate.
    residual_expected_arcsec : float
        RMS of a star's residual the centroid model expects, arcsec.
    scale : bool
        Apply the covariance scaling.

    Returns
    -------
    n_off : int
        Solved instants removed by the smoothness test.
    kept : ndarray of int64, shape (m,)
        Instants kept (ascending, a subset of ``sel``).
    t_s : ndarray, shape (m,)
    q : ndarray, shape (m, 4)
    cov : ndarray, shape (m, 3, 3)
        Scaled covariances, rad².
    n : ndarray of int64, shape (m,)
    """
    ts, qp, qs, cs = gather_instants(sel, t_exp, q_pred, q_all, cov_all)
    keep = smooth_instants(qp, qs, cs, ts, gate)
    m = keep.shape[0]
    kept = np.empty(m, dtype=np.int64)
    t_s = np.empty(m)
    q = np.empty((m, 4))
    cov = np.empty((m, 3, 3))
    n = np.empty(m, dtype=np.int64)
    factor = np.empty(m)
    grow = False
    for k in range(m):
        j = sel[keep[k]]
        kept[k] = j
        t_s[k] = ts[keep[k]]
        for a in range(4):  # element loops, as gather_instants
            q[k, a] = qs[keep[k], a]
        for a in range(3):
            for b in range(3):
                cov[k, a, b] = cs[keep[k], a, b]
        n[k] = n_stars[j]
        factor[k] = 1.0
        if scale:
            dof_share = max(1.0 - 1.5 / float(n_stars[j]), 0.25)
            ratio = rms_arcsec[j] / residual_expected_arcsec
            f = ratio * ratio / dof_share
            if f > 1.0:
                factor[k] = f
                grow = True
    if grow:
        for k in range(m):
            for a in range(3):
                for b in range(3):
                    cov[k, a, b] *= factor[k]
    return sel.shape[0] - m, kept, t_s, q, cov, n


@njit(cache=True, no_cfunc_wrapper=True)
def any_nonpositive(values):
    """Whether any value is ``<= 0`` (NaN is not): ``(values <= 0).any()`` in one pass, for the unit's test of a frame's
    detection intensities (:meth:`startracker.onboard.StarTrackerUnit.process_frame`).

    Parameters
    ----------
    values : ndarray, shape (n,)

    Returns
    -------
    bool
    """
    for i in range(values.shape[0]):
        if values[i] <= 0:
            return True
    return False
