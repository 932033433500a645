"""Compiled cores of the unscented filters on pilot internal models: joint and dual.

Both run on the same internal model as the DEKF (Euler step of the canonical states,
``x^- = x^+ + f(x^+, in_{k-1}, p) dt``, in ``cfg[CFG_SUBSTEPS]`` substeps where a sample
is longer than the papers' 0.01 s,
:func:`~manualcontrol.estimators._pilot_core.euler_substeps`; output
``u = g(x^-, in_k, p)``), the same noise rules and the same report
(:mod:`~manualcontrol.estimators._pilot_core`); the unscented transform replaces the
Jacobians and the total derivative.

Joint UKF
    One filter on the augmented state ``z = [theta; gains; x]``: the parameters of the
    parameter filter, the output gains and the canonical states. Parameters are random
    walks (``z^- = z^+`` in their entries); process noise as the DEKF's
    (``Gamma Q Gamma^T`` on each parameter, ``q^2 var(e)`` on the chain input state).
    The order puts the parameters first so that, with a lower Cholesky factor, the
    sigma points along the later columns share the centre's parameters: their
    coefficients are not evaluated again (only points whose parameters differ from
    the last evaluated point's are). ``f`` does not read the gains, so the prediction
    re-evaluates only when ``theta`` changes.

Dual UKF (the DEKF's arrangement with unscented filters, Wan & van der Merwe 2001)
    A state filter on ``s = [gains; x]`` with ``theta`` at its prior mean, and a
    parameter filter on ``theta`` (random walks). The parameter filter must see how the
    *state* depends on ``theta`` (in canonical coordinates the direct dependence of
    ``g`` on ``theta`` is large and mostly cancelled by the states'; a one-step
    "static" measurement model lets the parameter filter chase it and diverge within a
    second on the Popovici run). So the filter carries the sensitivity ``D = ds/dtheta``
    by the DEKF's total-derivative recursion (thesis eqs. 47-50, in the dimensional
    form that differentiates the Euler step), computed without Jacobians: by central
    differences (relative step :data:`SENSITIVITY_STEP`) of the Euler step and of
    ``g`` along the parameter filter's sigma directions ``E = c sqrt(Pp)``. (Carrying
    whole point states at the full sigma spread instead, and regressing them on the
    points, made the recursion blow up within a tenth of a second: at that spread the
    bilinear terms of ``f`` feed back.) The parameter images are
    ``Z_i = g(s^- + D delta_i, theta + delta_i)``: nonlinear in ``theta``, linear in
    the state response. Each sample: parameter prediction (``P^- = P^+ + Gamma Q
    Gamma^T``); the sensitivity predicted along the sigma directions; state prediction
    and correction with ``theta^-``; the parameter images; the sensitivity corrected
    with the state filter's gain (eq. 50); the parameter correction with the state
    filter's innovation (as the DEKF, thesis eq. 22) and ``R_parameter``. (With the
    parameter filter's own innovation ``u - mean(Z)`` the Popovici run ended further
    from the truth: K_p 1.30 against 1.40 of 1.5.) Where the prior parameter spread is
    wide (the papers' P0: 10 for omega_nms), the linear state response at the full
    sigma spread is a poor model and the dual UKF identifies worse than the DEKF; with
    the thesis's P0 it matches the DEKF.

Smoother storage (one row per sample, or none): priors, posteriors and the
cross-covariance ``cov(z^+_{k-1}, z^-_k)`` of the prediction (unscented RTS).

The kernels live in :mod:`~manualcontrol.estimators.members._ukf_kernels`, imported on
first use (where the C port runs, a joint or dual UKF never imports numba); the records
and the constants the kernels read stay here.
"""

from __future__ import annotations

from collections import namedtuple

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators._pilot_core import (  # noqa: F401  (the UKFs read them here)
    CFG_COUNT,
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_GAMMA2,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SPREAD,
    CFG_SUBSTEPS,
    SC_FROZEN,
    SC_K,
)

#: ``wm``, ``wc``: sigma weights; ``q``: process noise per filter state (before
#: ``Gamma^2``); ``slot``: model-order parameter index of each filter state (-1 for a
#: canonical state); ``limit``: limit entry of each state (-1: none); ``estimated``:
#: per model parameter; ``n_param``: the leading filter states that are parameters and
#: ``n_moving``: how many of them enter ``f`` (the rest are output gains).
UKFConfig = namedtuple(
    "UKFConfig", ["cfg", "wm", "wc", "q", "slot", "limit", "estimated", "n_param", "n_moving"]
)
UKFBelief = namedtuple("UKFBelief", ["z", "P", "prev_in", "p", "sc"])
UKFScratch = namedtuple(
    "UKFScratch",
    [
        "work",
        "Q",
        "zero",
        "R",
        "r",
        "z_prev",
        "cross",
        "point_p",
        "f",
        "F",
        "dfdp",
        "dgdx",
        "dgdp",
        "in_use",
        "variance",
        "scalars",
    ],
)
#: Per-row outputs (as :data:`~manualcontrol.estimators._pilot_core.PilotOutput`) plus
#: smoother storage for up to two filters (``*_2``: the dual filter's parameter filter).
UKFOutput = namedtuple(
    "UKFOutput",
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
        "cross",
        "x_prior_2",
        "P_prior_2",
        "x_post_2",
        "P_post_2",
    ],
)


# ------------------------------------------------------------------------- dual

#: The dual filter's parameter half: its config, belief (``th``, ``Pp``), the state
#: sensitivity ``D = ds/dtheta`` (n_s, n_t), its images along the sigma directions ``M``
#: (n_s, n_t), the spread directions ``E = c L`` (n_t, n_t) and scratch.
DualTheta = namedtuple(
    "DualTheta",
    ["config", "th", "Pp", "work", "R", "D", "M", "E", "zero", "point_s", "point_x", "point_p"],
)

# numba kernels read this module's constants
#: Relative step of the central differences along the sigma directions.
SENSITIVITY_STEP = 1e-3


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_point_parameters",
    "_propagate",
    "_measure",
    "joint_step",
    "joint_step_many",
    "_set_point",
    "_predict_sensitivity",
    "_output_at",
    "_theta_images",
    "_correct_sensitivity",
    "dual_step",
    "dual_step_many",
    "inputs_in_use",
    "noise_levels",
    "report_frozen",
    "report_row",
    "take",
    "clamp",
    "belief_health",
    "store_belief",
    "constrain_prior",
    "cross_covariance",
    "project_points",
    "sigma_points",
    "unscented_correct",
    "weighted_covariance",
    "weighted_mean",
    "evaluate_coefficients",
    "model_f",
    "model_g",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._ukf_kernels", _KERNELS
)
