"""Sigma points and the unscented Kalman filter's moments and correction, compiled.

The unscented transform (Julier & Uhlmann 1997; Zhao et al. 2019 Algorithm 1) pushes
``2N + 1`` sigma points ``X_0 = x``, ``X_i = x +- c (L)_i`` (``L L^T = P``, ``(L)_i``
the i-th column) through a function and takes weighted moments of the images. Two
weight schemes:

* *Merwe scaled* (van der Merwe 2004): ``lambda = alpha^2 (N + kappa) - N``,
  ``c = sqrt(N + lambda)``, ``W^m_0 = lambda/(N + lambda)``,
  ``W^c_0 = W^m_0 + 1 - alpha^2 + beta``, ``W_i = 1/(2(N + lambda))``;
* *cubature* (Zhao Alg. 1 eq. 8 and the choice below eq. 11): ``c = sqrt(N)``,
  ``W_0 = 0``, ``W_i = 1/(2N)``: the third-degree spherical-radial cubature rule.

The model propagates the points itself (its transition or measurement function, in
its own compiled step); the functions here generate the points, take the moments and
correct the belief:

* :func:`sigma_points`: the points of ``(x, P)`` into ``X`` (rows), False when ``P`` is
  not positive definite;
* :func:`weighted_mean` and :func:`weighted_covariance`: moments of the images, with
  additive noise (``Q`` or ``R``); :func:`cross_covariance` between two point sets;
* :func:`unscented_correct`: ``K = C_xz S^-1`` (Cholesky solve), ``x^+ = x^- + K r``,
  ``P^+ = P^- - K C_xz^T`` (Zhao Algorithm 2 step 3), symmetrised;
* :func:`project_points`: sigma points onto box limits before they are propagated
  (Kandepu, Foss & Imsland 2008). A prior spread wide against its limits otherwise
  sends points where the model is meaningless (a negative delay in a Padé
  approximant). Projected points no longer carry the prior's moments; before a
  correction :func:`constrain_prior` replaces the prior by the moments of the
  projected points, so that the prior, the cross-covariance and the innovation
  covariance come from one weighted point set and (with positive weights, as in the
  cubature rule) the corrected covariance stays positive semidefinite.

Points are stored centre last (row ``2N``), so a scheme whose centre weights are both
zero (cubature) propagates only the first ``2N`` rows.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba
import numpy as np

from manualcontrol.estimators.filters.linalg import (
    add_product,
    cholesky,
    cholesky_semidefinite,
    cholesky_solve_rows,
    log_determinant,
    symmetrise,
)

__all__ = [
    "SIGMA_SCHEMES",
    "SigmaWeights",
    "UnscentedWork",
    "constrain_prior",
    "cross_covariance",
    "project_points",
    "sigma_points",
    "sigma_weights",
    "unscented_correct",
    "unscented_work",
    "weighted_covariance",
    "weighted_mean",
]

#: Sigma-point weight schemes.
SIGMA_SCHEMES: tuple[str, ...] = ("merwe", "cubature")

#: Weights of a scheme: ``mean`` and ``cov`` (2N + 1,), centre last; ``spread`` = ``c``;
#: ``count`` = number of rows to propagate (2N when the centre weighs nothing, else 2N + 1).
SigmaWeights = namedtuple("SigmaWeights", ["mean", "cov", "spread", "count"])

#: Scratch of an unscented filter with ``n`` states and ``m`` outputs: ``L`` (n, n),
#: ``X`` and ``Y`` (2n + 1, n) points and their images, ``Z`` (2n + 1, m) measured
#: images, ``z`` (m,) predicted measurement, ``S`` and ``LS`` (m, m), ``Cxz`` and ``K``
#: (n, m), ``xbar`` (n,), ``log_det`` (1,).
UnscentedWork = namedtuple(
    "UnscentedWork", ["L", "X", "Y", "Z", "z", "S", "LS", "Cxz", "K", "xbar", "log_det"]
)


def sigma_weights(
    n: int, scheme: str = "merwe", alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0
) -> SigmaWeights:
    """Weights of ``scheme`` for ``n`` states (see the module docstring).

    ``alpha``, ``beta``, ``kappa`` apply to the Merwe scheme only (defaults: the common
    ``alpha = 1e-3``, ``beta = 2`` for Gaussian priors, ``kappa = 0``).
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n (number of states) must be an integer >= 1, got {n!r}")
    if scheme not in SIGMA_SCHEMES:
        raise ValueError(f"scheme must be one of {SIGMA_SCHEMES}, got {scheme!r}")
    mean = np.zeros(2 * n + 1)
    cov = np.zeros(2 * n + 1)
    if scheme == "cubature":
        mean[: 2 * n] = 1.0 / (2 * n)
        cov[: 2 * n] = 1.0 / (2 * n)
        return SigmaWeights(mean, cov, math.sqrt(n), 2 * n)
    for name, value in (("alpha", alpha), ("beta", beta), ("kappa", kappa)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
    if not alpha > 0.0:
        raise ValueError(f"alpha must be > 0, got {alpha!r}")
    lam = alpha * alpha * (n + kappa) - n
    if not n + lam > 0.0:
        raise ValueError(
            f"alpha and kappa must give n + lambda > 0 (lambda = alpha^2 (n + kappa) - n), "
            f"got alpha={alpha!r}, kappa={kappa!r} for n={n}"
        )
    mean[: 2 * n] = 1.0 / (2.0 * (n + lam))
    cov[: 2 * n] = mean[: 2 * n]
    mean[2 * n] = lam / (n + lam)
    cov[2 * n] = mean[2 * n] + 1.0 - alpha * alpha + beta
    return SigmaWeights(mean, cov, math.sqrt(n + lam), 2 * n + 1)


def unscented_work(n: int, m: int) -> UnscentedWork:
    """Scratch arrays for an ``n``-state unscented filter with ``m`` outputs."""
    points = 2 * n + 1
    return UnscentedWork(
        np.zeros((n, n)),
        np.zeros((points, n)),
        np.zeros((points, n)),
        np.zeros((points, m)),
        np.zeros(m),
        np.zeros((m, m)),
        np.zeros((m, m)),
        np.zeros((n, m)),
        np.zeros((n, m)),
        np.zeros(n),
        np.zeros(1),
    )


@numba.njit(cache=True, _nrt=False)
def sigma_points(x, P, spread, L, X):
    """Sigma points of ``(x, P)`` into the rows of ``X`` (centre last).

    ``P`` may be semidefinite (:func:`~.linalg.cholesky_semidefinite`: directions of
    zero variance get no spread); False if it is not, or not finite.
    """
    n = x.shape[0]
    if not cholesky_semidefinite(P, L):
        return False
    for i in range(n):
        for j in range(n):
            d = spread * L[j, i]
            X[i, j] = x[j] + d
            X[n + i, j] = x[j] - d
    for j in range(n):
        X[2 * n, j] = x[j]
    return True


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
