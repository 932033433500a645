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

The kernels live in :mod:`~manualcontrol.estimators.filters._kalman_kernels`, imported
on first use (a process whose filters run in C never imports numba); the records and
their builder stay here.
"""

from __future__ import annotations

from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np

from manualcontrol.envs._lazy import kernels_on_first_use

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.filters._kalman_kernels import (
        add_diagonal,
        clamp,
        joseph_correct,
        predict_covariance,
        textbook_correct,
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


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "predict_covariance",
    "add_diagonal",
    "_innovation_covariance",
    "_joseph_scalar",
    "joseph_correct",
    "textbook_correct",
    "clamp",
    "add_product",
    "cholesky",
    "cholesky_solve_rows",
    "log_determinant",
    "matmul",
    "matmul_transposed",
    "symmetrise",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._kalman_kernels", _KERNELS
)
