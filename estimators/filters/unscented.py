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
  not positive semidefinite (:func:`triangular_sigma_points` where the factor must be
  the lower triangular one);
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

The kernels live in :mod:`~manualcontrol.estimators.filters._unscented_kernels`,
imported on first use (where the C ports run, an unscented filter never imports
numba); the records and their builders stay here.
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np

from manualcontrol.envs._lazy import kernels_on_first_use

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.filters._unscented_kernels import (
        constrain_prior,
        cross_covariance,
        project_points,
        sigma_points,
        triangular_sigma_points,
        unscented_correct,
        weighted_covariance,
        weighted_mean,
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
    "triangular_sigma_points",
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


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "sigma_points",
    "triangular_sigma_points",
    "_spread_points",
    "weighted_mean",
    "weighted_covariance",
    "cross_covariance",
    "unscented_correct",
    "project_points",
    "constrain_prior",
    "add_product",
    "cholesky",
    "cholesky_semidefinite",
    "cholesky_semidefinite_pivoted",
    "cholesky_solve_rows",
    "log_determinant",
    "symmetrise",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._unscented_kernels", _KERNELS
)
