"""Compiled core of Zhao et al.'s UKF on the cybernetic driver model: one step, a whole run.

The augmented state (Zhao eq. 3) is the driver model's three states followed by the
estimated parameters (random walks). Each sample runs Algorithm 2:

1. output prediction by the unscented transform of ``g_d(x_a, u_k) = C(theta) x +
   D(theta) u_k`` over the sigma points of the prior (eq. 6), plus ``R_d``;
2. correction with the measured ``y_k = (Gamma_d, delta_sw)``
   (:func:`~manualcontrol.estimators.filters.unscented.unscented_correct`), estimates
   projected onto their limits;
3. prediction of the next prior by the unscented transform of ``f_d`` (eq. 6: Euler,
   ``x <- x + h (A(theta) x + B(theta) u_k)``, repeated ``substeps`` times over the
   sample, parameters unchanged), plus ``Q_a,d``.

The model matrices of every sigma point come from eq. 2's one definition, the driver
model's (:mod:`~manualcontrol.pilots.driver`), compiled as
:func:`~manualcontrol.pilots._driver_kernels.driver_matrices`. The
sigma points, moments and correction are the family's
(:mod:`~manualcontrol.estimators.filters.unscented`); the report of each sample (every
parameter's mean and standard deviation, limits, pins, divergence) is the pilot
filters' (:mod:`~manualcontrol.estimators._pilot_core`). With smoother storage each step
keeps the prior, the posterior and the cross-covariance of the prediction (the unscented
RTS smoother's link).

Dropped samples (NaN in an input or an output) skip the correction; the prediction uses
the last inputs held.

The kernels live in :mod:`~manualcontrol.estimators.members._zhao_kernels`, imported on
first use (where the C port runs, the Zhao UKF and the multi-UKF never import numba);
the records and the constants the kernels and the C port read stay here.
"""

from __future__ import annotations

from collections import namedtuple

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators._pilot_core import (  # noqa: F401  (names it has always exported)
    SC_DIV_INDEX,
    SC_DIV_PARAM,
    SC_DIV_REASON,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators.filters.monitor import (  # noqa: F401  (as the SC_* above)
    REASON_COVARIANCE,
    REASON_NONE,
)

# numba kernels read this module's constants

# ---- indices into ``cfg``
CFG_VX = 0
CFG_H = 1  # Euler sub-step (s)
CFG_SUBSTEPS = 2
CFG_SPREAD = 3
CFG_COUNT = 4
CFG_JITTER = 5
CFG_MAX_COV = 6
CFG_SIZE = 7

N_STATES = 3
N_OUTPUTS = 2
N_INPUTS = 4

#: Settings as arrays: ``cfg``, the base parameter vector (estimated entries
#: overwritten by the state), where each estimated parameter sits in it, ``Q`` and ``R``
#: per sample, the sigma-point weights, each augmented state's limit entry (-1: none)
#: and the mask of estimated parameters (model order).
ZhaoConfig = namedtuple(
    "ZhaoConfig",
    ["cfg", "base", "theta_index", "Q", "R", "w_mean", "w_cov", "limit", "estimated"],
)
#: The belief: prior (before a step) or posterior ``x, P``; the inputs held for dropped
#: samples; the parameter vector ``p``; scalars ``sc`` (``SC_*`` of the pilot core);
#: ``link``, the cross-covariance of the last prediction.
ZhaoBelief = namedtuple("ZhaoBelief", ["x", "P", "prev_in", "p", "sc", "link"])
ZhaoScratch = namedtuple(
    "ZhaoScratch",
    ["work", "A", "B", "C", "D", "Bu", "y", "r", "in_use", "variance", "scalars", "point"],
)
#: Per-row outputs (the first five are the pilot core's report); smoother storage has
#: one row per sample or none.
ZhaoOutput = namedtuple(
    "ZhaoOutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "predictions",
        "innovations",
        "S",
        "states",
        "x_prior",
        "P_prior",
        "x_post",
        "P_post",
        "link",
    ],
)


# ---------------------------------------------------------------------- multi-UKF

#: Fusion of a slow and a fast member
#: (see :class:`~manualcontrol.estimators.members.zhao_ukf.MultiUKF`):
#: EWMA factors of the disagreement (``a_short``) and of its level (``a_long``), the dead
#: zone per estimated parameter (absolute), whether to re-centre the slow member, and
#: where the estimated parameters sit in the model's parameter vector.
FusionConfig = namedtuple(
    "FusionConfig", ["a_short", "a_long", "dead_zone", "feedback", "theta_index"]
)
#: ``smooth``: EWMA of fast minus slow; ``level``: EWMA of its square; ``started`` (1,).
FusionState = namedtuple("FusionState", ["smooth", "level", "started"])
#: The fused rows (the fields of :data:`ZhaoOutput` without smoother storage), each
#: estimated parameter's gate ``lambda`` and the members' estimates (slow, then fast).
MultiOutput = namedtuple(
    "MultiOutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "predictions",
        "innovations",
        "S",
        "states",
        "gate",
        "members",
    ],
)


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_parameters",
    "_measure",
    "_propagate",
    "_store",
    "zhao_step",
    "zhao_run",
    "fuse_step",
    "multi_step",
    "multi_run",
    "report_frozen",
    "report_row",
    "clamp",
    "belief_health",
    "cross_covariance",
    "sigma_points",
    "unscented_correct",
    "weighted_covariance",
    "weighted_mean",
    "driver_matrices",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._zhao_kernels", _KERNELS
)
