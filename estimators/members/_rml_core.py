"""Compiled core of the recursive maximum-likelihood filter bank (:mod:`.rml`).

For fixed parameters the pilot's internal model with a remnant shaping filter is a
linear state-space model, and a linear Kalman filter gives the exact one-step
prediction ``z_k(theta)`` of the stick and its variance ``S_k(theta)``: the sample's
likelihood is ``N(u_k; z_k, S_k)``. The parameters (and optionally the remnant's
log intensity and log break frequency) are random walks with a Gaussian belief
``N(theta, P)``; each sample updates it with that likelihood (a Bayesian, recursive
maximum-likelihood step; Ljung & Söderström's recursive prediction-error method in
its Gauss-Newton form):

* a bank of ``2 n + 1`` Kalman filters runs at ``theta`` and ``theta +- h L e_j``
  (``L L^T = P``, ``h`` in standard deviations, reduced along a direction that would
  move a parameter further than its ``spread_cap``), each carrying its own states and
  covariance, so each has its own Kalman gain: the derivatives of the prediction
  include how the filter's gain depends on the parameters, which a joint filter
  (parameters as states) or a dual filter without that term leaves out, and which
  biases them (Ljung 1979; here: a remnant state and the output gains trade
  ``K -> a K``, remnant ``-> n/a``);
* central differences across the bank give ``dz/dxi`` and ``dS/dxi`` along the
  directions ``xi`` (``theta = theta^- + L xi``); the score of the sample is
  ``g = nu/S dz - (1/S - nu^2/S^2) dS/2`` and its Fisher information
  ``F = dz dz^T/S + dS dS^T/(2 S^2)``;
* with the prior ``xi ~ N(0, I)`` the posterior is ``Lambda = I + F``,
  ``xi = Lambda^-1 g``: ``theta^+ = theta^- + L xi``, ``P^+ = L Lambda^-1 L^T``.

Delays on the inputs
    The internal model is built without its delays (``delay_order = 0`` of
    :func:`~manualcontrol.estimators.members.internal_model.build_internal_model`): the pilot's
    delay ``tau`` and the anticipation delay ``tau_f*`` commute with the model's linear
    branches, so they are applied to the inputs instead, read from delay lines of the
    past samples with the bicubic kernel of Boer & Kenyon (1998, App.;
    :mod:`~manualcontrol.envs._interpolation`): input ``i`` at time ``t`` is the recorded
    signal at ``t - tau`` (``t - tau - tau_f*`` for ``ft_ahead``). Each bank member
    reads at its own delays: no Padé approximant stands between the delays and the
    data. The states advance over a sample in Euler substeps, each with the inputs
    read at its midpoint; the remnant state follows its exact discrete transition.

The remnant
    A first-order shaping filter ``r' = -omega_r r + w`` (Levison et al. 1969, thesis
    eq. 5) whose output enters where the remnant enters the pilot: added to the
    delayed perception at the main chain's input (``"input"``; a remnant injected
    before the delay is, for the filter, the same random process delayed) or to the
    stick (``"output"``). Its intensity (and optionally its break frequency) is one of
    the estimated parameters, in logarithms.

The ``dS`` term is what identifies a noise intensity: it is zero for parameters that
move the prediction only. It is exact maximum likelihood only if ``S`` is the true
innovation variance, and ``R`` is not a noise model here but a frequency weighting (see
:mod:`.rml`): ``S`` exceeds the innovations' variance, and the ``dS`` term then drives
every parameter it touches towards a smaller ``S``. ``variance_score`` keeps it for the
parameters that shape the remnant's path to the stick (which the likelihood must see
to tell the gains from the remnant's level, ``K -> a K``, remnant ``-> n/a``) and drops
it for the others, which then follow the prediction-error gradient alone.

Limits are imposed by projection of the mean and of the bank points.

The kernels live in :mod:`~manualcontrol.estimators.members._rml_kernels`, imported on
first use (where the C port runs, an RML never imports numba); the records and the
constants the kernels read stay here.
"""

from __future__ import annotations

import math
from collections import namedtuple

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators._pilot_core import (  # noqa: F401  (the RML reads them here)
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_FLOOR,
    CFG_GAMMA2,
    CFG_MAX_COV,
    PAPERS_DT,
    SC_E,
    SC_FROZEN,
    SC_K,
)

#: Delay lines of the raw inputs: ``hist`` (n_in, H) ring of past samples (index
#: ``k % H``); ``delay_slot``: model-order index of the pilot delay; ``extra_slot``
#: (n_in,): index of a second delay added for that input (``tau_f*`` for ``ft_ahead``)
#: or -1; ``point_in`` (n_in,): the delayed inputs of one point (scratch).
DelayLines = namedtuple("DelayLines", ["hist", "delay_slot", "extra_slot", "point_in"])


# numba kernels read this module's constants
#: Special parameter slots of the bank (besides model-order indices >= 0).
SLOT_LOG_INTENSITY = -2
SLOT_LOG_BREAK = -3

INJECT_INPUT = 0
INJECT_OUTPUT = 1

#: ``cfg`` (the pilot filters' configuration vector); ``slot`` (n_t,): what each
#: parameter is (model-order index or a ``SLOT_*`` code); ``lo``, ``hi`` (n_t,): its
#: limits (internal values); ``q`` (n_t,): its random-walk variance (before
#: ``Gamma^2``); ``step``: ``h``; ``substeps``: Euler substeps a sample at this sample
#: time (the setting's are per 0.01 s, see
#: :func:`~manualcontrol.estimators._pilot_core.euler_substeps`); ``inject``:
#: ``INJECT_*``; ``has_remnant``; ``remnant`` (2,): the log relative intensity and the
#: log break frequency used when they are not estimated; ``estimated`` (n_p,) per model
#: parameter; ``noise_first``: samples at the start during which only the noise
#: parameters learn; ``base`` (2,): the log error variance the intensity is relative
#: to and the sample from which it is fixed (before it, on a causal start, the
#: variance of the samples so far; no parameter learns before it);
#: ``variance_score`` (n_p,) per model parameter: whether the variance part of the
#: score (the ``dS`` terms) moves it; ``spread_cap`` (n_t,): the largest offset of a
#: bank member from the mean in each parameter (inf: none); ``remnant_weight`` (2,):
#: ``r2_remnant`` and the model index of the gain the remnant passes (-1: none, at the
#: stick), :func:`_remnant_weight`.
BankConfig = namedtuple(
    "BankConfig",
    [
        "cfg",
        "slot",
        "lo",
        "hi",
        "q",
        "step",
        "substeps",
        "inject",
        "has_remnant",
        "remnant",
        "estimated",
        "noise_first",
        "base",
        "variance_score",
        "spread_cap",
        "drift_rule",
        "remnant_weight",
    ],
)
#: ``th``, ``P``: the parameter belief; ``X`` (m, ns), ``PX`` (m, ns, ns): the m bank
#: members' state beliefs (member 0 at ``th``, members ``1 + 2 j`` and ``2 + 2 j`` at
#: ``th +- h L e_j``); ``prev_in``, ``p``, ``sc`` as in the other pilot filters;
#: ``drift`` (4, n_t): per parameter the moving mean of its normalised corrections, of
#: their magnitude, the factor on its process noise and the means' accumulated weight
#: (:func:`_adapt_process_noise`).
BankBelief = namedtuple("BankBelief", ["th", "P", "X", "PX", "prev_in", "p", "sc", "drift"])
#: Scratch: ``L``, ``points`` (m, n_t), ``z``, ``S`` (m,), ``dz``, ``dS``, ``g`` (n_t,),
#: ``Lam``, ``LamL``, ``B`` (n_t, n_t), ``xi`` (1, n_t), ``Phi``, ``sub``, ``Q``, ``T``
#: (ns, ns), ``H`` (1, ns), ``r`` (1,), ``R`` (1, 1), ``work`` (the shared Kalman
#: correction's scratch, ``filters.kalman.kalman_work``), ``xs``, ``f``, ``F``
#: (model), ``dfdp``, ``dgdx``, ``dgdp``, ``point_p``, ``in_use``, ``variance``,
#: ``scalars``, ``h_dir`` (n_t,): the spread in use along each direction; ``prior``
#: (2, n_t): this sample's prior mean and standard deviation of each parameter.
BankScratch = namedtuple(
    "BankScratch",
    [
        "L",
        "points",
        "z",
        "S",
        "dz",
        "dS",
        "g",
        "Lam",
        "LamL",
        "B",
        "xi",
        "Phi",
        "sub",
        "Q",
        "T",
        "H",
        "r",
        "R",
        "work",
        "xs",
        "f",
        "F",
        "dfdp",
        "dgdx",
        "dgdp",
        "point_p",
        "in_use",
        "variance",
        "scalars",
        "h_dir",
        "prior",
    ],
)
#: Per-row outputs as the other pilot filters', the parameter belief before and after
#: each sample (random-walk smoothing), and ``extra`` (n, 3): the remnant estimate of
#: the centre filter, its intensity and break frequency.
BankOutput = namedtuple(
    "BankOutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "th_prior",
        "P_prior",
        "th_post",
        "P_post",
        "extra",
    ],
)


#: Accumulated weight of the drift rule's moving means before it acts: one window's
#: worth (``1 - 1/e``).
_FILLED = 1.0 - math.exp(-1.0)


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_read",
    "_delayed_inputs",
    "_member_parameters",
    "_member_step",
    "_bank_points",
    "_update_parameters",
    "_adapt_process_noise",
    "_remnant_weight",
    "bank_step",
    "bank_step_many",
    "bicubic_weights",
    "inputs_in_use",
    "noise_levels",
    "report_frozen",
    "report_row",
    "take",
    "joseph_correct",
    "predict_covariance",
    "cholesky",
    "cholesky_solve_rows",
    "symmetrise",
    "belief_health",
    "window_variance",
    "store_belief",
    "evaluate_coefficients",
    "model_f",
    "model_g",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._rml_kernels", _KERNELS
)
