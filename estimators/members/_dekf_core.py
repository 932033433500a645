"""Compiled core of the Dual Extended Kalman Filter: one step, and the loop over it.

Pure numerics on small records (namedtuples of arrays):
:func:`dekf_step` advances a :data:`DEKFBelief` by one sample and writes that
sample's estimate into row ``row`` of a :data:`DEKFOutput`; :func:`dekf_step_many`
loops it, over a stack of filters on one sample each, or over a recording for one
filter (a stack of one, sample ``k`` into row ``k``). The online ``DEKF.update``, the
batch ``DEKF.estimate`` and the batched online path all call :func:`dekf_step`, so
they give identical numbers. The covariance algebra (Joseph
correction, symmetrisation, health checks, windowed variances, pin tracking) is the
family's shared code in :mod:`manualcontrol.estimators.filters`.

The six steps (thesis Part I eqs. 11-25, Popovici et al. 2017 eqs. 6-15):

1. parameter prediction ``theta^- = theta^+``, ``P_p^- = P_p^+ + Gamma Q_p Gamma^T``
   (eqs. 11-12, ``Phi_p = I``: the parameters are random walks, eq. 9);
2. state prediction by one Euler step ``x^- = x^+ + f(x^+, in_{k-1}, theta^-) dt``
   (eq. 13, Popovici eq. 8) and ``P_s^- = Phi_s P_s^+ Phi_s^T + Gamma Q_s Gamma^T``
   (eq. 14) with ``Phi_s = I + F dt``, the Jacobian of that Euler step, and
   ``Gamma = I dt`` (or ``I``, ``cfg[CFG_GAMMA2]`` holds its square); a sample longer
   than the papers' 0.01 s is predicted in ``m = cfg[CFG_SUBSTEPS]`` Euler substeps of
   ``h = dt/m`` (:func:`~manualcontrol.estimators._pilot_core.euler_substeps`: two at
   50 and 60 Hz), ``Phi_s`` their product and eq. 49's recursion run through each;
3. state correction with innovation ``r = u - g(x^-, theta^-)`` (eqs. 15-19, Joseph form);
4. state limitation by estimate projection (eq. 20);
5. parameter correction with the total derivative ``G_p^tot`` (eqs. 21-24, 47-50);
6. parameter limitation by estimate projection (eq. 25).

The first sample has no prediction (the prior is the initial belief). ``Phi_s`` is
applied through the structure of ``F`` (shift rows ``x_i' = x_{i+1}`` and one dense
row per canonical chain) in O(n^2) rather than as a dense product.

With smoother storage in the output record (arrays of one row per sample, see
:func:`manualcontrol.estimators.members.dekf.DEKF.estimate`), each step also stores the
state filter's prior, posterior and ``Phi_s`` and the parameter filter's prior and
posterior, from which :mod:`~manualcontrol.estimators.filters.smoothers` smooths the
state filter as an EKF and the parameter filter as random walks.

The kernels are compiled with ``_nrt=False`` (numba's array reference counting off):
they allocate nothing, and the atomic reference counts of the arrays passed around
each step otherwise cost more than the arithmetic.

The kernels live in :mod:`~manualcontrol.estimators.members._dekf_kernels`, imported on
first use (where the C port runs, a DEKF never imports numba); the records stay here.
"""

from __future__ import annotations

from collections import namedtuple

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators._pilot_core import (  # noqa: F401  (the DEKF reads them here)
    CFG_DIMENSIONAL,
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_GAMMA2,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SUBSTEPS,
    PAPERS_DT,
    SC_FROZEN,
    SC_K,
)

#: Settings as arrays: ``cfg`` (``CFG_*`` of :mod:`~manualcontrol.estimators._pilot_core`),
#: which canonical rows of ``F`` are dense, where the gains and parameters sit in the
#: model's parameter vector, their process noises, and the limit entry of each
#: state-filter and parameter-filter state (-1: none).
DEKFConfig = namedtuple(
    "DEKFConfig",
    [
        "cfg",
        "is_dense",
        "gain_index",
        "theta_index",
        "q_state",
        "q_theta",
        "state_limit",
        "theta_limit",
        "estimated",
    ],
)
#: The belief: state filter ``x, P`` (canonical states then gains), parameter filter
#: ``th, Pp``, the total derivative ``dx = dx^+/dtheta``, the previous inputs, the
#: parameter vector ``p`` in model order and the scalars ``sc`` (``SC_*``).
DEKFBelief = namedtuple("DEKFBelief", ["x", "P", "th", "Pp", "dx", "prev_in", "p", "sc"])
DEKFScratch = namedtuple(
    "DEKFScratch",
    [
        "F",
        "f",
        "dfdp",
        "dgdx",
        "dgdp",
        "M",
        "H_state",
        "H_theta",
        "R_state",
        "R_theta",
        "r",
        "state_work",
        "theta_work",
        "dxm",
        "in_use",
        "variance",
        "scalars",
    ],
)
#: Per-row outputs; the smoother storage has one row per sample or none.
DEKFOutput = namedtuple(
    "DEKFOutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "x_prior",
        "P_prior",
        "x_post",
        "P_post",
        "Phi",
        "th_prior",
        "Pp_prior",
        "th_post",
        "Pp_post",
    ],
)


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_apply_phi",
    "_apply_phi_transpose",
    "_store_phi",
    "dekf_step",
    "dekf_step_many",
    "inputs_in_use",
    "noise_levels",
    "report_frozen",
    "report_row",
    "take",
    "clamp",
    "joseph_correct",
    "symmetrise",
    "belief_health",
    "store_belief",
    "evaluate_coefficients",
    "model_f",
    "model_g",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._dekf_kernels", _KERNELS
)
