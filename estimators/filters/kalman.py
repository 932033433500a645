"""Extended Kalman filter steps: prediction and Joseph-form correction, compiled.

The filter is pure functions of a belief (mean ``x``, covariance ``P``: arrays the
caller owns and the functions update in place), the model's linearisation at that
belief and the sample (the split of dynamax's ``_predict`` / ``_condition_on``). The
model evaluates itself (``x^- = f(x^+)``, ``Phi = df/dx``,
``z^- = h(x^-)``, ``H = dh/dx``); the functions here hold the covariance algebra,
written once for every filter of the family:

* :func:`predict_covariance`: ``P^- = Phi P^+ Phi^T + Q`` (dense ``Phi``; models
  with structured Jacobians may propagate ``P`` themselves);
* :func:`add_diagonal`: the additive process noise of random-walk parameters and of
  noise inputs with identity gain;
* :func:`joseph_correct`: the correction for an ``m``-dimensional measurement,
  ``S = H P H^T + R``, ``K = P H^T S^-1`` (a Cholesky solve; a division when
  ``m = 1``), ``x^+ = x^- + K r`` and the Joseph form
  ``P^+ = (I - K H) P^- (I - K H)^T + K R K^T``, symmetrised (Bucy & Joseph; it stays
  positive semidefinite for any gain, where the textbook ``(I - K H) P`` loses that
  under rounding);
* :func:`clamp`: state limits by estimate projection (thesis Part I eqs. 20, 25:
  with a unit-row constraint matrix the projection is a clamp of the entry).

``KalmanWork`` holds the scratch arrays (:func:`kalman_work` allocates them once per
filter).
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from manualcontrol.estimators.filters.linalg import (
    add_product,
    cholesky,
    cholesky_solve_rows,
    log_determinant,
    matmul,
    matmul_transposed,
    symmetrise,
)

__all__ = [
    "KalmanWork",
    "add_diagonal",
    "clamp",
    "joseph_correct",
    "kalman_work",
    "predict_covariance",
    "textbook_correct",
]

#: Scratch of one filter: ``PHt`` (n, m), ``S`` and ``L`` (m, m), ``K`` and ``M`` (n, m),
#: ``T`` (n, n), ``log_det`` (1,), the ``log det S`` of the last correction.
KalmanWork = namedtuple("KalmanWork", ["PHt", "S", "L", "K", "M", "T", "log_det"])


def kalman_work(n: int, m: int, log_det: bool = True) -> KalmanWork:
    """Scratch arrays for an ``n``-state filter with ``m``-dimensional measurements.

    ``log_det=False`` skips the logarithm of each correction's innovation covariance
    (filters that never read the likelihood).
    """
    return KalmanWork(
        np.zeros((n, m)),
        np.zeros((m, m)),
        np.zeros((m, m)),
        np.zeros((n, m)),
        np.zeros((n, m)),
        np.zeros((n, n)),
        np.zeros(1 if log_det else 0),
    )


@numba.njit(cache=True, _nrt=False)
def predict_covariance(P, Phi, Q, T):
    """``P <- Phi P Phi^T + Q`` in place (``T`` is (n, n) scratch), symmetrised."""
    n = P.shape[0]
    matmul(Phi, P, T)
    matmul_transposed(T, Phi, P)
    for i in range(n):
        for j in range(n):
            P[i, j] += Q[i, j]
    symmetrise(P)


@numba.njit(cache=True, _nrt=False)
def add_diagonal(P, q, scale):
    """``P <- P + scale diag(q)``: additive white noise on each state."""
    for i in range(q.shape[0]):
        P[i, i] += q[i] * scale


@numba.njit(cache=True, _nrt=False)
def _innovation_covariance(P, H, R, PHt, S):
    """``PHt = P H^T`` and ``S = H P H^T + R``."""
    matmul_transposed(P, H, PHt)
    for a in range(S.shape[0]):
        for b in range(S.shape[1]):
            acc = R[a, b]
            for i in range(P.shape[0]):
                acc += H[a, i] * PHt[i, b]
            S[a, b] = acc


@numba.njit(cache=True, _nrt=False)
def _joseph_scalar(x, P, r, H, R, work, jitter):
    """:func:`joseph_correct` for a scalar measurement, fused (the same numbers).

    The same operations in the same order as the general form, with the loops over
    the measurement dimension gone and ``P H^T`` and ``S`` taken in one pass: a scalar
    correction is most of every pilot filter's step.
    """
    n = P.shape[0]
    PHt, K, M = work.PHt, work.K, work.M
    s = R[0, 0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * H[0, j]
        PHt[i, 0] = acc
        s += H[0, i] * acc
    work.S[0, 0] = s
    if not s > 0.0 or not np.isfinite(s):
        return False
    r0 = r[0]
    for i in range(n):
        k_i = PHt[i, 0] / s
        K[i, 0] = k_i
        acc = 0.0
        acc += k_i * r0
        x[i] += acc
    if work.log_det.shape[0] > 0:
        work.log_det[0] = np.log(s)
    for i in range(n):
        k_i = K[i, 0]
        for j in range(n):
            acc = 0.0
            acc += k_i * PHt[j, 0]
            P[i, j] -= acc
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * H[0, j]
        M[i, 0] = acc
    rv = R[0, 0]
    for i in range(n):
        m_i = M[i, 0]
        k_i = K[i, 0]
        for j in range(n):
            acc = 0.0
            acc -= m_i * K[j, 0]
            acc += k_i * rv * K[j, 0]
            P[i, j] += acc
    symmetrise(P)
    if jitter > 0.0:
        for i in range(n):
            P[i, i] += jitter
    return True


@numba.njit(cache=True, _nrt=False)
def joseph_correct(x, P, r, H, R, work, jitter):
    """Correct the belief ``(x, P)`` with innovation ``r`` (m,); Joseph form.

    ``H`` (m, n) is the measurement Jacobian at the prior, ``R`` (m, m) the measurement
    noise covariance. On return ``work.S`` holds the innovation covariance
    ``H P^- H^T + R``, ``work.K`` the gain and ``work.log_det[0]`` ``log det S``.
    ``jitter`` is added to the diagonal of ``P^+`` (0 = off). Returns False, leaving
    ``x`` and ``P`` as they were, when ``S`` is not positive definite.
    """
    n = P.shape[0]
    m = r.shape[0]
    if m == 1:
        return _joseph_scalar(x, P, r, H, R, work, jitter)
    PHt, S, L, K, M = work.PHt, work.S, work.L, work.K, work.M
    _innovation_covariance(P, H, R, PHt, S)
    for a in range(m):
        for b in range(a + 1, m):
            v = 0.5 * (S[a, b] + S[b, a])
            S[a, b] = v
            S[b, a] = v
    if not cholesky(S, L):
        return False
    cholesky_solve_rows(L, PHt, K)
    if work.log_det.shape[0] > 0:
        work.log_det[0] = log_determinant(L)
    add_product(x, K, r)
    # (I - K H) P = P - K (H P), H P = PHt^T for symmetric P
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(m):
                acc += K[i, a] * PHt[j, a]
            P[i, j] -= acc
    # M = [(I - K H) P] H^T, then  ... (I - K H)^T = ... - M K^T, plus K R K^T
    matmul_transposed(P, H, M)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(m):
                acc -= M[i, a] * K[j, a]
            for a in range(m):
                for b in range(m):
                    acc += K[i, a] * R[a, b] * K[j, b]
            P[i, j] += acc
    symmetrise(P)
    if jitter > 0.0:
        for i in range(n):
            P[i, i] += jitter
    return True


@numba.njit(cache=True, _nrt=False)
def textbook_correct(x, P, r, H, R, work):
    """The short form ``P^+ = (I - K H) P^-`` (for comparisons only; see the module doc).

    Loses positive definiteness under rounding where :func:`joseph_correct` keeps it:
    ``tests/estimators/test_filters.py`` shows a case. Not symmetrised.
    """
    n = P.shape[0]
    m = r.shape[0]
    PHt, S, L, K = work.PHt, work.S, work.L, work.K
    _innovation_covariance(P, H, R, PHt, S)
    if not cholesky(S, L):
        return False
    cholesky_solve_rows(L, PHt, K)
    add_product(x, K, r)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(m):
                acc += K[i, a] * PHt[j, a]
            P[i, j] -= acc
    return True


@numba.njit(cache=True, _nrt=False)
def clamp(x, index, lo, hi):
    """Estimate projection onto box limits: ``x[i]`` into ``[lo[j], hi[j]]``.

    ``index[i]`` names the limit entry ``j`` of state ``i`` (-1: unlimited). Returns
    the number of states that were moved.
    """
    moved = 0
    for i in range(index.shape[0]):
        j = index[i]
        if j < 0:
            continue
        if x[i] < lo[j]:
            x[i] = lo[j]
            moved += 1
        elif x[i] > hi[j]:
            x[i] = hi[j]
            moved += 1
    return moved
