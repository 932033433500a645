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
# theta_m of Al-Mohy & Higham (2009), Table 3.1 (theta_13 = 4.25 in their Algorithm 3.1),
# 1/|c_{2m+1}| of the backward-error bound ell(A, m) (their eq. 3.11, scipy's _ell),
# for m = 3, 5, 7, 9, 13
_ORDERS = np.array([3, 5, 7, 9, 13])
_THETA = np.array(
    [1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1, 2.097847961257068e0, 4.25]
)
_ELL_RECIPROCAL = np.array(
    [
        100800.0,
        10059033600.0,
        4487938430976000.0,
        5914384781877411840000.0,
        113250775606021113483283660800000000.0,
    ]
)


def _coefficient_table() -> FloatArray:
    """Rows of coefficients of ``(I, A^2, A^4, A^6, A^8)`` for each polynomial evaluated.

    Rows ``2i`` and ``2i + 1``: the odd part (without its leading ``A``) and the even
    part of ``r_m``, ``m = 3, 5, 7, 9``. Rows 8-11, order 13 (Higham 2005, eq. 2.3 and
    the evaluation of its Sec. 2): inner and outer terms of ``U`` then of ``V``.
    """
    table = np.zeros((12, 5))
    for i, b in enumerate((_B3, _B5, _B7, _B9)):
        table[2 * i, : (len(b) + 1) // 2] = b[1::2]
        table[2 * i + 1, : (len(b) + 1) // 2] = b[0::2]
    b = _B13
    table[8, 1:4] = b[9], b[11], b[13]
    table[9, :4] = b[1], b[3], b[5], b[7]
    table[10, 1:4] = b[8], b[10], b[12]
    table[11, :4] = b[0], b[2], b[4], b[6]
    return table


_COEFFICIENTS = _coefficient_table()
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
def _polynomial(out: FloatArray, add: bool, coefficients: FloatArray, powers: FloatArray) -> None:
    """``out (+)= sum_p c_p A^(2p)`` over ``p = 0 .. 4`` (``A^0 = I``), highest power last.

    Powers above the highest non-zero coefficient are skipped, not multiplied by
    zero: a power not computed holds whatever was there.
    """
    n = out.shape[0]
    top = 1
    for p in range(2, 5):
        if coefficients[p] != 0.0:
            top = p
    for i in range(n):
        for j in range(n):
            total = coefficients[0] if i == j else 0.0
            for p in range(1, top + 1):
                total = coefficients[p] * powers[p, i, j] + total
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
def _expm_batch(matrices: FloatArray, coefficients: FloatArray) -> FloatArray:
    """Algorithm 3.1 on every matrix (runs of equal ones once), in one compiled body.

    exp(A) = exp(A^T)^T: each matrix is transposed in and out and the algorithm run
    on the transpose, as scipy does (see the module docstring). One body with its
    helpers called from few places: LLVM inlines every call site, and a copy per
    call site had made this the slowest kernel of the package to compile.
    """
    count, n = matrices.shape[0], matrices.shape[1]
    result = np.empty_like(matrices)
    # powers[0..4] = A, A^2, A^4, A^6, A^8 (order 13: the scaled B, B^2, B^4, B^6, 2^-s A)
    powers = np.empty((5, n, n))
    work = np.empty((3, n, n))  # U, V and a scratch matrix
    out = np.empty((n, n))
    v = np.empty(n)
    w = np.empty(n)
    for k in range(count):
        if k > 0:
            same = True
            for i in range(n):
                for j in range(n):
                    if matrices[k, i, j] != matrices[k - 1, i, j]:
                        same = False
                        break
                if not same:
                    break
            if same:
                # element by element: a slice assignment would compile numba's shape
                # error message (about 4 CPU-s in every process that compiles this)
                for i in range(n):
                    for j in range(n):
                        result[k, i, j] = result[k - 1, i, j]
                continue
        a = powers[0]
        for i in range(n):
            for j in range(n):
                a[i, j] = matrices[k, j, i]
        for step in range(3):  # A^2 = A A, A^4 = A^2 A^2, A^6 = A^2 A^4
            _matmul(powers[1 if step else 0], powers[step], powers[step + 1])
        norm_a = _norm1(a)
        if norm_a == 0.0:
            for i in range(n):
                for j in range(n):
                    result[k, i, j] = 1.0 if i == j else 0.0
            continue
        d6 = _norm1(powers[3]) ** (1.0 / 6.0)
        eta = max(_norm1(powers[2]) ** 0.25, d6)
        choice = -1
        s = 0
        d8 = 0.0
        for option in range(4):
            if option == 2:  # orders 7 and 9 judge by eta_3 = max(d6, d8)
                _matmul(powers[2], powers[2], powers[4])
                d8 = _norm1(powers[4]) ** 0.125
                eta = max(d6, d8)
            if eta < _THETA[option] and (
                _ell(a, 1.0, norm_a, 2 * _ORDERS[option] + 1, _ELL_RECIPROCAL[option], v, w) == 0
            ):
                choice = option
                break
        if choice < 0:
            choice = 4
            _matmul(powers[2], powers[3], work[2])
            eta5 = min(eta, max(d8, _norm1(work[2]) ** 0.1))
            if eta5 > 0.0:
                s = max(math.ceil(math.log2(eta5 / _THETA[4])), 0)
            s += _ell(a, 2.0**-s, norm_a, 27, _ELL_RECIPROCAL[4], v, w)
            for i in range(n):
                for j in range(n):
                    powers[1, i, j] *= 2.0 ** (-2 * s)
                    powers[2, i, j] *= 2.0 ** (-4 * s)
                    powers[3, i, j] *= 2.0 ** (-6 * s)
                    powers[4, i, j] = 2.0**-s * a[i, j]
            # U = B [B6 (b13 B6 + b11 B4 + b9 B2) + b7 B6 + ... + b1 I], V likewise
            for part in range(2):
                _polynomial(out, False, coefficients[8 + 2 * part], powers)
                _matmul(powers[3], out, work[part])
                _polynomial(work[part], True, coefficients[9 + 2 * part], powers)
        else:
            # U without its leading A into work[0], V into work[1]
            for part in range(2):
                _polynomial(work[part], False, coefficients[2 * choice + part], powers)
        # U = A (odd part); r_m = (V - U)^{-1} (V + U)
        _matmul(powers[4] if choice == 4 else a, work[0], work[2])
        u, vv, scratch = work[2], work[1], work[0]
        for i in range(n):
            for j in range(n):
                scratch[i, j] = vv[i, j] - u[i, j]
                out[i, j] = vv[i, j] + u[i, j]
        _solve_in_place(scratch, out)
        for _ in range(s):
            _matmul(out, out, scratch)
            for i in range(n):
                for j in range(n):
                    out[i, j] = scratch[i, j]
        for i in range(n):
            for j in range(n):
                result[k, i, j] = out[j, i]
    return result


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
    # the table is an argument: numba will not cache a kernel that reads a 2-D global
    return _expm_batch(matrices, _COEFFICIENTS)
