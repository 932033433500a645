"""The numba kernels of :mod:`~manualcontrol.estimators.filters.kalman`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference): the records and their builder stay in the numba-free module,
which exports these kernels by name on first use.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators.filters._linalg_kernels import (
    add_product,
    cholesky,
    cholesky_solve_rows,
    log_determinant,
    matmul,
    matmul_transposed,
    symmetrise,
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
