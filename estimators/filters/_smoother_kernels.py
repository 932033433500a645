"""The numba kernels of :mod:`~manualcontrol.estimators.filters.smoothers`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference): the constants they read, the records and their builder stay in
the numba-free module, which exports these kernels by name on first use.
"""

from __future__ import annotations

import numba

from manualcontrol.estimators.filters._linalg_kernels import (
    cholesky,
    cholesky_solve_rows,
    matmul,
    matmul_transposed,
    symmetrise,
)
from manualcontrol.estimators.filters.smoothers import (
    LINK_CROSS,
    LINK_TRANSITION,
    REGULARISATION,
)


@numba.njit(cache=True, _nrt=False, inline="always")
def store_belief(row, x, P, x_store, P_store):
    """Copy a belief into row ``row`` of the storage above (a no-op when it has no rows)."""
    if x_store.shape[0] == 0:
        return
    for i in range(x.shape[0]):
        x_store[row, i] = x[i]
        for j in range(x.shape[0]):
            P_store[row, i, j] = P[i, j]


@numba.njit(cache=True, _nrt=False)
def _factor_prior(P, A, L):
    """Cholesky factor of the prior ``P`` into ``L``, loaded only if it must be.

    When ``P`` does not factor, ``A = P + load diag(P)`` (each variance loaded by its own
    size, blind to the states' units) is tried with ``load`` from
    :data:`REGULARISATION` growing by 1e3 up to five times. Returns the number of
    loadings used (0 normally), -1 if none succeeded.
    """
    if cholesky(P, L):
        return 0
    n = P.shape[0]
    load = REGULARISATION
    for attempt in range(1, 7):
        for i in range(n):
            for j in range(n):
                A[i, j] = P[i, j]
            A[i, i] += load * abs(P[i, i]) + 1e-300
        if cholesky(A, L):
            return attempt
        load *= 1e3
    return -1


@numba.njit(cache=True, _nrt=False)
def rts_smooth(x_filtered, P_filtered, x_predicted, P_predicted, link, kind, x_smooth, P_smooth, w):
    """Smooth a stored run backwards (module docstring); returns regularised-sample count.

    ``kind`` is :data:`LINK_CROSS`, :data:`LINK_TRANSITION` or :data:`LINK_RANDOM_WALK`.
    ``x_smooth`` (N, n) and ``P_smooth`` (N, n, n) receive the result. Returns the
    number of samples whose prior was regularised, or minus the number of samples
    whose prior could not be factored even then (those keep their filtered belief).
    """
    N = x_filtered.shape[0]
    n = x_filtered.shape[1]
    C, G, A, L, D, T = w.C, w.G, w.A, w.L, w.D, w.T
    regularised = 0
    failed = 0
    if N == 0:
        return 0
    for i in range(n):
        x_smooth[N - 1, i] = x_filtered[N - 1, i]
        for j in range(n):
            P_smooth[N - 1, i, j] = P_filtered[N - 1, i, j]
    for k in range(N - 2, -1, -1):
        Pf = P_filtered[k]
        Pp = P_predicted[k + 1]
        # C_{k+1} = cov(x^+_k, x^-_{k+1})
        if kind == LINK_CROSS:
            for i in range(n):
                for j in range(n):
                    C[i, j] = link[k + 1, i, j]
        elif kind == LINK_TRANSITION:
            matmul_transposed(Pf, link[k + 1], C)
        else:
            for i in range(n):
                for j in range(n):
                    C[i, j] = Pf[i, j]
        status = _factor_prior(Pp, A, L)
        if status < 0:
            failed += 1
            for i in range(n):
                x_smooth[k, i] = x_filtered[k, i]
                for j in range(n):
                    P_smooth[k, i, j] = Pf[i, j]
            continue
        regularised += 1 if status > 0 else 0
        # G = C P_p^-1 (rows of C solved against the symmetric P_p)
        cholesky_solve_rows(L, C, G)
        for i in range(n):
            acc = x_filtered[k, i]
            for j in range(n):
                acc += G[i, j] * (x_smooth[k + 1, j] - x_predicted[k + 1, j])
            x_smooth[k, i] = acc
        for i in range(n):
            for j in range(n):
                D[i, j] = P_smooth[k + 1, i, j] - Pp[i, j]
        matmul(G, D, T)
        matmul_transposed(T, G, A)
        for i in range(n):
            for j in range(n):
                A[i, j] += Pf[i, j]
        symmetrise(A)
        for i in range(n):
            for j in range(n):
                P_smooth[k, i, j] = A[i, j]
    return regularised if failed == 0 else -failed
