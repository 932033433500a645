"""Compiled matrix exponential of small dense matrices, one after another in a batch.

The LPV simulations exponentiate one augmented matrix per sample (every sample has its
own parameters when estimated traces drive the isolated pilot), so the per-call cost of
:func:`scipy.linalg.expm` (4-9 us of Python and argument checking around a 1 us
computation) was most of a run. This is the same algorithm, compiled, with all work
arrays allocated once per batch:

Al-Mohy & Higham (2009), "A new scaling and squaring algorithm for the matrix
exponential", SIAM J. Matrix Anal. Appl. 31(3), Algorithm 3.1: the Padé order
``m in (3, 5, 7, 9, 13)`` is picked from ``d_k = ||A^k||^(1/k)`` (computed exactly:
the matrices are small) and the backward-error bound ``ell`` (their eq. 3.11 via
``|c_{2m+1}| || |A|^{2m+1} || / ||A||``); order 13 scales by ``2^-s`` and squares
``s`` times. scipy.linalg.expm implements the same paper in a kernel that reads C-ordered
arrays as their transposes, so it computes ``exp(A^T)^T``: its norms are those of
``A^T`` and its Padé solve eliminates along the other axis. We do the same on purpose:
on the badly scaled canonical forms of high-order Padé delays (entries from 1e-3 to
1e5) the untransposed solve loses five digits in the small entries of the result
(measured 1e-5 relative against 60-digit arithmetic; transposed 6e-15, scipy 9e-14).
Both then agree to rounding (tested to 1e-12 relative). scipy also special-cases
triangular inputs in the squaring phase; that matters only for large norms of badly
scaled triangular matrices, never reached at our sample times.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["expm_batch"]

FloatArray = NDArray[np.float64]

# Padé coefficients b_0 .. b_m of r_m (Higham 2005, eq. 2.3; the same as scipy's)
_B3 = np.array([120.0, 60.0, 12.0, 1.0])
_B5 = np.array([30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0])
_B7 = np.array([17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0])
_B9 = np.array(
    [
        17643225600.0,
        8821612800.0,
        2075673600.0,
        302702400.0,
        30270240.0,
        2162160.0,
        110880.0,
        3960.0,
        90.0,
        1.0,
    ]
)
_B13 = np.array(
    [
        64764752532480000.0,
        32382376266240000.0,
        7771770303897600.0,
        1187353796428800.0,
        129060195264000.0,
        10559470521600.0,
        670442572800.0,
        33522128640.0,
        1323241920.0,
        40840800.0,
        960960.0,
        16380.0,
        182.0,
        1.0,
    ]
)
# theta_m of Al-Mohy & Higham (2009), Table 3.1 (theta_13 = 4.25 in their Algorithm 3.1)
_THETA3 = 1.495585217958292e-2
_THETA5 = 2.539398330063230e-1
_THETA7 = 9.504178996162932e-1
_THETA9 = 2.097847961257068e0
_THETA13 = 4.25
# 1/|c_{2m+1}| of the backward-error bound ell(A, m), their eq. 3.11 / scipy's _ell
_ELL3 = 100800.0
_ELL5 = 10059033600.0
_ELL7 = 4487938430976000.0
_ELL9 = 5914384781877411840000.0
_ELL13 = 113250775606021113483283660800000000.0
_UNIT_ROUNDOFF = 2.0**-53


@numba.njit(cache=True)
def _matmul(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
        for k in range(n):
            aik = a[i, k]
            if aik != 0.0:
                for j in range(n):
                    out[i, j] += aik * b[k, j]


@numba.njit(cache=True)
def _norm1(a: FloatArray) -> float:
    """Maximum absolute column sum."""
    n = a.shape[0]
    best = 0.0
    for j in range(n):
        total = 0.0
        for i in range(n):
            total += abs(a[i, j])
        best = max(best, total)
    return best


@numba.njit(cache=True)
def _ell(
    a: FloatArray,
    scale: float,
    norm_a: float,
    power: int,
    recip: float,
    v: FloatArray,
    w: FloatArray,
) -> int:
    """Al-Mohy & Higham's ell(scale A, m) with ``power = 2m + 1``.

    ``|| |A|^p ||_1`` of a non-negative matrix is the largest entry of ``1^T |A|^p``,
    computed exactly by ``p`` vector-matrix products.
    """
    n = a.shape[0]
    for j in range(n):
        v[j] = 1.0
    for _ in range(power):
        for j in range(n):
            total = 0.0
            for i in range(n):
                total += v[i] * abs(a[i, j])
            w[j] = scale * total
        for j in range(n):
            v[j] = w[j]
    abs_norm = 0.0
    for j in range(n):
        abs_norm = max(abs_norm, v[j])
    if abs_norm == 0.0:
        return 0
    alpha = abs_norm / (scale * norm_a * recip)
    value = math.ceil(math.log2(alpha / _UNIT_ROUNDOFF) / (power - 1))
    return max(int(value), 0)


@numba.njit(cache=True)
def _polynomial(
    out: FloatArray,
    add: bool,
    c0: float,
    c2: float,
    a2: FloatArray,
    c4: float,
    a4: FloatArray,
    c6: float,
    a6: FloatArray,
    c8: float,
    a8: FloatArray,
) -> None:
    """``out (+)= c8 A8 + c6 A6 + c4 A4 + c2 A2 + c0 I``; terms with a zero coefficient skipped.

    Skipped, not multiplied by zero: a power not computed holds whatever was there.
    """
    n = out.shape[0]
    for i in range(n):
        for j in range(n):
            total = c0 if i == j else 0.0
            if c8 != 0.0:
                total = c8 * a8[i, j] + (c6 * a6[i, j] + (c4 * a4[i, j] + (c2 * a2[i, j] + total)))
            elif c6 != 0.0:
                total = c6 * a6[i, j] + (c4 * a4[i, j] + (c2 * a2[i, j] + total))
            elif c4 != 0.0:
                total = c4 * a4[i, j] + (c2 * a2[i, j] + total)
            else:
                total = c2 * a2[i, j] + total
            out[i, j] = out[i, j] + total if add else total


@numba.njit(cache=True)
def _solve_in_place(p: FloatArray, q: FloatArray) -> None:
    """``q <- p^{-1} q`` by Gaussian elimination with partial pivoting (``p`` destroyed)."""
    n = p.shape[0]
    for col in range(n):
        pivot = col
        biggest = abs(p[col, col])
        for r in range(col + 1, n):
            if abs(p[r, col]) > biggest:
                biggest = abs(p[r, col])
                pivot = r
        if pivot != col:
            for j in range(n):
                p[col, j], p[pivot, j] = p[pivot, j], p[col, j]
                q[col, j], q[pivot, j] = q[pivot, j], q[col, j]
        inverse = 1.0 / p[col, col]
        for r in range(col + 1, n):
            factor = p[r, col] * inverse
            if factor != 0.0:
                for j in range(col + 1, n):
                    p[r, j] -= factor * p[col, j]
                for j in range(n):
                    q[r, j] -= factor * q[col, j]
    for col in range(n - 1, -1, -1):
        inverse = 1.0 / p[col, col]
        for j in range(n):
            total = q[col, j]
            for k in range(col + 1, n):
                total -= p[col, k] * q[k, j]
            q[col, j] = total * inverse


@numba.njit(cache=True)
def _expm_transposed(
    a: FloatArray, out: FloatArray, work: FloatArray, v: FloatArray, w: FloatArray
) -> None:
    """``out <- exp(a)`` (Algorithm 3.1); ``work`` has shape ``(7, n, n)``.

    Called with ``a`` the transpose of the wanted argument (see :func:`_expm_batch`).
    """
    n = a.shape[0]
    a2, a4, a6, a8, u, vv, t = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    _matmul(a, a, a2)
    _matmul(a2, a2, a4)
    _matmul(a2, a4, a6)
    norm_a = _norm1(a)
    if norm_a == 0.0:
        for i in range(n):
            for j in range(n):
                out[i, j] = 1.0 if i == j else 0.0
        return
    d4 = _norm1(a4) ** 0.25
    d6 = _norm1(a6) ** (1.0 / 6.0)
    eta1 = max(d4, d6)
    m = 0
    if eta1 < _THETA3 and _ell(a, 1.0, norm_a, 7, _ELL3, v, w) == 0:
        m = 3
    elif eta1 < _THETA5 and _ell(a, 1.0, norm_a, 11, _ELL5, v, w) == 0:
        m = 5
    s = 0
    if m == 0:
        _matmul(a4, a4, a8)
        d8 = _norm1(a8) ** 0.125
        eta3 = max(d6, d8)
        if eta3 < _THETA7 and _ell(a, 1.0, norm_a, 15, _ELL7, v, w) == 0:
            m = 7
        elif eta3 < _THETA9 and _ell(a, 1.0, norm_a, 19, _ELL9, v, w) == 0:
            m = 9
        else:
            m = 13
            _matmul(a4, a6, t)
            d10 = _norm1(t) ** 0.1
            eta5 = min(eta3, max(d8, d10))
            if eta5 > 0.0:
                s = max(math.ceil(math.log2(eta5 / _THETA13)), 0)
            s += _ell(a, 2.0**-s, norm_a, 27, _ELL13, v, w)
    # U (odd part, without its leading A) into t, V (even part) into vv
    if m == 3:
        _polynomial(t, False, _B3[1], _B3[3], a2, 0.0, a4, 0.0, a6, 0.0, a8)
        _polynomial(vv, False, _B3[0], _B3[2], a2, 0.0, a4, 0.0, a6, 0.0, a8)
    elif m == 5:
        _polynomial(t, False, _B5[1], _B5[3], a2, _B5[5], a4, 0.0, a6, 0.0, a8)
        _polynomial(vv, False, _B5[0], _B5[2], a2, _B5[4], a4, 0.0, a6, 0.0, a8)
    elif m == 7:
        _polynomial(t, False, _B7[1], _B7[3], a2, _B7[5], a4, _B7[7], a6, 0.0, a8)
        _polynomial(vv, False, _B7[0], _B7[2], a2, _B7[4], a4, _B7[6], a6, 0.0, a8)
    elif m == 9:
        _polynomial(t, False, _B9[1], _B9[3], a2, _B9[5], a4, _B9[7], a6, _B9[9], a8)
        _polynomial(vv, False, _B9[0], _B9[2], a2, _B9[4], a4, _B9[6], a6, _B9[8], a8)
    else:
        # scaled powers B^k = (2^-s A)^k, in place
        for i in range(n):
            for j in range(n):
                a2[i, j] *= 2.0 ** (-2 * s)
                a4[i, j] *= 2.0 ** (-4 * s)
                a6[i, j] *= 2.0 ** (-6 * s)
                a8[i, j] = 2.0**-s * a[i, j]
        b = _B13
        # U = B [B6 (b13 B6 + b11 B4 + b9 B2) + b7 B6 + b5 B4 + b3 B2 + b1 I]
        _polynomial(out, False, 0.0, b[9], a2, b[11], a4, b[13], a6, 0.0, a8)
        _matmul(a6, out, t)
        _polynomial(t, True, b[1], b[3], a2, b[5], a4, b[7], a6, 0.0, a8)
        # V = B6 (b12 B6 + b10 B4 + b8 B2) + b6 B6 + b4 B4 + b2 B2 + b0 I
        _polynomial(out, False, 0.0, b[8], a2, b[10], a4, b[12], a6, 0.0, a8)
        _matmul(a6, out, vv)
        _polynomial(vv, True, b[0], b[2], a2, b[4], a4, b[6], a6, 0.0, a8)
    if m == 13:
        _matmul(a8, t, u)
    else:
        _matmul(a, t, u)
    # r_m = (V - U)^{-1} (V + U)
    for i in range(n):
        for j in range(n):
            t[i, j] = vv[i, j] - u[i, j]
            out[i, j] = vv[i, j] + u[i, j]
    _solve_in_place(t, out)
    for _ in range(s):
        _matmul(out, out, t)
        for i in range(n):
            for j in range(n):
                out[i, j] = t[i, j]


@numba.njit(cache=True)
def _expm_batch(matrices: FloatArray) -> FloatArray:
    count, n = matrices.shape[0], matrices.shape[1]
    out = np.empty_like(matrices)
    work = np.empty((7, n, n))
    transposed = np.empty((n, n))
    result = np.empty((n, n))
    v = np.empty(n)
    w = np.empty(n)
    for k in range(count):
        if k > 0:
            # a run of equal matrices (a parameter held over samples) is done once
            same = True
            for i in range(n):
                for j in range(n):
                    if matrices[k, i, j] != matrices[k - 1, i, j]:
                        same = False
                        break
                if not same:
                    break
            if same:
                out[k] = out[k - 1]
                continue
        # exp(A) = exp(A^T)^T, computed in the transposed world as scipy does
        for i in range(n):
            for j in range(n):
                transposed[i, j] = matrices[k, j, i]
        _expm_transposed(transposed, result, work, v, w)
        for i in range(n):
            for j in range(n):
                out[k, i, j] = result[j, i]
    return out


def expm_batch(matrices: FloatArray) -> FloatArray:
    """``exp`` of each square matrix of ``matrices`` (shape ``(count, n, n)``, float64).

    Consecutive equal matrices are exponentiated once. Non-finite input raises.
    """
    matrices = np.ascontiguousarray(matrices, dtype=np.float64)
    if matrices.ndim != 3 or matrices.shape[1] != matrices.shape[2]:
        raise ValueError(f"matrices must have shape (count, n, n), got {matrices.shape}")
    if not np.all(np.isfinite(matrices)):
        raise ValueError("matrices must be finite")
    if matrices.shape[0] == 0 or matrices.shape[1] == 0:
        return matrices.copy()
    return _expm_batch(matrices)
