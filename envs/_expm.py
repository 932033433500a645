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

The computation runs in C (``_dynamics_native.c``, bound in
:mod:`~manualcontrol.envs._dynamics_native`) wherever it builds, and as numba's
:func:`~manualcontrol.envs._dynamics_kernels.expm_batch_kernel` elsewhere: the same
numbers bit for bit, and a process that only discretises never imports numba. This
module holds the tables both read.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs import _dynamics_native

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
_ORDERS = np.array([3, 5, 7, 9, 13], dtype=np.int64)
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
    tables = (_COEFFICIENTS, _THETA, _ORDERS, _ELL_RECIPROCAL, _UNIT_ROUNDOFF)
    lib = _dynamics_native.library()
    if lib is not None:
        return _dynamics_native.expm_batch(lib, matrices, *tables)
    from manualcontrol.envs._dynamics_kernels import expm_batch_kernel

    return expm_batch_kernel(matrices, *tables)
