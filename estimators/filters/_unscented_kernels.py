"""The numba kernels of :mod:`~manualcontrol.estimators.filters.unscented`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and their
builders stay in the numba-free module, which exports these kernels by name on first use.
"""

from __future__ import annotations

import numba

from manualcontrol.estimators.filters._linalg_kernels import (
    add_product,
    cholesky,
    cholesky_semidefinite,
    cholesky_semidefinite_pivoted,
    cholesky_solve_rows,
    log_determinant,
    symmetrise,
)


@numba.njit(cache=True, _nrt=False)
def sigma_points(x, P, spread, L, X):
    """Sigma points of ``(x, P)`` into the rows of ``X`` (centre last).

    ``P`` may be semidefinite (:func:`~.linalg.cholesky_semidefinite`: directions of
    zero variance get no spread); False if it is not, or not finite. Where the
    unpivoted factor refuses ``P``, the pivoted one
    (:func:`~.linalg.cholesky_semidefinite_pivoted`, ``X`` its scratch) tells a
    semidefinite ``P`` rounded below zero from an indefinite one; a ``P`` the unpivoted
    factor takes is spread along that factor's columns alone.
    """
    if not cholesky_semidefinite(P, L) and not cholesky_semidefinite_pivoted(P, L, X):
        return False
    _spread_points(x, spread, L, X)
    return True


@numba.njit(cache=True, _nrt=False)
def triangular_sigma_points(x, P, spread, L, X):
    """:func:`sigma_points` from the unpivoted factor alone: ``L`` lower triangular.

    For code that reads ``L`` after the points as a triangular matrix (the dual UKF's
    parameter sensitivity solves ``D E = M`` by back-substitution, ``E = c L``); the
    pivoted factor's rows are permuted. False where the unpivoted factor refuses ``P``.
    """
    if not cholesky_semidefinite(P, L):
        return False
    _spread_points(x, spread, L, X)
    return True


@numba.njit(cache=True, _nrt=False)
def _spread_points(x, spread, L, X):
    """``x`` plus and minus ``spread`` times each column of ``L`` into ``X``, centre last."""
    n = x.shape[0]
    for i in range(n):
        for j in range(n):
            d = spread * L[j, i]
            X[i, j] = x[j] + d
            X[n + i, j] = x[j] - d
    for j in range(n):
        X[2 * n, j] = x[j]


@numba.njit(cache=True, _nrt=False)
def weighted_mean(Y, weights, count, out):
    """``out = sum_i w_i Y_i`` over the first ``count`` rows (the centre is the last row)."""
    for j in range(Y.shape[1]):
        out[j] = 0.0
    for i in range(count):
        w = weights[i]
        for j in range(Y.shape[1]):
            out[j] += w * Y[i, j]


@numba.njit(cache=True, _nrt=False)
def weighted_covariance(Y, mean, weights, count, noise, out):
    """``out = sum_i w_i (Y_i - mean)(Y_i - mean)^T + noise``, symmetrised."""
    d = Y.shape[1]
    for a in range(d):
        for b in range(d):
            out[a, b] = noise[a, b]
    for i in range(count):
        w = weights[i]
        for a in range(d):
            da = w * (Y[i, a] - mean[a])
            for b in range(a, d):
                out[a, b] += da * (Y[i, b] - mean[b])
    for a in range(d):
        for b in range(a + 1, d):
            out[b, a] = out[a, b]
    symmetrise(out)


@numba.njit(cache=True, _nrt=False)
def cross_covariance(X, xmean, Z, zmean, weights, count, out):
    """``out = sum_i w_i (X_i - xmean)(Z_i - zmean)^T``."""
    for a in range(X.shape[1]):
        for b in range(Z.shape[1]):
            out[a, b] = 0.0
    for i in range(count):
        w = weights[i]
        for a in range(X.shape[1]):
            da = w * (X[i, a] - xmean[a])
            for b in range(Z.shape[1]):
                out[a, b] += da * (Z[i, b] - zmean[b])


@numba.njit(cache=True, _nrt=False)
def unscented_correct(x, P, r, Cxz, S, LS, K, log_det, jitter):
    """``K = C_xz S^-1``, ``x += K r``, ``P -= K C_xz^T`` (Zhao Algorithm 2 step 3).

    ``S`` is the innovation covariance (measurement spread plus ``R``). Returns False,
    leaving ``x`` and ``P`` unchanged, when ``S`` is not positive definite. Writes
    ``log det S`` to ``log_det[0]``.
    """
    n = x.shape[0]
    m = r.shape[0]
    if not cholesky(S, LS):
        return False
    cholesky_solve_rows(LS, Cxz, K)
    log_det[0] = log_determinant(LS)
    add_product(x, K, r)
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for a in range(m):
                acc += K[i, a] * Cxz[j, a]
            P[i, j] -= acc
            if j != i:
                P[j, i] = P[i, j]
    symmetrise(P)
    if jitter > 0.0:
        for i in range(n):
            P[i, i] += jitter
    return True


@numba.njit(cache=True, _nrt=False)
def project_points(X, count, index, lo, hi):
    """Clamp column ``i`` of the first ``count`` points into ``[lo[j], hi[j]]``, ``j = index[i]``.

    ``index[i] = -1`` leaves column ``i`` free. The centre row (last) is clamped too.
    Returns the number of entries moved.
    """
    n_points = X.shape[0]
    moved = 0
    for i in range(index.shape[0]):
        j = index[i]
        if j < 0:
            continue
        for r in range(n_points):
            if r >= count and r != n_points - 1:
                continue
            if X[r, i] < lo[j]:
                X[r, i] = lo[j]
                moved += 1
            elif X[r, i] > hi[j]:
                X[r, i] = hi[j]
                moved += 1
    return moved


@numba.njit(cache=True, _nrt=False)
def constrain_prior(X, wm, wc, count, index, lo, hi, x, P, zero):
    """Project the points of ``(x, P)``; if any moved, make ``(x, P)`` their moments.

    ``zero`` is an (n, n) array of zeros (no added noise). Returns the entries moved.
    """
    moved = project_points(X, count, index, lo, hi)
    if moved > 0:
        weighted_mean(X, wm, count, x)
        weighted_covariance(X, x, wc, count, zero, P)
    return moved
