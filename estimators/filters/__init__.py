"""The Kalman algebra of the estimator family, written once, compiled, model-agnostic.

Pure functions on caller-owned arrays (numba, ``_nrt=False``: nothing is allocated per
sample), in the dynamax manner: a model evaluates itself (its transition and
measurement functions, their Jacobians or sigma-point images) in its own compiled
step, and calls these for the covariance algebra:

* :mod:`.linalg`: symmetrisation, Cholesky factor and solves (never an inverse);
* :mod:`.kalman`: EKF covariance prediction, Joseph-form correction for ``m``-dimensional
  measurements, additive noise, limits by estimate projection;
* :mod:`.unscented`: sigma points (Merwe scaled; the cubature rule of Zhao et al. 2019
  Alg. 1), unscented moments and correction;
* :mod:`.smoothers`: the Rauch-Tung-Striebel smoother for random-walk, EKF and UKF runs;
* :mod:`.monitor`: belief health, pinned parameters, windowed variances.

The estimators built on them: the DEKF (dual EKF),
:class:`~manualcontrol.estimators.members.ukf.JointUKF` and
:class:`~manualcontrol.estimators.members.ukf.DualUKF` on the pilot internal models;
:mod:`manualcontrol.estimators.offline.smoothing` turns any of their filtered results into
smoothed ones.

Each public name is imported from its module when first used
(:mod:`manualcontrol.envs._lazy`).
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.estimators.filters.kalman import (
        KalmanWork,
        add_diagonal,
        clamp,
        joseph_correct,
        kalman_work,
        predict_covariance,
    )
    from manualcontrol.estimators.filters.linalg import cholesky, cholesky_solve_rows, symmetrise
    from manualcontrol.estimators.filters.smoothers import rts_smooth, smoother_work
    from manualcontrol.estimators.filters.unscented import (
        SIGMA_SCHEMES,
        SigmaWeights,
        UnscentedWork,
        cross_covariance,
        sigma_points,
        sigma_weights,
        unscented_correct,
        unscented_work,
        weighted_covariance,
        weighted_mean,
    )

__all__ = [
    "SIGMA_SCHEMES",
    "KalmanWork",
    "SigmaWeights",
    "UnscentedWork",
    "add_diagonal",
    "cholesky",
    "cholesky_solve_rows",
    "clamp",
    "cross_covariance",
    "joseph_correct",
    "kalman_work",
    "predict_covariance",
    "rts_smooth",
    "sigma_points",
    "sigma_weights",
    "smoother_work",
    "symmetrise",
    "unscented_correct",
    "unscented_work",
    "weighted_covariance",
    "weighted_mean",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.estimators.filters.kalman": (
            "KalmanWork",
            "add_diagonal",
            "clamp",
            "joseph_correct",
            "kalman_work",
            "predict_covariance",
        ),
        "manualcontrol.estimators.filters.linalg": (
            "cholesky",
            "cholesky_solve_rows",
            "symmetrise",
        ),
        "manualcontrol.estimators.filters.smoothers": ("rts_smooth", "smoother_work"),
        "manualcontrol.estimators.filters.unscented": (
            "SIGMA_SCHEMES",
            "SigmaWeights",
            "UnscentedWork",
            "cross_covariance",
            "sigma_points",
            "sigma_weights",
            "unscented_correct",
            "unscented_work",
            "weighted_covariance",
            "weighted_mean",
        ),
    },
)
