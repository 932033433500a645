"""Rauch-Tung-Striebel smoothers over a stored filter run, compiled.

Every fixed-interval smoother of the family is the same backward recursion
(Rauch, Tung & Striebel 1965; Särkkä 2013, Theorems 8.2 and 9.3):

    G_k   = C_{k+1} (P^-_{k+1})^-1
    x^s_k = x^+_k + G_k (x^s_{k+1} - x^-_{k+1})
    P^s_k = P^+_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^T

with ``C_{k+1} = cov(x^+_k, x^-_{k+1})`` the cross-covariance of a posterior and the
next prior. The filters differ only in how they know ``C``:

* random-walk states (``F = I``, Boer & Kenyon 1998 Sec. III-E): ``C_{k+1} = P^+_k``;
* the EKF (linearised transition ``Phi_{k+1}``): ``C_{k+1} = P^+_k Phi_{k+1}^T``;
* the UKF (the unscented RTS smoother, Särkkä 2008): ``C_{k+1}`` from the sigma points
  of the prediction, stored by the filter.

Storage, ``N`` samples: ``x_filtered[k], P_filtered[k]`` the posterior after sample k;
``x_predicted[k], P_predicted[k]`` the prior at sample k (for k = 0, the initial
belief); ``link[k]`` for k >= 1 either the cross-covariance ``C_k`` or the transition
Jacobian ``Phi_k`` (from sample k - 1 to k); ``link[0]`` is not read.

``P^-_{k+1}`` is solved by Cholesky. A prior singular to rounding (a state with no
process noise that the data have pinned down) is loaded on its diagonal, each
variance by ``REGULARISATION`` times itself (1e3 times more, up to five times, if that
is not enough), and the number of such samples is returned. (Loading every prior
instead changed the RDI's smoothed delay by 2e-8 relative against its exact numpy
recursion, and did not save the full-state unscented smoother of the pilot models,
whose canonical variances span twenty orders of magnitude: the unscented pilot
filters smooth their parameter marginals instead, see ``estimators/members/ukf.py``.)

The kernels live in :mod:`~manualcontrol.estimators.filters._smoother_kernels`, imported
on first use (a process whose filters run in C never imports numba); the constants they
read, the records and their builder stay here.
"""

from __future__ import annotations

from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np

from manualcontrol.envs._lazy import kernels_on_first_use

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.filters._smoother_kernels import (
        rts_smooth,
        store_belief,
    )


__all__ = [
    "LINK_CROSS",
    "LINK_RANDOM_WALK",
    "LINK_TRANSITION",
    "REGULARISATION",
    "SmootherWork",
    "rts_smooth",
    "smoother_work",
    "store_belief",
]

# numba kernels read this module's constants
#: ``link`` holds cross-covariances ``C_k`` (UKF).
LINK_CROSS = 0
#: ``link`` holds transition Jacobians ``Phi_k`` (EKF).
LINK_TRANSITION = 1
#: Random-walk states: no ``link`` needed (``C_k = P^+_{k-1}``).
LINK_RANDOM_WALK = 2
#: Relative diagonal loading of a prior covariance that does not factor as it is.
REGULARISATION = 1e-12

SmootherWork = namedtuple("SmootherWork", ["C", "G", "A", "L", "D", "T"])


def smoother_work(n: int) -> SmootherWork:
    """Scratch for an ``n``-state smoother pass."""
    return SmootherWork(*(np.zeros((n, n)) for _ in range(6)))


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "store_belief",
    "_factor_prior",
    "rts_smooth",
    "cholesky",
    "cholesky_solve_rows",
    "matmul",
    "matmul_transposed",
    "symmetrise",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._smoother_kernels", _KERNELS
)
