"""The numba kernels of :mod:`~manualcontrol.estimators.filters.linalg`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference): the constants they read stay in the numba-free module, which
exports these kernels by name on first use.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators.filters.linalg import SEMIDEFINITE_TOLERANCE, TINY


@numba.njit(cache=True, _nrt=False)
def symmetrise(P):
    """``P <- (P + P^T)/2`` in place, flushing entries below :data:`TINY` to zero."""
    n = P.shape[0]
    for i in range(n):
        if abs(P[i, i]) < TINY:
            P[i, i] = 0.0
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            if abs(v) < TINY:
                v = 0.0
            P[i, j] = v
            P[j, i] = v


@numba.njit(cache=True, _nrt=False)
def cholesky(A, L):
    """Lower Cholesky factor of the symmetric ``A`` into ``L`` (``A = L L^T``).

    Returns False (``L`` then undefined) when ``A`` is not positive definite or not
    finite. Reads the lower triangle of ``A`` only.
    """
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0 or not np.isfinite(s):
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
        for i in range(j):
            L[i, j] = 0.0
    return True


@numba.njit(cache=True, _nrt=False)
def semidefinite_floor(A):
    """Pivots at or below this count as zero in the semidefinite factors.

    :data:`SEMIDEFINITE_TOLERANCE` times ``A``'s largest diagonal entry (at least 0);
    -1 where a diagonal entry is not finite.
    """
    largest = 0.0
    for i in range(A.shape[0]):
        if not np.isfinite(A[i, i]):
            return -1.0
        largest = max(largest, A[i, i])
    return SEMIDEFINITE_TOLERANCE * largest


@numba.njit(cache=True, _nrt=False)
def cholesky_semidefinite(A, L):
    """A factor ``L`` (lower, ``A = L L^T``) of a positive *semi*definite ``A``.

    Directions whose variance the data have driven to zero (a state without process
    noise that the measurements pin down) leave pivots at rounding level, possibly
    below zero; a pivot under :data:`SEMIDEFINITE_TOLERANCE` times the largest diagonal
    entry is taken as zero and its column left zero. Returns False for a clearly
    negative pivot or non-finite entries.
    """
    n = A.shape[0]
    floor = semidefinite_floor(A)
    if floor < 0.0:
        return False
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        for i in range(j):
            L[i, j] = 0.0
        if s <= floor:
            if s < -1e3 * floor - 1e-300:
                return False
            for i in range(j, n):
                L[i, j] = 0.0
            continue
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    return True


@numba.njit(cache=True, _nrt=False)
def cholesky_semidefinite_pivoted(A, L, work):
    """A square root ``L`` (``A = L L^T``, not triangular) of a positive semidefinite ``A``.

    :func:`cholesky_semidefinite` with diagonal pivoting (the largest remaining pivot
    first, as LAPACK's ``dpstrf``), for the covariances it refuses that are semidefinite
    but for rounding. A covariance the data have made singular (an update by a
    measurement of almost no noise: a causal start whose stick has been still, so
    that its variance is the floor) has an unpivoted last pivot whose rounding error
    grows with the pivots before it, past the tolerance, while its smallest eigenvalue
    is at the rounding of the largest. Taking the largest pivot first keeps every
    pivot's error near the rounding of the largest, and leaves the zero direction
    last, where it gets no spread. ``L`` is the factor with its rows put back in
    ``A``'s order, so ``L L^T = A`` and points spread along its columns are points of
    ``A``; it is not triangular (:func:`~.unscented.triangular_sigma_points` is for code
    that needs that). Returns False for a clearly negative pivot or non-finite entries
    (every remaining pivot is checked where the factor stops). ``work`` is scratch of
    at least ``(n + 2, n)``: the factor in pivoted order, the remaining pivots and the
    order. Reads the lower triangle of ``A`` only.
    """
    n = A.shape[0]
    floor = semidefinite_floor(A)
    if floor < 0.0:
        return False
    pivots = n
    order = n + 1
    for i in range(n):
        work[order, i] = i
        work[pivots, i] = A[i, i]
        for j in range(n):
            work[i, j] = 0.0
    for k in range(n):
        m = k
        best = work[pivots, k]
        for i in range(k + 1, n):
            if work[pivots, i] > best:
                best = work[pivots, i]
                m = i
        if not np.isfinite(best):
            return False
        if m != k:
            work[pivots, m] = work[pivots, k]
            work[pivots, k] = best
            held = work[order, k]
            work[order, k] = work[order, m]
            work[order, m] = held
            for j in range(k):
                held = work[k, j]
                work[k, j] = work[m, j]
                work[m, j] = held
        if best <= floor:  # every remaining pivot is as small: no spread along them
            for i in range(k, n):  # unless one is clearly negative, or not a number
                if not work[pivots, i] >= -1e3 * floor - 1e-300:
                    return False
            break
        d = np.sqrt(best)
        work[k, k] = d
        at = int(work[order, k])
        for i in range(k + 1, n):
            other = int(work[order, i])
            s = A[other, at] if other > at else A[at, other]
            for j in range(k):
                s -= work[i, j] * work[k, j]
            work[i, k] = s / d
            work[pivots, i] -= work[i, k] * work[i, k]
    for i in range(n):
        row = int(work[order, i])
        for j in range(n):
            L[row, j] = work[i, j]
    return True


@numba.njit(cache=True, _nrt=False)
def cholesky_solve_rows(L, B, X):
    """Solve ``X S = B`` for ``X`` (rows of ``B``), ``S = L L^T`` symmetric.

    ``B`` and ``X`` have shape ``(r, m)``; ``X`` may be ``B``. This is the Kalman gain
    ``K = P H^T S^-1`` without an inverse: each row solves ``S k = b`` (S symmetric)
    by a forward and a backward substitution.
    """
    m = L.shape[0]
    for r in range(B.shape[0]):
        # forward: L z = b
        for i in range(m):
            s = B[r, i]
            for k in range(i):
                s -= L[i, k] * X[r, k]
            X[r, i] = s / L[i, i]
        # backward: L^T k = z
        for i in range(m - 1, -1, -1):
            s = X[r, i]
            for k in range(i + 1, m):
                s -= L[k, i] * X[r, k]
            X[r, i] = s / L[i, i]


@numba.njit(cache=True, _nrt=False)
def log_determinant(L):
    """``log det(L L^T)`` from a Cholesky factor."""
    total = 0.0
    for i in range(L.shape[0]):
        total += np.log(L[i, i])
    return 2.0 * total


@numba.njit(cache=True, _nrt=False)
def matmul(A, B, out):
    """``out = A B`` (``out`` must not alias ``A`` or ``B``)."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@numba.njit(cache=True, _nrt=False)
def matmul_transposed(A, B, out):
    """``out = A B^T`` (``out`` must not alias ``A`` or ``B``)."""
    for i in range(A.shape[0]):
        for j in range(B.shape[0]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[j, k]
            out[i, j] = acc


@numba.njit(cache=True, _nrt=False)
def add_product(x, K, r):
    """``x += K r`` for a matrix ``K`` and vector ``r`` (the Kalman mean update)."""
    for i in range(K.shape[0]):
        acc = 0.0
        for a in range(K.shape[1]):
            acc += K[i, a] * r[a]
        x[i] += acc
